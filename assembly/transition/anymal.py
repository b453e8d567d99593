"""goflow/Anymal-v0 stepped from any state: the env's own Drake model (AnymalEnv), with its xi (base
mass, the four hip frictions); the hips' loads and the last action ride in the state, since the
friction of a step and the observation depend on them."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.transition.drake import DrakeTransitionSim

__all__ = ["AnymalTransitionSim"]


class AnymalTransitionSim(DrakeTransitionSim):
    """goflow/Anymal-v0's Drake model stepped from arbitrary states.

    State (53,) = the plant's [q; v] (37), then the load |f| + |tau| each HAA joint transmitted over
    the last step (4, LEGS order; the env holds it to set the coming step's hip friction, so it is
    the memory a step needs; negative entries read as 0), then the last clipped action (12; only
    the observation reads it). xi = the env's (base mass, LF, RF, LH, RH HAA friction). Action: 12
    normalized joint-target offsets, held for one control step on the PD drives, as in the env. A
    step gives the new [q; v], the loads over that step and the clipped action; one step here equals
    one `env.step` from the same state (tested). It drives a private AnymalEnv.

    Arguments:
        env_kwargs: keyword arguments of AnymalEnv (AnymalConfig fields).
    """

    env_id = "goflow/Anymal-v0"
    action_dim = 12

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs.anymal import AnymalEnv

        self._env = env = AnymalEnv(**env_kwargs)
        self.config = env.config
        self.space = env.space
        self.control_dt = env.control_dt
        self._simulator, self._context = env._simulator, env._context
        self._plant, self._plant_context = env._plant, env._plant_context
        self._nx = env._nq + env._nv
        self.state_dim = self._nx + 4 + self.action_dim
        self._action = np.zeros(self.action_dim)

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """The base mass (its inertia scaled with it) and the hip frictions, every HAA damping reset,
        as the env's reset does."""
        from pydrake.multibody.tree import SpatialInertia

        env = self._env
        env._base.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(float(xi[0]), env._base_com, env._base_unit_inertia)
        )
        env._friction = np.asarray(xi[1:5], dtype=np.float64).copy()
        for joint in env._haa:
            joint.SetDamping(self._plant_context, 0.0)

    def _set_state(self, state: NDArray[np.float64]) -> None:
        """The plant at [q; v], time 0; the env's memory (state, hip loads) from the row."""
        super()._set_state(state[: self._nx])
        self._env._state = state[: self._nx].copy()
        self._env._haa_load = np.maximum(state[self._nx : self._nx + 4], 0.0)

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """The clipped action, held on the PD targets by `_advance` (the env's own step)."""
        self._action = np.clip(action, -1.0, 1.0)

    def _advance(self) -> None:
        """The env's control step (targets, hip friction of the row's loads, Drake), from time 0."""
        self._simulator.Initialize()
        self._env._k = 0
        self._env._advance(self._action)

    def _read_state(self) -> NDArray[np.float64]:
        """[q; v], the hips' loads over the step, the clipped action."""
        from assembly.envs.anymal import joint_loads

        env = self._env
        loads = joint_loads(env._reaction_port.Eval(self._plant_context), env._haa_index)[0]
        return np.concatenate([super()._read_state(), loads, self._action])

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset state for xi (its reset noise drawn from a seed taken from rng), no load,
        no last action.

        Arguments:
            xi: parameters, shape (5,).
            rng: the generator of the env's seed.

        Returns:
            The state, shape (53,).
        """
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi})
        return np.concatenate([self._env.state(), np.zeros(4 + self.action_dim)])

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """goflow/Anymal-v0's observation of a state (Isaac Lab's 48 entries, the last action included).

        Arguments:
            state: shape (53,).

        Returns:
            The observation, shape (48,).
        """
        from assembly.envs.anymal import base_motion, observe

        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_dim,):
            raise ValueError(f"{type(self).__name__}.observe: state has shape {s.shape}, expected ({self.state_dim},)")
        rows, layout = s[None, : self._nx], self._env._layout
        return observe(self.config, layout, rows, *base_motion(layout, rows), s[None, self._nx + 4 :])[0]
