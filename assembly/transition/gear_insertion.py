"""goflow/GearInsertion-v0 (variant "fast") stepped from any state: the env's own reduced Drake model
(assembly.insertion_model) with its grasp error as the parameters; the older poses of the policy's
history ride in the state so that a state is observable."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.transition.drake import DrakeTransitionSim
from goflow_common.errors import InputError, SimulationError

__all__ = ["GearInsertionTransitionSim"]

_NX = 8  # the plant's [q; v]: tool x, y, z [m], yaw [rad] and their rates


class GearInsertionTransitionSim(DrakeTransitionSim):
    """goflow/GearInsertion-v0's reduced model (variant "fast") stepped from arbitrary states.

    State (8 + 4 (history - 1), 44 by default) = the plant's [q; v] (tool x, y, z, yaw on its four
    PD-driven joints and their rates), then the older `history - 1` tool poses of the policy's
    observation, relative to the seated tool pose, newest first (zeros before the episode's first
    steps, as in the env); the newest pose is q itself. The plant has no other state: the impedance
    target is the measured pose plus the scaled action (InsertionLaw), rebuilt from the row, and
    the gear is welded to the tool. xi = the env's grasp error (x, y [m], yaw [rad]), written into
    the grasp frame. Action: (dx, dy, dz, dyaw) in [-1, 1], the env's, held for one control step.
    A step whose observation leaves the env's bounds is a failed row (NaN), as it ends the env's
    episode. It drives a private GearInsertionEnv, so a step is the env's step (tested).

    Arguments:
        env_kwargs: keyword arguments of GearInsertionEnv (GearInsertionConfig fields); the
            variant must be "fast" (the panda station's arm, hand and controller are not stepped
            from a state here).
    """

    env_id = "goflow/GearInsertion-v0"
    action_dim = 4

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs.gear_insertion import GearInsertionEnv

        variant = env_kwargs.get("variant", "fast")
        if variant != "fast":
            raise InputError(
                f"GearInsertionTransitionSim: variant {variant!r}; expected 'fast' (only the reduced model is "
                "stepped from a state)"
            )
        self._env = env = GearInsertionEnv(**env_kwargs)
        self.config = env.config
        self.space = env.space
        self.control_dt = env.control_dt
        self.law = env.law
        sim = env.sim
        self._sim = sim
        self._simulator, self._context = sim.simulator, sim.context
        self._plant, self._plant_context = sim.model.plant, sim._pc
        self._older_rows = self.config.history - 1
        self.state_dim = _NX + 4 * self._older_rows
        self._older = np.zeros((self._older_rows, 4))
        self._high = env.observation_space.high

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """The grasp error as the env's reset writes it: the grasp frame's pose on the tool."""
        from assembly.world import grasp_with_error

        self._sim.model.held.grasp_frame.SetPoseInParentFrame(
            self._plant_context, grasp_with_error(self.config.gear, *xi)
        )

    def _set_state(self, state: NDArray[np.float64]) -> None:
        """The plant at state[:8], time 0; the history after this step kept for `_read_state`."""
        super()._set_state(state[:_NX])
        older = state[_NX:].reshape(self._older_rows, 4)
        self._older = np.vstack([self.law.relative(state[:4]), older[:-1]])

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """The env's impedance target for the action at the row's measured tool pose (zero rates)."""
        target = self.law.target(action, state[:4])
        self._sim._desired.FixValue(self._context, np.concatenate([target, np.zeros(4)]))

    def _advance(self) -> None:
        """One control step; SimulationError when the observation leaves its bounds (the env's rule)."""
        super()._advance()
        obs = self.observe(self._read_state())
        if not np.all(np.abs(obs) <= self._high):
            raise SimulationError("GearInsertionTransitionSim: the observation left its bounds")

    def _read_state(self) -> NDArray[np.float64]:
        """The plant's [q; v] and the older poses of the history."""
        return np.concatenate([super()._read_state(), self._older.reshape(-1)])

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset state for xi: the tool at rest at its start pose, no older poses. The env
        draws no reset noise, so `rng` is not used.

        Arguments:
            xi: parameters, shape (3,).
            rng: unused (kept for the TransitionSim contract).

        Returns:
            The state, shape (state_dim,).
        """
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(options={"xi": xi})
        plant_state = self._plant.GetPositionsAndVelocities(self._plant_context)
        return np.concatenate([plant_state, self._env._history.poses[1:].reshape(-1)])

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """goflow/GearInsertion-v0's observation of a state: the history of tool poses relative to
        the seated pose and their finite-difference velocities, newest first (PoseHistory).

        Arguments:
            state: shape (state_dim,).

        Returns:
            The observation, shape (8 history,) (80 by default).
        """
        from assembly.insertion_law import PoseHistory

        s = np.asarray(state, dtype=np.float64)
        if s.shape != (self.state_dim,):
            raise ValueError(f"{type(self).__name__}.observe: state has shape {s.shape}, expected ({self.state_dim},)")
        history = PoseHistory(self.law)
        history.poses[0] = self.law.relative(s[:4])
        history.poses[1:] = s[_NX:].reshape(self._older_rows, 4)
        return history.observation()
