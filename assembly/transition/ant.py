"""goflow/Ant-v0 stepped from any plant state: the env's Drake model (same builder and config),
with the torso mass and the leg joint damping as parameters."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.envs.drake_sim import quiet_drake
from assembly.params import Param, ParamSpace
from assembly.transition.drake import DrakeTransitionSim

__all__ = ["ANT_SPACE", "AntTransitionSim"]

ANT_SPACE = ParamSpace(
    (
        Param("torso_mass", 0.01, 20.0, "kg"),  # the env's box (paper appendix A.1)
        Param("leg_damping", 0.0, 2.0, "N m s/rad", nominal=0.1),  # all 8 joints (nv_ant: 0.1)
    )
)


class AntTransitionSim(DrakeTransitionSim):
    """goflow/Ant-v0's Drake model stepped from arbitrary states.

    State = the plant's [q; v] (29,). Parameters: the torso mass (the env's randomized parameter;
    inertia scales with it) and the damping of all eight leg joints (fixed at 0.1 in the env).
    Action: normalized joint torques times the env's effort limit.

    Arguments:
        env_kwargs: keyword arguments of AntEnv (its config fields).
    """

    env_id = "goflow/Ant-v0"
    action_dim = 8

    def __init__(self, **env_kwargs: Any) -> None:
        from pydrake.systems.analysis import Simulator

        from assembly.envs import ant

        self._env = ant.AntEnv(**env_kwargs)  # initial states and observations
        self.config = self._env.config
        with quiet_drake():
            built = ant._build(self.config)
            self._diagram, self._plant, self._torso, self._joints, _, m_torso = built
            self._simulator = Simulator(self._diagram)
        self._com0 = np.asarray(m_torso.get_com())
        self._unit_inertia0 = m_torso.get_unit_inertia()
        self._context = self._simulator.get_mutable_context()
        self._plant_context = self._plant.GetMyMutableContextFromRoot(self._context)
        self._port = self._plant.get_actuation_input_port()
        self._u = np.zeros(self._plant.num_actuated_dofs())  # actuator order = joint order
        self.space = ANT_SPACE
        self.state_dim = self._plant.num_positions() + self._plant.num_velocities()
        self.control_dt = self.config.control_dt
        self._set: tuple[float, float] | None = None

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """Torso mass (spatial inertia scaled with it) and the damping of the eight leg joints."""
        from pydrake.multibody.tree import SpatialInertia

        mass, damping = float(xi[0]), float(xi[1])
        if self._set == (mass, damping):
            return
        self._torso.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(mass, self._com0, self._unit_inertia0)
        )
        for j in self._joints:
            j.SetDampingVector(self._plant_context, [damping])
        self._set = (mass, damping)

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Joint torques: the clipped action times the effort limit."""
        self._u[:] = np.clip(action, -1.0, 1.0) * self.config.effort_limit
        self._port.FixValue(self._plant_context, self._u)

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset pose (with its reset noise) for the torso mass xi[0].

        Arguments:
            xi: parameters, shape (2,).
            rng: the generator of the env's seed.

        Returns:
            The plant state, shape (29,).
        """
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi[:1]})
        return self._env.state()

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """goflow/Ant-v0's observation of a state.

        Arguments:
            state: the plant state, shape (29,).

        Returns:
            Torso height, quaternion, joint angles, torso linear and angular velocity, joint
            rates, shape (27,).
        """
        s = np.asarray(state, dtype=np.float64)
        nq = self._plant.num_positions()
        fb_q = self._torso.floating_positions_start()
        fb_v = self._torso.floating_velocities_start_in_v()
        qj = np.array([j.position_start() for j in self._joints])
        vj = np.array([j.velocity_start() for j in self._joints])
        quat = s[fb_q : fb_q + 4] / max(float(np.linalg.norm(s[fb_q : fb_q + 4])), 1e-12)
        obs = np.concatenate(
            [[s[fb_q + 6]], quat, s[qj], s[nq + fb_v + 3 : nq + fb_v + 6], s[nq + fb_v : nq + fb_v + 3], s[nq + vj]]
        )
        return obs.astype(np.float32)
