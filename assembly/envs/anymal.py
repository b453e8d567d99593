"""goflow/Anymal-v0: a quadruped of ANYmal C's size and mass built in Drake, tracking a fixed forward
velocity command; xi = base mass and the four hip (HAA) joint frictions.

The GoFlow paper's Anymal task (Curtis et al., ICML 2025, appendix A.1: xi = body mass [0, 200] kg
and hip joint frictions [0, 0.1], J_T = 1.5, t_max = 5 s) is Isaac Lab's direct ANYmal-C flat
velocity task with the command fixed at 1 m/s forward. The robot is our own model, built with
MultibodyPlant API calls (no files, no downloads) from the numbers of ANYbotics' public ANYmal C
description: discrete plant, point contact, `lagged`, 1/200 s steps, 4 per action (control_dt =
1/50 s, the seed's decimation), 250 steps.

- xi (5): base_mass [0, 200] kg (the base body alone; the legs keep their 25.8 kg), then the
  LF, RF, LH, RH HAA friction coefficients [0, 0.1] (PhysX's unitless joint friction: the friction
  torque is bounded by mu x (|f| + |tau|) of the load the joint transmits).
- Action (12,): joint position offsets in [-1, 1] (clipped), target = default pose + 0.5 x action,
  tracked by PD-controlled actuators (Kp 40 N m/rad, Kd 5 N m s/rad, |torque| <= 80 N m) inside
  Drake's solver. Joint order LF, RF, LH, RH legs x (HAA, HFE, KFE).
- Observation (48, float32), Isaac Lab's: base linear and angular velocity (base frame), projected
  gravity, the command (1, 0, 0), joint positions minus the default pose, joint velocities, the
  last (clipped) action.
- Reward: the seed's ten terms and weights (velocity tracking, penalties, feet air time), each
  times the step dt. Termination when the base touches the ground (Isaac Lab's base_contact; the
  seed disables it, see docs); success: return >= J_T = 1.506, the paper's 1.5 re-derived for
  250 rewarded steps instead of 249.

Model, task derivation, differences from the seed, speed and the standing robot's return:
docs/envs.md#anymal.

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025, appendix A.1 (box, J_T, t_max); github.com/aidan-curtis/goflow at 294d0ee3
(goflow/environments/anymal/anymal_env.py, agents/GOFLOW.yaml); ANYbotics anymal_c_simple_description
URDF (BSD-3) as converted in google-deepmind/mujoco_menagerie anybotics_anymal_c/anymal_c_mjx.xml at
4035abd3 (link masses, inertias, joint offsets, foot radius); Isaac Lab isaaclab_assets/robots/anymal.py
(default pose, ANYdrive 3 DC-motor gains and limits); NVIDIA PhysX
PxArticulationJointReducedCoordinate::setFrictionCoefficient (joint friction definition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs.base import ParamEnv, SimulationError, quaternion_rotation
from assembly.envs.drake_sim import HeldInput, PlantAccess, advance, point_contact_properties, quiet_drake
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from goflow_common.checks import check_choice, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError

__all__ = ["AnymalConfig", "AnymalEnv", "NOMINAL_BASE_MASS", "SEED_J_T", "LEGS", "JOINT_NAMES"]

# -- the seed's task (goflow/environments/anymal/anymal_env.py, agents/GOFLOW.yaml) --------------
SEED_J_T = 1.5  # paper appendix A.1 and GOFLOW.yaml success_threshold
SEED_CONTROL_DT = 0.02  # [s] Isaac Lab sim dt 1/200 s x decimation 4
SEED_EPISODE_STEPS = 249  # rewarded steps before Isaac Lab's time-out (max_episode_length - 1)

# -- the robot: ANYbotics anymal_c_simple_description (URDF frames, all aligned with the base) ---
NOMINAL_BASE_MASS = 19.2035  # [kg]
BASE_COM = (0.0025, 0.0, 0.0502)  # [m] in the base frame
BASE_INERTIA = (0.217374, 0.639559, 0.624031)  # [kg m^2] about the COM, principal ~ base x, y, z
HAA_OFFSET = (0.2999, 0.104, 0.0)  # [m] base origin -> HAA axis (x sign front/hind, y left/right)
HFE_OFFSET = (0.0599, 0.08381, 0.0)  # [m] HAA -> HFE
KFE_OFFSET = (0.0, 0.1003, -0.285)  # [m] HFE -> KFE (the thigh)
FOOT_OFFSET = (0.08795, 0.01305, -0.33797 + 0.02325)  # [m] KFE -> foot sphere centre (the shank)
FOOT_RADIUS = 0.03  # [m]
HIP_MASS, HIP_COM, HIP_INERTIA = 2.781, (0.0567, 0.0174, 0.0), (0.00586, 0.00492, 0.00329)
THIGH_MASS, THIGH_COM, THIGH_INERTIA = 3.071, (0.0, 0.0308, -0.2457), (0.03025, 0.02989, 0.00418)
SHANK_MASS, SHANK_COM, SHANK_INERTIA = 0.58842, (0.0613, 0.0055, -0.0807), (0.01016, 0.00924, 0.00112)
HAA_RANGE = (-0.72, 0.49)  # [rad] left legs (axis +x; positive = abduction); right legs mirrored
THIGH_RADIUS, SHANK_RADIUS = 0.04, 0.02  # [m] collision capsules (ours; see docs)
THIGH_TOP = (0.0, 0.03, -0.05)  # [m] HFE -> upper end of the thigh capsule (ours; its lower end is the KFE)
LEGS = ("LF", "RF", "LH", "RH")
_LEG_SIGNS = {"LF": (1.0, 1.0), "RF": (1.0, -1.0), "LH": (-1.0, 1.0), "RH": (-1.0, -1.0)}
JOINT_NAMES = tuple(f"{leg}_{j}" for leg in LEGS for j in ("HAA", "HFE", "KFE"))
# Isaac Lab ANYMAL_C_CFG init_state: HAA 0, front HFE 0.4, hind HFE -0.4, front KFE -0.8, hind KFE 0.8.
DEFAULT_POSE = tuple(v for leg in LEGS for v in ((0.0, 0.4, -0.8) if leg[1] == "F" else (0.0, -0.4, 0.8)))


def _box_from_inertia(mass: float, inertia: tuple[float, float, float]) -> tuple[float, float, float]:
    """Edge lengths (x, y, z) of the solid box of `mass` with the principal moments `inertia`."""
    sx, sy, sz = (12.0 * i / mass for i in inertia)  # y^2+z^2, x^2+z^2, x^2+y^2
    return (math.sqrt(0.5 * (sy + sz - sx)), math.sqrt(0.5 * (sx + sz - sy)), math.sqrt(0.5 * (sx + sy - sz)))


BASE_BOX = _box_from_inertia(NOMINAL_BASE_MASS, BASE_INERTIA)  # [m] 0.572 x 0.251 x 0.270


@dataclass(frozen=True)
class AnymalConfig:
    """Simulation, actuation, reward and episode settings of the Drake ANYmal (SI units)."""

    time_step: float = 1.0 / 200.0  # [s] plant discrete step (the seed's sim dt)
    control_dt: float = 1.0 / 50.0  # [s] one action (seed: decimation 4); an integer multiple of time_step
    t_max: float = 5.0  # [s] episode length (seed: 5 s)
    contact_approximation: str = "lagged"  # "lagged" | "similar" | "sap" (PD actuators need one of these)
    friction: float = 0.7  # Coulomb, static = dynamic (seed: robot 0.6-0.8 x ground 1.0)
    point_stiffness: float = 2.0e5  # [N/m] point contact
    hunt_crossley_dissipation: float = 5.0  # [s/m]
    kp: float = 40.0  # [N m/rad] Isaac Lab ANYDRIVE_3_SIMPLE_ACTUATOR_CFG stiffness
    kd: float = 5.0  # [N m s/rad] its damping
    effort_limit: float = 80.0  # [N m] its effort_limit
    action_scale: float = 0.5  # [rad] seed: target = default + 0.5 x action
    command: tuple[float, float, float] = (1.0, 0.0, 0.0)  # (v_x [m/s], v_y [m/s], yaw rate [rad/s]), base frame
    initial_height: float = 0.6  # [m] base origin at reset (seed: 0.6)
    reset_noise_scale: float = 0.0  # joint angles [rad] (uniform), base velocity [m/s, rad/s] (normal); seed: 0
    friction_speed: float = 0.05  # [rad/s] hip friction regularization v_s (docs/envs.md#anymal)
    contact_force_threshold: float = 1.0  # [N] a body is "in contact" above this (Isaac Lab's ContactSensor)
    terminate_on_base_contact: bool = True  # Isaac Lab's base_contact termination (the seed disables it)
    # reward weights (seed's), each times control_dt
    lin_vel_weight: float = 1.0
    yaw_rate_weight: float = 0.5
    z_vel_weight: float = -2.0
    ang_vel_weight: float = -0.05
    joint_torque_weight: float = -2.5e-5
    joint_accel_weight: float = -2.5e-7
    action_rate_weight: float = -0.01
    feet_air_time_weight: float = 0.5
    undesired_contact_weight: float = -1.0
    flat_orientation_weight: float = -5.0
    success_threshold: float | None = None  # J_T; None: the paper's 1.5 re-derived (see module doc)

    def __post_init__(self) -> None:
        for name in ("time_step", "control_dt", "t_max", "point_stiffness", "kp", "effort_limit",
                     "initial_height", "friction_speed"):
            check_number(getattr(self, name), f"AnymalConfig.{name}", 0.0, low_open=True)
        for name in ("friction", "hunt_crossley_dissipation", "kd", "action_scale", "reset_noise_scale",
                     "contact_force_threshold"):
            check_number(getattr(self, name), f"AnymalConfig.{name}", 0.0)
        for name in ("lin_vel_weight", "yaw_rate_weight", "z_vel_weight", "ang_vel_weight", "joint_torque_weight",
                     "joint_accel_weight", "action_rate_weight", "feet_air_time_weight",
                     "undesired_contact_weight", "flat_orientation_weight"):
            check_number(getattr(self, name), f"AnymalConfig.{name}")
        if self.success_threshold is not None:
            check_number(self.success_threshold, "AnymalConfig.success_threshold")
        if len(self.command) != 3:
            raise InputError(f"AnymalConfig.command = {self.command!r}; expected (v_x, v_y, yaw rate)")
        for i, c in enumerate(self.command):
            check_number(c, f"AnymalConfig.command[{i}]")
        object.__setattr__(self, "command", tuple(float(c) for c in self.command))
        check_choice(self.terminate_on_base_contact, (True, False), "AnymalConfig.terminate_on_base_contact")
        check_choice(self.contact_approximation, ("lagged", "similar", "sap"), "AnymalConfig.contact_approximation")
        ratio = self.control_dt / self.time_step
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise InputError(f"Anymal: control_dt ({self.control_dt:g} s) must be an integer multiple of "
                             f"time_step ({self.time_step:g} s)")

    def j_t(self) -> float:
        """J_T for this config: the paper's 1.5 scaled to our episode length (docs/envs.md#anymal)."""
        if self.success_threshold is not None:
            return float(self.success_threshold)
        return SEED_J_T * self.t_max / (SEED_EPISODE_STEPS * SEED_CONTROL_DT)


def _inertia(mass: float, com: tuple[float, ...], moments: tuple[float, float, float]):
    """SpatialInertia about the body origin: `mass` at `com` with principal `moments` about the COM
    (principal axes taken along the body axes)."""
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    return SpatialInertia.MakeFromCentralInertia(mass, np.asarray(com, float), RotationalInertia(*moments))


class _Mirror:
    """A URDF left-front offset moved to the leg with signs (sx, sy): x for front/hind, y for left/right."""

    def __init__(self, sx: float, sy: float) -> None:
        self.sx, self.sy = sx, sy

    def __call__(self, v: tuple[float, float, float]) -> tuple[float, float, float]:
        return (self.sx * v[0], self.sy * v[1], v[2])


def _build(config: AnymalConfig):
    """The Drake diagram (plant + scene graph) of the robot on a ground plane; returns handles."""
    from pydrake.geometry import Box, Capsule, CollisionFilterDeclaration, GeometrySet, HalfSpace, Sphere
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.multibody.tree import FixedOffsetFrame, PdControllerGains, RevoluteJoint
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=config.time_step, contact_model="point",
                             discrete_contact_approximation=config.contact_approximation,
                             use_sampled_output_ports=True),
        builder)
    def props():
        return point_contact_properties(config.point_stiffness, config.hunt_crossley_dissipation, config.friction)

    def segment(body, start, end, radius, name, color):
        """A collision + visual capsule on `body` from `start` to `end` (body frame)."""
        a, b = np.asarray(start, float), np.asarray(end, float)
        axis = b - a
        pose = RigidTransform(RotationMatrix.MakeFromOneVector(axis / np.linalg.norm(axis), 2), 0.5 * (a + b))
        shape = Capsule(radius, float(np.linalg.norm(axis)))
        plant.RegisterVisualGeometry(body, pose, shape, name, color)
        return plant.RegisterCollisionGeometry(body, pose, shape, name, props())

    base = plant.AddRigidBody("base", _inertia(NOMINAL_BASE_MASS, BASE_COM, BASE_INERTIA))
    base_pose = RigidTransform(np.asarray(BASE_COM))
    base_geoms = [plant.RegisterCollisionGeometry(base, base_pose, Box(*BASE_BOX), "base", props())]
    plant.RegisterVisualGeometry(base, base_pose, Box(*BASE_BOX), "base", [0.8, 0.1, 0.1, 1])

    joints, actuators, haa, thighs, feet = [], [], [], [], []
    for leg in LEGS:
        sx, sy = _LEG_SIGNS[leg]
        mirror = _Mirror(sx, sy)
        hip = plant.AddRigidBody(f"{leg}_HIP", _inertia(HIP_MASS, mirror(HIP_COM), HIP_INERTIA))
        thigh = plant.AddRigidBody(f"{leg}_THIGH", _inertia(THIGH_MASS, mirror(THIGH_COM), THIGH_INERTIA))
        shank = plant.AddRigidBody(f"{leg}_SHANK", _inertia(SHANK_MASS, mirror(SHANK_COM), SHANK_INERTIA))
        lo, hi = HAA_RANGE if sy > 0 else (-HAA_RANGE[1], -HAA_RANGE[0])
        chain = ((f"{leg}_HAA", base, hip, HAA_OFFSET, (1.0, 0.0, 0.0), lo, hi),
                 (f"{leg}_HFE", hip, thigh, HFE_OFFSET, (0.0, 1.0, 0.0), -math.inf, math.inf),
                 (f"{leg}_KFE", thigh, shank, KFE_OFFSET, (0.0, 1.0, 0.0), -math.inf, math.inf))
        for name, parent, child, offset, axis, lower, upper in chain:
            frame = plant.AddFrame(FixedOffsetFrame(f"{name}_parent", parent.body_frame(),
                                                    RigidTransform(np.asarray(mirror(offset)))))
            joint = plant.AddJoint(RevoluteJoint(name, frame, child.body_frame(), np.asarray(axis),
                                                 lower, upper, 0.0))
            act = plant.AddJointActuator(f"{name}_drive", joint, config.effort_limit)
            act.set_controller_gains(PdControllerGains(p=config.kp, d=config.kd))
            joints.append(joint)
            actuators.append(act)
        haa.append(joints[-3])
        knee = mirror(KFE_OFFSET)
        thighs.append(segment(thigh, mirror(THIGH_TOP), knee, THIGH_RADIUS, f"{leg}_thigh", [0.2, 0.2, 0.2, 1]))
        foot = np.asarray(mirror(FOOT_OFFSET))
        segment(shank, (0.0, 0.0, 0.0), foot, SHANK_RADIUS, f"{leg}_shank", [0.3, 0.3, 0.3, 1])
        feet.append(plant.RegisterCollisionGeometry(shank, RigidTransform(foot), Sphere(FOOT_RADIUS),
                                                    f"{leg}_foot", props()))
        plant.RegisterVisualGeometry(shank, RigidTransform(foot), Sphere(FOOT_RADIUS), f"{leg}_foot",
                                     [0.1, 0.1, 0.1, 1])

    ground = plant.world_body()
    plant.RegisterCollisionGeometry(ground, RigidTransform(), HalfSpace(), "ground", props())
    plant.RegisterVisualGeometry(ground, RigidTransform([0, 0, -0.005]), Box(20, 20, 0.01), "ground",
                                 [0.5, 0.5, 0.5, 1])
    plant.Finalize()

    # Only the ground touches the robot: no self-collisions.
    robot_geoms = [g for b in plant.GetBodyIndices(base.model_instance())
                   for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))]
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(robot_geoms)))
    diagram = builder.Build()
    return diagram, plant, base, joints, actuators, haa, base_geoms, thighs, feet


class AnymalEnv(PlantAccess, ParamEnv):
    """Track 1 m/s forward for 5 s with an ANYmal-C-sized quadruped whose base mass and hip joint
    frictions xi are drawn per episode."""

    def __init__(self, config: AnymalConfig | None = None, *, sampler: Sampler | None = None,
                 **overrides: Any) -> None:
        self.config = cfg = config_with_overrides(AnymalConfig, config, overrides, "AnymalEnv")
        self.space = ParamSpace((Param("base_mass", 0.0, 200.0, "kg", nominal=NOMINAL_BASE_MASS),)
                                + tuple(Param(f"{leg}_HAA_friction", 0.0, 0.1, "1", nominal=0.0) for leg in LEGS))
        super().__init__(self.space, sampler)
        self._set_timing(cfg.control_dt, cfg.t_max, cfg.j_t())

        from pydrake.systems.analysis import Simulator

        # Silence Drake's "half spaces are not supported for deformable contact" (we have none).
        with quiet_drake():
            (self._diagram, self._plant, self._base, self._joints, self._actuators, self._haa,
             base_geoms, thigh_geoms, foot_geoms) = _build(cfg)
            self._simulator = Simulator(self._diagram)
            self._simulator.Initialize()
        plant = self._plant
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        m_base = self._base.default_spatial_inertia()
        self._base_com = np.asarray(m_base.get_com())
        self._base_unit_inertia = m_base.get_unit_inertia()
        # Geometry -> contact category: 0 base, 1 thigh, 2 + i foot of leg i.
        self._geom_kind = {g: 0 for g in base_geoms}
        self._geom_kind.update({g: 1 for g in thigh_geoms})
        self._geom_kind.update({g: 2 + i for i, g in enumerate(foot_geoms)})
        # Index maps into q and v (floating base: quaternion wxyz, position; angular, linear velocity
        # in the world frame).
        fb_q = self._base.floating_positions_start()
        fb_v = self._base.floating_velocities_start_in_v()
        self._iq_quat = slice(fb_q, fb_q + 4)
        self._iq_pos = slice(fb_q + 4, fb_q + 7)
        self._iv_ang = slice(fb_v, fb_v + 3)
        self._iv_lin = slice(fb_v + 3, fb_v + 6)
        self._q_joint = np.array([j.position_start() for j in self._joints])
        self._v_joint = np.array([j.velocity_start() for j in self._joints])
        self._haa_v = [j.velocity_start() for j in self._haa]
        self._haa_index = [int(j.index()) for j in self._haa]
        self._q_default = np.array(DEFAULT_POSE)
        # Desired-state port: [q_d; v_d] ordered by actuator index; action i is joint i's.
        self._n_act = plant.num_actuators()
        self._act_order = np.array([a.input_start() for a in self._actuators])
        self._desired = np.zeros(2 * self._n_act)
        self._desired_input = HeldInput(plant.get_desired_state_input_port(self._base.model_instance()),
                                        self._plant_context, self._desired)
        self._actuation_input = HeldInput(plant.get_actuation_input_port(), self._plant_context,
                                          np.zeros(self._n_act))
        self._net_actuation_port = plant.get_net_actuation_output_port()
        self._accel_port = plant.get_generalized_acceleration_output_port()
        self._contact_port = plant.get_contact_results_output_port()
        self._reaction_port = plant.get_reaction_forces_output_port()
        self._command = np.array(cfg.command)
        self._k = 0
        self._state = np.zeros(self._nq + self._nv)
        self._action = np.zeros(12)
        self._friction = np.zeros(4)
        self._haa_load = np.zeros(4)
        self._reset_feet()
        self.last_reward_terms: dict[str, float] = {}

        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(48,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(12,), dtype=np.float32)

    # -- model ----------------------------------------------------------------------------------

    def base_mass(self) -> float:
        """The base mass currently set in the Context [kg]."""
        return float(self._base.get_mass(self._plant_context))

    def _reset_feet(self) -> None:
        """Isaac Lab ContactSensor air/contact timers of the four feet, zeroed."""
        self._air_time = [0.0] * 4
        self._contact_time = [0.0] * 4
        self._last_air_time = [0.0] * 4

    def _set_initial_state(self, xi: NDArray[np.float64]) -> None:
        """Set the base mass, the hip frictions and the default pose in the reused Context; time 0."""
        from pydrake.multibody.tree import SpatialInertia

        cfg = self.config
        # Mass and rotational inertia scale together (same unit inertia, same COM); 0 kg is allowed.
        self._base.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(float(xi[0]), self._base_com, self._base_unit_inertia))
        self._friction = np.asarray(xi[1:5], dtype=np.float64).copy()
        for joint in self._haa:
            joint.SetDamping(self._plant_context, 0.0)
        self._context.SetTime(0.0)
        q = np.zeros(self._nq)
        v = np.zeros(self._nv)
        q[self._iq_quat] = [1.0, 0.0, 0.0, 0.0]
        q[self._iq_pos] = [0.0, 0.0, cfg.initial_height]
        q[self._q_joint] = self._q_default
        s = cfg.reset_noise_scale
        if s > 0:
            rng = self.np_random
            q[self._q_joint] += rng.uniform(-s, s, size=12)
            v[self._iv_ang] = s * rng.standard_normal(3)
            v[self._iv_lin] = s * rng.standard_normal(3)
        self._plant.SetPositionsAndVelocities(self._plant_context, np.concatenate([q, v]))
        self._action = np.zeros(12)
        self._set_targets(self._action)
        self._simulator.Initialize()
        self._k = 0
        self._state = np.concatenate([q, v])
        self._haa_load[:] = 0.0
        self._reset_feet()

    def _set_targets(self, action: NDArray[np.float64]) -> None:
        """Joint position targets default + scale x action (zero velocity targets) on the PD drives."""
        self._desired[self._act_order] = self._q_default + self.config.action_scale * action
        self._desired_input.set(self._desired)

    def _apply_hip_friction(self, x: NDArray[np.float64]) -> None:
        """Hold, for the coming control step, each HAA joint's friction as an implicit damping
        mu (|f| + |tau|) / max(|v|, v_s): at |v| >= v_s it opposes the motion with the Coulomb torque
        of the current load; below, it is a stiff viscous regularization. Being a damping, Drake
        treats it implicitly and it can only dissipate."""
        for joint, mu, load, iv in zip(self._haa, self._friction, self._haa_load, self._haa_v):
            if mu > 0.0:
                speed = max(abs(float(x[self._nq + iv])), self.config.friction_speed)
                joint.SetDamping(self._plant_context, float(mu * load / speed))

    def _read_loads(self) -> None:
        """|f| + |tau| of the spatial force each HAA joint transmits (the last plant step's)."""
        forces = self._reaction_port.Eval(self._plant_context)
        for i, index in enumerate(self._haa_index):
            F = forces[index]
            self._haa_load[i] = float(np.linalg.norm(F.translational()) + np.linalg.norm(F.rotational()))

    def _advance(self, action: NDArray[np.float64]) -> NDArray[np.float64]:
        """Hold the targets of a clipped action (and the hip friction) for one control step; return [q; v]."""
        self._set_targets(action)
        if self._friction.any():
            self._apply_hip_friction(self._state)
        self._k += 1
        advance(self._simulator, self._k * self.control_dt, f"AnymalEnv (xi {self._xi_text()})")
        x = np.array(self._plant.GetPositionsAndVelocities(self._plant_context))
        if not np.all(np.isfinite(x)):
            raise SimulationError(f"AnymalEnv: non-finite state at t = {self._k * self.control_dt:g} s "
                                  f"(xi {self._xi_text()})")
        if self._friction.any():
            self._read_loads()
        return x

    def _xi_text(self) -> str:
        return "unset" if self._xi is None else str(np.round(self._xi, 4).tolist())

    def _contacts(self) -> tuple[bool, int, list[bool]]:
        """(base in contact, number of thighs in contact, each foot in contact) after the last plant step:
        a body is in contact when its net contact force exceeds contact_force_threshold."""
        results = self._contact_port.Eval(self._plant_context)
        force = {}
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            pair = info.point_pair()
            f = info.contact_force()
            for g, sign in ((pair.id_A, -1.0), (pair.id_B, 1.0)):
                kind = self._geom_kind.get(g)
                if kind is not None:
                    key = (kind, g)
                    force[key] = force.get(key, 0.0) + sign * f
        threshold = self.config.contact_force_threshold
        touching = {key for key, f in force.items() if float(np.linalg.norm(f)) > threshold}
        base = any(kind == 0 for kind, _ in touching)
        thighs = sum(1 for kind, _ in touching if kind == 1)
        feet = [any(kind == 2 + i for kind, _ in touching) for i in range(4)]
        return base, thighs, feet

    def _base_motion(self, x: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Base linear velocity, angular velocity and projected gravity, all in the base frame."""
        nq = self._nq
        R = quaternion_rotation(x[self._iq_quat])
        v_b = R.T @ x[nq + self._iv_lin.start:nq + self._iv_lin.stop]
        w_b = R.T @ x[nq + self._iv_ang.start:nq + self._iv_ang.stop]
        return v_b, w_b, -R[2]  # R^T (0, 0, -1)

    def _observe(self, x: NDArray[np.float64], v_b: NDArray[np.float64], w_b: NDArray[np.float64],
                 g_b: NDArray[np.float64]) -> NDArray[np.float32]:
        obs = np.concatenate([v_b, w_b, g_b, self._command, x[self._q_joint] - self._q_default,
                              x[self._nq + self._v_joint], self._action])
        return obs.astype(np.float32)

    # -- ParamEnv -------------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        self._set_initial_state(xi)
        return self._observe(self._state, *self._base_motion(self._state))

    def _step_model(self, action: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        cfg = self.config
        dt = self.control_dt
        a = np.clip(action, -1.0, 1.0)
        x = self._advance(a)
        self._state = x
        v_b, w_b, g_b = self._base_motion(x)
        tau = self._net_actuation_port.Eval(self._plant_context)
        qdd = self._accel_port.Eval(self._plant_context)[self._v_joint]
        base_contact, thighs, feet = self._contacts()
        # Isaac Lab ContactSensor timers, updated once per control step.
        air_reward = 0.0
        for i, touching in enumerate(feet):
            if touching:
                if self._air_time[i] > 0.0:
                    self._last_air_time[i] = self._air_time[i] + dt
                self._air_time[i] = 0.0
                self._contact_time[i] += dt
                if self._contact_time[i] < dt + 1e-8:  # first contact within the last step
                    air_reward += self._last_air_time[i] - 0.5
            else:
                self._air_time[i] += dt
                self._contact_time[i] = 0.0
        cmd = self._command
        if math.hypot(cmd[0], cmd[1]) <= 0.1:
            air_reward = 0.0
        lin_err = (cmd[0] - v_b[0]) ** 2 + (cmd[1] - v_b[1]) ** 2
        yaw_err = (cmd[2] - w_b[2]) ** 2
        terms = {
            "track_lin_vel_xy_exp": cfg.lin_vel_weight * math.exp(-lin_err / 0.25),
            "track_ang_vel_z_exp": cfg.yaw_rate_weight * math.exp(-yaw_err / 0.25),
            "lin_vel_z_l2": cfg.z_vel_weight * v_b[2] ** 2,
            "ang_vel_xy_l2": cfg.ang_vel_weight * (w_b[0] ** 2 + w_b[1] ** 2),
            "dof_torques_l2": cfg.joint_torque_weight * float(tau @ tau),
            "dof_acc_l2": cfg.joint_accel_weight * float(qdd @ qdd),
            "action_rate_l2": cfg.action_rate_weight * float((a - self._action) @ (a - self._action)),
            "feet_air_time": cfg.feet_air_time_weight * air_reward,
            "undesired_contacts": cfg.undesired_contact_weight * thighs,
            "flat_orientation_l2": cfg.flat_orientation_weight * (g_b[0] ** 2 + g_b[1] ** 2),
        }
        self.last_reward_terms = {k: float(v) * dt for k, v in terms.items()}
        reward = sum(self.last_reward_terms.values())
        self._action = a
        terminated = base_contact and cfg.terminate_on_base_contact
        obs = self._observe(x, v_b, w_b, g_b)
        info = {"base_height": float(x[self._iq_pos.start + 2]), "forward_velocity": float(v_b[0]),
                "base_contact": bool(base_contact)}
        return obs, float(reward), bool(terminated), info
