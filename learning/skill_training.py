"""Training a shipped skill: the recipe behind `goflow skill train`, a `goflow train` run folder
exported as a skill file, and one job per gear (docs/skills.md).
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from goflow_common.files import check_output_file
from learning.execution import Backend, InlineBackend, Job, run_grid
from learning.experiment import SamplerFitConfig, TrainConfig, fit_sampler, load_run, train
from learning.feasible_grid import FeasibleGridConfig, FlowRefitConfig
from learning.ppo import PPOConfig
from learning.skill_feasible_set import INSERT_GRID, refit_skill
from learning.skill_file import SKILL_ENVS, Skill, check_skill_name, skill_path

__all__ = ["RUNS_SKILL_DIR", "SkillRecipe", "export_skill", "skill_run_folder", "train_skill", "train_skills"]

#: Where `train_skill` and `goflow skill train/export` write by default (never the shipped files).
RUNS_SKILL_DIR = Path("runs") / "skills"


def skill_run_folder(name: str, gear: str, runs: str | os.PathLike[str] = RUNS_SKILL_DIR) -> Path:
    """The `goflow train` run folder in which `train_skill` trains skill `name` for `gear`."""
    check_skill_name(name, gear)
    return Path(runs) / f"{name}-{gear}"


@dataclass
class SkillRecipe:
    """How a shipped skill is trained: the `goflow train` settings behind `goflow skill train`."""

    method: str = "goflow"
    variant: str = "fast"
    # What the policy observes (assembly.insertion_law.SENSING): "pose" (the shipped blind skills)
    # or "wrench" (also the Panda's estimated external wrench, assembly.wrench_sensor).
    sensing: str = "pose"
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
        check_skill_name(name, gear)
        return TrainConfig(
            env=SKILL_ENVS[name],
            env_kwargs={"gear": gear, "variant": self.variant}
            | ({"sensing": self.sensing} if self.sensing != "pose" else {}),
            method=self.method,
            sampler_kwargs=dict(self.sampler_kwargs),
            seed=self.seed,
            total_steps=self.total_steps,
            iterations_per_round=self.iterations_per_round,
            eval_episodes=self.eval_episodes,
            ppo=self.ppo,
            out=Path(out),
        )

    def refine_config(self, name: str, gear: str, out: Path) -> TrainConfig:
        """Stage 2: the same run continued for `refine_steps`, the flow learning from its own draws."""
        return dataclasses.replace(
            self.train_config(name, gear, out),
            total_steps=self.total_steps + self.refine_steps,
            iterations_per_round=self.refine_iterations_per_round,
            eval_episodes=self.refine_eval_episodes,
            sampler_batch="training",
        )

    def stages(self, name: str, gear: str, out: Path) -> list[TrainConfig]:
        """The TrainConfigs run one after the other on run folder `out`."""
        return [self.train_config(name, gear, out)] + (
            [self.refine_config(name, gear, out)] if self.refine_steps > 0 else []
        )


def export_skill(
    run: str | os.PathLike[str], name: str, gear: str, out: str | os.PathLike[str], command: str = ""
) -> Skill:
    """Package a `goflow train` run folder (checkpoint.pt, log.json) as a skill file at `out`
    (`command` is recorded as provenance)."""
    check_skill_name(name, gear)
    check_output_file(out, "skill file")
    loaded = load_run(run)
    log = loaded.state["log"]
    cfg = log["config"]
    if cfg["env"] != SKILL_ENVS[name] or cfg["env_kwargs"].get("gear", "medium") != gear:
        raise ValueError(
            f"{run} trained {cfg['env']} with {cfg['env_kwargs']}, not the {name!r} skill for the {gear} gear"
        )
    sampler, agent = loaded.sampler, loaded.agent
    step, success, mean_return = log["curve"][-1]
    provenance = {
        "command": command,
        "steps": int(step),
        "rounds": int(log["rounds"]),
        "train_seconds": float(log["seconds"]),
        "sampler_seconds": float(log["sampler_seconds"]),
        "final_uniform_success": float(success),
        "final_uniform_return": float(mean_return),
        "sampler_kwargs": dict(cfg["sampler_kwargs"]),
        "train_config": cfg,
        "sampler_fit": log.get("sampler_fit", []),
        "sampler_fit_config": log.get("sampler_fit_config"),
        "sampler_fit_best": log.get("sampler_fit_best"),
        "exported": time.strftime("%Y-%m-%d"),
    }
    skill = Skill(
        name, gear, cfg["env"], cfg["env_kwargs"], cfg["method"], agent, sampler, log["success_threshold"], provenance
    )
    skill.save(out)
    return skill


def train_skill(
    name: str,
    gear: str,
    recipe: SkillRecipe | None = None,
    runs: str | os.PathLike[str] = RUNS_SKILL_DIR,
    out: str | os.PathLike[str] | None = None,
    command: str = "",
    progress: bool = True,
) -> Skill:
    """Train (or resume) skill `name` for `gear` with `recipe` in run folder `<runs>/<name>-<gear>`,
    then export it to `out` (default: `<runs>/<name>-<gear>.pt`; the shipped file in
    learning/skill_files is replaced only when `out` names it). The output paths are checked
    before training starts."""
    recipe = recipe or SkillRecipe()
    check_skill_name(name, gear)
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
    return refit_skill(stage3, out, recipe.grid, recipe.refit, folder=run / "refit", command=command, progress=progress)


def _train_skill_file(name: str, gear: str, recipe: SkillRecipe, runs: str, out: str, command: str) -> str:
    """One gear of `train_skills`, in a worker: train_skill without progress bars; the file written."""
    train_skill(name, gear, recipe, runs=runs, out=out, command=command, progress=False)
    return out


def train_skills(
    name: str,
    gears: list[str] | tuple[str, ...],
    recipe: SkillRecipe | None = None,
    runs: str | os.PathLike[str] = RUNS_SKILL_DIR,
    out: str | os.PathLike[str] | None = None,
    command: str = "",
    backend: Backend | None = None,
    progress: bool = True,
) -> list[Skill]:
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
        check_skill_name(name, gear)
    if out is not None and len(gears) > 1:
        raise ValueError(
            f"out = {str(out)!r} names one skill file, but {len(gears)} gears are trained; leave it out "
            f"(each gear's file goes to {Path(runs)}/{name}-<gear>.pt)"
        )
    if backend is None and len(gears) == 1:
        return [train_skill(name, gears[0], recipe, runs=runs, out=out, command=command, progress=progress)]
    with backend or InlineBackend() as grid:
        outs = [str(check_output_file(out or skill_path(name, gear, runs), "skill file")) for gear in gears]
        jobs = [
            Job(f"{name}-{gear}", _train_skill_file, (name, gear, recipe, str(runs), out, command))
            for gear, out in zip(gears, outs)
        ]
        files = run_grid(jobs, grid, progress, f"skill train {name}")
    return [Skill.load(f) for f in files]
