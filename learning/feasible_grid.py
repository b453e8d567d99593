"""Where a skill's frozen policy succeeds, measured on a grid of its parameters; how the skill's
flow sits on that set; and the flow refitted to it in GoFlow's constrained mode.

The grid (`FeasibleGridConfig`) has two levels over the parameter box:
- a fine region around a centre (default: the flow's per-axis median), cut into `fine_cells`
  equal cells per axis;
- coarse cells over the whole box (`coarse_cells` per axis).

One episode of the deterministic policy at each cell centre labels the cell: success when its
return reaches the skill's J_T. Coarse cells whose centre lies in the fine region are not run.
Any point of the box takes the label of the fine cell it lies in; outside the fine region, that of
its coarse cell; and where that coarse cell was not run, that of the nearest fine cell. The
measured feasible set F is the union of the successful cells (`FeasibleSet.contains`).

Against F, `flow_report` gives a flow's mass on F and the share of F it covers (where its density
exceeds 10 % or 1 % of the uniform-on-F density), the measures of `learning.feasible_sets`.

`refit_flow` is the frozen-policy refit in GoFlow's constrained mode (max H(p) s.t.
E_p[success] >= 1 - delta): the flow starts from the skill's, learns first from the measured grid
and then from `rounds` batches of its own draws, each labelled by the policy. It checkpoints after
every update and resumes.

This module knows nothing of skill files or episodes: `learning.skill_feasible_set.measure_feasible_set`
runs the grid's episodes and `learning.skill_feasible_set.refit_skill` the refit of a skill file.

    skill = load_skill("insert", "medium")
    flow_report(skill.sampler, skill.feasible)   # {"share": ..., "mass_on": ..., "coverage10": ...}

Measurements and the refit of the shipped skills: docs/skills.md.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from goflow_common.checks import check_int, check_number
from goflow_common.config import config_to_dict
from goflow_common.errors import FileFormatError, InputError
from goflow_common.files import load_tensors, save_tensors
from learning.feasible_sets import coverage, mass_on
from learning.samplers.goflow import GoFlowSampler
from learning.samplers.goflow_config import GoFlowConfig

__all__ = [
    "FeasibleGridConfig",
    "GridPlan",
    "FeasibleSet",
    "FlowRefitConfig",
    "flow_report",
    "constrained_copy",
    "refit_flow",
]

_FORMAT = "goflow-feasible-set-1"
_REFIT_FORMAT = "goflow-flow-refit-1"
#: Flow draws and points uniform on F behind `flow_report` (fixed seed: the report is deterministic).
REPORT_SAMPLES = 100_000
REPORT_SEED = 20_261_124


def _per_axis(value: Any, dim: int, name: str, integer: bool) -> tuple:
    """`value` as a tuple of `dim` entries (a scalar is repeated), each checked."""
    values = tuple(value) if isinstance(value, (tuple, list)) else (value,) * dim
    if len(values) != dim:
        raise InputError(f"{name} = {value!r}; expected one entry or {dim} (one per parameter)")
    if integer:
        return tuple(check_int(v, f"{name} entry", 1) for v in values)
    return tuple(check_number(v, f"{name} entry", 0.0, low_open=True) for v in values)


@dataclass(frozen=True)
class FeasibleGridConfig:
    """The measurement grid. Widths are in parameter units; a tuple gives one entry per
    parameter, a single number applies to all. A fine region wider than the box is cut to it."""

    fine_width: tuple[float, ...] | float | None = None  # None: a tenth of the box per axis
    fine_cells: tuple[int, ...] | int = 10  # fine cells per axis
    coarse_cells: tuple[int, ...] | int = 11  # coarse cells per axis over the whole box
    centre: tuple[float, ...] | None = None  # None: the flow's per-axis median
    variant: str | None = None  # the skill's env variant the episodes run in (None: its own)
    # a second variant in which every cell and draw that succeeded is run again; it stays feasible
    # only if it succeeds there too (e.g. "panda": the full station confirms the fast variant)
    confirm_variant: str | None = None

    def plan(self, space: ParamSpace, median: ArrayLike) -> GridPlan:
        """The grid over `space`, its fine region centred on `centre` or else on `median` (the
        flow's per-axis median) and moved inside the box."""
        d = space.dim
        width = space.high - space.low
        fine = np.asarray(
            _per_axis(self.fine_width, d, "fine_width", False) if self.fine_width is not None else 0.1 * width,
            np.float64,
        )
        centre = np.asarray(median if self.centre is None else self.centre, np.float64)
        if centre.shape != (d,) or not np.all(np.isfinite(centre)):
            raise InputError(f"centre = {self.centre!r}; expected {d} finite numbers")
        fine = np.minimum(fine, width)
        low = np.clip(centre - fine / 2, space.low, space.high - fine)
        return GridPlan(
            space,
            low,
            low + fine,
            _per_axis(self.fine_cells, d, "fine_cells", True),
            _per_axis(self.coarse_cells, d, "coarse_cells", True),
        )


@dataclass(frozen=True)
class GridPlan:
    """The cells of one measurement: the fine region [low, high] cut into `fine_cells`, and the
    box cut into `coarse_cells`, of which those whose centre lies outside the fine region are run."""

    space: ParamSpace
    low: NDArray[np.float64]
    high: NDArray[np.float64]
    fine_cells: tuple[int, ...]
    coarse_cells: tuple[int, ...]

    @property
    def coarse_run(self) -> NDArray[np.bool_]:
        centres = _centres(self.space.low, self.space.high, self.coarse_cells)
        return ~np.all((centres >= self.low) & (centres <= self.high), axis=1)

    def points(self) -> NDArray[np.float64]:
        """The cell centres to run: the fine ones, then the coarse ones outside the fine region."""
        coarse = _centres(self.space.low, self.space.high, self.coarse_cells)
        return np.concatenate([_centres(self.low, self.high, self.fine_cells), coarse[self.coarse_run]])

    def key(self) -> list[Any]:
        """Plain data that identifies the grid (for checkpoints)."""
        return [self.low.tolist(), self.high.tolist(), list(self.fine_cells), list(self.coarse_cells)]

    def feasible_set(self, returns: ArrayLike, success_threshold: float, variant: str) -> FeasibleSet:
        """The measured set from the returns at `points()`, in order."""
        returns = np.asarray(returns, np.float64)
        n_fine = int(np.prod(self.fine_cells))
        run = self.coarse_run
        if returns.shape != (n_fine + int(run.sum()),):
            raise InputError(f"{returns.shape} returns; expected one per point of the grid ({n_fine + run.sum()})")
        coarse = np.full(len(run), np.nan)
        coarse[run] = returns[n_fine:]
        return FeasibleSet(
            self.space,
            self.low,
            self.high,
            self.fine_cells,
            self.coarse_cells,
            returns[:n_fine],
            coarse,
            success_threshold,
            variant,
        )


def _centres(low: NDArray, high: NDArray, cells: tuple[int, ...]) -> NDArray[np.float64]:
    """Cell centres of a box cut into `cells` per axis, (prod(cells), d), C order."""
    axes = [low[i] + (np.arange(n) + 0.5) * (high[i] - low[i]) / n for i, n in enumerate(cells)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(cells))


def _index(x: NDArray, low: NDArray, high: NDArray, cells: tuple[int, ...]) -> NDArray[np.int64]:
    """Flat C-order index of the cell of each point (clipped into the box)."""
    n = np.asarray(cells)
    k = np.clip(np.floor((x - low) / (high - low) * n), 0, n - 1).astype(np.int64)
    return np.ravel_multi_index(tuple(k.T), cells)


class FeasibleSet:
    """A measured feasible set: labelled fine and coarse cells over a skill's box (module docstring)."""

    def __init__(
        self,
        space: ParamSpace,
        fine_low: ArrayLike,
        fine_high: ArrayLike,
        fine_cells: tuple[int, ...],
        coarse_cells: tuple[int, ...],
        fine_returns: ArrayLike,
        coarse_returns: ArrayLike,
        success_threshold: float,
        variant: str,
    ) -> None:
        self.space = space
        self.fine_low, self.fine_high = np.asarray(fine_low, np.float64), np.asarray(fine_high, np.float64)
        self.fine_cells, self.coarse_cells = tuple(fine_cells), tuple(coarse_cells)
        self.fine_returns = np.asarray(fine_returns, np.float64)  # (prod(fine_cells),)
        self.coarse_returns = np.asarray(coarse_returns, np.float64)  # NaN where not run
        self.success_threshold = float(success_threshold)
        self.variant = variant
        if self.fine_returns.shape != (int(np.prod(self.fine_cells)),) or self.coarse_returns.shape != (
            int(np.prod(self.coarse_cells)),
        ):
            raise FileFormatError("feasible set: the returns do not match the grid's cells")

    @property
    def fine_success(self) -> NDArray[np.bool_]:
        return self.fine_returns >= self.success_threshold

    @property
    def coarse_success(self) -> NDArray[np.bool_]:
        return np.nan_to_num(self.coarse_returns, nan=-np.inf) >= self.success_threshold

    def points(self, rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """One point uniform in each measured cell (fine, then the coarse ones run) and its 0/1
        label from `contains` (a flow's update learns better from points spread over the cells
        than from a lattice of their centres)."""
        run = np.isfinite(self.coarse_returns)
        fine_cell = (self.fine_high - self.fine_low) / np.asarray(self.fine_cells)
        coarse_cell = (self.space.high - self.space.low) / np.asarray(self.coarse_cells)
        fine = _centres(self.fine_low, self.fine_high, self.fine_cells)
        coarse = _centres(self.space.low, self.space.high, self.coarse_cells)[run]
        xi = np.concatenate(
            [fine + fine_cell * (rng.random(fine.shape) - 0.5), coarse + coarse_cell * (rng.random(coarse.shape) - 0.5)]
        )
        return xi, self.contains(xi)

    def plan(self) -> GridPlan:
        """The grid this set was measured on."""
        return GridPlan(self.space, self.fine_low, self.fine_high, self.fine_cells, self.coarse_cells)

    def returns(self) -> NDArray[np.float64]:
        """The returns at `plan().points()`, in order (the inverse of `GridPlan.feasible_set`)."""
        return np.concatenate([self.fine_returns, self.coarse_returns[self.plan().coarse_run]])

    def contains(self, xi: ArrayLike) -> NDArray[np.bool_]:
        """Whether each point (n, d) lies in the measured feasible set."""
        x = np.atleast_2d(np.asarray(xi, np.float64))
        fine = np.all((x >= self.fine_low) & (x <= self.fine_high), axis=1)
        label = self.fine_success[_index(x, self.fine_low, self.fine_high, self.fine_cells)]
        coarse = _index(x, self.space.low, self.space.high, self.coarse_cells)
        run = np.isfinite(self.coarse_returns[coarse])
        use = ~fine & run
        label[use] = self.coarse_success[coarse[use]]
        return label

    def sample_box(self, n: int, rng: np.random.Generator) -> tuple[NDArray[np.float64], float]:
        """Up to `n` points uniform on F, and F's share of the box, by stratified uniform draws: the
        fine region, whose feasible cells are known exactly, and the rest of the box by rejection
        (4 n draws; fewer points come back when F outside the fine region is hit less often)."""
        d = self.space.dim
        width = self.space.high - self.space.low
        fine_share = float(np.prod((self.fine_high - self.fine_low) / width))
        fine_cell = (self.fine_high - self.fine_low) / np.asarray(self.fine_cells)
        good = np.flatnonzero(self.fine_success)
        share_in = fine_share * len(good) / len(self.fine_success)
        outer = self.space.low + width * rng.random((4 * n, d))
        outer = outer[~np.all((outer >= self.fine_low) & (outer <= self.fine_high), axis=1)]
        hit = self.contains(outer)
        share_out = (1.0 - fine_share) * float(hit.mean()) if len(outer) else 0.0
        share = share_in + share_out
        if share <= 0.0:
            return np.zeros((0, d)), 0.0
        n_in = int(round(n * share_in / share))
        corners = _centres(self.fine_low, self.fine_high, self.fine_cells)[good] - fine_cell / 2
        inside = (
            corners[rng.integers(len(good), size=n_in)] + fine_cell * rng.random((n_in, d))
            if len(good)
            else np.zeros((0, d))
        )
        return np.concatenate([inside, outer[hit][: n - n_in]]), share

    @cached_property
    def share(self) -> float:
        """F's share of the box (`sample_box` with REPORT_SAMPLES points and a fixed seed)."""
        return self.sample_box(REPORT_SAMPLES, np.random.default_rng(REPORT_SEED))[1]

    def summary(self) -> dict[str, Any]:
        """Plain data: cells run, successes, the fine region and F's share of the box."""
        return {
            "variant": self.variant,
            "fine_low": self.fine_low.tolist(),
            "fine_high": self.fine_high.tolist(),
            "fine_cells": list(self.fine_cells),
            "coarse_cells": list(self.coarse_cells),
            "episodes": int(len(self.fine_returns) + np.isfinite(self.coarse_returns).sum()),
            "fine_successes": int(self.fine_success.sum()),
            "coarse_successes": int(self.coarse_success.sum()),
            "share": self.share,
        }

    def state_dict(self) -> dict[str, Any]:
        """Tensors and plain data (for a skill file or a checkpoint)."""
        return {
            "format": _FORMAT,
            "space": self.space.to_dict(),
            "fine_low": self.fine_low.tolist(),
            "fine_high": self.fine_high.tolist(),
            "fine_cells": list(self.fine_cells),
            "coarse_cells": list(self.coarse_cells),
            "fine_returns": torch.from_numpy(self.fine_returns),
            "coarse_returns": torch.from_numpy(self.coarse_returns),
            "success_threshold": self.success_threshold,
            "variant": self.variant,
        }

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> FeasibleSet:
        """Inverse of `state_dict`; FileFormatError for anything else."""
        if not isinstance(state, Mapping) or state.get("format") != _FORMAT:
            raise FileFormatError(f"not a measured feasible set (format {_FORMAT!r})")
        try:
            return cls(
                ParamSpace.from_dict(state["space"]),
                state["fine_low"],
                state["fine_high"],
                tuple(state["fine_cells"]),
                tuple(state["coarse_cells"]),
                torch.as_tensor(state["fine_returns"]).numpy(),
                torch.as_tensor(state["coarse_returns"]).numpy(),
                state["success_threshold"],
                state["variant"],
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(f"a malformed measured feasible set ({type(exc).__name__}: {exc})") from None


# -- the flow against the set ----------------------------------------------------------------


def flow_report(
    sampler: Any, feasible: FeasibleSet, samples: int = REPORT_SAMPLES, seed: int = REPORT_SEED
) -> dict[str, float]:
    """A sampler against a measured feasible set F: its mass on F (share of `samples` draws), the
    mass outside, and its coverage of F at 10 % and 1 % of the uniform-on-F density (at
    `samples` / 10 points uniform on F), with F's share of the box (`FeasibleSet.share`).
    Deterministic for a given sampler (fixed seed)."""
    samples = check_int(samples, "samples", 1)
    rng = np.random.default_rng(seed)
    inside, _ = feasible.sample_box(samples // 10, rng)
    share = feasible.share
    mass = mass_on(sampler.sample(samples, rng), feasible.contains)
    volume = float(np.prod(feasible.space.high - feasible.space.low))
    report = {"share": share, "mass_on": mass, "mass_outside": 1.0 - mass, "coverage10": 0.0, "coverage1": 0.0}
    if share > 0 and len(inside):
        report["coverage10"] = coverage(sampler.log_prob, inside, share, 0.1, volume)
        report["coverage1"] = coverage(sampler.log_prob, inside, share, 0.01, volume)
    return report


@dataclass(frozen=True)
class FlowRefitConfig:
    """The constrained-mode refit of a skill's flow (`refit_flow`)."""

    rounds: int = 20  # updates from the flow's own draws, after the one from the measured grid
    episodes: int = 64  # episodes per round, parameters drawn from the flow
    delta: float = 0.002  # the mass allowed outside the feasible set (GoFlowConfig.delta)
    # Adam steps per update (GoFlowConfig.steps): a flow trained narrow in some direction (the grasp
    # yaw) needs several hundred to spread over a set that is wide in it
    steps: int = 1000
    # Adam steps of the success classifier behind F-hat per update (GoFlowConfig.classifier_steps; its
    # first fit takes ten times as many): a set of 0.16-0.4 % of the box needs about ten times
    # GoFlow's default before the classifier's even-odds contour holds most of it (docs/skills.md)
    classifier_steps: int = 1000
    # GoFlowConfig.floor, the share of the mass in F-hat drawn uniformly on it. 0 here, not GoFlow's
    # 0.2: on the medium gear's set it raised the mass and lowered the coverage as the level rose
    # (0.995 / 0.846 against 0.986 / 0.871 after 20 rounds, docs/skills.md), and the shipped files have none
    floor: float = 0.0
    seed: int = 0  # the draws' generator

    def __post_init__(self) -> None:
        check_int(self.rounds, "FlowRefitConfig.rounds", 0)
        check_int(self.episodes, "FlowRefitConfig.episodes", 1)
        check_number(self.delta, "FlowRefitConfig.delta", 0.0, 1.0, low_open=True, high_open=True)
        check_int(self.steps, "FlowRefitConfig.steps", 1)
        check_int(self.classifier_steps, "FlowRefitConfig.classifier_steps", 1)
        check_number(self.floor, "FlowRefitConfig.floor", 0.0, 1.0, high_open=True)
        check_int(self.seed, "FlowRefitConfig.seed", 0)

    def to_dict(self) -> dict[str, Any]:
        return config_to_dict(self)


def constrained_copy(sampler: GoFlowSampler, config: FlowRefitConfig) -> GoFlowSampler:
    """A GoFlow sampler with `sampler`'s flow (same architecture and weights) in constrained mode,
    with no evidence yet: GoFlow's constrained defaults, with the refit's delta, floor and the
    flow's and classifier's steps per update from `config`."""
    if not isinstance(sampler, GoFlowSampler):
        raise InputError(f"the refit needs a GoFlow flow, not {type(sampler).__name__}")
    state = sampler.state_dict()
    # the constrained mode's own estimate of the feasible set and its truncation, whatever the
    # source flow was saved with (a flow saved before they existed loads with the k-NN vote)
    fresh = GoFlowConfig()
    settings = {
        k: getattr(fresh, k)
        for k in ("feasible_model", "truncate", "feasible_level", "leak_target", "level_step", "classifier_hidden")
    }
    config_dict = {
        **state["config"],
        **settings,
        "mode": "constrained",
        "beta": 0.0,
        "delta": float(config.delta),
        "floor": float(config.floor),
        "steps": int(config.steps),
        "classifier_steps": int(config.classifier_steps),
    }
    new = GoFlowSampler(sampler.space, sampler.success_threshold, config_dict)
    state.pop("feasible_level", None)  # F-hat's level starts again at the config's
    dim = sampler.space.dim
    if sampler.config.classifier_layers(dim) != new.config.classifier_layers(dim):
        state.pop("classifier", None)  # a classifier of other layers: the refit fits its own from the grid
    new.load_state_dict({**state, "config": config_dict, "n_updates": 0, "evidence": {}})
    return new


#: Runs the frozen policy: (parameters (n, d), round) -> returns (n,).
Evaluate = Callable[[NDArray[np.float64], int], NDArray[np.float64]]


def refit_flow(
    sampler: GoFlowSampler,
    feasible: FeasibleSet,
    evaluate: Evaluate,
    config: FlowRefitConfig | None = None,
    checkpoint: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> tuple[GoFlowSampler, list[dict[str, float]]]:
    """Refit `sampler`'s flow in GoFlow's constrained mode: one update from the measured grid
    `feasible` (a point uniform in each cell, with the cell's label), then `config.rounds`
    updates, each from `config.episodes` of the flow's own draws labelled by `evaluate`
    (success: return >= the set's J_T). Returns the refitted sampler (a
    new one; `sampler` is not changed) and one record per update: the success on its draws, and
    `flow_report` against `feasible` after it. With `checkpoint`, the state is written there after
    every update and a call with the same config resumes from it. Torch runs on one thread (the
    flow is small; more threads only contend with the episodes' simulators)."""
    torch.set_num_threads(1)
    config = config or FlowRefitConfig()
    new = constrained_copy(sampler, config)
    records: list[dict[str, float]] = []
    if checkpoint is not None and Path(checkpoint).is_file():
        saved = load_tensors(checkpoint, "flow refit checkpoint")
        if not isinstance(saved, dict) or saved.get("format") != _REFIT_FORMAT:
            raise FileFormatError(f"{checkpoint}: not a flow refit checkpoint")
        saved_config = saved.get("config")
        if not isinstance(saved_config, dict) or {"floor": 0.0, **saved_config} != config.to_dict():  # no floor: 0
            raise InputError(
                f"{checkpoint} holds a refit with {saved.get('config')}, not {config.to_dict()}; "
                "remove it or choose another folder"
            )
        new.load_state_dict(saved["sampler"])
        records = list(saved["records"])
    total = config.rounds + 1
    bar = tqdm(total=total, initial=len(records), disable=not progress, desc="refit flow", unit="update")
    try:
        while len(records) < total:
            r = len(records)
            t0 = time.perf_counter()
            if r == 0:  # the measured grid, a point uniform in each cell
                xi, success = feasible.points(np.random.default_rng([config.seed, 0]))
                rate = None
            else:
                xi = new.sample(config.episodes, np.random.default_rng([config.seed, r]))
                success = np.asarray(evaluate(xi, r), np.float64) >= feasible.success_threshold
                rate = float(success.mean())
            new.update(xi, success.astype(np.float64))
            records.append(
                {
                    "update": r,
                    "episodes": int(len(xi)),
                    "success_on_draws": rate,
                    **flow_report(new, feasible),
                    "entropy": float(new.entropy()),
                    "seconds": time.perf_counter() - t0,
                }
            )
            if checkpoint is not None:
                save_tensors(
                    checkpoint,
                    {
                        "format": _REFIT_FORMAT,
                        "config": config.to_dict(),
                        "sampler": new.state_dict(),
                        "records": records,
                    },
                )
            bar.set_postfix(mass=f"{records[-1]['mass_on']:.3f}", cover=f"{records[-1]['coverage10']:.2f}")
            bar.update(1)
    finally:
        bar.close()
    return new, records
