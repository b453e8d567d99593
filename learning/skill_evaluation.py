"""What a skill does: episodes of its deterministic policy (one, or many split into jobs), how
wide its flow is, and a one-line report of its provenance and measured feasible set.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import Sampler, check_sample_args
from goflow_common.checks import check_int, check_number
from learning.execution import Backend, InlineBackend, Job, run_grid
from learning.feasible_grid import flow_report
from learning.skill_file import Skill

__all__ = [
    "CaptureDisk",
    "SkillEvaluation",
    "XI_SOURCES",
    "capture_radius",
    "xi_source",
    "describe",
    "evaluate_skill",
    "evaluate_skill_jobs",
    "feasible_report",
    "flow_width",
    "rollout_return",
]


#: Where an evaluation's xi are drawn from: the skill's flow, uniform over the box, or a given
#: sampler (an estimate, `goflow evaluate --sampler-file`); besides, "radius:R" (`CaptureDisk`).
XI_SOURCES = ("flow", "uniform", "estimate")


class CaptureDisk:
    """Grasp errors uniform over the disk of `radius` [m] around `centre` in the first two
    parameters (x, y), the others uniform over the box: where a skill's capture range is checked
    (`evaluate_skill(xi="radius:R")`, around the skill's centre). The disk must lie inside the
    box; a fixed sampler (`update` learns nothing)."""

    def __init__(self, space: ParamSpace, centre: ArrayLike, radius: float) -> None:
        self.space = space
        self.centre = space.validate(np.asarray(centre, dtype=np.float64), what="CaptureDisk centre")
        self.radius = check_number(radius, "CaptureDisk radius", 0.0, low_open=True)
        lo, hi = space.low[:2], space.high[:2]
        if np.any(self.centre[:2] - self.radius < lo) or np.any(self.centre[:2] + self.radius > hi):
            raise ValueError(
                f"a disk of radius {self.radius} m around {self.centre[:2].round(4).tolist()} leaves the "
                f"box x in [{lo[0]}, {hi[0]}], y in [{lo[1]}, {hi[1]}]; expected a smaller radius"
            )

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        n = check_sample_args(n, rng)
        xi = self.space.low + (self.space.high - self.space.low) * rng.random((n, self.space.dim))
        r, phi = self.radius * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
        xi[:, 0], xi[:, 1] = self.centre[0] + r * np.cos(phi), self.centre[1] + r * np.sin(phi)
        return xi

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        x = np.atleast_2d(np.asarray(xi, dtype=np.float64))
        inside = np.hypot(x[:, 0] - self.centre[0], x[:, 1] - self.centre[1]) <= self.radius
        inside &= np.all((x[:, 2:] >= self.space.low[2:]) & (x[:, 2:] <= self.space.high[2:]), axis=1)
        return np.where(inside, -self.entropy(), -np.inf)

    def entropy(self) -> float:
        return math.log(math.pi * self.radius**2) + float(np.sum(np.log(self.space.high[2:] - self.space.low[2:])))

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        return {}

    def state_dict(self) -> dict[str, Any]:
        return {
            "type": "CaptureDisk",
            "space": self.space.to_dict(),
            "centre": self.centre.tolist(),
            "radius": self.radius,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        raise ValueError("CaptureDisk is made from its skill, not loaded")


def capture_radius(xi: str) -> float | None:
    """R of an xi source "radius:R" (metres, > 0), None for another source; ValueError naming a
    malformed one."""
    if not isinstance(xi, str) or not xi.startswith("radius:"):
        return None
    try:
        radius = float(xi.split(":", 1)[1])
    except ValueError:
        radius = float("nan")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"xi source {xi!r}; expected radius:R with R > 0 metres (e.g. radius:0.005)")
    return radius


@dataclass(frozen=True)
class SkillEvaluation:
    """What `evaluate_skill` measured: the success rate (with its binomial standard error) and mean
    return of the deterministic policy, and where xi came from (the flow, the uniform box or a
    given sampler, whose state_dict is `xi_sampler`)."""

    gear: str
    variant: str  # the env variant ("fast" or "panda")
    xi: str  # one of XI_SOURCES
    episodes: int
    success_rate: float
    success_se: float
    mean_return: float
    seed: int
    seconds: float  # wall time
    xi_mean: list[float]  # mean and std of the episodes' xi (parameter units)
    xi_std: list[float]
    jobs: int = 1  # the episodes were split into this many jobs (evaluate_skill_jobs), seeded per job
    xi_sampler: dict[str, Any] | None = None  # xi "estimate": the sampler's state_dict (type, space, dist)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON data (the `goflow evaluate --json` file)."""
        return dataclasses.asdict(self)


def xi_source(text: str) -> str:
    """`text` if it names an evaluation's xi source on the command line (uniform, flow or
    radius:R, R > 0 metres); argparse.ArgumentTypeError otherwise (a `type=` for argparse)."""
    import argparse

    try:
        if text in ("uniform", "flow") or capture_radius(text) is not None:
            return text
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    raise argparse.ArgumentTypeError(f"{text!r}; expected uniform, flow or radius:R (R > 0 metres, e.g. radius:0.005)")


def _check_xi_source(xi: str, sampler: Sampler | None, skill: Skill) -> Sampler | None:
    """`xi` is one of XI_SOURCES or "radius:R" (its disk inside the skill's box), and `sampler`
    is given (over the skill's ParamSpace) exactly when it is "estimate"; ValueError otherwise.
    Returns the sampler the episodes draw from, None for the skill's flow or the uniform box: the
    given one, or the CaptureDisk of "radius:R"."""
    radius = capture_radius(xi)
    if radius is not None:
        if sampler is not None:
            raise ValueError(f"xi source {xi!r} with sampler {sampler!r}: a sampler goes with xi 'estimate' only")
        return CaptureDisk(skill.space, skill.centre(), radius)
    if xi not in XI_SOURCES:
        raise ValueError(f"xi source {xi!r}; expected one of {list(XI_SOURCES)} or radius:R")
    if (xi == "estimate") != (sampler is not None):
        raise ValueError(f"xi source {xi!r} with sampler {sampler!r}: a sampler goes with xi 'estimate' only")
    if sampler is not None and sampler.space != skill.space:
        raise ValueError(
            f"the sampler's ParamSpace differs from skill {skill.name}-{skill.gear}'s (skill vs sampler): "
            + "; ".join(skill.space.diff(sampler.space))
        )
    return sampler


def _episodes(
    skill: Skill,
    variant: str,
    xi: str,
    sampler: Sampler | None,
    episodes: int,
    seed: int,
    num_envs: int,
    progress: bool,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """`episodes` episodes of the skill's deterministic policy in `num_envs` envs, xi from
    `sampler` when given (an estimate, a CaptureDisk), else from `xi` ("flow" or "uniform"): (xi,
    returns, successes)."""

    def make() -> gymnasium.Env:
        env = skill.make_env(variant, "uniform" if sampler is not None else xi)
        if sampler is not None:
            env.unwrapped.sampler = sampler
        return env

    n = max(1, min(int(num_envs), int(episodes)))
    vec = gymnasium.vector.SyncVectorEnv(
        [make for _ in range(n)], autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP
    )
    try:
        return skill.agent.evaluate(vec, int(episodes), deterministic=True, seed=seed, progress=progress)
    finally:
        vec.close()


def evaluate_skill(
    skill: Skill,
    variant: str = "fast",
    xi: str = "flow",
    episodes: int = 100,
    seed: int = 0,
    num_envs: int = 4,
    progress: bool = False,
    sampler: Sampler | None = None,
) -> SkillEvaluation:
    """Run `episodes` episodes of the skill's deterministic policy in `num_envs` environments,
    with xi from its flow (`xi="flow"`), uniform over the box ("uniform"), uniform over the disk
    of radius R [m] around the skill's centre in x, y with the yaw uniform over the box
    ("radius:R", `CaptureDisk`: a capture range), or from `sampler` ("estimate": e.g. the
    EstimatedSampler of a `goflow estimate` file; required then, and over the skill's ParamSpace); `progress` shows a bar of the episodes finished. ValueError on a bad
    source, before any episode."""
    episodes = check_int(episodes, "episodes", 1)
    draws = _check_xi_source(xi, sampler, skill)
    t0 = time.perf_counter()
    xis, returns, successes = _episodes(skill, variant, xi, draws, episodes, seed, num_envs, progress)
    return _evaluation(
        skill.gear, variant, xi, seed, time.perf_counter() - t0, xis, returns, successes, sampler=sampler
    )


def _evaluation(
    gear: str,
    variant: str,
    xi: str,
    seed: int,
    seconds: float,
    xis: NDArray[np.float64],
    returns: NDArray[np.float64],
    successes: NDArray[np.bool_],
    jobs: int = 1,
    sampler: Sampler | None = None,
) -> SkillEvaluation:
    rate = float(np.mean(successes))
    return SkillEvaluation(
        gear=gear,
        variant=variant,
        xi=xi,
        episodes=len(successes),
        success_rate=rate,
        success_se=float(math.sqrt(max(rate * (1 - rate), 1e-12) / len(successes))),
        mean_return=float(np.mean(returns)),
        seed=int(seed),
        seconds=seconds,
        xi_mean=xis.mean(axis=0).tolist(),
        xi_std=xis.std(axis=0).tolist(),
        jobs=jobs,
        xi_sampler=None if sampler is None else sampler.state_dict(),
    )


def _evaluate_part(
    path: str, variant: str, xi: str, sampler: Sampler | None, episodes: int, seed: int, num_envs: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """One job of `evaluate_skill_jobs`, in a worker: the skill file's episodes (xi, returns, successes)."""
    torch.set_num_threads(1)
    return _episodes(Skill.load(path), variant, xi, sampler, episodes, seed, num_envs, False)


def evaluate_skill_jobs(
    path: str | os.PathLike[str],
    variant: str = "fast",
    xi: str = "flow",
    episodes: int = 100,
    seed: int = 0,
    jobs: int = 1,
    num_envs: int = 4,
    backend: Backend | None = None,
    progress: bool = False,
    sampler: Sampler | None = None,
) -> SkillEvaluation:
    """`evaluate_skill` of the skill file at `path` with its episodes split into `jobs` parts run on
    `backend` (learning.execution; default: this process), each loading the file (a path every
    worker reaches; `sampler`, for xi "estimate", travels with each job). Part j runs
    `episodes // jobs` episodes (one more for the first `episodes % jobs`) seeded with `seed` itself
    when `jobs` is 1 (the same episodes as `evaluate_skill`), else with a seed drawn from (seed, j):
    the result depends on `jobs`, never on the backend or the number of workers. ValueError on a
    bad xi source (see `evaluate_skill`), before any job."""
    episodes = check_int(episodes, "episodes", 1)
    jobs = check_int(jobs, "jobs", 1)
    if jobs > episodes:
        raise ValueError(f"jobs = {jobs}; expected at most episodes = {episodes}")
    path = Path(path).resolve()
    skill = Skill.load(path)  # a bad file fails here, before any job
    draws = _check_xi_source(xi, sampler, skill)
    t0 = time.perf_counter()
    sizes = [episodes // jobs + (1 if j < episodes % jobs else 0) for j in range(jobs)]
    seeds = (
        [int(seed)]
        if jobs == 1
        else [int(np.random.SeedSequence([int(seed), j]).generate_state(1)[0]) for j in range(jobs)]
    )
    parts = run_grid(
        [
            Job(
                f"episodes {sum(sizes[:j])}-{sum(sizes[: j + 1]) - 1}",
                _evaluate_part,
                (str(path), variant, xi, draws, sizes[j], seeds[j], num_envs),
            )
            for j in range(jobs)
        ],
        backend or InlineBackend(),
        progress,
        f"evaluate {skill.name}-{skill.gear}",
    )
    xis, returns, successes = (np.concatenate([part[k] for part in parts]) for k in range(3))
    return _evaluation(
        skill.gear, variant, xi, seed, time.perf_counter() - t0, xis, returns, successes, jobs, sampler=sampler
    )


def flow_width(skill: Skill, eps: float, samples: int = 200_000, seed: int = 0) -> dict[str, float]:
    """How wide the skill's flow is: its differential entropy (nats, parameter units), the uniform
    box's, and the fraction of the box (by volume) where its density exceeds `eps` (the planner's
    trust threshold, in 1 / parameter-unit volume)."""
    if not (isinstance(eps, (int, float)) and math.isfinite(eps) and eps >= 0):
        raise ValueError(f"eps must be a finite number >= 0, got {eps!r}")
    rng = np.random.default_rng(seed)
    u = skill.space.low + (skill.space.high - skill.space.low) * rng.random((samples, skill.space.dim))
    density = skill.density(u)
    volume = float(np.prod(skill.space.high - skill.space.low))
    return {
        "entropy": float(skill.sampler.entropy()),
        "uniform_entropy": math.log(volume),
        "eps": float(eps),
        "eps_uniform_ratio": float(eps * volume),
        "trusted_fraction": float(np.mean(density > eps)),
    }


def describe(skill: Skill) -> str:
    """One JSON line of a skill's provenance (for the CLI and docs) and, when the file holds a
    measured feasible set, the flow against it: the set's share of the box, the flow's mass on it
    and outside it, and the share of it the flow covers at 10 % and 1 % of the uniform-on-set
    density (learning.feasible_grid.flow_report)."""
    keep = ("steps", "rounds", "train_seconds", "final_uniform_success", "command", "exported")
    line = {
        "skill": skill.name,
        "gear": skill.gear,
        "method": skill.method,
        "mode": getattr(getattr(skill.sampler, "config", None), "mode", None),
        **{k: skill.provenance.get(k) for k in keep},
    }
    if "refit" in skill.provenance:
        line["refit_command"] = skill.provenance["refit"].get("command")
    if skill.feasible is not None:
        line["feasible_set"] = feasible_report(skill)
    return json.dumps(line)


def feasible_report(skill: Skill) -> dict[str, Any] | None:
    """The skill's measured feasible set (`FeasibleSet.summary`) and its flow against it
    (`flow_report`) in one plain dict, or None when the file holds no measurement."""
    if skill.feasible is None:
        return None
    return {**skill.feasible.summary(), **flow_report(skill.sampler, skill.feasible)}


def rollout_return(skill: Skill, xi: ArrayLike, env: gymnasium.Env | None = None, seed: int = 0) -> float:
    """The undiscounted return of one episode of the skill's deterministic policy at parameters
    xi (in `env`, default a new env of the skill's own variant), reset with `seed`. Any object
    whose `act(obs)` gives the action serves as `skill` when `env` is given."""
    own = env is None
    env = skill.make_env() if own else env
    try:
        obs, _ = env.reset(seed=seed, options={"xi": np.asarray(xi, np.float64)})
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(skill.act(obs))
            total += float(reward)
            done = terminated or truncated
    finally:
        if own:
            env.close()
    return total
