"""`goflow collect`: log trajectories of a simulator whose parameters are drawn per trajectory from a
known target distribution (assembly/transition/ is the "real system" here)."""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from assembly.transition import make_transition_sim
from goflow_common.errors import FileFormatError
from learning.estimation.dataset import TransitionDataset, save_dataset
from learning.estimation.targets import TargetConfig, sample_target, target_description

__all__ = ["CollectConfig", "collect", "collect_to_file", "DEFAULT_STEPS"]

#: Steps per trajectory by default: the env's episode length (Cartpole, Ant: 2 s), 1 s of the arm;
#: 100 steps of the locomotion envs (Hopper, Walker2d 0.8 s, HalfCheetah 5 s, Humanoid 1.5 s).
DEFAULT_STEPS = {
    "goflow/PointMass-v0": 40,
    "goflow/Cartpole-v0": 120,
    "goflow/Ant-v0": 128,
    "goflow/PandaArm-v0": 100,
    "goflow/Hopper-v0": 100,
    "goflow/Walker2d-v0": 100,
    "goflow/HalfCheetah-v0": 100,
    "goflow/Humanoid-v0": 100,
}


@dataclass
class CollectConfig:
    """One dataset. Every `goflow collect` flag maps to a field."""

    env: str = "goflow/Cartpole-v0"
    xi: str = "gaussian"  # target kind: one of targets.TARGETS
    episodes: int = 48
    steps: int | None = None  # per trajectory; None: DEFAULT_STEPS[env]
    policy: str = "random"  # "random" or the path of a PPO checkpoint (PPO.save or `goflow train`)
    seed: int = 0
    target: TargetConfig | None = None  # None: TargetConfig(kind=xi)

    def __post_init__(self) -> None:
        if isinstance(self.episodes, bool) or int(self.episodes) < 1:
            raise ValueError(f"collect: episodes must be >= 1, got {self.episodes!r}")
        if self.steps is not None and int(self.steps) < 1:
            raise ValueError(f"collect: steps must be >= 1, got {self.steps!r}")
        if self.target is None:
            self.target = TargetConfig(kind=self.xi)
        elif self.target.kind != self.xi:
            raise ValueError(f"collect: xi={self.xi!r} but target.kind={self.target.kind!r}")
        if self.policy != "random" and not Path(self.policy).is_file():
            raise ValueError(
                f"collect: policy must be 'random' or the path of a PPO checkpoint; {self.policy!r} is not a file"
            )


def _load_policy(path: str) -> Callable[[NDArray[np.float32]], NDArray[np.float64]]:
    """Deterministic actions of a PPO checkpoint (a PPO.save file or a `goflow train` checkpoint.pt),
    loaded as data only; FileFormatError naming the file if it is neither."""
    from goflow_common.files import load_tensors
    from learning.ppo import PPO

    state = load_tensors(path, "PPO checkpoint or `goflow train` checkpoint.pt")
    if isinstance(state, dict) and "agent" in state:  # goflow train's checkpoint.pt
        state = state["agent"]
    try:
        agent = PPO.from_state_dict(state)
    except (ValueError, KeyError, TypeError) as exc:
        raise FileFormatError(f"{path}: not a PPO checkpoint or `goflow train` checkpoint.pt ({exc})") from None
    return lambda obs: np.asarray(agent.act(obs, deterministic=True), dtype=np.float64)


def collect(
    config: CollectConfig, progress: bool = False, command: str = ""
) -> tuple[TransitionDataset, NDArray[np.float64]]:
    """Run `episodes` trajectories, each with its own true xi; return (dataset, true xi (E, d))."""
    sim = make_transition_sim(config.env)
    steps = int(config.steps or DEFAULT_STEPS.get(config.env, 100))
    rng = np.random.default_rng(config.seed)
    true_xi = sample_target(config.target, sim.space, config.episodes, rng)
    policy = None if config.policy == "random" else _load_policy(config.policy)
    rows: list[tuple[NDArray, NDArray, NDArray, int]] = []
    kept: list[NDArray] = []
    for e in tqdm(range(config.episodes), disable=not progress, desc=f"collect {config.env}", unit="episode"):
        s = sim.initial_state(true_xi[e], rng)
        ep_rows = []
        for _ in range(steps):
            a = sim.random_action(rng) if policy is None else policy(sim.observe(s))
            s_next = sim.step(s[None], a[None], true_xi[e][None])[0]
            if not np.all(np.isfinite(s_next)):
                break  # the physics failed: the trajectory ends here
            ep_rows.append((s, a, s_next))
            s = s_next
        if ep_rows:
            idx = len(kept)
            rows.extend((s0, a0, s1, idx) for s0, a0, s1 in ep_rows)
            kept.append(true_xi[e])
    if not rows:
        raise RuntimeError(f"collect: no trajectory of {config.env} produced a single valid step")
    collection = {
        "xi": config.xi,
        "target": target_description(config.target),
        "policy": config.policy,
        "episodes": len(kept),
        "steps_per_episode": steps,
        "seed": config.seed,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": command,
    }
    ds = TransitionDataset(
        env_id=config.env,
        space=sim.space,
        states=np.array([r[0] for r in rows]),
        actions=np.array([r[1] for r in rows]),
        next_states=np.array([r[2] for r in rows]),
        episode=np.array([r[3] for r in rows], dtype=np.int64),
        control_dt=float(sim.control_dt),
        collection=collection,
    )
    return ds, np.array(kept)


def collect_to_file(
    config: CollectConfig, out: str | Path, progress: bool = False, command: str = ""
) -> TransitionDataset:
    """collect() and save the dataset (with its truth) to `out`; `command` is recorded as provenance."""
    ds, truth = collect(config, progress=progress, command=command)
    save_dataset(out, ds, truth)
    return ds
