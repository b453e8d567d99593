"""`goflow collect`: log trajectories of a simulator whose parameters are drawn per trajectory from a
known distribution, a synthetic target (targets.py) or an estimate file of `goflow estimate` (to check
an estimate by re-collecting from it); assembly/transition/ is the "real system" here."""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from assembly.transition import TRANSITION_SIMS, make_transition_sim
from goflow_common.errors import FileFormatError, InputError
from learning.estimation.dataset import TransitionDataset, save_dataset
from learning.estimation.targets import TargetConfig, sample_target, target_description

__all__ = ["CollectConfig", "collect", "collect_to_file", "DEFAULT_STEPS", "NO_TRANSITIONS"]

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
    "goflow/Quadrotor-v0": 100,  # its episode: 2 s of 0.02 s steps
    "goflow/Anymal-v0": 250,  # its episode: 5 s of 0.02 s steps
    "goflow/GearInsertion-v0": 100,  # its episode: 4 s of 0.04 s steps
}

#: Registered env ids `collect` refuses, and why (what `goflow collect --env` says).
NO_TRANSITIONS = {
    "goflow/Toy2D-v0": "its episodes are one guess of a position that never moves: no state dynamics depend on xi",
}


@dataclass
class CollectConfig:
    """One dataset. Every `goflow collect` flag maps to a field."""

    env: str = "goflow/Cartpole-v0"
    # the true parameters: a synthetic target, one of targets.TARGETS (None: "gaussian"), or
    # "estimate": drawn from `sampler_file` (set when that is given)
    xi: str | None = None
    sampler_file: str | Path | None = None  # an estimate file of `goflow estimate` (JSON)
    episodes: int = 48
    steps: int | None = None  # per trajectory; None: DEFAULT_STEPS[env]
    policy: str = "random"  # "random" or the path of a PPO checkpoint (PPO.save or `goflow train`)
    seed: int = 0
    target: TargetConfig | None = None  # None: TargetConfig(kind=xi); none with sampler_file

    def __post_init__(self) -> None:
        if isinstance(self.episodes, bool) or int(self.episodes) < 1:
            raise ValueError(f"collect: episodes must be >= 1, got {self.episodes!r}")
        if self.steps is not None and int(self.steps) < 1:
            raise ValueError(f"collect: steps must be >= 1, got {self.steps!r}")
        if self.sampler_file is not None:
            if self.xi not in (None, "estimate") or self.target is not None:
                given = f"xi={self.xi!r}" if self.target is None else f"target={self.target!r}"
                raise InputError(
                    f"collect: {given} and sampler_file={str(self.sampler_file)!r}; expected one source of the "
                    "true xi (a synthetic target or an estimate file)"
                )
            self.xi = "estimate"
        elif self.xi == "estimate":
            raise InputError("collect: xi='estimate' needs sampler_file (an estimate file of `goflow estimate`)")
        else:
            self.xi = self.xi or (self.target.kind if self.target is not None else "gaussian")
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


def _transition_sim(env: str) -> Any:
    """The env's transition simulator; InputError saying why for a registered env `collect` refuses
    (NO_TRANSITIONS), UnknownOptionError listing the ids it takes for an unknown one."""
    if env in NO_TRANSITIONS:
        raise InputError(
            f"collect: env {env!r} is refused: {NO_TRANSITIONS[env]}; collect takes {list(TRANSITION_SIMS)}"
        )
    return make_transition_sim(env)


def collect(
    config: CollectConfig, progress: bool = False, command: str = ""
) -> tuple[TransitionDataset, NDArray[np.float64]]:
    """Run `episodes` trajectories, each with its own true xi; return (dataset, true xi (E, d)).

    The true xi are drawn from `config.target`, or from the estimate file `config.sampler_file`
    (read first; its ParamSpace must be the simulator's: InputError otherwise, before any step).
    The dataset's collection record names the source: the target's description, or the estimate
    file's path, SHA-256 and distribution (`estimate_source`)."""
    if config.sampler_file is not None:
        from learning.estimation.estimate_file import check_estimate_space, estimate_source, load_estimate

        estimate, doc = load_estimate(config.sampler_file)  # a bad file fails before the simulator is built
        sim = _transition_sim(config.env)
        check_estimate_space(estimate, config.sampler_file, sim.space, config.env)
        source = estimate_source(config.sampler_file, estimate, doc)
    else:
        sim = _transition_sim(config.env)
        source = target_description(config.target)
    steps = int(config.steps or DEFAULT_STEPS.get(config.env, 100))
    rng = np.random.default_rng(config.seed)
    if config.sampler_file is not None:
        true_xi = estimate.sample(config.episodes, rng)
    else:
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
        "target": source,
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
