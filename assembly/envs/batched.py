"""BatchedEnv: N copies of an env's model in one Drake diagram, behind `gymnasium.vector.VectorEnv`.

One `Simulator.AdvanceTo` per vector step advances every copy; observations, rewards and endings
are computed for all copies at once in numpy. `gymnasium.make_vec(id, num_envs=N,
vectorization_mode="vector_entry_point")` returns it for the ids that have one (docs/envs.md,
"Batched simulation").

The contract is the single env's (`assembly.envs.base`), per copy, with the vector layout of
`SyncVectorEnv(..., autoreset_mode=AutoresetMode.SAME_STEP)`, which PPO needs:
- reset(seed=s) seeds copy i with s + i (a list seeds each copy), as SyncVectorEnv does, so copy i
  draws the same xi and initial state as a single env reset with seed s + i;
  reset(options={"xi": x}) starts every copy at x (shape (d,)) or copy i at x[i] (shape (N, d)).
- info["xi"], info["critic_obs"] per copy (with the "_xi", "_critic_obs" masks); an ended copy is
  reset in the same step: its last observation and info are in info["final_obs"][i] and
  info["final_info"][key][i] (episode_return, success, xi, critic_obs, sim_error).
- A copy whose physics fails (a non-finite state, or a Drake failure traced to it by replaying
  each copy alone in a one-copy twin) ends truncated with info["final_info"]["sim_error"][i]
  naming its index; the other copies step on unharmed.
- `sampler` (or `set_attr("sampler", s)`) sets the distribution every copy draws from.

Subclasses build the N copies and implement the batched hooks `_apply_xi`, `_reset_copies`,
`_step_copies`, `_get_state` and `_set_state` (see their docstrings).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import check_sampler
from assembly.params import ParamSpace
from assembly.samplers import FullDR, Sampler
from goflow_common.errors import InputError, SimulationError

__all__ = ["BatchedEnv", "check_num_envs", "episode_steps", "instance_state_columns", "refuse_render", "rowwise_dot"]


def check_num_envs(num_envs: Any, owner: str) -> int:
    """num_envs as an int >= 1; InputError naming `owner` and the bad value otherwise."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise InputError(f"{owner}: num_envs = {num_envs!r}; expected a whole number >= 1 of copies")
    return int(num_envs)


def rowwise_dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row-by-row dot products of two (N, n) arrays, (N,): for each row the same BLAS call (and so
    the same bits) as the 1-D `a[i] @ b[i]` a single env computes; `(a * b).sum(axis=1)` differs
    from it in the last bit."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]


def instance_state_columns(plant, instance) -> NDArray[np.int64]:
    """Where a model instance's positions and velocities sit in a finalized plant's state [q; v],
    each in increasing order: the order a plant holding only that model has them."""
    nq = plant.num_positions()
    q = plant.GetPositionsFromArray(instance, np.arange(nq, dtype=float))
    v = plant.GetVelocitiesFromArray(instance, np.arange(plant.num_velocities(), dtype=float))
    return np.concatenate((np.sort(q), nq + np.sort(v))).astype(np.int64)


def episode_steps(t_max: float, control_dt: float, max_episode_steps: int | None) -> int:
    """The time limit in steps: the single env's own, t_max / control_dt, or `max_episode_steps` when
    that is smaller. gymnasium.make_vec passes the spec's max_episode_steps (or its caller's), and
    a single env made by gymnasium.make ends at the earlier of its own limit and its TimeLimit
    wrapper's, so the copies end where it would; None or -1 (gymnasium's "no TimeLimit"): t_max
    alone. InputError for any other value below 1."""
    own = int(round(t_max / control_dt))
    if max_episode_steps is None or max_episode_steps == -1:
        return own
    if (
        isinstance(max_episode_steps, bool)
        or not isinstance(max_episode_steps, (int, np.integer))
        or max_episode_steps < 1
    ):
        raise InputError(
            f"max_episode_steps = {max_episode_steps!r}; expected a whole number >= 1 of steps, -1 or None (no limit)"
        )
    return min(own, int(max_episode_steps))


def refuse_render(render_mode: Any, owner: str) -> None:
    """The batched envs do not render: InputError naming `owner` unless render_mode is None."""
    if render_mode is not None:
        raise InputError(
            f"{owner}: render_mode={render_mode!r} is not supported; expected None (the batched vector envs do not "
            "render: make a single env with gymnasium.make(id, render_mode='rgb_array') to record episodes)"
        )


class BatchedEnv(VectorEnv):
    """Base of the batched vector envs: episode bookkeeping, seeding, xi, autoreset, failures."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    _owner = "BatchedEnv"

    def __init__(
        self,
        num_envs: int,
        space: ParamSpace,
        sampler: Sampler | None,
        single_observation_space: gymnasium.spaces.Box,
        single_action_space: gymnasium.spaces.Box,
        control_dt: float,
        max_episode_steps: int | None,
        success_threshold: float,
    ) -> None:
        self.num_envs = check_num_envs(num_envs, self._owner)
        self.space = space
        self.sampler = FullDR(space) if sampler is None else sampler
        self.single_observation_space = single_observation_space
        self.single_action_space = single_action_space
        self.observation_space = batch_space(single_observation_space, self.num_envs)
        self.action_space = batch_space(single_action_space, self.num_envs)
        self.control_dt = float(control_dt)
        self.max_episode_steps = max_episode_steps
        self.success_threshold = float(success_threshold)
        n = self.num_envs
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._xi = np.zeros((n, space.dim))
        self._xi_normalized = np.zeros((n, space.dim), dtype=np.float32)
        self._obs: NDArray[np.float32] | None = None
        self._steps = np.zeros(n, dtype=np.int64)
        self._returns = np.zeros(n)
        self._twin: BatchedEnv | None = None  # the one-copy replay of a failed step, built when needed
        # {copy: why} of the copies `_step_copies` gave a NaN reward for a reason of its own.
        self._step_failures: dict[int, str] = {}

    # -- to implement ----------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        """Write xi[k] (parameter units) into copy idx[k]'s part of the Context."""
        raise NotImplementedError

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: Sequence[np.random.Generator]
    ) -> NDArray[np.float32]:
        """Put copies idx in their initial state for xi (already applied), drawing what the single
        env draws at reset from rngs[k] in the same order; return their first observations."""
        raise NotImplementedError

    def _step_copies(
        self, actions: NDArray[np.float64]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], dict[str, NDArray]]:
        """Advance every copy one control period under validated actions (N, m); return obs (N, o),
        rewards (N,), terminated (N,) and per-copy extra info arrays. A copy whose state is not
        finite gets a NaN reward (the base ends it; a reason of the subclass's own goes in
        `self._step_failures[i]`); a Drake failure raises SimulationError."""
        raise NotImplementedError

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """Everything that makes copies idx's next step: (len(idx), s) rows (plant state and any
        per-copy task data such as a goal)."""
        raise NotImplementedError

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        """The inverse of `_get_state`."""
        raise NotImplementedError

    def _advance_period(self) -> None:
        """Advance `self._simulator` from control step `self._k` to `self._k + 1` (simulated time
        k * control_dt, as the single env counts it); a Drake failure (SimulationError) leaves the
        clock at step k, so that the step can be repeated."""
        from assembly.envs.drake_sim import advance

        try:
            advance(self._simulator, (self._k + 1) * self.control_dt, self._owner)
        except Exception:
            self._context.SetTime(self._k * self.control_dt)
            raise
        self._k += 1

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """`_get_state` rows of copies idx at rest for their current xi (where a failed copy waits
        while the others repeat their step)."""
        raise NotImplementedError

    def _make_twin(self) -> BatchedEnv:
        """A one-copy env of the same model and settings (replays a failed step copy by copy)."""
        raise NotImplementedError

    # -- the shared contract -----------------------------------------------------------------------

    @property
    def sampler(self) -> Sampler:
        """The distribution every copy draws xi from at reset (checked as the single env checks it)."""
        return self._sampler

    @sampler.setter
    def sampler(self, sampler: Sampler) -> None:
        self._sampler = check_sampler(sampler, self.space, self._owner)

    def set_attr(self, name: str, values: Any) -> None:
        """SyncVectorEnv's `set_attr` for the one shared attribute, "sampler" (one value, or one per
        copy that must all be the same object: the copies share one sampler)."""
        if name != "sampler":
            raise AttributeError(f"{self._owner}.set_attr: only 'sampler' can be set, got {name!r}")
        if isinstance(values, (list, tuple)):
            if len(values) != self.num_envs or any(v is not values[0] for v in values):
                raise ValueError(
                    f"{self._owner}.set_attr('sampler', ...): the copies share one sampler; "
                    "give one sampler (or the same one num_envs times)"
                )
            values = values[0]
        self.sampler = values

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """SyncVectorEnv's `get_attr`: the attribute once per copy."""
        return tuple(getattr(self, name) for _ in range(self.num_envs))

    @property
    def xi(self) -> NDArray[np.float64]:
        """Each copy's current parameters, (N, d) (a copy)."""
        return self._xi.copy()

    def _seed(self, seed: int | Sequence[int] | None) -> None:
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"{self._owner}.reset: {len(seeds)} seeds for {n} copies")
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)

    def _draw_xi(self, idx: NDArray[np.int64], given: NDArray[np.float64] | None) -> NDArray[np.float64]:
        if given is not None:
            return given[idx]
        rows = [self.sampler.sample(1, self._rngs[i])[0] for i in idx]
        return self.space.validate(np.array(rows), what="sampler output")

    def _check_options(self, options: dict[str, Any] | None) -> NDArray[np.float64] | None:
        options = options or {}
        unknown = sorted(set(options) - {"xi"})
        if unknown:
            raise ValueError(f"{self._owner}.reset: unknown options {unknown}; the only option is 'xi'")
        if "xi" not in options:
            return None
        xi = np.asarray(options["xi"], dtype=np.float64)
        n, d = self.num_envs, self.space.dim
        if xi.shape == (d,):
            xi = np.tile(xi, (n, 1))
        if xi.shape != (n, d):
            raise ValueError(
                f"{self._owner}.reset: options['xi'] has shape {xi.shape}, expected ({d},) "
                f"or ({n}, {d}) for parameters {self.space.names}"
            )
        for i in range(n):
            self.space.validate(xi[i], what=f"reset options['xi'] of copy {i}")
        return xi

    def _start(self, idx: NDArray[np.int64], given: NDArray[np.float64] | None) -> NDArray[np.float32]:
        xi = self._draw_xi(idx, given)
        self._xi[idx] = xi
        self._xi_normalized[idx] = self.space.normalize(xi).astype(np.float32)
        self._apply_xi(idx, xi)
        obs = np.asarray(self._reset_copies(idx, xi, [self._rngs[i] for i in idx]), dtype=np.float32)
        self._steps[idx] = 0
        self._returns[idx] = 0.0
        return obs

    def _info(self) -> dict[str, Any]:
        n = self.num_envs
        every = np.ones(n, dtype=bool)
        return {
            "xi": self._xi.copy(),
            "_xi": every,
            "critic_obs": np.concatenate((self._obs, self._xi_normalized), axis=1),
            "_critic_obs": every.copy(),
        }

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start every copy's episode (see the module docstring for seeds and options["xi"])."""
        given = self._check_options(options)
        self._seed(seed)
        self._obs = self._start(np.arange(self.num_envs), given)
        return self._obs.copy(), self._info()

    def _check_actions(self, actions: ArrayLike) -> NDArray[np.float64]:
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"{self._owner}.step: actions have shape {a.shape}, expected {self.action_space.shape}")
        bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
        if bad.size:
            raise ValueError(f"{self._owner}.step: actions must be finite; copy {int(bad[0])} got {a[bad[0]].tolist()}")
        return a

    def _step_guarded(
        self, actions: NDArray[np.float64]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], dict[str, NDArray], dict[int, str]]:
        """`_step_copies`, with the copies that fail found and named: {index: message}."""
        before = self._get_state(np.arange(self.num_envs))
        try:
            obs, reward, terminated, extra = self._step_copies(actions)
        except SimulationError as exc:
            failed = self._replay_alone(before, actions, str(exc))
            # Step the batch again, the failed copies held at rest meanwhile (they are reset after).
            idx = np.array(sorted(failed))
            state = before.copy()
            state[idx] = self._rest_state(idx)
            self._set_state(np.arange(self.num_envs), state)
            obs, reward, terminated, extra = self._step_copies(actions)
            return obs, reward, terminated, extra, failed
        bad = np.flatnonzero(~np.isfinite(reward))
        failed = {
            int(i): self._step_failures.get(
                int(i), f"copy {int(i)}: non-finite state after step {int(self._steps[i]) + 1}"
            )
            for i in bad
        }
        self._step_failures = {}
        return obs, reward, terminated, extra, failed

    def _replay_alone(self, before: NDArray[np.float64], actions: NDArray[np.float64], message: str) -> dict[int, str]:
        """Which copies fail their step on their own: each replayed in a one-copy twin."""
        if self._twin is None:
            self._twin = self._make_twin()
        twin, zero = self._twin, np.zeros(1, dtype=np.int64)
        failed = {}
        for i in range(self.num_envs):
            twin._apply_xi(zero, self._xi[i : i + 1])
            twin._set_state(zero, before[i : i + 1])
            try:
                _, reward, _, _ = twin._step_copies(actions[i : i + 1])
                if not math.isfinite(float(reward[0])):
                    failed[i] = f"copy {i}: " + twin._step_failures.get(0, "non-finite state")
                twin._step_failures = {}
            except SimulationError as exc:
                failed[i] = f"copy {i}: {exc}"
        if not failed:  # the batch failed although no copy fails alone (the solver couples them)
            raise SimulationError(f"{self._owner}: the batched step failed, but no copy fails alone: {message}")
        return failed

    def step(
        self, actions: ArrayLike
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Advance every copy one control period; ended copies are reset in the same step."""
        if self._obs is None:
            raise RuntimeError(f"{self._owner}.step called before reset()")
        a = self._check_actions(actions)
        obs, reward, terminated, extra, failed = self._step_guarded(a)
        obs = np.asarray(obs, dtype=np.float32)
        terminated = np.asarray(terminated, dtype=bool).copy()
        reward = np.asarray(reward, dtype=np.float64).copy()
        failed_mask = np.zeros(self.num_envs, dtype=bool)
        if failed:
            failed_mask[list(failed)] = True
            obs[failed_mask] = self._obs[failed_mask]  # a failed step keeps the last observation, as the single env
            reward[failed_mask] = 0.0
            terminated[failed_mask] = False
        self._steps += 1
        self._returns += reward
        self._obs = obs
        truncated = failed_mask.copy()
        if self.max_episode_steps is not None:
            truncated |= ~terminated & (self._steps >= self.max_episode_steps)
        done = terminated | truncated
        info = self._info()
        if done.any():
            idx = np.flatnonzero(done)
            final = {key: value[idx] for key, value in info.items() if not key.startswith("_")}
            final_info: dict[str, Any] = {}
            for key, value in list(final.items()) + [(k, np.asarray(v)[idx]) for k, v in extra.items()]:
                full = np.zeros((self.num_envs, *value.shape[1:]), dtype=value.dtype)
                full[idx] = value
                final_info[key], final_info["_" + key] = full, done.copy()
            final_info["episode_return"], final_info["_episode_return"] = self._returns.copy(), done.copy()
            final_info["success"] = self._returns >= self.success_threshold
            final_info["_success"] = done.copy()
            if failed:
                errors = np.full(self.num_envs, None, dtype=object)
                for i, msg in failed.items():
                    errors[i] = msg
                final_info["sim_error"], final_info["_sim_error"] = errors, failed_mask
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in idx:
                final_obs[i] = obs[i].copy()
            self._obs = self._obs.copy()
            self._obs[idx] = self._start(idx, None)
            info = self._info()
            info.update(final_obs=final_obs, _final_obs=done.copy(), final_info=final_info, _final_info=done.copy())
        for key, value in extra.items():
            info[key], info["_" + key] = np.asarray(value), ~done
        return self._obs.copy(), reward, terminated, truncated, info
