"""The diagnosis of an insertion log against the station: the contact and grasp effects.

The log is replayed open loop in the nominal station (sim2real.station_logs.replay_insertion: the
logged impedance targets from the logged start), which gives two residual channels: "tau", the
arm's joint torques, and "tool", the tool position (x, y, z) and the contact wrench on the gear
(fx, fy, fz, mz). Each contact/grasp effect is replayed at a grid of values; a value's prediction
is its replay minus the nominal one, so the same blocked cross-validation, selection and verdict
as for the arm (sim2real.diagnosis.analyse) name the effect and say how far it closes the gap,
per phase. The downstream figure is the shipped skill's success rate in the nominal station and
in the station with the selected effect at its fitted value (and, when a caller knows the truth,
in the "real" one).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from goflow_common.errors import InputError
from sim2real.diagnosis import Diagnosis, DiagnosisConfig, Evidence, Progress, analyse
from sim2real.effects import Candidate
from sim2real.log import RobotLog
from sim2real.phases import segment_phases

__all__ = ["GRIDS", "TOOL_COLUMNS", "station_evidence", "diagnose_insertion", "downstream"]

#: The values each station effect is replayed at (the catalogue's ranges).
GRIDS: dict[str, tuple[float, ...]] = {
    "shaft_friction": (0.1, 0.2, 0.5, 0.7, 1.0, 1.3),
    "hydroelastic_modulus": (0.1, 0.3, 3.0, 10.0),
    "hydroelastic_dissipation": (2.0, 8.0, 35.0, 50.0),
    "grasp_slip": (0.05, 0.1, 0.2, 0.5),
}
TOOL_COLUMNS = ["x", "y", "z", "fx", "fy", "fz", "mz"]
Array = NDArray[np.float64]


def _signals(log: RobotLog) -> dict[str, Array]:
    if log.tool_pose is None or log.wrench is None or log.tau is None:
        raise InputError(
            "an insertion log needs tau, tool_pose and wrench; expected a log made by "
            "sim2real.station_logs.make_insertion_log or one with the same fields"
        )
    # position (x, y, z) [m], contact force (fx, fy, fz) [N] and torque about z [N m] (world axes)
    tool = np.concatenate([log.tool_pose[:, :3, 3], log.wrench[:, :3], log.wrench[:, 5:6]], axis=1)
    return {"tau": log.tau, "tool": tool}


def _offset_candidate(
    name: str, param: str, value: float, sim: dict[str, Array], nominal: dict[str, Array]
) -> Candidate:
    off = {ch: sim[ch] - nominal[ch] for ch in nominal}
    return Candidate(name, {param: value}, {}, off, [], np.zeros((0, 2)), lambda coef, p=param, v=value: {p: v})


def station_evidence(
    log: RobotLog, effects: tuple[str, ...] | None = None, progress: Progress | None = None
) -> Evidence:
    """Replay `log` nominally and with each station effect on its grid; the evidence for analyse."""
    from sim2real.catalogue import CATALOGUE
    from sim2real.station_logs import replay_insertion

    say = progress or (lambda what, i, n: None)
    names = [n for n in (effects or tuple(GRIDS)) if n in GRIDS]
    if effects and not names:
        raise InputError(f"effects {list(effects)}: none is a station effect; expected some of {list(GRIDS)}")
    total = 1 + sum(len(GRIDS[n]) for n in names)
    done = 0
    say("replays", done, total)
    measured = _signals(log)
    sim0 = _signals(replay_insertion(log, {}))
    done += 1
    residual = {ch: measured[ch] - sim0[ch] for ch in measured}
    pool: dict[str, list[Candidate]] = {}
    for name in names:
        param = CATALOGUE[name].params[0].name
        pool[name] = []
        for value in GRIDS[name]:
            say("replays", done, total)
            sim = _signals(replay_insertion(log, {name: {param: value}}))
            pool[name].append(_offset_candidate(name, param, value, sim, sim0))
            done += 1
    say("replays", total, total)
    speed = np.linalg.norm(np.gradient(log.tool_pose[:, :3, 3], log.time, axis=0), axis=1)
    x = np.repeat(log.time[:, None], 7, axis=1)
    valid = np.ones(log.n_samples, dtype=bool)
    valid[:2] = False
    force = np.linalg.norm(log.wrench[:, :3], axis=1)
    regions = {
        "touching (|f| > 0.1 N)": np.repeat((force > 0.1)[:, None], 7, axis=1),
        "tool moving (> 1 cm/s)": np.repeat((speed > 0.01)[:, None], 7, axis=1),
    }
    labels = {"tau": [f"joint {j + 1}" for j in range(7)], "tool": list(TOOL_COLUMNS)}
    return Evidence(
        residual=residual,
        labels=labels,
        valid=valid,
        phase=segment_phases(log),
        regions=regions,
        pool=pool,
        audit=None,
        x=x,
        x_label="t [s]",
        time=log.time,
        meta=dict(log.meta),
        floor_min={"tau": 1e-3, "tool": np.array([1e-6] * 3 + [1e-3] * 4)},
    )


def downstream(effects: dict[str, dict[str, float]], gear: str, episodes: int, seed: int = 0) -> float:
    """The shipped insertion skill's success rate in the station with `effects`."""
    from sim2real.station_logs import skill_success

    return skill_success(effects, gear=gear, episodes=episodes, seed=seed)


def diagnose_insertion(
    log: RobotLog,
    config: DiagnosisConfig | None = None,
    progress: Progress | None = None,
    episodes: int = 10,
    truth_success: Callable[[], float] | None = None,
) -> Diagnosis:
    """Diagnose an insertion log against the station (see the module docstring). With `episodes`
    > 0 the report adds the skill's success rate in the nominal station and in the station with
    the selected effects at their fitted values; `truth_success` (for simulated logs) adds the
    rate in the "real" station."""
    c = config or DiagnosisConfig()
    ev = station_evidence(log, c.effects, progress)
    d = analyse(ev, c, progress)
    if episodes > 0 and d.selected:
        gear = str(log.meta.get("task", {}).get("gear", "medium"))
        fitted = {s["effect"]: {k: v["value"] for k, v in s["params"].items()} for s in d.selected}
        nominal = downstream({}, gear, episodes)
        with_effects = downstream(fitted, gear, episodes)
        out: dict[str, Any] = {
            "episodes": episodes,
            "gear": gear,
            "nominal_sim": nominal,
            "sim_with_effects": with_effects,
            "effects": fitted,
        }
        text = (
            f"Success of the shipped insertion skill ({gear} gear, {episodes} episodes, the same grasp "
            f"errors): nominal sim {100 * nominal:.0f} %, sim with {', '.join(fitted)} at the fitted "
            f"values {100 * with_effects:.0f} %"
        )
        if truth_success is not None:
            real = truth_success()
            out["real"] = real
            gap0, gap1 = abs(nominal - real), abs(with_effects - real)
            out["gap_before"], out["gap_after"] = gap0, gap1
            text += f'; the "real" station {100 * real:.0f} %: the success gap shrinks from {100 * gap0:.0f} to {100 * gap1:.0f} points'
        out["text"] = text + "."
        d.extra["downstream"] = out
    return d
