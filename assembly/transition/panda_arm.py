"""goflow/PandaArm-v0 transition simulator: our Panda arm (assembly/models/panda) under joint torques,
with link masses, joint damping and joint friction as the parameters xi.

Model: the arm URDF (no hand, no contact) parsed offline (world.model_parser), base welded to the
world, a discrete MultibodyPlant (SAP, `lagged`: it enforces the joint limits) with a 5 ms step and
a 10 ms control period. Joint damping is the plant's (implicit); joint friction is a smooth Coulomb
torque -f_j tanh(v_j / v_s) per joint, evaluated at the start of each control step and held for it
(applied generalized force). Its per-joint amplitudes are Gaz et al. 2019's identified friction
amplitudes (assembly/panda_model.py) times `friction_scale`; the damping is the model's per-joint
damping times `damping_scale`.

Action: normalized torques in [-1, 1]^7 times `action_scale` x the effort limits, added to the
gravity compensation of the NOMINAL model (the controller does not know the true masses, so mass
errors show up as drift: that is what makes them identifiable). State: (q, v), 14 values.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import SimulationError
from assembly.params import Param, ParamSpace

__all__ = ["PandaArmConfig", "PandaArmSim", "PANDA_ARM_SPACE"]

PANDA_ARM_SPACE = ParamSpace((
    Param("link4_mass", 1.5, 6.0, "kg", nominal=3.587895),  # URDF panda_link4
    Param("link7_mass", 0.2, 3.0, "kg", nominal=0.735522),  # URDF panda_link7 (+ any payload)
    Param("damping_scale", 0.0, 3.0, "1", nominal=1.0),  # x the model's joint damping
    Param("friction_scale", 0.0, 2.0, "1", nominal=1.0),  # x Gaz et al.'s friction amplitudes
))


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
            raise ValueError(f"PandaArmConfig: control_dt {self.control_dt} s must be a multiple of "
                             f"time_step {self.time_step} s")


class PandaArmSim:
    """Step the Panda arm from any (q, v) under torques for given (masses, damping, friction)."""

    env_id = "goflow/PandaArm-v0"
    state_dim = 14
    action_dim = 7

    def __init__(self, config: PandaArmConfig | None = None, **overrides: Any) -> None:
        import dataclasses

        from pydrake.multibody.plant import MultibodyPlant, MultibodyPlantConfig, AddMultibodyPlant
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        from assembly.panda_model import _FRICTION_A, Q_HOME, panda_model_paths
        from assembly.world import model_parser

        self.config = cfg = dataclasses.replace(config or PandaArmConfig(), **overrides)
        self.space = PANDA_ARM_SPACE
        self.control_dt = cfg.control_dt
        builder = DiagramBuilder()
        plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=cfg.time_step,
                                                          discrete_contact_approximation="lagged"), builder)
        arm_path, _ = panda_model_paths()
        (model,) = model_parser(plant).AddModels(str(arm_path))
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0", model))
        plant.Finalize()
        self._diagram = builder.Build()
        self._plant: MultibodyPlant = plant
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._pc = plant.GetMyMutableContextFromRoot(self._context)
        self._nominal_context = plant.CreateDefaultContext()
        self._links = [plant.GetBodyByName(n, model) for n in ("panda_link4", "panda_link7")]
        self._joints = [plant.GetJointByName(f"panda_joint{i}", model) for i in range(1, 8)]
        self._damping0 = np.array([j.default_damping_vector()[0] for j in self._joints])
        self._friction0 = np.asarray(_FRICTION_A, dtype=np.float64)
        self._effort = np.array([plant.get_joint_actuator(i).effort_limit()
                                 for i in plant.GetJointActuatorIndices(model)])
        self._q_home = np.asarray(Q_HOME, dtype=np.float64)
        self._lower = plant.GetPositionLowerLimits()
        self._upper = plant.GetPositionUpperLimits()
        self._act_port = plant.get_actuation_input_port()
        self._force_port = plant.get_applied_generalized_force_input_port()
        self._set: tuple[float, ...] | None = None

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        key = tuple(float(v) for v in xi)
        if key == self._set:
            return
        m4, m7, damping_scale, _ = key
        self._links[0].SetMass(self._pc, m4)  # unit inertia kept: inertia scales with the mass
        self._links[1].SetMass(self._pc, m7)
        for j, d0 in zip(self._joints, self._damping0):
            j.SetDampingVector(self._pc, [damping_scale * d0])
        self._set = key

    def gravity_compensation(self, q: ArrayLike) -> NDArray[np.float64]:
        """Torques [N m] that hold the NOMINAL arm still at q."""
        self._plant.SetPositions(self._nominal_context, np.asarray(q, dtype=np.float64))
        return -self._plant.CalcGravityGeneralizedForces(self._nominal_context)

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row (rows grouped by xi); NaN rows where Drake failed."""
        from assembly.envs.drake_sim import advance
        from assembly.transition_sim import _grouped_rows, check_step_args

        s, a, x = check_step_args(self, states, actions, xi)
        out = np.full_like(s, np.nan)
        cfg = self.config
        for i in _grouped_rows(x):
            self._apply_xi(x[i])
            q, v = s[i, :7], s[i, 7:]
            tau = self.gravity_compensation(q) + np.clip(a[i], -1.0, 1.0) * cfg.action_scale * self._effort
            friction = -x[i, 3] * self._friction0 * np.tanh(v / cfg.friction_speed)
            self._context.SetTime(0.0)
            self._plant.SetPositionsAndVelocities(self._pc, s[i])
            self._act_port.FixValue(self._pc, tau)
            self._force_port.FixValue(self._pc, friction)
            try:
                self._simulator.Initialize()
                advance(self._simulator, cfg.control_dt, "PandaArmSim")
            except (SimulationError, RuntimeError):
                continue
            nxt = self._plant.GetPositionsAndVelocities(self._pc)
            if np.all(np.isfinite(nxt)):
                out[i] = nxt
        return out

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """Q_HOME plus uniform joint noise (inside the limits), at rest."""
        self.space.validate(np.asarray(xi, dtype=np.float64))
        noise = self.config.reset_noise
        q = np.clip(self._q_home + rng.uniform(-noise, noise, 7), self._lower, self._upper)
        return np.concatenate([q, np.zeros(7)])

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The state itself (q, v)."""
        return np.asarray(state, dtype=np.float32)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Uniform in [-1, 1]^7."""
        return rng.uniform(-1.0, 1.0, size=7)
