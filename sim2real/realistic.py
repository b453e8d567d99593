"""The realistic validation grid: torque-only logs with the Panda's sensors and logger, at set SNRs.

Each case is a log as the real Panda log is: q, dq and link-side tau_J only, the simulated
reality's motion of the bare arm recorded by the calibrated logger (`sim2real.logger.PANDA_LOGGER`:
jittered polling, stale repeats, gaps, coloured speed-dependent torque noise with the vibration
band), written in the real log's folder layout (Gaz et al.) or the Franka CSV layout and read back.
An effect's size is set by its in-band SNR: the RMS over the joints of (the effect's torque below
the analysis band's edge) / (the in-band noise), both per joint, measured on noise-free and
noise-only logs of the same seed. Groups:

- single catalogue effects the log can show, at SNR 8 and 2.5: named right when the first selected
  effect is the injected one;
- pairs at SNR 8 each: both named as the first two;
- noise only: named right when the verdict is "no gap"; the floor's check (predicted / observed
  in-band residual per joint);
- effects outside the catalogue at SNR 8 (a ripple in the joint angle, a drag quadratic in speed,
  a drifting sensor offset): named right when the verdict is "unexplained".

"Where" is right when the joint ranked first carries the largest effect torque (in N m), or one
within 10 % of it (an effect of one size on every joint is a near tie).
"""

from __future__ import annotations

import dataclasses
import functools
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim2real.catalogue import CATALOGUE
from sim2real.log import RobotLog
from sim2real.validation import drag_torque, drifting_sensor, ripple_torque

__all__ = [
    "UNIT_SETTINGS",
    "REALISTIC_PAIRS",
    "SNRS",
    "RealisticCase",
    "realistic_cases",
    "make_case_log",
    "run_realistic",
    "summarize_realistic",
]

Array = NDArray[np.float64]

#: Per effect a torque-only log can show: a setting whose torque the SNR scales; `SCALED` names the
#: parameters scaled (their deviation from the catalogue's `none`); the others keep their value.
UNIT_SETTINGS: dict[str, dict[str, Any]] = {
    "coulomb": {"fc": 0.2, "v_smooth": 0.05},
    "stribeck": {"fs": 0.3, "vs": 0.05},
    "viscous": {"fv": 0.1},
    "payload": {"dm": 0.3, "com_z": 0.08},
    "torque_offset": {"offset": 0.1},
    # one link heavier and another's centre of mass moved: a uniform scale of every link's mass and
    # inertia is a scale of the rigid-body torque, which a torque-only log cannot tell from a
    # torque sensor's scale (that direction is in the identifiability warnings, not in the grid)
    "link_inertia": {
        "mass_scale": [1.0, 1.0, 1.0, 1.1, 1.0, 1.0, 1.0],
        "com_shift": [0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.0],
    },
    "torque_scale": {"k": 0.97},
    "torque_delay": {"d": 0.005},
    "joint_inertia": {"dJ": 0.05},
    "backlash_motor": {"b": 0.005},
}
SCALED: dict[str, tuple[str, ...]] = {
    "coulomb": ("fc",),
    "stribeck": ("fs",),
    "viscous": ("fv",),
    "payload": ("dm",),
    "torque_offset": ("offset",),
    "link_inertia": ("mass_scale", "com_shift"),
    "torque_scale": ("k",),
    "torque_delay": ("d",),
    "joint_inertia": ("dJ",),
    "backlash_motor": ("b",),
}
#: Effects outside the catalogue: a unit size of their one parameter (the functions live in
#: sim2real.validation; the diagnosis never sees them).
OUTSIDE_UNITS: dict[str, float] = {"ripple": 0.1, "drag": 0.2, "drift": 0.2}
REALISTIC_PAIRS: tuple[tuple[str, str], ...] = (
    ("coulomb", "payload"),
    ("viscous", "torque_offset"),
    ("link_inertia", "coulomb"),
    ("torque_scale", "joint_inertia"),
)
SNRS: tuple[float, ...] = (8.0, 2.5)


@dataclasses.dataclass(frozen=True)
class RealisticCase:
    """kind: "single", "pair", "noise" or "outside"; snr: each effect's in-band SNR (None for
    noise); layout: "gaz" (the real log's folder) or "csv" (Franka's)."""

    name: str
    effects: tuple[str, ...]
    kind: str
    snr: float | None
    seed: int
    layout: str


def realistic_cases(
    seeds: tuple[int, ...] = (0, 1, 2), effects: tuple[str, ...] | None = None, noise_seeds: int = 2
) -> list[RealisticCase]:
    """The grid: every torque-only effect x SNR x seed, the pairs, `noise_seeds` noise-only logs per
    seed and the effects outside the catalogue; layouts alternate with the seed."""
    out = []
    layout = lambda seed: "gaz" if seed % 2 == 0 else "csv"  # noqa: E731
    for name in effects or tuple(UNIT_SETTINGS):
        for snr in SNRS:
            for seed in seeds:
                out.append(RealisticCase(f"{name}-snr{snr:g}-s{seed}", (name,), "single", snr, seed, layout(seed)))
    if effects is None:
        for a, b in REALISTIC_PAIRS:
            for seed in seeds:
                out.append(RealisticCase(f"{a}+{b}-s{seed}", (a, b), "pair", SNRS[0], seed, layout(seed)))
    for seed in seeds:
        for k in range(noise_seeds):
            s = seed + 100 * k
            out.append(RealisticCase(f"noise-s{s}", (), "noise", None, s, layout(s)))
    for name in OUTSIDE_UNITS:
        for seed in seeds:
            out.append(RealisticCase(f"{name}-s{seed}", (name,), "outside", SNRS[0], seed, layout(seed)))
    return out


# ---------------------------------------------------------------------------------------------- logs


def _reality(duration: float, seed: int, sensors: str, noise: bool = True):
    from sim2real.reality import RealityConfig

    return RealityConfig(duration=duration, seed=seed, end_effector="none", sensors=sensors, noise=noise)


def _torque_only(log: RobotLog) -> RobotLog:
    meta = {k: v for k, v in log.meta.items() if k != "controller"}
    return dataclasses.replace(log, tau_cmd=None, q_cmd=None, dq_cmd=None, meta=meta)


def _outside(name: str, size: float) -> tuple[Any, Any]:
    """(extra joint torque, change of the measurement) of an effect outside the catalogue."""
    if name == "ripple":
        return functools.partial(ripple_torque, amplitude=size), None
    if name == "drag":
        return functools.partial(drag_torque, coefficient=size), None
    return None, functools.partial(drifting_sensor, drift=size)


def _band_residual(log: RobotLog) -> tuple[Array, Any, NDArray[np.bool_]]:
    """The tau channel's band-limited residual of a torque-only log as the diagnosis sees it."""
    from sim2real.band import choose_band
    from sim2real.clean import clean
    from sim2real.replay import ReplayConfig, replay

    cleaned = clean(log)
    rep = replay(cleaned.log, ReplayConfig(velocity_source="q"))
    band = choose_band(rep.dq, rep.dt)
    valid = band.inner(rep.valid & cleaned.fresh)
    return band.filter(rep.residual["tau"]), band, valid


@functools.lru_cache(maxsize=8)
def _nominal(duration: float, seed: int) -> tuple[Array, Array]:
    """The noise-free nominal log's band-limited residual (T, 7) and the in-band noise (7,) that
    the logger leaves (the noise-only log's band-limited residual spread)."""
    from sim2real.reality import make_arm_log

    clean_res, _, valid = _band_residual(_torque_only(make_arm_log({}, _reality(duration, seed, "ideal", False))))
    noisy_res, _, nvalid = _band_residual(_torque_only(make_arm_log({}, _reality(duration, seed, "panda"))))
    return clean_res, np.std(noisy_res[nvalid], axis=0)


def _effect_torque(effects: dict[str, dict[str, Any]], extra: Any, sense: Any, duration: float, seed: int) -> Array:
    """The in-band RMS per joint (7,) of what the effects add to the tau residual (noise-free)."""
    from sim2real.reality import make_arm_log

    log = _torque_only(make_arm_log(effects, _reality(duration, seed, "ideal", False), extra_torque=extra))
    if sense is not None:
        log = sense(log)
    res, _, valid = _band_residual(log)
    base, _ = _nominal(duration, seed)
    return np.sqrt(np.mean((res - base)[valid] ** 2, axis=0))


def _scale(name: str, factor: float) -> dict[str, Any]:
    """The effect's unit setting with its scaled parameters' deviation from `none` times factor,
    within the catalogue's range."""
    spec = CATALOGUE[name]
    out = dict(UNIT_SETTINGS[name])
    for key in SCALED[name]:
        p = spec.param(key)
        value = np.clip(p.none + (np.asarray(out[key], dtype=float) - p.none) * factor, p.low, p.high)
        out[key] = value.tolist() if value.ndim else float(value)
    return out


def _snr(torque: Array, noise: Array) -> float:
    return float(np.sqrt(np.mean((torque / noise) ** 2)))


def make_case_log(
    case: RealisticCase, duration: float = 20.0, folder: str | Path | None = None
) -> tuple[RobotLog, dict[str, Any]]:
    """The case's torque-only realistic log, written in its layout under `folder` (None: a
    temporary folder) and read back, and its truth: the settings, each effect's SNR, the in-band
    effect torque per joint and the in-band noise per joint."""
    from sim2real.importers import load_log, write_franka_csv, write_gaz_layout
    from sim2real.reality import make_arm_log

    _, noise = _nominal(duration, case.seed)
    settings: dict[str, dict[str, Any]] = {}
    extra = sense = None
    snrs = {}
    for name in case.effects:
        if case.kind == "outside":
            unit = OUTSIDE_UNITS[name]
            e, s = _outside(name, unit)
            factor = case.snr / max(_snr(_effect_torque({}, e, s, duration, case.seed), noise), 1e-9)
            extra, sense = _outside(name, unit * factor)
        else:
            unit = _effect_torque({name: UNIT_SETTINGS[name]}, None, None, duration, case.seed)
            settings[name] = _scale(name, case.snr / max(_snr(unit, noise), 1e-9))
    torque = _effect_torque(settings, extra, sense, duration, case.seed) if case.effects else np.zeros(7)
    for name in case.effects:
        alone = (
            torque
            if len(case.effects) == 1
            else _effect_torque({name: settings[name]}, None, None, duration, case.seed)
        )
        snrs[name] = _snr(alone, noise)
    log = _torque_only(make_arm_log(settings, _reality(duration, case.seed, "panda"), extra_torque=extra))
    if sense is not None:
        log = sense(log)
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(folder) if folder is not None else Path(tmp)
        path = (
            write_gaz_layout(log, where / case.name)
            if case.layout == "gaz"
            else write_franka_csv(log, where / f"{case.name}.csv")
        )
        loaded = load_log(path)
    truth = {
        "settings": settings,
        "snr": snrs,
        "effect_torque": torque.tolist(),
        "noise": noise.tolist(),
        "largest_joint": int(np.argmax(torque)) + 1 if case.effects else None,
    }
    return loaded, truth


# ---------------------------------------------------------------------------------------------- scoring


def run_realistic(case: RealisticCase, duration: float = 20.0, config: Any = None) -> dict[str, Any]:
    """Make the case's log, diagnose it without its truth, score it; plain data."""
    from sim2real.diagnosis import diagnose

    start = time.perf_counter()
    log, truth = make_case_log(case, duration)
    made = time.perf_counter() - start
    d = diagnose(log, config)
    s = d.summary()
    chosen = [r["effect"] for r in s["selected"]]
    label = s["verdict"]["label"]
    if case.kind == "noise":
        right = label == "no gap"
    elif case.kind == "outside":
        right = label == "unexplained"
    else:
        right = set(chosen[: len(case.effects)]) == set(case.effects)
    tau = [r for r in s["where"]["channels"] if r["channel"] == "tau"]
    torque = np.asarray(truth["effect_torque"])
    # right when the joint ranked first carries the largest effect torque, or one within 10 % of it
    # (a friction of one level on every joint is a near tie between joints)
    where_right = (
        None if truth["largest_joint"] is None else bool(tau and torque[tau[0]["joint"] - 1] >= 0.9 * torque.max())
    )
    a = d.arrays
    ci = list(d.channels).index("tau")
    observed = np.std(a["residual"][a["valid"], ci], axis=0)
    floor = a["floor"][ci]
    return {
        "case": case.name,
        "kind": case.kind,
        "effects": list(case.effects),
        "snr": case.snr,
        "seed": case.seed,
        "layout": case.layout,
        "truth": truth,
        "selected": chosen,
        "verdict": label,
        "right": bool(right),
        "where_right": where_right,
        "top_joint": tau[0]["joint"] if tau else None,
        "floor_ratio": (floor / observed).tolist(),
        "closed": s["verdict"].get("closed"),
        "selected_params": {
            r["effect"]: {k: v["value"] for k, v in r["params"].items() if k != "base"} for r in s["selected"]
        },
        "make_s": made,
        "diagnose_s": time.perf_counter() - start - made,
    }


def summarize_realistic(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Per group (single at each SNR, pair, noise, outside): cases, named right, where right; for
    the noise-only logs the floor's predicted / observed in-band residual per joint (mean and
    range over the logs)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        key = f"single SNR {r['snr']:g}" if r["kind"] == "single" else r["kind"]
        groups.setdefault(key, []).append(r)
    out: dict[str, Any] = {}
    for key, rows in groups.items():
        where = [r["where_right"] for r in rows if r["where_right"] is not None]
        out[key] = {
            "cases": len(rows),
            "right": float(np.mean([r["right"] for r in rows])),
            "where_right": float(np.mean(where)) if where else None,
            "verdicts": {v: sum(r["verdict"] == v for r in rows) for v in ("explained", "unexplained", "no gap")},
            "diagnose_s_median": float(np.median([r["diagnose_s"] for r in rows])),
        }
    noise = [r["floor_ratio"] for r in results if r["kind"] == "noise"]
    if noise:
        x = np.asarray(noise)
        out["floor_check"] = {
            "logs": len(noise),
            "mean": x.mean(axis=0).tolist(),
            "min": x.min(axis=0).tolist(),
            "max": x.max(axis=0).tolist(),
        }
    per_effect: dict[str, dict[str, Any]] = {}
    for r in results:
        if r["kind"] == "single":
            e = per_effect.setdefault(
                f"{r['effects'][0]} (SNR {r['snr']:g})", {"n": 0, "right": 0, "where": 0, "missed_as": []}
            )
            e["n"] += 1
            e["right"] += int(r["right"])
            e["where"] += int(bool(r["where_right"]))
            if not r["right"]:
                e["missed_as"].append(r["selected"][:1] or [r["verdict"]])
    out["per_effect"] = per_effect
    return out
