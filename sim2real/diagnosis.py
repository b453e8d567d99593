"""The three answers for a robot log: where the gap lies, which effect causes it, how far it shrinks.

`diagnose(log)` is the pipeline, each stage a module, in the order the log meets them:

1. load and clean (sim2real/clean.py): stale repeats dropped, a uniform grid, gaps not fitted;
2. replay (sim2real/replay.py): the nominal arm's residual channels;
3. band and floor (sim2real/band.py): the residual below the band's edge, the noise floor in it;
   together with 1-2: the evidence (sim2real/evidence.py);
4. where (sim2real/where.py): RMS against the floor per channel, joint, phase and region;
5. fit and select (sim2real/selection.py): each effect fitted on training blocks and scored on
   held-out ones, forward selection and backward elimination, parameters with intervals;
6. verdict and how far (sim2real/verdict.py): "no gap", "explained" or "unexplained" with the
   excess's interval and the structure left, the gap closed per channel, joint and phase;
7. report (sim2real/report.py).

`analyse(evidence)` runs 4-6 on any model's evidence (the arm's, the station's, the camera's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim2real.band import noise_floor
from sim2real.config import DiagnosisConfig
from sim2real.evidence import Evidence, arm_evidence
from sim2real.fitting import Design
from sim2real.log import RobotLog
from sim2real.selection import (
    block_folds,
    heldout_prediction,
    identifiability_warnings,
    rank_effects,
    score,
    select,
    selected_effects,
)
from sim2real.verdict import excess_interval, friction_table, how_far_table, structure_left, verdict_of
from sim2real.where import rank_by_prediction, where_table

__all__ = ["DiagnosisConfig", "Diagnosis", "Evidence", "diagnose", "analyse", "arm_evidence", "noise_floor"]

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


@dataclasses.dataclass
class Diagnosis:
    """Everything the report shows; `summary()` is plain JSON-compatible data."""

    log_meta: dict[str, Any]
    channels: tuple[str, ...]
    where: dict[str, Any]
    audit: list[dict[str, Any]]
    ranking: list[dict[str, Any]]
    selected: list[dict[str, Any]]
    warnings: list[str]
    how_far: dict[str, Any]
    verdict: dict[str, Any]
    arrays: dict[str, Array]
    labels: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    x_label: str = "dq [rad/s]"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {
            "log": self.log_meta,
            "channels": list(self.channels),
            "columns": {c: self.labels.get(c, [f"joint {j + 1}" for j in range(7)]) for c in self.channels},
            "where": self.where,
            "audit": self.audit,
            "ranking": self.ranking,
            "selected": self.selected,
            "warnings": self.warnings,
            "how_far": self.how_far,
            "verdict": self.verdict,
            **self.extra,
        }


def diagnose(log: RobotLog, config: DiagnosisConfig | None = None, progress: Progress | None = None) -> Diagnosis:
    """Answer where, which and how far for an arm log (see the module docstring)."""
    say = progress or (lambda what, i, n: None)
    say("replay", 0, 1)
    return analyse(arm_evidence(log, config), config, progress)


def analyse(ev: Evidence, config: DiagnosisConfig | None = None, progress: Progress | None = None) -> Diagnosis:
    """The three answers from a replayed log's evidence (any model: arm, station, camera).

    Arguments:
        ev: the evidence (sim2real/evidence.py).
        config: the thresholds (None: DiagnosisConfig()).
        progress: called as progress(stage, i, n).

    Returns:
        The Diagnosis: where, ranking, selected effects with intervals, audit, how far, verdict.
    """
    c = config or DiagnosisConfig()
    say = progress or (lambda what, i, n: None)
    rng = np.random.default_rng(c.seed)
    chans = tuple(ch for ch in ("tau", "cmd", "ctrl", "dq", "tool", "pose") if ch in ev.residual)
    y = np.stack([ev.residual[ch] for ch in chans], axis=1)
    # per channel its noise: the evidence's where it knows it (in the band; the filtered torques;
    # one row per scene, with no time to smooth over), else estimated from the residual
    noise = np.stack([ev.floor[ch] if ch in ev.floor else np.zeros(7) for ch in chans])
    free = [i for i, ch in enumerate(chans) if ch not in ev.floor]
    if free:
        noise[free] = noise_floor(y[:, free].reshape(len(y), -1), ev.valid, reach=ev.reach).reshape(len(free), 7)
    floor = np.stack([np.maximum(noise[i], ev.floor_min.get(ch, 0.0)) for i, ch in enumerate(chans)])
    # what a log with no gap reads, in noise variances: 1 per column, less where the floor is the
    # channel's resolution (a control law reproduced to rounding)
    level = float(np.mean((noise / floor) ** 2))
    design = Design(ev.residual, chans, floor, ev.valid, c.blocks)
    folds = block_folds(design, c.folds)
    n_rows = design.count

    # where
    where = where_table(ev, design, floor)
    base = score(design, [], folds)
    e0 = base.sse.sum() / n_rows.sum()
    excess0 = max(e0 - level, 0.0)

    # which: each effect alone, then the selection
    say("effects", 0, 1)
    ranking, best_single = rank_effects(design, ev.pool, folds, base, excess0, c, rng, say)
    say("selection", 0, 1)
    selection = select(design, ev.pool, folds, base, best_single, excess0, c, rng)
    say("selection", 1, 1)
    selected = selected_effects(design, selection, c, rng)
    friction = (
        friction_table(selected, np.asarray(ev.preprocessing["nominal_damping"]))
        if "nominal_damping" in ev.preprocessing
        else None
    )
    for r in selected:
        r.pop("_samples", None)
    warnings = identifiability_warnings(design, ranking, selection)
    say("audit", 0, 1)
    audit = ev.audit(design, folds, base.sse, excess0, n_rows) if ev.audit is not None else []
    say("audit", 1, 1)

    # how far, and the verdict
    chosen, current = selection.chosen, selection.current
    pred = heldout_prediction(design, current, folds)
    if chosen:
        rank_by_prediction(where, design, pred, ev.valid)
    else:
        where["ranked_by"] = "the excess over the noise floor (RMS)"
    how_far = how_far_table(ev, design, floor, pred, level)
    e_final = current.sse.sum() / n_rows.sum()
    structure = structure_left(design, design.y - pred, ev.valid, folds, ev.structure, excess0, e_final, level, c, rng)
    excess = excess_interval(base.sse, current.sse, n_rows, level, c.bootstrap, rng)
    verdict = verdict_of(c, chosen, structure, excess, e0, e_final, level)
    verdict.update(
        heldout_before=float(e0), heldout_after=float(e_final), floor_level=level, excess=excess, structure=structure
    )

    meta = {k: v for k, v in ev.meta.items() if k != "truth"}
    arrays = {
        "residual": design.y,
        "after": design.y - pred,
        "floor": floor,
        "x": ev.x,
        "time": ev.time,
        "valid": ev.valid,
    }
    return Diagnosis(
        log_meta=meta,
        channels=chans,
        where=where,
        audit=audit,
        ranking=ranking,
        selected=selected,
        warnings=warnings,
        how_far=how_far,
        verdict=verdict,
        arrays=arrays,
        labels=ev.labels,
        x_label=ev.x_label,
        extra={
            "notes": list(ev.notes),
            "preprocessing": ev.preprocessing,
            **({"friction": friction} if friction else {}),
        },
    )
