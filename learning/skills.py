"""Trained skills: a policy, its privileged value function V(s, xi), its sampling distribution
(the flow) and the ParamSpace and observation normalization they were trained with, in one small
file made by our own training command.

    skill = load_skill("insert", gear="medium")     # learning/skill_files/insert-medium.pt
    action = skill.act(obs)                          # deterministic policy mean
    v = skill.value(obs, xi)                         # privileged value V(s, xi)
    density = skill.density(xi)                      # the flow's density over the box

A skill file is written by `export_skill` from a `goflow train` run folder (its checkpoint and
log); `goflow skill train --gear G` does both with the recipe below, so every shipped file is
reproduced by one command (docs/skills.md).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

import assembly  # noqa: F401  (registers the environment ids)
from assembly.gearset import GEARS
from assembly.params import ParamSpace
from assembly.samplers import FullDR, Sampler
from goflow_common.checks import check_int
from goflow_common.errors import FileFormatError, InputError
from goflow_common.files import check_output_file, load_tensors, run_folder_lock, save_tensors
from learning.execution import Backend, InlineBackend, Job, run_grid
from learning.experiment import SamplerFitConfig, TrainConfig, fit_sampler, load_run, protocol_sampler_kwargs, train
from learning.feasible_grid import FeasibleGridConfig, FeasibleSet, FlowRefitConfig, GridPlan, flow_report, refit_flow
from learning.ppo import PPO, PPOConfig
from learning.samplers.registry import make_sampler

__all__ = ["SKILLS", "SKILL_DIR", "RUNS_SKILL_DIR", "INSERT_GRID", "Skill", "SkillEvaluation", "SkillRecipe",
           "describe", "evaluate_skill", "evaluate_skill_jobs", "export_skill", "feasible_report", "flow_width",
           "load_skill", "measure_feasible_set", "refit_skill", "rollout_return", "skill_path", "skill_run_folder",
           "train_skill", "train_skills"]

SKILL_DIR = Path(__file__).parent / "skill_files"
#: Where `train_skill` and `goflow skill train/export` write by default (never the shipped files).
RUNS_SKILL_DIR = Path("runs") / "skills"
SKILLS = ("insert",)
_FORMAT = "goflow-skill-1"
_ENV = {"insert": "goflow/GearInsertion-v0"}
#: The insert skill's measurement grid: 0.3 mm cells over 12 mm x 12 mm around the flow's median,
#: 3 yaw layers over the whole yaw range, and 11 x 11 x 3 coarse cells over the box (docs/skills.md).
INSERT_GRID = FeasibleGridConfig(fine_width=(0.012, 0.012, 0.786), fine_cells=(40, 40, 3), coarse_cells=(11, 11, 3))
#: Episodes per job of a measurement, and of a refit update (whose batch is small: several workers share it).
PART = 128
REFIT_PART = 16


def _check_name(name: str, gear: str) -> None:
    if name not in SKILLS:
        raise ValueError(f"unknown skill {name!r}; expected one of {list(SKILLS)}")
    if gear not in GEARS:
        raise ValueError(f"unknown gear {gear!r}; expected one of {sorted(GEARS)}")


def skill_run_folder(name: str, gear: str, runs: str | os.PathLike[str] = RUNS_SKILL_DIR) -> Path:
    """The `goflow train` run folder in which `train_skill` trains skill `name` for `gear`."""
    _check_name(name, gear)
    return Path(runs) / f"{name}-{gear}"


def skill_path(name: str, gear: str, folder: str | os.PathLike[str] = SKILL_DIR) -> Path:
    """The file of skill `name` for `gear` in `folder` (default: where the shipped file lives)."""
    _check_name(name, gear)
    return Path(folder) / f"{name}-{gear}.pt"


@dataclass
class SkillRecipe:
    """How a shipped skill is trained: the `goflow train` settings behind `goflow skill train`."""

    method: str = "goflow"
    variant: str = "fast"
    seed: int = 0
    total_steps: int = 120_000
    iterations_per_round: int = 2
    # The flow learns from the uniform-box validation batch, where only ~0.3 % of grasp errors
    # are within the chamfer's capture range: a larger batch shows it a success more often.
    eval_episodes: int = 96
    # GoFlow from a narrow start (std 5 mm in x, y) with a small entropy weight (the seed swept
    # alpha in {0.1, ..., 2}): the training probes in docs/skills.md.
    sampler_kwargs: dict[str, Any] = field(default_factory=lambda: {"alpha": 0.1, "base_scale": 0.5})
    ppo: PPOConfig = field(default_factory=lambda: PPOConfig(num_steps=100, init_log_std=-1.0))
    # Stage 2, refinement: GoFlow learns from its own training episodes (sampler_batch="training"),
    # which hit the chamfer's capture range as often as the flow does; 4 iterations per round give
    # each flow update 32 episodes. The uniform-box validation goes on, smaller (docs/skills.md).
    refine_steps: int = 48_000
    refine_iterations_per_round: int = 4
    refine_eval_episodes: int = 16
    # Stage 3, the policy frozen: the flow learns where the deterministic policy (the one shipped)
    # succeeds on the flow's own draws (learning.experiment.fit_sampler); 0 rounds: none.
    fit_rounds: int = 30
    fit_episodes: int = 64
    # Stage 4, the policy still frozen: the flow refitted in GoFlow's constrained mode to where the
    # policy succeeds, measured on `grid` (`refit_skill`); None: no stage 4.
    grid: FeasibleGridConfig = INSERT_GRID
    refit: FlowRefitConfig | None = field(default_factory=FlowRefitConfig)

    def train_config(self, name: str, gear: str, out: Path) -> TrainConfig:
        """Stage 1 of this recipe for skill `name` on `gear`, writing to run folder `out`."""
        _check_name(name, gear)
        return TrainConfig(env=_ENV[name], env_kwargs={"gear": gear, "variant": self.variant},
                           method=self.method, sampler_kwargs=dict(self.sampler_kwargs), seed=self.seed,
                           total_steps=self.total_steps, iterations_per_round=self.iterations_per_round,
                           eval_episodes=self.eval_episodes, ppo=self.ppo, out=Path(out))

    def refine_config(self, name: str, gear: str, out: Path) -> TrainConfig:
        """Stage 2: the same run continued for `refine_steps`, the flow learning from its own draws."""
        return dataclasses.replace(self.train_config(name, gear, out),
                                   total_steps=self.total_steps + self.refine_steps,
                                   iterations_per_round=self.refine_iterations_per_round,
                                   eval_episodes=self.refine_eval_episodes, sampler_batch="training")

    def stages(self, name: str, gear: str, out: Path) -> list[TrainConfig]:
        """The TrainConfigs run one after the other on run folder `out`."""
        return [self.train_config(name, gear, out)] + (
            [self.refine_config(name, gear, out)] if self.refine_steps > 0 else [])


class Skill:
    """A trained skill: policy, privileged value function, sampling distribution, ParamSpace."""

    def __init__(self, name: str, gear: str, env_id: str, env_kwargs: dict[str, Any], method: str,
                 agent: PPO, sampler: Sampler, success_threshold: float, provenance: dict[str, Any],
                 feasible: FeasibleSet | None = None) -> None:
        _check_name(name, gear)
        self.name, self.gear, self.env_id = name, gear, env_id
        self.env_kwargs = dict(env_kwargs)
        self.method = method
        self.agent = agent
        self.sampler = sampler
        self.space: ParamSpace = sampler.space
        self.success_threshold = float(success_threshold)
        self.provenance = dict(provenance)
        #: where the policy succeeds, measured on a grid (`measure_feasible_set`), or None
        self.feasible = feasible

    def __repr__(self) -> str:
        return (f"Skill({self.name!r}, gear={self.gear!r}, method={self.method!r}, "
                f"params={self.space.names}, trained {self.provenance.get('steps', '?')} steps)")

    def act(self, obs: ArrayLike, deterministic: bool = True) -> NDArray[np.float32]:
        """Actions for raw observations (obs_dim,) or (n, obs_dim); the policy mean by default."""
        return self.agent.act(obs, deterministic=deterministic)

    def value(self, obs: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """Privileged value V(s, xi) for observations (n, obs_dim) or (obs_dim,) and parameters
        xi (n, d) or (d,) in parameter units (checked against the skill's box)."""
        o = np.asarray(obs, dtype=np.float64)
        single = o.ndim == 1
        o = o[None] if single else o
        x = self.space.as_batch(xi)
        if len(x) == 1 and len(o) > 1:
            x = np.repeat(x, len(o), axis=0)
        if o.ndim != 2 or o.shape[1] != self.agent.obs_dim or len(x) != len(o):
            raise ValueError(f"Skill.value: obs has shape {np.shape(obs)} and xi {np.shape(xi)}; expected "
                             f"({self.agent.obs_dim},) or (n, {self.agent.obs_dim}) and (d,) or (n, {self.space.dim})")
        self.space.validate(x, what="Skill.value xi")
        critic_obs = np.concatenate([o, self.space.normalize(x)], axis=1)
        with torch.no_grad():
            v = self.agent.critic(torch.from_numpy(self.agent._norm_critic_obs(critic_obs))).numpy()
        return v[0] if single else v.astype(np.float64)

    def density(self, xi: ArrayLike) -> NDArray[np.float64]:
        """The skill's sampling density at xi (parameter units; 0 outside the box)."""
        return np.exp(self.sampler.log_prob(xi))

    def make_env(self, variant: str | None = None, xi: str = "flow") -> gymnasium.Env:
        """The skill's environment (default: the variant it was trained on), drawing xi from the
        skill's flow (`xi="flow"`) or uniformly over the box (`xi="uniform"`)."""
        if xi not in ("flow", "uniform"):
            raise ValueError(f"xi source {xi!r}; expected 'flow' or 'uniform'")
        kwargs = dict(self.env_kwargs)
        if variant is not None:
            kwargs["variant"] = variant
        env = gymnasium.make(self.env_id, **kwargs)
        env.unwrapped.sampler = self.sampler if xi == "flow" else FullDR(self.space)
        return env

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the skill file atomically (tensors and plain data only); return its path."""
        path = check_output_file(path, "skill file")
        agent_state = self.agent.state_dict()
        state = {"format": _FORMAT, "name": self.name, "gear": self.gear, "env": self.env_id,
                 "env_kwargs": self.env_kwargs, "method": self.method,
                 "success_threshold": self.success_threshold, "space": self.space.to_dict(),
                 "agent": {k: v for k, v in agent_state.items() if k != "optimizer"},
                 "sampler": self.sampler.state_dict(), "provenance": self.provenance}
        if self.feasible is not None:
            state["feasible"] = self.feasible.state_dict()
        return save_tensors(path, state)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Skill:
        """Read a skill file written by `save`, as data only (torch.load with weights_only=True).

        Raises FileNotFoundError if there is no file and FileFormatError (a ValueError) naming the
        file when it is empty, truncated, foreign or not a goflow skill file."""
        what = f"goflow skill file (format {_FORMAT!r})"
        state = load_tensors(path, what)
        if not isinstance(state, dict) or state.get("format") != _FORMAT:
            raise FileFormatError(f"{path}: not a {what}")
        try:
            space = ParamSpace.from_dict(state["space"])
            agent = PPO.from_state_dict(state["agent"], optimizer=False)  # skills ship without Adam's moments
            sampler_kwargs = protocol_sampler_kwargs(state["method"], state["provenance"].get("sampler_kwargs", {}))
            sampler = make_sampler(state["method"], space, state["success_threshold"], sampler_kwargs)
            sampler.load_state_dict(state["sampler"])
            feasible = FeasibleSet.from_state_dict(state["feasible"]) if "feasible" in state else None
        except (KeyError, TypeError, AttributeError, FileFormatError) as exc:
            raise FileFormatError(f"{path}: a malformed {what} ({type(exc).__name__}: {exc})") from None
        return cls(state["name"], state["gear"], state["env"], state["env_kwargs"], state["method"], agent,
                   sampler, state["success_threshold"], state["provenance"], feasible)


def load_skill(name: str = "insert", gear: str = "medium", path: str | os.PathLike[str] | None = None) -> Skill:
    """The shipped skill `name` for `gear` (or the file at `path`)."""
    if path is None:
        path = skill_path(name, gear)
        if not path.is_file():
            raise FileNotFoundError(f"no shipped {name!r} skill for the {gear} gear at {path}; "
                                    f"train it with `goflow skill train --skill {name} --gear {gear}`")
    skill = Skill.load(path)
    if (skill.name, skill.gear) != (name, gear):
        raise ValueError(f"{path} holds the {skill.name!r} skill for the {skill.gear} gear, not {name!r} for {gear}")
    return skill


def export_skill(run: str | os.PathLike[str], name: str, gear: str, out: str | os.PathLike[str],
                 command: str = "") -> Skill:
    """Package a `goflow train` run folder (checkpoint.pt, log.json) as a skill file at `out`
    (`command` is recorded as provenance)."""
    _check_name(name, gear)
    check_output_file(out, "skill file")
    loaded = load_run(run)
    log = loaded.state["log"]
    cfg = log["config"]
    if cfg["env"] != _ENV[name] or cfg["env_kwargs"].get("gear", "medium") != gear:
        raise ValueError(f"{run} trained {cfg['env']} with {cfg['env_kwargs']}, not the {name!r} skill for "
                         f"the {gear} gear")
    sampler, agent = loaded.sampler, loaded.agent
    step, success, mean_return = log["curve"][-1]
    provenance = {"command": command, "steps": int(step), "rounds": int(log["rounds"]),
                  "train_seconds": float(log["seconds"]), "sampler_seconds": float(log["sampler_seconds"]),
                  "final_uniform_success": float(success), "final_uniform_return": float(mean_return),
                  "sampler_kwargs": dict(cfg["sampler_kwargs"]), "train_config": cfg,
                  "sampler_fit": log.get("sampler_fit", []), "sampler_fit_config": log.get("sampler_fit_config"),
                  "sampler_fit_best": log.get("sampler_fit_best"),
                  "exported": time.strftime("%Y-%m-%d")}
    skill = Skill(name, gear, cfg["env"], cfg["env_kwargs"], cfg["method"], agent, sampler,
                  log["success_threshold"], provenance)
    skill.save(out)
    return skill


def train_skill(name: str, gear: str, recipe: SkillRecipe | None = None, runs: str | os.PathLike[str] = RUNS_SKILL_DIR,
                out: str | os.PathLike[str] | None = None, command: str = "", progress: bool = True) -> Skill:
    """Train (or resume) skill `name` for `gear` with `recipe` in run folder `<runs>/<name>-<gear>`,
    then export it to `out` (default: `<runs>/<name>-<gear>.pt`; the shipped file in
    learning/skill_files is replaced only when `out` names it). The output paths are checked
    before training starts."""
    recipe = recipe or SkillRecipe()
    _check_name(name, gear)
    out = check_output_file(out or skill_path(name, gear, runs), "skill file")
    run = skill_run_folder(name, gear, runs)
    for config in recipe.stages(name, gear, run):
        train(config, progress=progress)
    if recipe.fit_rounds > 0:
        fit_sampler(run, SamplerFitConfig(rounds=recipe.fit_rounds, episodes=recipe.fit_episodes), progress=progress)
    if recipe.refit is None:
        return export_skill(run, name, gear, out, command=command)
    stage3 = check_output_file(run / "stage3.pt", "skill file")
    export_skill(run, name, gear, stage3, command=command)
    return refit_skill(stage3, out, recipe.grid, recipe.refit, folder=run / "refit", command=command,
                       progress=progress)


def _train_skill_file(name: str, gear: str, recipe: SkillRecipe, runs: str, out: str, command: str) -> str:
    """One gear of `train_skills`, in a worker: train_skill without progress bars; the file written."""
    train_skill(name, gear, recipe, runs=runs, out=out, command=command, progress=False)
    return out


def train_skills(name: str, gears: list[str] | tuple[str, ...], recipe: SkillRecipe | None = None,
                 runs: str | os.PathLike[str] = RUNS_SKILL_DIR, out: str | os.PathLike[str] | None = None,
                 command: str = "", backend: Backend | None = None, progress: bool = True) -> list[Skill]:
    """`train_skill` for each of `gears` (each writing `<runs>/<name>-<gear>.pt`, or `out` when
    there is one gear), one job per gear
    on `backend` (learning.execution; default: one after the other in this process, with their
    progress bars); return the skills in the order of `gears`. The names and the output paths are
    checked before any training (after the backend has started); each run resumes from its
    checkpoint, and a failed gear does not stop the others (GridError at the end)."""
    recipe = recipe or SkillRecipe()
    if not gears or len(set(gears)) < len(gears):
        raise ValueError(f"gears = {list(gears)}; expected one or more distinct gears")
    for gear in gears:
        _check_name(name, gear)
    if out is not None and len(gears) > 1:
        raise ValueError(f"out = {str(out)!r} names one skill file, but {len(gears)} gears are trained; leave it out "
                         f"(each gear's file goes to {Path(runs)}/{name}-<gear>.pt)")
    if backend is None and len(gears) == 1:
        return [train_skill(name, gears[0], recipe, runs=runs, out=out, command=command, progress=progress)]
    with backend or InlineBackend() as grid:
        outs = [str(check_output_file(out or skill_path(name, gear, runs), "skill file")) for gear in gears]
        jobs = [Job(f"{name}-{gear}", _train_skill_file, (name, gear, recipe, str(runs), out, command))
                for gear, out in zip(gears, outs)]
        files = run_grid(jobs, grid, progress, f"skill train {name}")
    return [Skill.load(f) for f in files]


@dataclass(frozen=True)
class SkillEvaluation:
    """What `evaluate_skill` measured: the success rate (with its binomial standard error) and mean
    return of the deterministic policy, and where xi came from (the flow or the uniform box)."""

    gear: str
    variant: str  # the env variant ("fast" or "panda")
    xi: str  # "flow" or "uniform"
    episodes: int
    success_rate: float
    success_se: float
    mean_return: float
    seed: int
    seconds: float  # wall time
    xi_mean: list[float]  # mean and std of the episodes' xi (parameter units)
    xi_std: list[float]
    jobs: int = 1  # the episodes were split into this many jobs (evaluate_skill_jobs), seeded per job

    def to_json(self) -> dict[str, Any]:
        """Plain JSON data (the `goflow evaluate --json` file)."""
        return dataclasses.asdict(self)


def evaluate_skill(skill: Skill, variant: str = "fast", xi: str = "flow", episodes: int = 100, seed: int = 0,
                   num_envs: int = 4, progress: bool = False) -> SkillEvaluation:
    """Run `episodes` episodes of the skill's deterministic policy with xi from its flow or uniform
    over the box, in `num_envs` environments; `progress` shows a bar of the episodes finished."""
    episodes = check_int(episodes, "episodes", 1)
    t0 = time.perf_counter()
    n = max(1, min(int(num_envs), int(episodes)))
    vec = gymnasium.vector.SyncVectorEnv([lambda: skill.make_env(variant, xi) for _ in range(n)],
                                         autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)
    try:
        xis, returns, successes = skill.agent.evaluate(vec, int(episodes), deterministic=True, seed=seed,
                                                       progress=progress)
    finally:
        vec.close()
    return _evaluation(skill.gear, variant, xi, seed, time.perf_counter() - t0, xis, returns, successes)


def _evaluation(gear: str, variant: str, xi: str, seed: int, seconds: float, xis: NDArray[np.float64],
                returns: NDArray[np.float64], successes: NDArray[np.bool_], jobs: int = 1) -> SkillEvaluation:
    rate = float(np.mean(successes))
    return SkillEvaluation(gear=gear, variant=variant, xi=xi, episodes=len(successes), success_rate=rate,
                           success_se=float(math.sqrt(max(rate * (1 - rate), 1e-12) / len(successes))),
                           mean_return=float(np.mean(returns)), seed=int(seed), seconds=seconds,
                           xi_mean=xis.mean(axis=0).tolist(), xi_std=xis.std(axis=0).tolist(), jobs=jobs)


def _evaluate_part(path: str, variant: str, xi: str, episodes: int, seed: int,
                   num_envs: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """One job of `evaluate_skill_jobs`, in a worker: the skill file's episodes (xi, returns, successes)."""
    torch.set_num_threads(1)
    skill = Skill.load(path)
    n = max(1, min(int(num_envs), int(episodes)))
    vec = gymnasium.vector.SyncVectorEnv([lambda: skill.make_env(variant, xi) for _ in range(n)],
                                         autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)
    try:
        return skill.agent.evaluate(vec, int(episodes), deterministic=True, seed=seed)
    finally:
        vec.close()


def evaluate_skill_jobs(path: str | os.PathLike[str], variant: str = "fast", xi: str = "flow", episodes: int = 100,
                        seed: int = 0, jobs: int = 1, num_envs: int = 4, backend: Backend | None = None,
                        progress: bool = False) -> SkillEvaluation:
    """`evaluate_skill` of the skill file at `path` with its episodes split into `jobs` parts run on
    `backend` (learning.execution; default: this process), each loading the file (a path every
    worker reaches). Part j runs `episodes // jobs` episodes (one more for the first
    `episodes % jobs`) seeded with `seed` itself when `jobs` is 1 (the same episodes as
    `evaluate_skill`), else with a seed drawn from (seed, j): the result depends on `jobs`, never
    on the backend or the number of workers."""
    episodes = check_int(episodes, "episodes", 1)
    jobs = check_int(jobs, "jobs", 1)
    if jobs > episodes:
        raise ValueError(f"jobs = {jobs}; expected at most episodes = {episodes}")
    if xi not in ("flow", "uniform"):
        raise ValueError(f"xi source {xi!r}; expected 'flow' or 'uniform'")
    path = Path(path).resolve()
    skill = Skill.load(path)  # a bad file fails here, before any job
    t0 = time.perf_counter()
    sizes = [episodes // jobs + (1 if j < episodes % jobs else 0) for j in range(jobs)]
    seeds = [int(seed)] if jobs == 1 else [int(np.random.SeedSequence([int(seed), j]).generate_state(1)[0])
                                           for j in range(jobs)]
    parts = run_grid([Job(f"episodes {sum(sizes[:j])}-{sum(sizes[:j + 1]) - 1}", _evaluate_part,
                          (str(path), variant, xi, sizes[j], seeds[j], num_envs)) for j in range(jobs)],
                     backend or InlineBackend(), progress, f"evaluate {skill.name}-{skill.gear}")
    xis, returns, successes = (np.concatenate([part[k] for part in parts]) for k in range(3))
    return _evaluation(skill.gear, variant, xi, seed, time.perf_counter() - t0, xis, returns, successes, jobs)


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
    return {"entropy": float(skill.sampler.entropy()), "uniform_entropy": math.log(volume),
            "eps": float(eps), "eps_uniform_ratio": float(eps * volume),
            "trusted_fraction": float(np.mean(density > eps))}


def describe(skill: Skill) -> str:
    """One JSON line of a skill's provenance (for the CLI and docs) and, when the file holds a
    measured feasible set, the flow against it: the set's share of the box, the flow's mass on it
    and outside it, and the share of it the flow covers at 10 % and 1 % of the uniform-on-set
    density (learning.feasible_grid.flow_report)."""
    keep = ("steps", "rounds", "train_seconds", "final_uniform_success", "command", "exported")
    line = {"skill": skill.name, "gear": skill.gear, "method": skill.method,
            "mode": getattr(getattr(skill.sampler, "config", None), "mode", None),
            **{k: skill.provenance.get(k) for k in keep}}
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


# -- where the policy succeeds, and the flow refitted to it ---------------------------------------


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


def _returns_at(path: str, variant: str, xi: NDArray[np.float64]) -> NDArray[np.float64]:
    """One job, in a worker: the returns of the skill file's deterministic policy at each row of xi."""
    torch.set_num_threads(1)
    skill = Skill.load(path)
    env = skill.make_env(variant)
    try:
        return np.array([rollout_return(skill, x, env) for x in xi])
    finally:
        env.close()


def _returns(path: str, variant: str, xi: NDArray[np.float64], backend: Backend, progress: bool, desc: str,
             done: dict[int, NDArray[np.float64]] | None = None, save: Any = None,
             part: int = PART) -> NDArray[np.float64]:
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
        run_grid([Job(f"{desc} {k}", _returns_at, (path, variant, xi[parts[k]])) for k in todo], backend, progress,
                 desc, on_result=keep)
    return np.concatenate([done[k] for k in range(len(parts))]) if parts else np.zeros(0)


def _flow_median(skill: Skill) -> NDArray[np.float64]:
    return np.median(skill.sampler.sample(4096, np.random.default_rng(0)), axis=0)


def _variants(skill: Skill, grid: FeasibleGridConfig) -> tuple[str, ...]:
    """The env variants a cell must succeed in: the grid's (default the skill's own), then the
    confirming one."""
    first = grid.variant or skill.env_kwargs.get("variant", "fast")
    return (first,) if grid.confirm_variant in (None, first) else (first, grid.confirm_variant)


def _covered(variant: str, variants: tuple[str, ...]) -> int:
    """How many of `variants` a measurement made in `variant` ("fast", "fast+panda") covers: the
    length of its chain when that chain starts `variants`, else 0."""
    done = tuple(variant.split("+"))
    return len(done) if done == variants[:len(done)] else 0


def _checkpointed_returns(path: Path, variant: str, xi: NDArray[np.float64], key: dict[str, Any],
                          checkpoint: Path | None, backend: Backend, progress: bool, desc: str) -> NDArray[np.float64]:
    """`_returns` whose finished jobs are saved in `checkpoint` under `key` and reused from it."""
    done: dict[int, NDArray[np.float64]] = {}
    if checkpoint is not None and checkpoint.is_file():
        saved = load_tensors(checkpoint, "feasible-set measurement checkpoint")
        if isinstance(saved, dict) and saved.get("key") == key:
            done = {int(k): torch.as_tensor(v).numpy() for k, v in saved["parts"].items()}

    def save(parts: dict[int, NDArray[np.float64]]) -> None:
        save_tensors(checkpoint, {"key": key, "parts": {str(k): torch.from_numpy(v) for k, v in parts.items()}})

    return _returns(str(path), variant, xi, backend, progress, desc, done, save if checkpoint is not None else None)


def measure_feasible_set(path: str | os.PathLike[str], grid: FeasibleGridConfig = INSERT_GRID,
                         backend: Backend | None = None, progress: bool = False,
                         checkpoint: str | os.PathLike[str] | None = None,
                         known: FeasibleSet | None = None) -> FeasibleSet:
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
        done, plan = 1, grid.plan(skill.space, _flow_median(skill))
        returns = _checkpointed_returns(path, variants[0], plan.points(),
                                        {"skill_sha256": sha, "grid": [*plan.key(), variants[0], PART]},
                                        checkpoint, backend, progress, "feasible set")
    xi = plan.points()
    for variant in variants[done:]:
        good = np.flatnonzero(returns >= skill.success_threshold)
        again = _checkpointed_returns(
            path, variant, xi[good],
            {"skill_sha256": sha, "grid": [*plan.key(), variant, PART], "cells": good.tolist()},
            None if checkpoint is None else checkpoint.with_name(f"{checkpoint.stem}-{variant}.pt"), backend,
            progress, f"feasible set, {variant}")
        returns[good] = np.minimum(returns[good], again)
    return plan.feasible_set(returns, skill.success_threshold, "+".join(variants))


def _same_policy(a: Skill, b: Skill) -> bool:
    """Whether two skills run the same deterministic policy in the same environment and box (so a
    feasible set measured with one holds for the other)."""
    if (a.env_id, a.env_kwargs, a.space.to_dict(), a.success_threshold) != \
            (b.env_id, b.env_kwargs, b.space.to_dict(), b.success_threshold):
        return False
    for mine, theirs in ((a.agent.actor.state_dict(), b.agent.actor.state_dict()),
                         (a.agent.obs_rms.state_dict(), b.agent.obs_rms.state_dict())):
        if mine.keys() != theirs.keys() or not all(
                torch.equal(torch.as_tensor(mine[k]), torch.as_tensor(theirs[k])) for k in mine):
            return False
    return True


def refit_skill(path: str | os.PathLike[str], out: str | os.PathLike[str], grid: FeasibleGridConfig = INSERT_GRID,
                refit: FlowRefitConfig | None = None, folder: str | os.PathLike[str] | None = None,
                backend: Backend | None = None, command: str = "", progress: bool = False,
                feasible_from: str | os.PathLike[str] | None = None) -> Skill:
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
            raise InputError(f"feasible_from = {str(feasible_from)!r}: its policy, environment or box differ from "
                             f"{str(path)!r}'s; a measured feasible set holds only for the policy that ran it")
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
    if feasible is None or (feasible.fine_cells, feasible.coarse_cells) != (plan.fine_cells, plan.coarse_cells) \
            or not np.allclose(feasible.fine_high - feasible.fine_low, plan.high - plan.low):
        return 0
    return _covered(feasible.variant, variants)


def _refit_skill(skill: Skill, path: Path, out: Path, grid: FeasibleGridConfig, refit: FlowRefitConfig,
                 folder: Path | None, backend: Backend, command: str, progress: bool,
                 known: FeasibleSet | None) -> Skill:
    variants = _variants(skill, grid)
    plan = grid.plan(skill.space, _flow_median(skill))
    # the file's own measurement first, then the one handed in: whichever covers more variants
    covered, feasible = max(((_usable(f, plan, variants), f) for f in (skill.feasible, known)), key=lambda c: c[0])
    if covered < len(variants):
        feasible = measure_feasible_set(path, grid, backend, progress,
                                        folder / "feasible.pt" if folder is not None else None,
                                        feasible if covered else None)
    before = flow_report(skill.sampler, feasible)

    def evaluate(xi: NDArray[np.float64], update: int) -> NDArray[np.float64]:
        returns = _returns(str(path), variants[0], xi, backend, False, f"refit update {update}", part=REFIT_PART)
        for variant in variants[1:]:  # a success must hold in the confirming variant too
            good = np.flatnonzero(returns >= skill.success_threshold)
            returns[good] = np.minimum(returns[good], _returns(str(path), variant, xi[good], backend, False,
                                                               f"refit update {update}, {variant}", part=REFIT_PART))
        return returns

    with backend:  # one pool or cluster for every update
        sampler, records = refit_flow(skill.sampler, feasible, evaluate, refit,
                                      _refit_checkpoint(folder, path, feasible), progress)
    provenance = {**skill.provenance, "refit": {"command": command, "config": refit.to_dict(),
                                                "feasible_set": feasible.summary(), "before": before,
                                                "updates": records, "date": time.strftime("%Y-%m-%d")}}
    new = Skill(skill.name, skill.gear, skill.env_id, skill.env_kwargs, skill.method, skill.agent, sampler,
                skill.success_threshold, provenance, feasible)
    new.save(out)
    return new
