"""Where a skill's frozen policy succeeds, measured on a grid of episodes (resumable jobs), and
the skill's flow refitted to that set in GoFlow's constrained mode (stage 4 of a recipe).
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from goflow_common.errors import InputError
from goflow_common.files import check_output_file, load_tensors, run_folder_lock, save_tensors
from learning.execution import Backend, InlineBackend, Job, run_grid
from learning.feasible_grid import FeasibleGridConfig, FeasibleSet, FlowRefitConfig, GridPlan, flow_report, refit_flow
from learning.skill_evaluation import rollout_return
from learning.skill_file import Skill

__all__ = ["INSERT_GRID", "PART", "REFIT_PART", "measure_feasible_set", "refit_skill"]

#: The insert skill's measurement grid: 0.3 mm cells over 12 mm x 12 mm around the flow's median,
#: 3 yaw layers over the whole yaw range, and 11 x 11 x 3 coarse cells over the box (docs/skills.md).
INSERT_GRID = FeasibleGridConfig(fine_width=(0.012, 0.012, 0.786), fine_cells=(40, 40, 3), coarse_cells=(11, 11, 3))
#: Episodes per job of a measurement, and of a refit update (whose batch is small: several workers share it).
PART = 128
REFIT_PART = 16


def _returns_at(path: str, variant: str, xi: NDArray[np.float64]) -> NDArray[np.float64]:
    """One job, in a worker: the returns of the skill file's deterministic policy at each row of xi."""
    torch.set_num_threads(1)
    skill = Skill.load(path)
    env = skill.make_env(variant)
    try:
        return np.array([rollout_return(skill, x, env) for x in xi])
    finally:
        env.close()


def _returns(
    path: str,
    variant: str,
    xi: NDArray[np.float64],
    backend: Backend,
    progress: bool,
    desc: str,
    done: dict[int, NDArray[np.float64]] | None = None,
    save: Any = None,
    part: int = PART,
) -> NDArray[np.float64]:
    """Returns at each row of xi, in jobs of `part` rows on `backend`. Jobs already in `done`
    (job index -> returns) are not run again; `save(done)` is called as each job finishes."""
    parts = [np.arange(k, min(k + part, len(xi))) for k in range(0, len(xi), part)]
    done = {} if done is None else done
    todo = [k for k in range(len(parts)) if k not in done]

    def keep(i: int, value: Any) -> None:
        done[todo[i]] = np.asarray(value, np.float64)
        if save is not None:
            save(done)

    if todo:
        run_grid(
            [Job(f"{desc} {k}", _returns_at, (path, variant, xi[parts[k]])) for k in todo],
            backend,
            progress,
            desc,
            on_result=keep,
        )
    return np.concatenate([done[k] for k in range(len(parts))]) if parts else np.zeros(0)


def _variants(skill: Skill, grid: FeasibleGridConfig) -> tuple[str, ...]:
    """The env variants a cell must succeed in: the grid's (default the skill's own), then the
    confirming one."""
    first = grid.variant or skill.env_kwargs.get("variant", "fast")
    return (first,) if grid.confirm_variant in (None, first) else (first, grid.confirm_variant)


def _covered(variant: str, variants: tuple[str, ...]) -> int:
    """How many of `variants` a measurement made in `variant` ("fast", "fast+panda") covers: the
    length of its chain when that chain starts `variants`, else 0."""
    done = tuple(variant.split("+"))
    return len(done) if done == variants[: len(done)] else 0


def _checkpointed_returns(
    path: Path,
    variant: str,
    xi: NDArray[np.float64],
    key: dict[str, Any],
    checkpoint: Path | None,
    backend: Backend,
    progress: bool,
    desc: str,
) -> NDArray[np.float64]:
    """`_returns` whose finished jobs are saved in `checkpoint` under `key` and reused from it."""
    done: dict[int, NDArray[np.float64]] = {}
    if checkpoint is not None and checkpoint.is_file():
        saved = load_tensors(checkpoint, "feasible-set measurement checkpoint")
        if isinstance(saved, dict) and saved.get("key") == key:
            done = {int(k): torch.as_tensor(v).numpy() for k, v in saved["parts"].items()}

    def save(parts: dict[int, NDArray[np.float64]]) -> None:
        save_tensors(checkpoint, {"key": key, "parts": {str(k): torch.from_numpy(v) for k, v in parts.items()}})

    return _returns(str(path), variant, xi, backend, progress, desc, done, save if checkpoint is not None else None)


def measure_feasible_set(
    path: str | os.PathLike[str],
    grid: FeasibleGridConfig = INSERT_GRID,
    backend: Backend | None = None,
    progress: bool = False,
    checkpoint: str | os.PathLike[str] | None = None,
    known: FeasibleSet | None = None,
) -> FeasibleSet:
    """Where the deterministic policy of the skill file at `path` succeeds: one episode at the
    centre of each cell of `grid` (learning.feasible_grid), in the grid's variant (default the
    skill's own), in jobs of `PART` cells on `backend` (default: this process); with
    `grid.confirm_variant`, the cells that succeeded are run again there and keep the lower
    return. With `checkpoint`, each finished job is saved there (the confirming episodes beside
    it, "<stem>-<variant>.pt"), and a later call for the same file and grid resumes from them.
    `known` is a measurement of this same policy in the first of those variants (or more of
    them, in order): its cells and returns are kept and only the variants it lacks are run;
    InputError if its variants are not the start of the grid's."""
    path = Path(path).resolve()
    skill = Skill.load(path)
    variants = _variants(skill, grid)
    backend = backend or InlineBackend()
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    checkpoint = None if checkpoint is None else Path(checkpoint)
    if known is not None:
        done = _covered(known.variant, variants)
        if not done:
            raise InputError(f"a measurement in {known.variant!r} cannot start one in {'+'.join(variants)!r}")
        plan, returns = known.plan(), known.returns()
    else:
        done, plan = 1, grid.plan(skill.space, skill.centre())
        returns = _checkpointed_returns(
            path,
            variants[0],
            plan.points(),
            {"skill_sha256": sha, "grid": [*plan.key(), variants[0], PART]},
            checkpoint,
            backend,
            progress,
            "feasible set",
        )
    xi = plan.points()
    for variant in variants[done:]:
        good = np.flatnonzero(returns >= skill.success_threshold)
        again = _checkpointed_returns(
            path,
            variant,
            xi[good],
            {"skill_sha256": sha, "grid": [*plan.key(), variant, PART], "cells": good.tolist()},
            None if checkpoint is None else checkpoint.with_name(f"{checkpoint.stem}-{variant}.pt"),
            backend,
            progress,
            f"feasible set, {variant}",
        )
        returns[good] = np.minimum(returns[good], again)
    return plan.feasible_set(returns, skill.success_threshold, "+".join(variants))


def _same_policy(a: Skill, b: Skill) -> bool:
    """Whether two skills run the same deterministic policy in the same environment and box (so a
    feasible set measured with one holds for the other)."""
    if (a.env_id, a.env_kwargs, a.space.to_dict(), a.success_threshold) != (
        b.env_id,
        b.env_kwargs,
        b.space.to_dict(),
        b.success_threshold,
    ):
        return False
    for mine, theirs in (
        (a.agent.actor.state_dict(), b.agent.actor.state_dict()),
        (a.agent.obs_rms.state_dict(), b.agent.obs_rms.state_dict()),
    ):
        if mine.keys() != theirs.keys() or not all(
            torch.equal(torch.as_tensor(mine[k]), torch.as_tensor(theirs[k])) for k in mine
        ):
            return False
    return True


def refit_skill(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    grid: FeasibleGridConfig = INSERT_GRID,
    refit: FlowRefitConfig | None = None,
    folder: str | os.PathLike[str] | None = None,
    backend: Backend | None = None,
    command: str = "",
    progress: bool = False,
    feasible_from: str | os.PathLike[str] | None = None,
) -> Skill:
    """The frozen-policy refit of a skill file's flow (stage 4 of `train_skill`): measure where
    its policy succeeds on `grid`, refit the flow to that set in GoFlow's constrained mode
    (`learning.feasible_grid.refit_flow`), and write the skill with the new flow and the
    measurement to `out` (checked first). A measurement already made with the grid's cells is
    used instead of running it again, and only the confirming variant it lacks is run: the file's
    own, or else the one in `feasible_from`, a skill file with the same policy (InputError if its
    policy, environment or box differ, or it holds none). With `folder`, the measurement and the
    refit checkpoint there (locked) and resume."""
    refit = refit or FlowRefitConfig()
    out = check_output_file(out, "skill file")
    path = Path(path).resolve()
    skill = Skill.load(path)
    known = None
    if feasible_from is not None:
        other = Skill.load(feasible_from)
        if other.feasible is None:
            raise InputError(f"feasible_from = {str(feasible_from)!r} holds no measured feasible set")
        if not _same_policy(skill, other):
            raise InputError(
                f"feasible_from = {str(feasible_from)!r}: its policy, environment or box differ from "
                f"{str(path)!r}'s; a measured feasible set holds only for the policy that ran it"
            )
        known = other.feasible
    backend = backend or InlineBackend()
    if folder is None:
        return _refit_skill(skill, path, out, grid, refit, None, backend, command, progress, known)
    Path(folder).mkdir(parents=True, exist_ok=True)
    with run_folder_lock(folder):
        return _refit_skill(skill, path, out, grid, refit, Path(folder), backend, command, progress, known)


def _refit_checkpoint(folder: Path | None, path: Path, feasible: FeasibleSet) -> Path | None:
    """The refit's checkpoint in `folder`, named for the input file's content and the variants
    its feasible set was measured in (another input or measurement starts afresh)."""
    if folder is None:
        return None
    return folder / f"refit-{hashlib.sha256(path.read_bytes()).hexdigest()[:16]}-{feasible.variant}.pt"


def _usable(feasible: FeasibleSet | None, plan: GridPlan, variants: tuple[str, ...]) -> int:
    """How many of `variants` (in order) a stored measurement covers on a grid with `plan`'s cells
    and fine width (0: none; its fine region may lie elsewhere, around the flow it was made for)."""
    if (
        feasible is None
        or (feasible.fine_cells, feasible.coarse_cells) != (plan.fine_cells, plan.coarse_cells)
        or not np.allclose(feasible.fine_high - feasible.fine_low, plan.high - plan.low)
    ):
        return 0
    return _covered(feasible.variant, variants)


def _refit_skill(
    skill: Skill,
    path: Path,
    out: Path,
    grid: FeasibleGridConfig,
    refit: FlowRefitConfig,
    folder: Path | None,
    backend: Backend,
    command: str,
    progress: bool,
    known: FeasibleSet | None,
) -> Skill:
    variants = _variants(skill, grid)
    plan = grid.plan(skill.space, skill.centre())
    # the file's own measurement first, then the one handed in: whichever covers more variants
    covered, feasible = max(((_usable(f, plan, variants), f) for f in (skill.feasible, known)), key=lambda c: c[0])
    if covered < len(variants):
        feasible = measure_feasible_set(
            path,
            grid,
            backend,
            progress,
            folder / "feasible.pt" if folder is not None else None,
            feasible if covered else None,
        )
    before = flow_report(skill.sampler, feasible)

    def evaluate(xi: NDArray[np.float64], update: int) -> NDArray[np.float64]:
        returns = _returns(str(path), variants[0], xi, backend, False, f"refit update {update}", part=REFIT_PART)
        for variant in variants[1:]:  # a success must hold in the confirming variant too
            good = np.flatnonzero(returns >= skill.success_threshold)
            returns[good] = np.minimum(
                returns[good],
                _returns(
                    str(path), variant, xi[good], backend, False, f"refit update {update}, {variant}", part=REFIT_PART
                ),
            )
        return returns

    with backend:  # one pool or cluster for every update
        sampler, records = refit_flow(
            skill.sampler, feasible, evaluate, refit, _refit_checkpoint(folder, path, feasible), progress
        )
    provenance = {
        **skill.provenance,
        "refit": {
            "command": command,
            "config": refit.to_dict(),
            "feasible_set": feasible.summary(),
            "before": before,
            "updates": records,
            "date": time.strftime("%Y-%m-%d"),
        },
    }
    new = Skill(
        skill.name,
        skill.gear,
        skill.env_id,
        skill.env_kwargs,
        skill.method,
        skill.agent,
        sampler,
        skill.success_threshold,
        provenance,
        feasible,
    )
    new.save(out)
    return new
