"""goflow/PandaArm-v0: our Panda arm (assembly/models/panda) under joint torques, with link masses,
joint damping and joint friction as the parameters xi.

Model: the arm URDF (no hand, no contact) parsed offline (world.model_parser), base welded to the
world, a discrete MultibodyPlant (SAP, `lagged`: it enforces the joint limits) with a 5 ms step and
a 10 ms control period. Joint damping is the plant's (implicit); joint friction is a smooth Coulomb
torque -f_j tanh(v_j / v_s) per joint, evaluated at the start of each control step and held for it
(applied generalized force). Its per-joint amplitudes are Gaz et al.'s identified friction
amplitudes (IEEE RA-L 4(4), 2019; assembly/panda_model.py) times `friction_scale`; the damping is
the model's per-joint damping times `damping_scale`.

Action: normalized torques in [-1, 1]^7 times `action_scale` x the effort limits, added to the
gravity compensation of the NOMINAL model (the controller does not know the true masses, so mass
errors show up as drift: that is what makes them identifiable). State: (q, v), 14 values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import Param, ParamSpace
from assembly.transition.drake import DrakeTransitionSim
from goflow_common.config import config_with_overrides

__all__ = ["PandaArmConfig", "PandaArmSim", "PANDA_ARM_SPACE"]

PANDA_ARM_SPACE = ParamSpace(
    (
        Param("link4_mass", 1.5, 6.0, "kg", nominal=3.587895),  # URDF panda_link4
        Param("link7_mass", 0.2, 3.0, "kg", nominal=0.735522),  # URDF panda_link7 (+ any payload)
        Param("damping_scale", 0.0, 3.0, "1", nominal=1.0),  # x the model's joint damping
        Param("friction_scale", 0.0, 2.0, "1", nominal=1.0),  # x Gaz et al.'s friction amplitudes
    )
)


@dataclass(frozen=True)
class PandaArmConfig:
    """Time steps, actuation and reset noise of the arm simulator (SI units)."""

    time_step: float = 0.005  # [s] plant step
    control_dt: float = 0.01  # [s] one action (a multiple of time_step)
    action_scale: float = 0.1  # fraction of each joint's effort limit at action 1
    friction_speed: float = 0.1  # [rad/s] v_s of the smooth Coulomb friction
    reset_noise: float = 0.1  # [rad] uniform joint noise around Q_HOME at reset

    def __post_init__(self) -> None:
        for name in ("time_step", "control_dt", "action_scale", "friction_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"PandaArmConfig.{name} must be > 0, got {getattr(self, name)!r}")
        ratio = self.control_dt / self.time_step
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(
                f"PandaArmConfig: control_dt {self.control_dt} s must be a multiple of time_step {self.time_step} s"
            )


class PandaArmSim(DrakeTransitionSim):
    """Step the Panda arm from any (q, v) under torques for given (masses, damping, friction).

    `_apply_action` fixes two inputs: the actuation (`_torques`) and the applied generalized
    force (`_joint_friction`); a torque or friction effect overrides one of these two.

    Arguments:
        config: the config (None: defaults).
        overrides: fields of PandaArmConfig applied last.
    """

    env_id = "goflow/PandaArm-v0"
    state_dim = 14
    action_dim = 7

    def __init__(self, config: PandaArmConfig | None = None, **overrides: Any) -> None:
        from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        from assembly.panda_model import _FRICTION_A, Q_HOME, panda_model_paths
        from assembly.world import model_parser

        self.config = cfg = config_with_overrides(PandaArmConfig, config, overrides, "PandaArmSim")
        self.space = PANDA_ARM_SPACE
        self.control_dt = cfg.control_dt
        builder = DiagramBuilder()
        plant_config = MultibodyPlantConfig(time_step=cfg.time_step, discrete_contact_approximation="lagged")
        plant, _ = AddMultibodyPlant(plant_config, builder)
        arm_path, _ = panda_model_paths()
        (model,) = model_parser(plant).AddModels(str(arm_path))
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0", model))
        plant.Finalize()
        self._diagram = builder.Build()
        self._plant: MultibodyPlant = plant
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._nominal_context = plant.CreateDefaultContext()
        self._links = [plant.GetBodyByName(n, model) for n in ("panda_link4", "panda_link7")]
        self._joints = [plant.GetJointByName(f"panda_joint{i}", model) for i in range(1, 8)]
        self._damping0 = np.array([j.default_damping_vector()[0] for j in self._joints])
        self._friction0 = np.asarray(_FRICTION_A, dtype=np.float64)
        self._effort = np.array(
            [plant.get_joint_actuator(i).effort_limit() for i in plant.GetJointActuatorIndices(model)]
        )
        self._q_home = np.asarray(Q_HOME, dtype=np.float64)
        self._lower = plant.GetPositionLowerLimits()
        self._upper = plant.GetPositionUpperLimits()
        self._act_port = plant.get_actuation_input_port()
        self._force_port = plant.get_applied_generalized_force_input_port()
        self._set: tuple[float, ...] | None = None
        self._friction_scale = 1.0

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """Link masses (unit inertias kept), joint damping, the scale of `_joint_friction`."""
        key = tuple(float(v) for v in xi)
        if key == self._set:
            return
        m4, m7, damping_scale, friction_scale = key
        self._links[0].SetMass(self._plant_context, m4)  # unit inertia kept: inertia scales
        self._links[1].SetMass(self._plant_context, m7)
        for j, d0 in zip(self._joints, self._damping0):
            j.SetDampingVector(self._plant_context, [damping_scale * d0])
        self._friction_scale = friction_scale
        self._set = key

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Hold the torques and the joint friction of this state for the control step."""
        self._act_port.FixValue(self._plant_context, self._torques(state, action))
        self._force_port.FixValue(self._plant_context, self._joint_friction(state))

    def _torques(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> NDArray[np.float64]:
        """Actuation [N m]: nominal gravity compensation + clipped action x scale x effort."""
        return (
            self.gravity_compensation(state[:7]) + np.clip(action, -1.0, 1.0) * self.config.action_scale * self._effort
        )

    def _joint_friction(self, state: NDArray[np.float64]) -> NDArray[np.float64]:
        """Smooth Coulomb friction [N m] at the state's joint speeds, for the applied scale."""
        speed = self.config.friction_speed
        return -self._friction_scale * self._friction0 * np.tanh(state[7:] / speed)

    def gravity_compensation(self, q: ArrayLike) -> NDArray[np.float64]:
        """Torques that hold the NOMINAL arm still.

        Arguments:
            q: joint positions [rad], shape (7,).

        Returns:
            The torques [N m], shape (7,).
        """
        self._plant.SetPositions(self._nominal_context, np.asarray(q, dtype=np.float64))
        return -self._plant.CalcGravityGeneralizedForces(self._nominal_context)

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """Q_HOME plus uniform joint noise (inside the limits), at rest.

        Arguments:
            xi: parameters, shape (4,) (checked, unused).
            rng: the generator of the noise.

        Returns:
            The state (q, 0), shape (14,).
        """
        self.space.validate(np.asarray(xi, dtype=np.float64))
        noise = self.config.reset_noise
        q = np.clip(self._q_home + rng.uniform(-noise, noise, 7), self._lower, self._upper)
        return np.concatenate([q, np.zeros(7)])
