"""ParamEnv: the gymnasium.Env base of every environment whose physical parameters xi are drawn
per episode by a Sampler.

The contract every goflow env keeps (subclasses implement only `_reset_model` and `_step_model`):
- reset(seed, options={"xi": ...}) uses the given xi (validated against the env's ParamSpace),
  else draws xi from the env's sampler with the env's own np_random (same seed, same xi).
- info["xi"] is the episode's xi (parameter units); info["critic_obs"] = concat(obs, normalized xi)
  so a privileged critic sees xi while the policy sees obs only.
- Actions of the wrong shape or with non-finite entries raise ValueError.
- An episode ends terminated by the task, or truncated at `max_episode_steps` (the time limit
  t_max / control_dt): a time limit is truncation, never termination.
- A failed physics step (SimulationError) ends the episode truncated, with info["sim_error"]; it
  never crashes a run.
- When an episode ends, info["episode_return"] is its undiscounted return and info["success"] is
  return >= success_threshold (J_T).
- render_mode (a constructor keyword) is None or one of metadata["render_modes"] (ValueError
  naming the bad value otherwise); render() returns the current frame, (H, W, 3) uint8, for
  "rgb_array", and None (with gymnasium's warning) when render_mode is None. metadata["render_fps"]
  is 1 / control_dt.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import FullDR, Sampler
from goflow_common.errors import SimulationError

__all__ = [
    "ParamEnv",
    "SimulationError",
    "check_render_mode",
    "check_sampler",
    "clipped_float32",
    "quaternion_rotation",
]


def clipped_float32(values: Sequence[float], high: Sequence[float]) -> NDArray[np.float32]:
    """values clipped to [-high, high] as a float32 array, in plain Python (an env's per-step path:
    numpy calls between AdvanceTo calls cost several times their isolated time)."""
    if all(-h <= v <= h for v, h in zip(values, high)):
        return np.array(values, dtype=np.float32)
    return np.array([min(h, max(-h, v)) for v, h in zip(values, high)], dtype=np.float32)


def quaternion_rotation(q: ArrayLike) -> NDArray[np.float64]:
    """R_WB of the quaternion q = (w, x, y, z) (Drake's floating-body order), normalized first: a
    discrete plant's quaternion drifts slightly off unit length."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / math.sqrt(float(np.dot(q, q)))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def check_sampler(sampler: Any, space: ParamSpace, owner: str) -> Sampler:
    """`sampler` if it implements the Sampler protocol over exactly `space`; TypeError (not a
    Sampler) or ValueError (another ParamSpace, with the differences) naming `owner` otherwise."""
    if not isinstance(sampler, Sampler):
        raise TypeError(f"{owner}: sampler must implement assembly.samplers.Sampler, got {type(sampler).__name__}")
    if sampler.space != space:
        raise ValueError(
            f"{owner}: the sampler's ParamSpace differs from the environment's (env vs sampler): "
            + "; ".join(space.diff(sampler.space))
        )
    return sampler


def check_render_mode(render_mode: Any, owner: str, modes: Sequence[str]) -> str | None:
    """`render_mode` if it is None or one of `modes`; ValueError naming `owner`, the bad value and
    the accepted ones otherwise."""
    if render_mode is None or (isinstance(render_mode, str) and render_mode in modes):
        return render_mode
    accepted = f"None or one of {list(modes)}" if modes else f"None ({owner} does not render)"
    raise ValueError(f"{owner}: render_mode={render_mode!r} is not supported; expected {accepted}")


class ParamEnv(gymnasium.Env):
    """Base for environments with per-episode parameters xi drawn from a Sampler."""

    metadata = {"render_modes": []}
    success_threshold: float = np.inf  # J_T, set by each environment
    control_dt: float = np.nan  # simulated seconds per step, set by each environment
    max_episode_steps: int | None = None  # t_max / control_dt; None: the task ends episodes

    def __init__(self, space: ParamSpace, sampler: Sampler | None) -> None:
        self.space = space
        self.sampler = FullDR(space) if sampler is None else sampler
        self._xi: NDArray[np.float64] | None = None
        self._obs: NDArray[np.float32] | None = None
        self._steps = 0
        self._return = 0.0
        self._done = True

    # -- to implement --------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        """Put the model in its initial state for parameters xi; return the first observation."""
        raise NotImplementedError

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        """Apply a validated action for control_dt; return (obs, reward, terminated, extra info).
        Raise SimulationError if the physics step fails."""
        raise NotImplementedError

    # -- the shared contract -------------------------------------------------------------------

    @property
    def sampler(self) -> Sampler:
        """The distribution xi is drawn from at reset. Setting it (directly, or through a vector
        env's `set_attr("sampler", ...)`) runs the same checks as the constructor: it must
        implement the Sampler protocol over exactly this env's ParamSpace."""
        return self._sampler

    @sampler.setter
    def sampler(self, sampler: Sampler) -> None:
        self._sampler = check_sampler(sampler, self.space, type(self).__name__)

    @property
    def xi(self) -> NDArray[np.float64] | None:
        """The current episode's parameters (None before the first reset)."""
        return None if self._xi is None else self._xi.copy()

    def _info(self) -> dict[str, Any]:
        return {"xi": self._xi.copy(), "critic_obs": np.concatenate((self._obs, self._xi_normalized))}

    def _init_render(self, render_mode: str | None) -> None:
        """Check and keep `render_mode` (see the module docstring); metadata["render_fps"] from
        control_dt, so call it after `_set_timing`."""
        self.render_mode = check_render_mode(render_mode, type(self).__name__, type(self).metadata["render_modes"])
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.control_dt}

    def render(self) -> NDArray[np.uint8] | None:
        """The current frame, (H, W, 3) uint8, when made with render_mode="rgb_array"; None, with
        gymnasium's warning, when render_mode is None."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                f"{type(self).__name__}.render() called with render_mode None: "
                f"make the env with render_mode='rgb_array' to get frames"
            )
            return None
        return self._render_frame()

    def _render_frame(self) -> NDArray[np.uint8]:
        """The current frame (render_mode "rgb_array"); envs that render implement it."""
        raise NotImplementedError

    def _set_timing(self, control_dt: float, t_max: float, success_threshold: float) -> None:
        """control_dt [s], the time limit t_max [s] as max_episode_steps, and J_T."""
        self.control_dt = float(control_dt)
        self.max_episode_steps = int(round(t_max / control_dt))
        self.success_threshold = float(success_threshold)

    def validate_xi(self, xi: ArrayLike, what: str = "xi") -> NDArray[np.float64]:
        """xi as a float array of shape (d,) inside the box; ValueError naming the problem."""
        arr = np.asarray(xi, dtype=np.float64)
        if arr.shape != (self.space.dim,):
            raise ValueError(
                f"{what} has shape {arr.shape}, expected shape ({self.space.dim},) for parameters {self.space.names}"
            )
        return self.space.validate(arr, what=what)

    def _choose_xi(self, options: dict[str, Any] | None) -> NDArray[np.float64]:
        options = options or {}
        unknown = sorted(set(options) - {"xi"})
        if unknown:
            raise ValueError(f"{type(self).__name__}.reset: unknown options {unknown}; the only option is 'xi'")
        if "xi" in options:
            return self.validate_xi(options["xi"], what="reset options['xi']")
        return self.space.validate(self.sampler.sample(1, self.np_random), what="sampler output")[0]

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start an episode at options["xi"] if given (validated), else at a draw from the sampler."""
        super().reset(seed=seed)
        self._xi = self._choose_xi(options)
        self._xi_normalized = self.space.normalize(self._xi).astype(np.float32)
        self._obs = np.asarray(self._reset_model(self._xi), dtype=np.float32)
        self._steps, self._return, self._done = 0, 0.0, False
        return self._obs.copy(), self._info()

    def _check_action(self, action: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(action, dtype=np.float64)
        shape = self.action_space.shape
        if a.shape != shape:
            raise ValueError(f"{type(self).__name__}.step: action has shape {a.shape}, expected {shape}")
        if not math.isfinite(sum(a.tolist()) if a.ndim == 1 else a.sum()):  # any NaN or inf
            raise ValueError(f"{type(self).__name__}.step: action must be finite, got {a.tolist()}")
        return a

    def step(self, action: ArrayLike) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Advance one control step; see the module docstring for the ending rules."""
        if self._done or self._xi is None:
            raise RuntimeError(f"{type(self).__name__}.step called on a finished episode: call reset() first")
        a = self._check_action(action)
        try:
            obs, reward, terminated, extra = self._step_model(a)
        except SimulationError as exc:
            self._done = True
            info = self._info()
            info.update(sim_error=str(exc), episode_return=self._return, success=self._return >= self.success_threshold)
            return self._obs.copy(), 0.0, False, True, info
        self._obs = obs if type(obs) is np.ndarray and obs.dtype == np.float32 else np.asarray(obs, dtype=np.float32)
        self._steps += 1
        self._return += float(reward)
        truncated = not terminated and self.max_episode_steps is not None and self._steps >= self.max_episode_steps
        info = self._info()
        info.update(extra)
        if terminated or truncated:
            self._done = True
            info["episode_return"] = self._return
            info["success"] = bool(self._return >= self.success_threshold)
        # _step_model returns a fresh observation every step, so it is handed out without a copy.
        return self._obs, float(reward), bool(terminated), bool(truncated), info
