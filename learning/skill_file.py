"""The skill file: a trained policy, its privileged value function V(s, xi), its sampling
distribution (the flow), the ParamSpace and observation normalization they were trained with, and
optionally the measured feasible set, in one small data-only file.

    skill = load_skill("insert", gear="medium")     # learning/skill_files/insert-medium.pt
    action = skill.act(obs)                          # deterministic policy mean
    v = skill.value(obs, xi)                         # privileged value V(s, xi)
    density = skill.density(xi)                      # the flow's density over the box

Files are written by `learning.skill_training` (`goflow skill train`, docs/skills.md).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from numpy.typing import ArrayLike, NDArray

import assembly  # noqa: F401  (registers the environment ids)
from assembly.gearset import GEARS
from assembly.params import ParamSpace
from assembly.samplers import FullDR, Sampler
from goflow_common.errors import FileFormatError
from goflow_common.files import check_output_file, load_tensors, save_tensors
from learning.feasible_grid import FeasibleSet
from learning.ppo import PPO
from learning.samplers.registry import make_sampler, protocol_sampler_kwargs

__all__ = ["SKILLS", "SKILL_DIR", "SKILL_ENVS", "SKILL_FORMAT", "Skill", "check_skill_name", "load_skill", "skill_path"]

SKILL_DIR = Path(__file__).parent / "skill_files"
SKILLS = ("insert",)
#: The `format` entry of every skill file.
SKILL_FORMAT = "goflow-skill-1"
#: The environment id each skill is trained and run in.
SKILL_ENVS = {"insert": "goflow/GearInsertion-v0"}


def check_skill_name(name: str, gear: str) -> None:
    """ValueError unless `name` is one of SKILLS and `gear` one of assembly.gearset.GEARS."""
    if name not in SKILLS:
        raise ValueError(f"unknown skill {name!r}; expected one of {list(SKILLS)}")
    if gear not in GEARS:
        raise ValueError(f"unknown gear {gear!r}; expected one of {sorted(GEARS)}")


def skill_path(name: str, gear: str, folder: str | os.PathLike[str] = SKILL_DIR) -> Path:
    """The file of skill `name` for `gear` in `folder` (default: where the shipped file lives)."""
    check_skill_name(name, gear)
    return Path(folder) / f"{name}-{gear}.pt"


class Skill:
    """A trained skill: policy, privileged value function, sampling distribution, ParamSpace."""

    def __init__(
        self,
        name: str,
        gear: str,
        env_id: str,
        env_kwargs: dict[str, Any],
        method: str,
        agent: PPO,
        sampler: Sampler,
        success_threshold: float,
        provenance: dict[str, Any],
        feasible: FeasibleSet | None = None,
    ) -> None:
        check_skill_name(name, gear)
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
        return (
            f"Skill({self.name!r}, gear={self.gear!r}, method={self.method!r}, sensing={self.sensing!r}, "
            f"params={self.space.names}, trained {self.provenance.get('steps', '?')} steps)"
        )

    def centre(self) -> NDArray[np.float64]:
        """The skill's centre: its flow's per-axis median (4096 draws, a fixed seed), shape (d,)."""
        return np.median(self.sampler.sample(4096, np.random.default_rng(0)), axis=0)

    @property
    def sensing(self) -> str:
        """What the policy observes (assembly.insertion_law.SENSING): "pose" (tool poses only, as
        every file written before the force channel) or "wrench" (poses and the external wrench)."""
        return str(self.env_kwargs.get("sensing", "pose"))

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
            raise ValueError(
                f"Skill.value: obs has shape {np.shape(obs)} and xi {np.shape(xi)}; expected "
                f"({self.agent.obs_dim},) or (n, {self.agent.obs_dim}) and (d,) or (n, {self.space.dim})"
            )
        self.space.validate(x, what="Skill.value xi")
        critic_obs = np.concatenate([o, self.space.normalize(x)], axis=1)
        v = self.agent.value(critic_obs)
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
        state = {
            "format": SKILL_FORMAT,
            "name": self.name,
            "gear": self.gear,
            "env": self.env_id,
            "env_kwargs": self.env_kwargs,
            "method": self.method,
            "success_threshold": self.success_threshold,
            "space": self.space.to_dict(),
            "agent": {k: v for k, v in agent_state.items() if k != "optimizer"},
            "sampler": self.sampler.state_dict(),
            "provenance": self.provenance,
        }
        if self.feasible is not None:
            state["feasible"] = self.feasible.state_dict()
        return save_tensors(path, state)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Skill:
        """Read a skill file written by `save`, as data only (torch.load with weights_only=True).

        Raises FileNotFoundError if there is no file and FileFormatError (a ValueError) naming the
        file when it is empty, truncated, foreign or not a goflow skill file."""
        what = f"goflow skill file (format {SKILL_FORMAT!r})"
        state = load_tensors(path, what)
        if not isinstance(state, dict) or state.get("format") != SKILL_FORMAT:
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
        return cls(
            state["name"],
            state["gear"],
            state["env"],
            state["env_kwargs"],
            state["method"],
            agent,
            sampler,
            state["success_threshold"],
            state["provenance"],
            feasible,
        )


def load_skill(
    name: str = "insert", gear: str = "medium", path: str | os.PathLike[str] | None = None, sensing: str | None = None
) -> Skill:
    """The shipped skill `name` for `gear` (or the file at `path`). With `sensing` ("pose" or
    "wrench"), FileFormatError naming the file and what it lacks unless its policy observes that
    (a file from before the force channel observes tool poses only)."""
    if path is None:
        path = skill_path(name, gear)
        if not path.is_file():
            raise FileNotFoundError(
                f"no shipped {name!r} skill for the {gear} gear at {path}; "
                f"train it with `goflow skill train --skill {name} --gear {gear}`"
            )
    skill = Skill.load(path)
    if (skill.name, skill.gear) != (name, gear):
        raise ValueError(f"{path} holds the {skill.name!r} skill for the {skill.gear} gear, not {name!r} for {gear}")
    if sensing is not None and skill.sensing != sensing:
        lacks = "has no force channel (its policy observes tool poses only)" if sensing == "wrench" else ""
        raise FileFormatError(
            f"{path}: the {gear} {name} skill observes {skill.sensing!r}, expected {sensing!r}"
            + (f": it {lacks}; train one with `goflow skill train --gear {gear} --sensing wrench`" if lacks else "")
        )
    return skill
