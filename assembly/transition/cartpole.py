"""goflow/Cartpole-v0 stepped from any plant state: the env's own Drake model (CartpoleEnv)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.transition.drake import DrakeTransitionSim

__all__ = ["CartpoleTransitionSim"]


class CartpoleTransitionSim(DrakeTransitionSim):
    """goflow/Cartpole-v0's Drake model; state = plant state (x, z, theta, xdot, zdot, thetadot).

    It drives a private CartpoleEnv through the PlantEnv attributes (`_simulator`, `_context`,
    `_plant`, `_plant_context`, the held input `_input`, `_apply_xi`, `_inputs`), so a step is the
    env's step (as `CartpoleEnv.bare_rollout`). xi = (pole mass, cart mass, slider friction).

    Arguments:
        env_kwargs: keyword arguments of CartpoleEnv (its config fields).
    """

    env_id = "goflow/Cartpole-v0"
    state_dim = 6
    action_dim = 1

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs.cartpole import CartpoleEnv

        self._env = env = CartpoleEnv(**env_kwargs)
        self.space = env.space
        self.control_dt = env.control_dt
        self._simulator, self._context = env._simulator, env._context
        self._plant, self._plant_context = env._plant, env._plant_context

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """The env's own: body masses and the wheel/ground friction coefficient."""
        self._env._apply_xi(xi)

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Hold the env's slider force for the normalized action."""
        self._env._input.set(self._env._inputs(action[None])[0])

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's own reset state for xi (its pole angle drawn from a seed taken from rng).

        Arguments:
            xi: parameters, shape (3,).
            rng: the generator of the env's seed.

        Returns:
            The plant state, shape (6,).
        """
        xi = np.asarray(xi, dtype=np.float64)
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi})
        return self._env.initial_state

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The env's observation (x, xdot, cos theta, sin theta, thetadot), clipped to its bounds.

        Arguments:
            state: the plant state, shape (6,).

        Returns:
            The observation, shape (5,).
        """
        s = np.asarray(state, dtype=np.float64)
        obs = np.array([s[0], s[3], math.cos(s[2]), math.sin(s[2]), s[5]])
        high = self._env.observation_space.high.astype(np.float64)
        return np.clip(obs, -high, high).astype(np.float32)
