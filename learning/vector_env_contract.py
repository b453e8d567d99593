"""What PPO needs of a gymnasium vector env, checked at each reset and step: SAME_STEP autoreset,
the agent's observation and action spaces, `info["critic_obs"]`, the ParamEnv final info of an
ended episode (assembly/envs/base.py), and finite numbers.

Every check raises a ValueError (NonFiniteError for NaN or infinite numbers) whose message starts
with `PPO` and names the quantity, the sub-env and the rollout step where it applies.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from numpy.typing import ArrayLike, NDArray

__all__ = ["NonFiniteError", "check_finite", "check_vec_env", "read_final_info", "read_obs"]


class NonFiniteError(ValueError):
    """An environment returned a NaN or infinite reward or observation (or a loss became non-finite)."""


def check_finite(x: ArrayLike, what: str, step: int | None = None) -> None:
    """Return if `x` is finite; else NonFiniteError naming `what`, the first bad sub-env (row of
    `x`) and the rollout `step` (when given)."""
    arr = np.asarray(x, dtype=np.float64)
    if np.isfinite(arr).all():
        return
    rows = arr.reshape(len(arr), -1) if arr.ndim else arr.reshape(1, 1)
    env = int(np.flatnonzero(~np.isfinite(rows).all(axis=1))[0])
    where = f" at rollout step {step}" if step is not None else ""
    raise NonFiniteError(
        f"PPO: the environment returned a non-finite {what}{where} in sub-env {env}: "
        f"{rows[env].tolist()}; refusing to train on it (fix the environment, or end the "
        "episode truncated with info['sim_error'])"
    )


def check_vec_env(vec_env: Any, what: str, obs_dim: int, action_space: spaces.Box) -> int:
    """The number of sub-envs of `vec_env`, after checking that it is a gymnasium VectorEnv in
    AutoresetMode.SAME_STEP whose single observation space has shape (obs_dim,) and whose single
    action space equals `action_space` (as float32 bounds). TypeError for another object,
    ValueError (naming `PPO.<what>`) for a mismatch."""
    if not isinstance(vec_env, gymnasium.vector.VectorEnv):
        raise TypeError(
            f"PPO.{what}: expected a gymnasium.vector.VectorEnv (SyncVectorEnv or "
            f"AsyncVectorEnv), got {type(vec_env).__name__}"
        )
    mode = vec_env.metadata.get("autoreset_mode")
    try:
        mode = AutoresetMode(mode) if not isinstance(mode, AutoresetMode) else mode
    except ValueError:
        mode = None
    if mode != AutoresetMode.SAME_STEP:
        raise ValueError(
            f"PPO.{what}: the vector env's autoreset mode is {mode!r}; PPO needs "
            "autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP (pass it to "
            "SyncVectorEnv/AsyncVectorEnv) so that final observations come in "
            "info['final_obs'] / info['final_info']"
        )
    obs_shape = vec_env.single_observation_space.shape
    if obs_shape != (obs_dim,):
        raise ValueError(
            f"PPO.{what}: the env's observations have shape {obs_shape}, this PPO was built for obs_dim={obs_dim}"
        )
    act = vec_env.single_action_space
    low = np.asarray(action_space.low, dtype=np.float32)
    high = np.asarray(action_space.high, dtype=np.float32)
    if (
        not isinstance(act, spaces.Box)
        or act.shape != (len(low),)
        or not np.array_equal(act.low, low)
        or not np.array_equal(act.high, high)
    ):
        raise ValueError(f"PPO.{what}: the env's action space {act!r} differs from this PPO's {action_space!r}")
    return int(vec_env.num_envs)


def read_obs(
    obs: Any, info: dict[str, Any], n: int, obs_dim: int, critic_obs_dim: int, what: str, step: int | None
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """(obs, critic_obs) of a reset or step result `what` of `n` sub-envs, as float32 arrays of
    shapes (n, obs_dim) and (n, critic_obs_dim); ValueError for a missing info["critic_obs"] or a
    wrong shape, NonFiniteError for a NaN or infinite entry."""
    obs = np.asarray(obs, dtype=np.float32)
    if obs.shape != (n, obs_dim):
        raise ValueError(f"PPO: {what} returned observations of shape {obs.shape}, expected ({n}, {obs_dim})")
    if "critic_obs" not in info or not np.all(info.get("_critic_obs", True)):
        raise ValueError(
            f"PPO: {what} did not return info['critic_obs'] for every sub-env; the env must "
            "follow the ParamEnv contract (critic_obs = concat(obs, normalized xi))"
        )
    cobs = np.asarray(info["critic_obs"], dtype=np.float32)
    if cobs.shape != (n, critic_obs_dim):
        raise ValueError(
            f"PPO: {what} returned info['critic_obs'] of shape {cobs.shape}, expected ({n}, {critic_obs_dim})"
        )
    check_finite(obs, "observation", step)
    check_finite(cobs, "info['critic_obs']", step)
    return obs, cobs


def read_final_info(
    info: dict[str, Any], done: NDArray[np.bool_], critic_obs_dim: int, step: int | None
) -> dict[str, Any]:
    """The final info of the sub-envs whose episode ended (`done`, in index order): "critic_obs"
    (float32, (n, critic_obs_dim)), "episode_return" (float64), "success", "xi" and "sim_error"
    (False where the env does not report it). ValueError when info has no SAME_STEP final info,
    its mask disagrees with `done`, or a key of the ParamEnv contract is missing; NonFiniteError
    for a NaN or infinite critic_obs or return."""
    if "final_info" not in info:
        raise ValueError(
            "PPO: an episode ended but info has no 'final_info'; is the vector env in AutoresetMode.SAME_STEP?"
        )
    mask = np.asarray(info.get("_final_info", done), dtype=bool)
    if not np.array_equal(mask, done):
        raise ValueError(
            f"PPO: info['_final_info'] {mask.tolist()} disagrees with terminated | truncated {done.tolist()}"
        )
    fi = info["final_info"]
    idx = np.flatnonzero(done)
    out: dict[str, Any] = {}
    for key in ("critic_obs", "episode_return", "success", "xi"):
        if key not in fi or not np.all(np.asarray(fi.get("_" + key, done))[idx]):
            raise ValueError(
                f"PPO: the final info of an ended episode lacks {key!r}; the env must follow "
                "the ParamEnv contract (assembly/envs/base.py)"
            )
        out[key] = np.asarray(fi[key])[idx]
    out["critic_obs"] = np.asarray(out["critic_obs"], dtype=np.float32)
    if out["critic_obs"].shape != (len(idx), critic_obs_dim):
        raise ValueError(
            f"PPO: final info['critic_obs'] has shape {out['critic_obs'].shape[1:]} per env, "
            f"expected ({critic_obs_dim},)"
        )
    check_finite(out["critic_obs"], "final info['critic_obs'] (last observation of an episode)", step)
    out["episode_return"] = np.asarray(out["episode_return"], dtype=np.float64)
    check_finite(out["episode_return"], "info['episode_return']", step)
    if "sim_error" in fi:
        out["sim_error"] = np.asarray(fi.get("_sim_error", np.zeros_like(done)), dtype=bool)[idx]
    else:
        out["sim_error"] = np.zeros(len(idx), dtype=bool)
    return out
