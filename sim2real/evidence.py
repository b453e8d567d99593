"""The evidence: a log cleaned, replayed and seen through the band, as the analysis needs it.

`arm_evidence` runs the stages a log meets before the analysis, in order: load-and-clean
(sim2real/clean.py), replay against the nominal arm (sim2real/replay.py: the end effector and the
velocity source chosen by the data where the log does not say), the analysis band and its noise
floor (sim2real/band.py), the state regions, the catalogue's candidates the log's channels can show
(sim2real/effects.py) and the model audit's terms. The station (sim2real/contact.py) and the
perception channel (sim2real/perception_channel.py) make their own `Evidence`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim2real.arm import END_EFFECTORS, ArmModel
from sim2real.band import Band, BandConfig, band_candidate, band_floor, band_pool, choose_band, noise_floor
from sim2real.clean import clean
from sim2real.config import DiagnosisConfig
from sim2real.effects import Candidate, candidates, untestable
from sim2real.fitting import Design
from sim2real.log import RobotLog
from sim2real.phases import segment_phases
from sim2real.replay import Replay, replay
from sim2real.selection import score
from sim2real.structure import hat_basis, trend_basis

__all__ = ["Evidence", "ARM_FLOOR_MIN", "arm_evidence", "arm_regions"]

Array = NDArray[np.float64]


@dataclasses.dataclass
class Evidence:
    """What the analysis needs from a replayed log, whatever the model.

    residual: channel -> (T, 7) measured minus nominal; labels: channel -> the 7 columns' names;
    valid: (T,) samples the fits use; phase: (T,) labels indexing PHASES; regions: name -> (T, 7)
    state-region masks; pool: effect -> its candidates; audit: the model audit (or None);
    x: (T, 7) what the residual figure plots it against, x_label its name; time: (T,); floor_min:
    the least noise floor per channel; floor: a channel's noise floor when the evidence knows it
    (else it is estimated from the residual by `noise_floor`); reach: the residual noise's
    correlation length in samples, where known (`noise_floor`); structure: bases (T, 7, K) of the
    state in which the verdict looks for structure the selection left (sim2real/structure.py)."""

    residual: dict[str, Array]
    labels: dict[str, list[str]]
    valid: NDArray[np.bool_]
    phase: NDArray[np.int64]
    regions: dict[str, NDArray[np.bool_]]
    pool: dict[str, list[Candidate]]
    audit: Callable[..., list[dict[str, Any]]] | None
    x: Array
    x_label: str
    time: Array
    meta: dict[str, Any]
    floor_min: dict[str, float | Array] = dataclasses.field(default_factory=dict)
    notes: list[str] = dataclasses.field(default_factory=list)
    floor: dict[str, Array] = dataclasses.field(default_factory=dict)
    reach: int | None = None
    structure: dict[str, Array] = dataclasses.field(default_factory=dict)
    preprocessing: dict[str, Any] = dataclasses.field(default_factory=dict)


#: The least noise floor per arm channel: a torque resolution of 1e-3 N m (a channel the model
#: reproduces to rounding, as the control law does, is not infinitely precise evidence).
ARM_FLOOR_MIN: dict[str, float] = {"tau": 1e-3, "cmd": 1e-3, "ctrl": 1e-3, "dq": 1e-5}


def arm_regions(rep: Replay) -> dict[str, NDArray[np.bool_]]:
    """State regions per joint (T, 7) masks: velocity sign, reversals, speed, load."""
    dq = rep.dq
    load = np.abs(rep.terms.total)
    lo, hi = np.quantile(load[rep.valid], [1 / 3, 2 / 3], axis=0)
    speed = np.abs(dq)
    return {
        "dq>0": dq > 0,
        "dq<0": dq < 0,
        "reversal (|dq|<0.05)": speed < 0.05,
        "slow (0.05-0.3)": (speed >= 0.05) & (speed < 0.3),
        "medium (0.3-1)": (speed >= 0.3) & (speed < 1.0),
        "fast (>1 rad/s)": speed >= 1.0,
        "load low": load < lo,
        "load mid": (load >= lo) & (load < hi),
        "load high": load >= hi,
    }


def _nominal_fit(rep: Replay) -> float:
    """The torque channels' residual mean square relative to the measured torque's, summed over
    joints (scale-free: every joint counts alike)."""
    total = 0.0
    signals = {"tau": rep.log.tau, "cmd": rep.tau_cmd}
    for ch in ("tau", "cmd"):
        if ch in rep.residual:
            r = rep.residual[ch][rep.valid]
            x = signals[ch][rep.valid]
            total += float(np.sum(np.mean(r**2, axis=0) / np.maximum(np.mean(x**2, axis=0), 1e-12)))
    return total


def arm_evidence(log: RobotLog, config: DiagnosisConfig | None = None) -> Evidence:
    """The arm's evidence: the log cleaned (stale repeats dropped, a uniform grid: sim2real/clean.py),
    replayed against the nominal model, seen through the analysis band with its noise floor
    (sim2real/band.py; `config.band` None: every sample, the fast-part/variogram floor), its state
    regions and the catalogue's arm effects the log's channels can show."""
    c = config or DiagnosisConfig()
    cleaned = clean(log, c.clean)
    log = cleaned.log
    notes = list(cleaned.notes)
    ees = (
        ["none", "hand"]
        if c.replay.end_effector is None
        and (log.meta.get("end_effector") is None or log.meta.get("end_effector_assumed"))
        else [None]
    )
    sources = ["q", "dq"] if c.band is not None else [c.replay.velocity_source]
    options = {
        (ee, src): replay(
            log, dataclasses.replace(c.replay, end_effector=ee or c.replay.end_effector, velocity_source=src)
        )
        for ee in ees
        for src in sources
    }
    if len(ees) > 1:
        # the log does not say what the arm carries: the bare arm or the hand, whichever the
        # nominal residual supports (a held gear or tool shows as a payload effect)
        score = {ee: _nominal_fit(options[(ee, sources[0])]) for ee in ees}
        best = min(score, key=score.get)
        notes.append(
            f"the log does not state its end effector; the data support {best!r} "
            f"(nominal residual {score[best]:.3g} against {max(score.values()):.3g})"
        )
        options = {k: r for k, r in options.items() if k[0] == best}
    if len(sources) > 1:
        # the velocity and acceleration from the encoder's position or from the measured velocity,
        # whichever leaves the less noise in the band (a log's position can carry its stamps'
        # rounding; its velocity the noise of the robot's own estimate)
        probe = {src: _band_noise(r, c.band) for (ee, src), r in options.items()}
        chosen_source = min(probe, key=probe.get)
        notes.append(
            f"velocity and acceleration from the measured {'position' if chosen_source == 'q' else 'velocity'}"
            f" (its in-band torque noise {probe[chosen_source]:.3g} N m, geometric mean over joints, against "
            f"{max(probe.values()):.3g} from the {'velocity' if chosen_source == 'q' else 'position'})"
        )
        options = {k: r for k, r in options.items() if k[1] == chosen_source}
    rep = next(iter(options.values()))
    rep.valid &= cleaned.fresh
    phase = segment_phases(rep.log)
    if rep.log.phase is None and np.any(phase != 0):
        notes.append("the log has no phase labels: phases segmented from its external force (sim2real/phases.py)")
    labels = {ch: [f"joint {j + 1}" for j in range(7)] for ch in rep.channels}
    meta = {**log.meta, "end_effector": rep.model.end_effector}
    pool = candidates(rep, c.effects)
    structure = {"joint velocity": hat_basis(rep.dq), "time": trend_basis(rep.log.time, 7)}
    preprocessing: dict[str, Any] = {
        "clean": cleaned.report,
        "nominal_damping": rep.model.damping.tolist(),
        "untestable": {k: v for k, v in untestable(rep).items() if c.effects is None or k in c.effects},
    }
    if c.band is None:
        # the filtered torque channels' noise: kernel-smoothed white noise's share of the fast
        # part, or the variogram's nugget (noise_floor)
        floor = {
            ch: noise_floor(rep.residual[ch], rep.valid, kernel=rep.kernel, reach=rep.reach) for ch in rep.unfiltered
        }
        return Evidence(
            residual=rep.residual,
            labels=labels,
            valid=rep.valid,
            phase=phase,
            regions=arm_regions(rep),
            pool=pool,
            audit=functools.partial(_arm_audit, rep, None),
            x=rep.log.dq,
            x_label="dq [rad/s]",
            time=rep.log.time,
            meta=meta,
            floor_min=dict(ARM_FLOOR_MIN),
            notes=notes,
            floor=floor,
            reach=rep.reach,
            structure=structure,
            preprocessing=preprocessing,
        )
    band = choose_band(rep.dq, rep.dt, c.band)
    valid = band.inner(rep.valid)
    floor = {}
    detail = {}
    for ch in rep.channels:
        floor[ch], detail[ch] = band_floor(
            rep.residual[ch], valid, band, rep.kernel if ch in rep.unfiltered else None, *_derivative(rep, ch)
        )
    preprocessing["band"] = band.summary()
    preprocessing["floor"] = {ch: {"in_band": floor[ch].tolist(), **detail[ch]} for ch in rep.channels}
    notes.append(
        f"the residual is judged below {band.cutoff:.3g} Hz ({band.reason}), sampled at "
        f"{1.0 / (band.dt * band.stride):.3g} Hz; noise floor from its spectrum in "
        f"{band.cutoff:.3g}-{band.reference * band.cutoff:.3g} Hz"
    )
    return Evidence(
        residual={ch: band.apply(r) for ch, r in rep.residual.items()},
        labels=labels,
        valid=band.rows(valid),
        phase=band.rows(phase),
        regions={k: band.rows(m) for k, m in arm_regions(rep).items()},
        pool=band_pool(pool, band),
        audit=functools.partial(_arm_audit, rep, band),
        x=band.rows(rep.dq),
        x_label="dq [rad/s]",
        time=band.rows(rep.log.time),
        meta=meta,
        floor_min=dict(ARM_FLOOR_MIN),
        notes=notes,
        floor=floor,
        reach=None,
        structure={k: band.apply(b) for k, b in structure.items()},
        preprocessing=preprocessing,
    )


def _band_noise(rep: Replay, config: BandConfig) -> float:
    """The geometric mean over joints of a replay's in-band noise floor in its first torque channel,
    read flat from the reference band (one rule for both sources: a fair comparison)."""
    ch = next((c for c in ("tau", "cmd") if c in rep.residual), rep.channels[0])
    band = choose_band(rep.dq, rep.dt, config)
    floor, _ = band_floor(rep.residual[ch], band.inner(rep.valid), band, rep.kernel if ch in rep.unfiltered else None)
    return float(np.exp(np.mean(np.log(floor))))


def _derivative(rep: Replay, channel: str) -> tuple[int | None, int, Array | None, Array | None]:
    """What band_floor needs of the acceleration a torque channel's prediction holds, where its
    noise rises with frequency: the derivative's order, its window, the measurement differentiated
    and the mass matrix it enters through (the links', plus the reflected rotor inertia where the
    channel holds it). Only for a velocity differentiated once (its noise rising as f^2 into the
    band: the Panda's velocity estimate); an encoder's position, differentiated twice, adds little
    in the band, and a spectrum rising at the reference band's top (the arm's vibration setting in)
    would be read as its f^4 noise: (None, ...), the floor read flat, as for other channels."""
    if channel not in ("tau", "cmd") or rep.velocity_source == "q":
        return None, rep.window, None, None
    rotor = channel == "cmd" or rep.rotor_in_tau
    mass = rep.terms.mass + (np.eye(7)[None] * rep.model.reflected_inertia[None, :, None] if rotor else 0.0)
    return 1, rep.window, rep.log.dq, mass


# ---------------------------------------------------------------------------------------------- the audit


def term_candidate(rep: Replay, name: str, torque: Array, channels: tuple[str, ...] = ("tau", "cmd")) -> Candidate:
    """A fixed change of the model's torque prediction by `torque` (T, 7) in `channels` and dq."""
    off: dict[str, Array] = {}
    for c in channels:
        if c in rep.residual:
            off[c] = torque
    if "dq" in rep.residual:
        off["dq"] = -rep.forward(torque)
    return Candidate(name, {}, {}, off, [], np.zeros((0, 2)), lambda coef: {})


def audit_verdict(change: str, after: float, before: float) -> str:
    better = after < before * 0.98
    if change.startswith("with "):  # a term the model leaves out, put in
        return "the log asks for it: the model is missing it" if better else "the model is right to leave it out"
    if change.startswith("without "):
        return "the model makes the fit worse here" if better else "the model term is supported"
    return "the log fits the alternative better" if better else "the model's choice is supported"


def _arm_audit(
    rep: Replay, band: Band | None, design: Design, folds, base_sse: Array, excess0: float, n_rows: Array
) -> list[dict[str, Any]]:
    terms = rep.terms
    items = [("without the joint damping", -terms.damping, ("tau", "cmd"))]
    if rep.rotor_in_tau:
        items.append(("without the reflected rotor inertia", -terms.rotor, ("tau", "cmd")))
    else:
        items.append(("without the reflected rotor inertia (motor side)", -terms.rotor, ("cmd",)))
        items.append(("with the reflected rotor inertia in the measured torque", terms.rotor, ("tau",)))
    ee = rep.model.end_effector
    for other in END_EFFECTORS:
        if other == ee or (other.startswith("hand+gear") and not ee.startswith("hand")):
            continue
        if other.startswith("hand+gear") and other != "hand+gear_medium" and ee != "hand":
            continue
        alt = ArmModel(other).terms(rep.q, rep.dq, rep.ddq)
        items.append((f"end effector {other!r} instead of {ee!r}", alt.rigid - terms.rigid, ("tau", "cmd")))
    out = []
    base = base_sse.sum() / n_rows.sum()
    for label, torque, chans in items:
        if not np.any(torque) or not any(ch in rep.residual for ch in chans):
            continue
        cand = term_candidate(rep, label, torque, chans)
        if band is not None:
            cand = band_candidate(cand, band, {})
        s = score(design, [cand], folds)
        e = s.sse.sum() / n_rows.sum()
        out.append(
            {
                "change": label,
                "heldout_before": base,
                "heldout_after": float(e),
                "closed": float((base - e) / max(excess0, 1e-12)),
                "verdict": audit_verdict(label, e, base),
            }
        )
    out.sort(key=lambda r: r["heldout_after"])
    return out
