"""goflow/Hopper-v0, Walker2d-v0, HalfCheetah-v0 and Humanoid-v0 stepped from any plant state: the
envs' own Drake plants (`assembly.envs.locomotion`), with their Table I parameters."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.envs.drake_sim import quiet_drake
from assembly.transition.drake import DrakeTransitionSim

__all__ = [
    "LocomotionTransitionSim",
    "HopperTransitionSim",
    "Walker2dTransitionSim",
    "HalfCheetahTransitionSim",
    "HumanoidTransitionSim",
]


class LocomotionTransitionSim(DrakeTransitionSim):
    """A locomotion env's plant stepped from arbitrary states under arbitrary xi.

    State = the plant's [q; v] (Drake's coordinates; `model.to_mujoco` gives MuJoCo's qpos, qvel).
    Parameters: the env's xi (its `space`, the NFPDE paper's Table I). Action: normalized in
    [-1, 1], mapped linearly onto the actuators' `ctrlrange` (the Humanoid's is [-0.4, 0.4], the
    others' [-1, 1]); the torque is gear x ctrl, held for one control step (frame_skip plant steps),
    as in the env. One step here equals one `env.step` from the same state (tested).

    Arguments:
        env_kwargs: keyword arguments of the env (LocomotionConfig fields).
    """

    env_class: ClassVar[str]  # the env's class name in assembly.envs.locomotion

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs import locomotion

        with quiet_drake():  # the parser's warnings about what mjcf rebuilds
            self._env = env = getattr(locomotion, self.env_class)(**env_kwargs)
        m = env.model
        self.config = env.config
        self._simulator, self._context = env._simulator, env._context
        self._plant, self._plant_context = m.plant, env._plant_context
        self.space = env.space
        self.state_dim = m.plant.num_positions() + m.plant.num_velocities()
        self.action_dim = len(m.gear)
        self.control_dt = env.control_dt
        self._half_range = (m.ctrl_high - m.ctrl_low) / 2.0
        self._mid = (m.ctrl_high + m.ctrl_low) / 2.0
        self._set: NDArray[np.float64] | None = None

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """The env's masses, dampings and friction (skipped when xi is the one already set)."""
        if self._set is not None and np.array_equal(self._set, xi):
            return
        self._env._apply_xi(xi)
        self._set = xi.copy()

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Torques gear x ctrl, ctrl = the clipped action mapped onto ctrlrange."""
        self._env._u[:] = self._env.model.gear * self.ctrl(action)
        self._env._input.set(self._env._u)

    def ctrl(self, action: ArrayLike) -> NDArray[np.float64]:
        """The env action (MuJoCo's ctrl) of a normalized action.

        Arguments:
            action: shape (da,), in [-1, 1] (clipped).

        Returns:
            ctrl, shape (da,), inside the actuators' ctrlrange.
        """
        return self._mid + np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self._half_range

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset state (gymnasium's initial pose plus its reset noise) under xi.

        Arguments:
            xi: parameters, shape (d,), inside `space`.
            rng: the generator the env's reset seed is drawn from.

        Returns:
            The plant state [q; v], shape (ds,).
        """
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi})
        self._set = xi.copy()
        return self._env.plant_state

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The env's observation of a plant state (gymnasium v5's layout).

        Arguments:
            state: the plant state [q; v], shape (ds,).

        Returns:
            The observation, float32 (the Humanoid's com-based terms from this state and the
            xi last applied; its actuator forces are the last action's, as after an env step).
        """
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_dim,):
            raise ValueError(f"{type(self).__name__}.observe: state has shape {s.shape}, expected ({self.state_dim},)")
        self._plant.SetPositionsAndVelocities(self._plant_context, s)
        return self._env._observe(*self._env.model.to_mujoco(s))


class HopperTransitionSim(LocomotionTransitionSim):
    """goflow/Hopper-v0 (6 parameters)."""

    env_id = "goflow/Hopper-v0"
    env_class = "HopperEnv"


class Walker2dTransitionSim(LocomotionTransitionSim):
    """goflow/Walker2d-v0 (7 parameters)."""

    env_id = "goflow/Walker2d-v0"
    env_class = "Walker2dEnv"


class HalfCheetahTransitionSim(LocomotionTransitionSim):
    """goflow/HalfCheetah-v0 (14 parameters)."""

    env_id = "goflow/HalfCheetah-v0"
    env_class = "HalfCheetahEnv"


class HumanoidTransitionSim(LocomotionTransitionSim):
    """goflow/Humanoid-v0 (30 parameters)."""

    env_id = "goflow/Humanoid-v0"
    env_class = "HumanoidEnv"
