"""Leave-one-effect-out validation: logs of the simulated reality with known effects, diagnosed
without being told, and scored.

A case is a set of injected effects (one catalogue effect at a "large", "small" or "faint"
magnitude, a pair, or one effect outside the catalogue) and a seed. Scores per case:
- top1: the first effect the selection adds is the injected one (a pair: the first two are the
  pair, in either order; an effect outside the catalogue: the verdict is "unexplained");
- located: the channel carrying the most excess is one the effect acts in (sim2real.catalogue
  places) and the phase with the most excess is the effect's ("free" for arm logs);
- closed: the fraction of the held-out gap (RMS toward the noise floor) the selection closes.
- explained: the verdict reads "explained" (what a catalogue effect should get).
The effects outside the catalogue live only here, the diagnosis never sees their definitions: a
position-periodic joint torque ripple (cogging-like), a drag quadratic in the joint speed, and a
torque-sensor offset drifting in time.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sim2real.catalogue import CATALOGUE
from sim2real.log import RobotLog

if TYPE_CHECKING:
    from sim2real.diagnosis import DiagnosisConfig

__all__ = [
    "Case",
    "MAGNITUDES",
    "FAINT",
    "PAIRS",
    "OUTSIDE_EFFECTS",
    "cases",
    "run_case",
    "rates_by_magnitude",
    "ripple_torque",
    "drag_torque",
    "drifting_sensor",
]

#: Per effect: (large, small) settings; per-joint values apply to every joint.
MAGNITUDES: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "coulomb": ({"fc": 1.0}, {"fc": 0.3}),
    "stribeck": ({"fs": 1.5, "vs": 0.05}, {"fs": 0.5, "vs": 0.05}),
    "viscous": ({"fv": 0.8}, {"fv": 0.25}),
    "rotor_inertia": ({"dI": 0.2}, {"dI": 0.06}),
    "payload": ({"dm": 1.0, "com_z": 0.08}, {"dm": 0.3, "com_z": 0.08}),
    "torque_offset": ({"offset": 0.8}, {"offset": 0.25}),
    "actuation_delay": ({"delay": 0.01}, {"delay": 0.004}),
    "torque_gain": ({"k": 0.85}, {"k": 0.95}),
    "torque_saturation": ({"s": 0.25}, {"s": 0.4}),
    "backlash": ({"b": 0.01}, {"b": 0.004}),
    "controller_gain": ({"kp_scale": 0.6}, {"kp_scale": 0.85}),
}
#: Per effect: a setting near the noise floor (the torque sensor's 0.05 N m): the held-out gain
#: such an effect can give is a fraction of a noise variance.
FAINT: dict[str, dict[str, Any]] = {
    "coulomb": {"fc": 0.08},
    "stribeck": {"fs": 0.15, "vs": 0.05},
    "viscous": {"fv": 0.05},
    "rotor_inertia": {"dI": 0.01},
    "payload": {"dm": 0.08, "com_z": 0.08},
    "torque_offset": {"offset": 0.06},
    "actuation_delay": {"delay": 0.001},
    "torque_gain": {"k": 0.99},
    "torque_saturation": {"s": 0.6},
    "backlash": {"b": 0.001},
    "controller_gain": {"kp_scale": 0.95},
}
PAIRS: tuple[tuple[str, str], ...] = (
    ("coulomb", "payload"),
    ("viscous", "torque_offset"),
    ("rotor_inertia", "actuation_delay"),
    ("coulomb", "torque_gain"),
)
RIPPLE_AMPLITUDE = 0.5  # [N m]
RIPPLE_PERIODS = 6.0  # periods per radian of joint travel
DRAG = 1.0  # [N m s^2/rad^2] the quadratic drag's coefficient
DRIFT = 0.4  # [N m] the torque sensors' offset drift over the log


def ripple_torque(
    q: NDArray[np.float64], dq: NDArray[np.float64], amplitude: float = RIPPLE_AMPLITUDE
) -> NDArray[np.float64]:
    """An out-of-catalogue effect: a joint torque ripple periodic in the joint angle (cogging, a
    worn gear tooth), acting on every joint: -A sin(2 pi n q), A = `amplitude` [N m]."""
    return -amplitude * np.sin(2 * np.pi * RIPPLE_PERIODS * np.asarray(q))


def drag_torque(q: NDArray[np.float64], dq: NDArray[np.float64], coefficient: float = DRAG) -> NDArray[np.float64]:
    """An out-of-catalogue effect: a drag growing with the square of the joint speed (a seal or
    lubricant shearing at speed), on every joint: -c dq |dq|. The catalogue's viscous friction fits
    most of it and leaves a function of the speed."""
    return -coefficient * np.asarray(dq) * np.abs(dq)


def drifting_sensor(log: RobotLog, drift: float = DRIFT) -> RobotLog:
    """An out-of-catalogue sensing effect: every torque sensor's offset drifts linearly from 0 to
    `drift` [N m] over the log (a strain gauge warming up). It acts on the measurement, where a
    sensor effect acts: the catalogue's constant offset fits its mean."""
    return dataclasses.replace(log, tau=log.tau + np.linspace(0.0, drift, log.n_samples)[:, None])


#: The effects outside the catalogue, which live only here: name -> (a joint torque acting in the
#: dynamics, or a change of the measurement) and the place it acts (for "located").
OUTSIDE_EFFECTS: dict[
    str, tuple[Callable[..., NDArray[np.float64]] | None, Callable[[RobotLog], RobotLog] | None, str]
] = {
    "ripple": (ripple_torque, None, "dynamics"),
    "drag": (drag_torque, None, "dynamics"),
    "drift": (None, drifting_sensor, "sensing"),
}


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    effects: tuple[str, ...]  # injected catalogue effects, or one of OUTSIDE_EFFECTS
    magnitude: str  # "large", "small", "faint", "pair", "outside"
    seed: int

    def settings(self, n_joints: int = 7) -> dict[str, dict[str, Any]]:
        out = {}
        for name in self.effects:
            if name in OUTSIDE_EFFECTS:
                continue
            large, small = MAGNITUDES[name]
            chosen = {"small": small, "faint": FAINT[name]}.get(self.magnitude, large)
            spec = CATALOGUE[name]
            out[name] = {k: ([v] * n_joints if spec.param(k).per_joint else v) for k, v in chosen.items()}
        return out


def cases(
    magnitudes: tuple[str, ...] = ("large", "small", "faint"),
    seeds: tuple[int, ...] = (0, 1),
    effects: tuple[str, ...] | None = None,
    pairs: bool = True,
    outside: bool = True,
) -> list[Case]:
    """The validation grid: every effect x magnitude x seed, then the pairs and the effects outside
    the catalogue (each seed)."""
    out = []
    for name in effects or tuple(MAGNITUDES):
        for mag in magnitudes:
            for seed in seeds:
                out.append(Case(f"{name}-{mag}-s{seed}", (name,), mag, seed))
    if pairs:
        for a, b in PAIRS:
            for seed in seeds:
                out.append(Case(f"{a}+{b}-s{seed}", (a, b), "pair", seed))
    if outside:
        for name in OUTSIDE_EFFECTS:
            for seed in seeds:
                out.append(Case(f"{name}-s{seed}", (name,), "outside", seed))
    return out


def _expected_channels(names: tuple[str, ...]) -> set[str]:
    chans: set[str] = set()
    for name in names:
        place = CATALOGUE[name].place if name in CATALOGUE else OUTSIDE_EFFECTS[name][2]
        chans |= {"dynamics": {"tau", "cmd"}, "sensing": {"tau"}, "actuation": {"cmd"}, "controller": {"ctrl"}}.get(
            place, set()
        )
        if name == "rotor_inertia":
            chans = (chans - {"tau"}) | {"cmd"}
    return chans


def run_case(case: Case, duration: float = 10.0, config: DiagnosisConfig | None = None) -> dict[str, Any]:
    """Make the case's log, diagnose it (with `config`; None: the defaults), score it; plain data."""
    from sim2real.diagnosis import diagnose
    from sim2real.reality import RealityConfig, make_arm_log

    start = time.perf_counter()
    outside = case.effects[0] if case.effects[0] in OUTSIDE_EFFECTS else None
    extra, sense, _ = OUTSIDE_EFFECTS.get(outside, (None, None, ""))
    log = make_arm_log(case.settings(), RealityConfig(duration=duration, seed=case.seed), extra_torque=extra)
    if sense is not None:
        log = sense(log)
    made = time.perf_counter() - start
    d = diagnose(log, config)
    s = d.summary()
    chosen = [r["effect"] for r in s["selected"]]
    active = True
    if s["verdict"]["label"] == "no gap" and outside is None:
        # an effect the trajectory never triggers (a saturation level it never reaches) leaves
        # the log as the nominal one, sample for sample: "no gap" is then the right answer
        nominal = make_arm_log({}, RealityConfig(duration=duration, seed=case.seed))
        active = not all(np.array_equal(getattr(log, f), getattr(nominal, f)) for f in ("q", "dq", "tau", "tau_cmd"))
    carry = s["where"]["channels"][0]["channel"] if s["where"]["channels"] else ""
    structure = s["verdict"].get("structure", [])
    if outside is not None:
        top1 = s["verdict"]["label"] == "unexplained"
    elif not active:
        top1 = True
    else:
        k = len(case.effects)
        top1 = set(chosen[:k]) == set(case.effects)
    located = (carry in _expected_channels(case.effects) and s["where"]["dominant_phase"] == "free") or not active
    return {
        "case": case.name,
        "effects": list(case.effects),
        "magnitude": case.magnitude,
        "seed": case.seed,
        "active": active,
        "selected": chosen,
        "verdict": s["verdict"]["label"],
        "top1": bool(top1),
        "structure_left": [st["basis"] for st in structure if st["left"]],
        "structure": [{k: st[k] for k in ("basis", "gain", "low", "share", "share_rest")} for st in structure],
        "located": bool(located),
        "top_channel": carry,
        "closed": s["how_far"]["closed_total"],  # None: no gap above the floor
        "heldout_before": s["verdict"]["heldout_before"],
        "heldout_after": s["verdict"]["heldout_after"],
        "make_s": made,
        "diagnose_s": time.perf_counter() - start - made,
    }


def rates_by_magnitude(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Rates per magnitude group: top1, located, closed >= 0.8 (catalogue cases), flagged (ripple);
    `inactive` counts cases whose effect never acted (their log is the nominal one; scored right
    when the verdict is "no gap")."""
    out: dict[str, Any] = {}
    for mag in ("large", "small", "faint", "pair", "outside"):
        rows = [r for r in results if r["magnitude"] == mag]
        if not rows:
            continue
        gaps = [r["closed"] for r in rows if r["closed"] is not None]
        out[mag] = {
            "cases": len(rows),
            "top1": float(np.mean([r["top1"] for r in rows])),
            "located": float(np.mean([r["located"] for r in rows])),
            "no_gap": len(rows) - len(gaps),
            "inactive": sum(not r.get("active", True) for r in rows),
            "explained": float(np.mean([r["verdict"] == "explained" for r in rows])),
            "closed_median": float(np.median(gaps)) if gaps else None,
            "closed_ge_80": float(np.mean([g >= 0.8 for g in gaps])) if gaps else None,
        }
    per_effect: dict[str, dict[str, Any]] = {}
    for r in results:
        if r["magnitude"] in ("large", "small", "faint"):
            e = per_effect.setdefault(
                f"{r['effects'][0]} ({r['magnitude']})",
                {"n": 0, "top1": 0.0, "located": 0.0, "closed": [], "inactive": 0},
            )
            e["n"] += 1
            e["inactive"] += int(not r.get("active", True))
            e["top1"] += r["top1"] / 1.0
            e["located"] += r["located"] / 1.0
            if r["closed"] is not None:
                e["closed"].append(r["closed"])
    for e in per_effect.values():
        e["top1"] /= e["n"]
        e["located"] /= e["n"]
        e["no_gap"] = e["n"] - len(e["closed"])
        e["closed"] = float(np.mean(e["closed"])) if e["closed"] else None
    out["per_effect"] = per_effect
    return out
