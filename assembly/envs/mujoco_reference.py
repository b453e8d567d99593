"""Our Drake locomotion envs beside gymnasium's MuJoCo originals: the same initial state and the
same actions in both, for the fidelity benchmark (benchmarks/mujoco_fidelity.py) and its test.

Needs the `mujoco` package (the `mujoco` extra, benchmark-only); `reference_env` raises InputError
naming it when it is missing. Our envs run at their nominal xi.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from goflow_common.errors import InputError

__all__ = ["ORIGINALS", "reference_env", "PairedRollout", "paired_rollout", "random_action_episodes"]

#: our id -> gymnasium's original
ORIGINALS = {
    "goflow/Hopper-v0": "Hopper-v5",
    "goflow/Walker2d-v0": "Walker2d-v5",
    "goflow/HalfCheetah-v0": "HalfCheetah-v5",
    "goflow/Humanoid-v0": "Humanoid-v5",
}


def reference_env(env_id: str):
    """gymnasium's MuJoCo original of our `env_id` (unwrapped: no time limit)."""
    import gymnasium

    if env_id not in ORIGINALS:
        raise InputError(f"no MuJoCo original for {env_id!r}; expected one of {sorted(ORIGINALS)}")
    try:
        import mujoco  # noqa: F401
    except ImportError as exc:
        raise InputError("the fidelity check needs the `mujoco` package: pip install -e '.[mujoco]'") from exc
    return gymnasium.make(ORIGINALS[env_id]).unwrapped


@dataclass
class PairedRollout:
    """Both envs driven from one state by one action sequence (rows: steps; NaN after an end)."""

    qpos_ours: NDArray[np.float64]
    qpos_ref: NDArray[np.float64]
    reward_ours: NDArray[np.float64]
    reward_ref: NDArray[np.float64]

    def divergence(self, steps: int) -> float:
        """Max abs difference of the generalized positions after `steps` steps (x excluded)."""
        d = np.abs(self.qpos_ours[steps - 1, 1:] - self.qpos_ref[steps - 1, 1:])
        return float(np.max(d))


def paired_rollout(ours, ref, actions: NDArray[np.float64], seed: int) -> PairedRollout:
    """Reset `ref` with `seed`, copy its state into `ours` (at nominal xi), then apply `actions`
    to both without ending at termination."""
    ref.reset(seed=seed)
    qpos0, qvel0 = ref.data.qpos.copy(), ref.data.qvel.copy()
    ours.reset(seed=seed, options={"xi": ours.space.nominal()})
    ours.set_mujoco_state(qpos0, qvel0)
    rows = []
    for a in actions:
        _, r_ref, *_ = ref.step(a)
        r_ours = ours.step_physics(a)  # past a termination too: we compare the physics
        rows.append((ours.mujoco_state()[0], ref.data.qpos.copy(), r_ours, r_ref))
    return PairedRollout(
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]),
        np.array([r[2] for r in rows]),
        np.array([r[3] for r in rows]),
    )


def random_action_episodes(
    env, episodes: int, seed: int, max_steps: int = 1000, reset_options: dict | None = None
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Returns and lengths of `episodes` episodes of uniform random actions (at most `max_steps`)."""
    rng = np.random.default_rng(seed)
    returns, lengths = [], []
    low, high = env.action_space.low, env.action_space.high
    for e in range(episodes):
        env.reset(seed=seed + e, options=reset_options)
        total, n = 0.0, 0
        while n < max_steps:
            _, r, terminated, truncated, _ = env.step(rng.uniform(low, high))
            total += r
            n += 1
            if terminated or truncated:
                break
        returns.append(total)
        lengths.append(n)
    return np.array(returns), np.array(lengths)
