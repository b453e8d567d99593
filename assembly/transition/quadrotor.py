"""goflow/Quadrotor-v0 stepped from any state: the env's own Drake model (QuadrotorEnv), with its
mass as the parameter; the episode's goal rides in the state so that a state is observable."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.transition.drake import DrakeTransitionSim
from goflow_common.errors import SimulationError

__all__ = ["QuadrotorTransitionSim"]

_NX = 13  # the plant's [q; v]: quaternion wxyz, position; angular, linear velocity (world frame)


class QuadrotorTransitionSim(DrakeTransitionSim):
    """goflow/Quadrotor-v0's Drake model stepped from arbitrary states.

    State (16,) = the plant's [q; v] (13: quaternion w, x, y, z, position, angular and linear
    velocity in the world frame), then the episode's goal position (3) [m], which no step changes
    and `observe` needs. xi = (mass,), the env's box. Action: four normalized rotor thrusts,
    thrust_i = T_max (clip(a_i) + 1) / 2, held for one control step (2 plant steps), as in the env.
    A step whose body rate passes the env's `max_angular_rate` is a failed row (NaN), as it ends
    the env's episode. It drives a private QuadrotorEnv through its PlantEnv attributes, so a
    step is the env's step (tested).

    Arguments:
        env_kwargs: keyword arguments of QuadrotorEnv (QuadrotorConfig fields).
    """

    env_id = "goflow/Quadrotor-v0"
    state_dim = _NX + 3
    action_dim = 4

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs.quadrotor import QuadrotorEnv

        self._env = env = QuadrotorEnv(**env_kwargs)
        self.config = env.config
        self.space = env.space
        self.control_dt = env.control_dt
        self._simulator, self._context = env._simulator, env._context
        self._plant, self._plant_context = env._plant, env._plant_context
        self._goal = np.zeros(3)

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """The env's own: the body mass (its inertia fixed, as in the env)."""
        self._env._apply_xi(xi)

    def _set_state(self, state: NDArray[np.float64]) -> None:
        """The plant at state[:13], time 0; the goal kept for `_read_state`."""
        super()._set_state(state[:_NX])
        self._goal = state[_NX:].copy()

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Hold the env's rotor thrusts for the normalized action."""
        self._env._input.set(self._env._inputs(action[None])[0])

    def _advance(self) -> None:
        """One control step; SimulationError when the body rate passes max_angular_rate (the env's rule)."""
        super()._advance()
        w = self._plant.GetPositionsAndVelocities(self._plant_context)[7:10]
        if not np.all(np.abs(w) <= self.config.max_angular_rate):
            raise SimulationError(f"QuadrotorTransitionSim: body rate {w.tolist()} rad/s beyond max_angular_rate")

    def _read_state(self) -> NDArray[np.float64]:
        """The plant's [q; v] and the goal."""
        return np.concatenate([super()._read_state(), self._goal])

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset state for xi and its goal (drawn from a seed taken from rng).

        Arguments:
            xi: parameters, shape (1,).
            rng: the generator of the env's seed.

        Returns:
            The state, shape (16,).
        """
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi})
        return np.concatenate([self._env.initial_state, self._env.goal])

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """goflow/Quadrotor-v0's observation of a state: body-frame linear and angular velocity,
        gravity direction and goal offset, clipped to the env's bounds.

        Arguments:
            state: shape (16,).

        Returns:
            The observation, shape (12,).
        """
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_dim,):
            raise ValueError(f"{type(self).__name__}.observe: state has shape {s.shape}, expected ({self.state_dim},)")
        self._env._goal_xyz = tuple(float(g) for g in s[_NX:])
        return self._env._observe_and_reward(s[:_NX].tolist())[0]
