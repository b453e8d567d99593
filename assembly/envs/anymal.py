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

Model and the seed's task: docs/env_models.md#anymal; differences from the seed, speed and the
standing robot's return: docs/envs.md#anymal.

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

from assembly.envs.base import ParamEnv, SimulationError
from assembly.envs.batched import rowwise_dot
from assembly.envs.drake_sim import (
    HeldInput,
    PlantAccess,
    SceneRendering,
    advance,
    point_contact_properties,
    quiet_drake,
)
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from goflow_common.checks import check_choice, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError

__all__ = [
    "AnymalConfig",
    "AnymalEnv",
    "AnymalLayout",
    "AnymalModel",
    "FootTimers",
    "JOINT_NAMES",
    "LEGS",
    "NOMINAL_BASE_MASS",
    "SEED_J_T",
    "add_anymal",
    "add_ground",
    "anymal_layout",
    "anymal_space",
    "base_motion",
    "contact_slots",
    "contacts",
    "desired_order",
    "exclude_self_contact",
    "hip_damping",
    "initial_row",
    "joint_loads",
    "observe",
    "plant_config",
    "reward_terms",
]

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
    friction_speed: float = 0.05  # [rad/s] hip friction regularization v_s (docs/env_models.md#anymal)
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
        for name in (
            "time_step",
            "control_dt",
            "t_max",
            "point_stiffness",
            "kp",
            "effort_limit",
            "initial_height",
            "friction_speed",
        ):
            check_number(getattr(self, name), f"AnymalConfig.{name}", 0.0, low_open=True)
        for name in (
            "friction",
            "hunt_crossley_dissipation",
            "kd",
            "action_scale",
            "reset_noise_scale",
            "contact_force_threshold",
        ):
            check_number(getattr(self, name), f"AnymalConfig.{name}", 0.0)
        for name in (
            "lin_vel_weight",
            "yaw_rate_weight",
            "z_vel_weight",
            "ang_vel_weight",
            "joint_torque_weight",
            "joint_accel_weight",
            "action_rate_weight",
            "feet_air_time_weight",
            "undesired_contact_weight",
            "flat_orientation_weight",
        ):
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
            raise InputError(
                f"Anymal: control_dt ({self.control_dt:g} s) must be an integer multiple of "
                f"time_step ({self.time_step:g} s)"
            )

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


def plant_config(config: AnymalConfig):
    """The MultibodyPlantConfig of the robot's plant (discrete step, point contact, approximation,
    sampled output ports)."""
    from pydrake.multibody.plant import MultibodyPlantConfig

    return MultibodyPlantConfig(
        time_step=config.time_step,
        contact_model="point",
        discrete_contact_approximation=config.contact_approximation,
        use_sampled_output_ports=True,
    )


@dataclass(frozen=True)
class AnymalModel:
    """One robot added to a plant by `add_anymal`."""

    base: Any  # RigidBody (the floating base)
    joints: tuple[Any, ...]  # RevoluteJoints, JOINT_NAMES order
    actuators: tuple[Any, ...]  # their PD-controlled JointActuators, same order
    haa: tuple[Any, ...]  # the four HAA joints, LEGS order
    base_geometries: tuple[Any, ...]  # collision GeometryIds: the base box
    thigh_geometries: tuple[Any, ...]  # the four thigh capsules
    foot_geometries: tuple[Any, ...]  # the four foot spheres
    geometries: tuple[Any, ...]  # every collision geometry of the robot


def _props(config: AnymalConfig):
    return point_contact_properties(config.point_stiffness, config.hunt_crossley_dissipation, config.friction)


def add_anymal(plant, config: AnymalConfig, instance=None) -> AnymalModel:
    """Add one robot (bodies, joints, PD drives, collision and visual geometry) to an unfinalized
    plant, in model instance `instance` (default: the plant's default instance), its base free."""
    from pydrake.geometry import Box, Capsule, Sphere
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.multibody.tree import FixedOffsetFrame, PdControllerGains, RevoluteJoint, default_model_instance

    instance = default_model_instance() if instance is None else instance

    def segment(body, start, end, radius, name, color):
        """A collision + visual capsule on `body` from `start` to `end` (body frame)."""
        a, b = np.asarray(start, float), np.asarray(end, float)
        axis = b - a
        pose = RigidTransform(RotationMatrix.MakeFromOneVector(axis / np.linalg.norm(axis), 2), 0.5 * (a + b))
        shape = Capsule(radius, float(np.linalg.norm(axis)))
        plant.RegisterVisualGeometry(body, pose, shape, name, color)
        return plant.RegisterCollisionGeometry(body, pose, shape, name, _props(config))

    base = plant.AddRigidBody("base", instance, _inertia(NOMINAL_BASE_MASS, BASE_COM, BASE_INERTIA))
    base_pose = RigidTransform(np.asarray(BASE_COM))
    base_geoms = [plant.RegisterCollisionGeometry(base, base_pose, Box(*BASE_BOX), "base", _props(config))]
    plant.RegisterVisualGeometry(base, base_pose, Box(*BASE_BOX), "base", [0.8, 0.1, 0.1, 1])

    joints, actuators, haa, thighs, shanks, feet = [], [], [], [], [], []
    for leg in LEGS:
        sx, sy = _LEG_SIGNS[leg]
        mirror = _Mirror(sx, sy)
        hip = plant.AddRigidBody(f"{leg}_HIP", instance, _inertia(HIP_MASS, mirror(HIP_COM), HIP_INERTIA))
        thigh = plant.AddRigidBody(f"{leg}_THIGH", instance, _inertia(THIGH_MASS, mirror(THIGH_COM), THIGH_INERTIA))
        shank = plant.AddRigidBody(f"{leg}_SHANK", instance, _inertia(SHANK_MASS, mirror(SHANK_COM), SHANK_INERTIA))
        lo, hi = HAA_RANGE if sy > 0 else (-HAA_RANGE[1], -HAA_RANGE[0])
        chain = (
            (f"{leg}_HAA", base, hip, HAA_OFFSET, (1.0, 0.0, 0.0), lo, hi),
            (f"{leg}_HFE", hip, thigh, HFE_OFFSET, (0.0, 1.0, 0.0), -math.inf, math.inf),
            (f"{leg}_KFE", thigh, shank, KFE_OFFSET, (0.0, 1.0, 0.0), -math.inf, math.inf),
        )
        for name, parent, child, offset, axis, lower, upper in chain:
            frame = plant.AddFrame(
                FixedOffsetFrame(f"{name}_parent", parent.body_frame(), RigidTransform(np.asarray(mirror(offset))))
            )
            joint = plant.AddJoint(RevoluteJoint(name, frame, child.body_frame(), np.asarray(axis), lower, upper, 0.0))
            act = plant.AddJointActuator(f"{name}_drive", joint, config.effort_limit)
            act.set_controller_gains(PdControllerGains(p=config.kp, d=config.kd))
            joints.append(joint)
            actuators.append(act)
        haa.append(joints[-3])
        knee = mirror(KFE_OFFSET)
        thighs.append(segment(thigh, mirror(THIGH_TOP), knee, THIGH_RADIUS, f"{leg}_thigh", [0.2, 0.2, 0.2, 1]))
        foot = np.asarray(mirror(FOOT_OFFSET))
        shanks.append(segment(shank, (0.0, 0.0, 0.0), foot, SHANK_RADIUS, f"{leg}_shank", [0.3, 0.3, 0.3, 1]))
        feet.append(
            plant.RegisterCollisionGeometry(
                shank, RigidTransform(foot), Sphere(FOOT_RADIUS), f"{leg}_foot", _props(config)
            )
        )
        plant.RegisterVisualGeometry(
            shank, RigidTransform(foot), Sphere(FOOT_RADIUS), f"{leg}_foot", [0.1, 0.1, 0.1, 1]
        )
    return AnymalModel(
        base,
        tuple(joints),
        tuple(actuators),
        tuple(haa),
        tuple(base_geoms),
        tuple(thighs),
        tuple(feet),
        tuple(base_geoms + thighs + shanks + feet),
    )


def add_ground(plant, config: AnymalConfig) -> Any:
    """The ground: a half space z <= 0 on the world body (and a visual slab); its GeometryId."""
    from pydrake.geometry import Box, HalfSpace
    from pydrake.math import RigidTransform

    ground = plant.RegisterCollisionGeometry(
        plant.world_body(), RigidTransform(), HalfSpace(), "ground", _props(config)
    )
    plant.RegisterVisualGeometry(
        plant.world_body(), RigidTransform([0, 0, -0.005]), Box(20, 20, 0.01), "ground", [0.5, 0.5, 0.5, 1]
    )
    return ground


def exclude_self_contact(scene_graph, model: AnymalModel) -> None:
    """Only the ground touches the robot: no self-collisions."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(list(model.geometries)))
    )


def _build(config: AnymalConfig):
    """The Drake diagram (plant + scene graph) of the robot on a ground plane: (diagram, plant, model)."""
    from pydrake.multibody.plant import AddMultibodyPlant
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(plant_config(config), builder)
    model = add_anymal(plant, config)
    add_ground(plant, config)
    plant.Finalize()
    exclude_self_contact(scene_graph, model)
    return builder.Build(), plant, model


# -- per-step math, for N robots at once (AnymalEnv is N = 1) ------------------------------------


@dataclass(frozen=True)
class AnymalLayout:
    """Where one robot's coordinates sit in its row of [q; v] (ordered as the single env's plant
    state) and in the plant's output vectors."""

    nq: int  # positions in the row (velocities follow)
    quat: NDArray[np.int64]  # base quaternion w, x, y, z
    pos: NDArray[np.int64]  # base position x, y, z
    v_ang: NDArray[np.int64]  # base angular velocity (world frame)
    v_lin: NDArray[np.int64]  # base linear velocity (world frame)
    joint_q: NDArray[np.int64]  # the 12 joint angles, JOINT_NAMES order
    joint_v: NDArray[np.int64]  # the 12 joint rates
    haa_v: NDArray[np.int64]  # the four HAA rates, LEGS order


def anymal_layout(plant, model: AnymalModel, columns: NDArray[np.int64]) -> AnymalLayout:
    """The layout of `model`'s row, for a finalized plant whose state [q; v] the row gathers at
    `columns` (all of [q; v] for a plant holding one robot)."""
    nq_plant = plant.num_positions()
    where = {int(c): k for k, c in enumerate(columns)}

    def rows(plant_indices) -> NDArray[np.int64]:
        return np.array([where[int(i)] for i in plant_indices], dtype=np.int64)

    fb_q = model.base.floating_positions_start()
    fb_v = nq_plant + model.base.floating_velocities_start_in_v()
    return AnymalLayout(
        sum(1 for c in columns if c < nq_plant),
        rows(range(fb_q, fb_q + 4)),
        rows(range(fb_q + 4, fb_q + 7)),
        rows(range(fb_v, fb_v + 3)),
        rows(range(fb_v + 3, fb_v + 6)),
        rows(j.position_start() for j in model.joints),
        rows(nq_plant + j.velocity_start() for j in model.joints),
        rows(nq_plant + j.velocity_start() for j in model.haa),
    )


def desired_order(model: AnymalModel) -> NDArray[np.int64]:
    """Where joint i's target sits in the model instance's desired-state port (ordered by
    actuator index)."""
    index = np.array([int(a.index()) for a in model.actuators])
    return np.argsort(np.argsort(index))


def initial_row(
    config: AnymalConfig, layout: AnymalLayout, width: int, rng: np.random.Generator
) -> NDArray[np.float64]:
    """A robot's reset state row (`width` = its nq + nv): the default pose at initial_height, at
    rest, with the reset noise drawn from rng (joint angles, then base angular and linear velocity)."""
    row = np.zeros(width)
    row[layout.quat] = [1.0, 0.0, 0.0, 0.0]
    row[layout.pos] = [0.0, 0.0, config.initial_height]
    row[layout.joint_q] = DEFAULT_POSE
    s = config.reset_noise_scale
    if s > 0:
        row[layout.joint_q] += rng.uniform(-s, s, size=12)
        row[layout.v_ang] = s * rng.standard_normal(3)
        row[layout.v_lin] = s * rng.standard_normal(3)
    return row


# Quaternion (w, x, y, z) = columns 0-3: products ww.. as _PROD_I x _PROD_J; entry k of R (row major)
# is _R_SCALE[k] * (products[_R_A[k]] + _R_SIGN[k] * products[_R_B[k]]) (+ 1 on the diagonal).
_PROD_I = np.array([1, 2, 3, 1, 0, 1, 0, 2, 0])  # xx yy zz xy wz xz wy yz wx
_PROD_J = np.array([1, 2, 3, 2, 3, 3, 2, 3, 1])
_R_A = np.array([1, 3, 5, 3, 0, 7, 5, 7, 0])  # yy xy xz | xy xx yz | xz yz xx
_R_B = np.array([2, 4, 6, 4, 2, 8, 6, 8, 1])  # zz wz wy | wz zz wx | wy wx yy
_R_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_R_SCALE = np.array([-2.0, 2.0, 2.0, 2.0, -2.0, 2.0, 2.0, 2.0, -2.0])


def base_motion(
    layout: AnymalLayout, rows: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Base linear velocity, angular velocity and projected gravity, (N, 3) each, in the base
    frame, of state rows (N, nq + nv); `quaternion_rotation` row by row, to the last bit."""
    q = rows[:, layout.quat]
    q = q / np.sqrt(rowwise_dot(q, q))[:, None]
    # R's nine entries as scale * (a + sign b) of quaternion products, the diagonal then plus 1:
    # the same operations as `quaternion_rotation`'s 1 - 2 (y y + z z), 2 (x y - w z), ...
    products = q[:, _PROD_I] * q[:, _PROD_J]
    R = _R_SCALE * (products[:, _R_A] + _R_SIGN * products[:, _R_B])
    R[:, ::4] += 1.0
    R = R.reshape(-1, 3, 3)
    Rt = R.transpose(0, 2, 1)
    v_b = np.matmul(Rt, rows[:, layout.v_lin][:, :, None])[:, :, 0]
    w_b = np.matmul(Rt, rows[:, layout.v_ang][:, :, None])[:, :, 0]
    return v_b, w_b, -R[:, 2]  # R^T (0, 0, -1)


def observe(
    config: AnymalConfig,
    layout: AnymalLayout,
    rows: NDArray[np.float64],
    v_b: NDArray[np.float64],
    w_b: NDArray[np.float64],
    g_b: NDArray[np.float64],
    actions: NDArray[np.float64],
) -> NDArray[np.float32]:
    """Observations (N, 48): v_b, w_b, g_b, the command, joint angles minus the default pose,
    joint rates, the last clipped actions (N, 12)."""
    command = np.broadcast_to(np.asarray(config.command), (len(rows), 3))
    obs = np.concatenate(
        [v_b, w_b, g_b, command, rows[:, layout.joint_q] - np.asarray(DEFAULT_POSE), rows[:, layout.joint_v], actions],
        axis=1,
    )
    return obs.astype(np.float32)


def hip_damping(
    config: AnymalConfig,
    layout: AnymalLayout,
    friction: NDArray[np.float64],
    loads: NDArray[np.float64],
    rows: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The HAA damping (N, 4) [N m s/rad] that holds each hip's friction for the coming control
    step: mu (|f| + |tau|) / max(|v|, v_s) of the current load and rate. At |v| >= v_s it opposes
    the motion with the Coulomb torque of the load; below, it is a stiff viscous regularization.
    Being a damping, Drake treats it implicitly and it can only dissipate. Meaningful where mu > 0
    (a joint without friction keeps damping 0)."""
    speed = np.maximum(np.abs(rows[:, layout.haa_v]), config.friction_speed)
    return friction * loads / speed


def joint_loads(forces: list, joint_index: NDArray[np.int64]) -> NDArray[np.float64]:
    """|f| + |tau| of the spatial force each joint transmits: `forces` the plant's reaction-force
    output (one SpatialForce per joint index), `joint_index` (N, 4) the HAA joints' indices."""
    F = np.array([forces[j].get_coeffs() for j in joint_index.ravel()])  # rotational, translational
    trans, rot = F[:, 3:], F[:, :3]
    return (np.sqrt(rowwise_dot(trans, trans)) + np.sqrt(rowwise_dot(rot, rot))).reshape(joint_index.shape)


def contact_slots(models: list[AnymalModel]) -> tuple[dict[Any, int], int]:
    """GeometryId -> slot of the geometries whose contact the task reads, and the slots per robot:
    robot i's base geometries, then its four thighs, then its four feet."""
    slots: dict[Any, int] = {}
    for model in models:
        for gid in model.base_geometries + model.thigh_geometries + model.foot_geometries:
            slots[gid] = len(slots)
    return slots, len(slots) // max(1, len(models))


def contacts(
    results, slots: dict[Any, int], per_robot: int, n: int, threshold: float
) -> tuple[NDArray[np.bool_], NDArray[np.int64], NDArray[np.bool_]]:
    """(base in contact (N,), number of thighs in contact (N,), each foot in contact (N, 4)) from
    the plant's ContactResults: a geometry is in contact when its net contact force exceeds
    `threshold` [N]."""
    force = np.zeros((n * per_robot, 3))
    for k in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(k)
        pair = info.point_pair()
        a, b = slots.get(pair.id_A), slots.get(pair.id_B)
        if a is None and b is None:
            continue
        f = info.contact_force()  # on body B, from A
        if a is not None:
            force[a] = force[a] + -1.0 * f
        if b is not None:
            force[b] = force[b] + 1.0 * f
    touching = (np.sqrt(rowwise_dot(force, force)) > threshold).reshape(n, per_robot)
    nb = per_robot - 8
    return touching[:, :nb].any(axis=1), touching[:, nb : nb + 4].sum(axis=1), touching[:, nb + 4 :]


class FootTimers:
    """Isaac Lab ContactSensor air/contact timers of N robots' four feet, (N, 4) arrays [s]."""

    def __init__(self, n: int) -> None:
        self.air = np.zeros((n, 4))
        self.contact = np.zeros((n, 4))
        self.last_air = np.zeros((n, 4))

    def reset(self, idx) -> None:
        """Zero robots idx's timers."""
        self.air[idx] = self.contact[idx] = self.last_air[idx] = 0.0

    def update(self, feet: NDArray[np.bool_], dt: float) -> NDArray[np.float64]:
        """Advance the timers one control step of dt [s] with the feet in contact `feet` (N, 4);
        return each robot's air-time reward: the sum of last air time - 0.5 s over feet that
        touched down within the step."""
        landed = feet & (self.air > 0.0)
        self.last_air = np.where(landed, self.air + dt, self.last_air)
        self.air = np.where(feet, 0.0, self.air + dt)
        self.contact = np.where(feet, self.contact + dt, 0.0)
        first = feet & (self.contact < dt + 1e-8)  # first contact within the last step
        return np.where(first, self.last_air - 0.5, 0.0).sum(axis=1)


def reward_terms(
    config: AnymalConfig,
    dt: float,
    v_b: NDArray[np.float64],
    w_b: NDArray[np.float64],
    g_b: NDArray[np.float64],
    tau: NDArray[np.float64],
    qdd: NDArray[np.float64],
    actions: NDArray[np.float64],
    last_actions: NDArray[np.float64],
    air_reward: NDArray[np.float64],
    thighs: NDArray[np.int64],
) -> dict[str, NDArray[np.float64]]:
    """The seed's ten reward terms (N,) each, times dt: base motion (N, 3 each), joint torques
    and accelerations (N, 12), this step's and the last clipped actions (N, 12), the feet's air
    reward (N,) and the thighs in contact (N,)."""
    cfg, cmd = config, config.command
    if math.hypot(cmd[0], cmd[1]) <= 0.1:
        air_reward = np.zeros_like(air_reward)
    lin_err = _square(cmd[0] - v_b[:, 0]) + _square(cmd[1] - v_b[:, 1])
    yaw_err = _square(cmd[2] - w_b[:, 2])
    change = actions - last_actions
    terms = {
        "track_lin_vel_xy_exp": cfg.lin_vel_weight * _exp(-lin_err / 0.25),
        "track_ang_vel_z_exp": cfg.yaw_rate_weight * _exp(-yaw_err / 0.25),
        "lin_vel_z_l2": cfg.z_vel_weight * _square(v_b[:, 2]),
        "ang_vel_xy_l2": cfg.ang_vel_weight * (_square(w_b[:, 0]) + _square(w_b[:, 1])),
        "dof_torques_l2": cfg.joint_torque_weight * rowwise_dot(tau, tau),
        "dof_acc_l2": cfg.joint_accel_weight * rowwise_dot(qdd, qdd),
        "action_rate_l2": cfg.action_rate_weight * rowwise_dot(change, change),
        "feet_air_time": cfg.feet_air_time_weight * air_reward,
        "undesired_contacts": cfg.undesired_contact_weight * thighs,
        "flat_orientation_l2": cfg.flat_orientation_weight * (_square(g_b[:, 0]) + _square(g_b[:, 1])),
    }
    return {k: v * dt for k, v in terms.items()}


# The single env's scalar math, element by element: numpy's array kernels for exp and x ** 2
# (SIMD exp, x * x) differ from libm's exp and pow in the last bit of a few values in 1,000.
def _exp(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([math.exp(v) for v in x.tolist()])


def _square(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([v**2 for v in x.tolist()])


def anymal_space() -> ParamSpace:
    """xi's box: the base mass [0, 200] kg, then the LF, RF, LH, RH HAA friction coefficients [0, 0.1]."""
    return ParamSpace(
        (Param("base_mass", 0.0, 200.0, "kg", nominal=NOMINAL_BASE_MASS),)
        + tuple(Param(f"{leg}_HAA_friction", 0.0, 0.1, "1", nominal=0.0) for leg in LEGS)
    )


class AnymalEnv(SceneRendering, PlantAccess, ParamEnv):
    """Track 1 m/s forward for 5 s with an ANYmal-C-sized quadruped whose base mass and hip joint
    frictions xi are drawn per episode."""

    def __init__(
        self,
        config: AnymalConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = cfg = config_with_overrides(AnymalConfig, config, overrides, "AnymalEnv")
        self.space = anymal_space()
        super().__init__(self.space, sampler)
        self._set_timing(cfg.control_dt, cfg.t_max, cfg.j_t())
        self._init_render(render_mode)

        from pydrake.systems.analysis import Simulator

        # Silence Drake's "half spaces are not supported for deformable contact" (we have none).
        with quiet_drake():
            self._diagram, self._plant, model = _build(cfg)
            self._simulator = Simulator(self._diagram)
            self._simulator.Initialize()
        plant = self._plant
        self._base, self._joints, self._actuators, self._haa = model.base, model.joints, model.actuators, model.haa
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        m_base = self._base.default_spatial_inertia()
        self._base_com = np.asarray(m_base.get_com())
        self._base_unit_inertia = m_base.get_unit_inertia()
        self._slots, self._per_robot = contact_slots([model])
        # Where the base (quaternion wxyz, position; angular, linear velocity in the world frame)
        # and the joints sit in x = [q; v]; the joint rates in the acceleration output.
        self._layout = anymal_layout(plant, model, np.arange(self._nq + self._nv))
        self._v_joint = np.array([j.velocity_start() for j in self._joints])
        self._haa_index = np.array([[int(j.index()) for j in self._haa]])
        # Desired-state port: [q_d; v_d] ordered by actuator index; action i is joint i's.
        self._act_order = desired_order(model)
        self._desired = np.zeros(24)
        self._desired_input = HeldInput(
            plant.get_desired_state_input_port(self._base.model_instance()), self._plant_context, self._desired
        )
        self._actuation_input = HeldInput(plant.get_actuation_input_port(), self._plant_context, np.zeros(12))
        self._net_actuation_port = plant.get_net_actuation_output_port()
        self._accel_port = plant.get_generalized_acceleration_output_port()
        self._contact_port = plant.get_contact_results_output_port()
        self._reaction_port = plant.get_reaction_forces_output_port()
        self._k = 0
        self._state = np.zeros(self._nq + self._nv)
        self._action = np.zeros(12)
        self._friction = np.zeros(4)
        self._haa_load = np.zeros(4)
        self._feet = FootTimers(1)
        self.last_reward_terms: dict[str, float] = {}

        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(48,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(12,), dtype=np.float32)

    # -- model ----------------------------------------------------------------------------------

    def base_mass(self) -> float:
        """The base mass currently set in the Context [kg]."""
        return float(self._base.get_mass(self._plant_context))

    def _set_initial_state(self, xi: NDArray[np.float64]) -> None:
        """Set the base mass, the hip frictions and the default pose in the reused Context; time 0."""
        from pydrake.multibody.tree import SpatialInertia

        # Mass and rotational inertia scale together (same unit inertia, same COM); 0 kg is allowed.
        self._base.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(float(xi[0]), self._base_com, self._base_unit_inertia)
        )
        self._friction = np.asarray(xi[1:5], dtype=np.float64).copy()
        for joint in self._haa:
            joint.SetDamping(self._plant_context, 0.0)
        self._context.SetTime(0.0)
        x = initial_row(self.config, self._layout, self._nq + self._nv, self.np_random)
        self._plant.SetPositionsAndVelocities(self._plant_context, x)
        self._action = np.zeros(12)
        self._set_targets(self._action)
        self._simulator.Initialize()
        self._k = 0
        self._state = x
        self._haa_load[:] = 0.0
        self._feet.reset(0)

    def _set_targets(self, action: NDArray[np.float64]) -> None:
        """Joint position targets default + scale x action (zero velocity targets) on the PD drives."""
        self._desired[self._act_order] = np.asarray(DEFAULT_POSE) + self.config.action_scale * action
        self._desired_input.set(self._desired)

    def _advance(self, action: NDArray[np.float64]) -> NDArray[np.float64]:
        """Hold the targets of a clipped action (and the hip friction) for one control step; return [q; v]."""
        self._set_targets(action)
        if self._friction.any():
            damping = hip_damping(
                self.config, self._layout, self._friction[None], self._haa_load[None], self._state[None]
            )[0]
            for joint, mu, d in zip(self._haa, self._friction, damping):
                if mu > 0.0:
                    joint.SetDamping(self._plant_context, float(d))
        self._k += 1
        advance(self._simulator, self._k * self.control_dt, f"AnymalEnv (xi {self._xi_text()})")
        x = np.array(self._plant.GetPositionsAndVelocities(self._plant_context))
        if not np.all(np.isfinite(x)):
            raise SimulationError(
                f"AnymalEnv: non-finite state at t = {self._k * self.control_dt:g} s (xi {self._xi_text()})"
            )
        if self._friction.any():
            self._haa_load = joint_loads(self._reaction_port.Eval(self._plant_context), self._haa_index)[0]
        return x

    def _xi_text(self) -> str:
        return "unset" if self._xi is None else str(np.round(self._xi, 4).tolist())

    # -- rendering ------------------------------------------------------------------------------

    def _make_renderer(self):
        """A camera behind and to the right of the base, following it over a checkered floor."""
        from assembly.envs.rendering import CameraView, SceneRenderer, scene_graph_of

        view = CameraView(target=(0.0, 0.0, 0.45), eye_offset=(-1.5, -3.5, 1.6))
        r = SceneRenderer(scene_graph_of(self._diagram), self._context, self._plant.get_source_id(), view)
        r.add_checker_floor(1.0, cells=16)
        return r

    def _render_track(self) -> NDArray[np.float64]:
        return self._plant.EvalBodyPoseInWorld(self._plant_context, self._base).translation()

    # -- ParamEnv -------------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        self._set_initial_state(xi)
        x = self._state[None]
        return observe(self.config, self._layout, x, *base_motion(self._layout, x), self._action[None])[0]

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        cfg = self.config
        a = np.clip(action, -1.0, 1.0)
        x = self._advance(a)
        self._state = x
        rows = x[None]
        v_b, w_b, g_b = base_motion(self._layout, rows)
        tau = np.asarray(self._net_actuation_port.Eval(self._plant_context))[None]
        qdd = self._accel_port.Eval(self._plant_context)[self._v_joint][None]
        base_contact, thighs, feet = contacts(
            self._contact_port.Eval(self._plant_context), self._slots, self._per_robot, 1, cfg.contact_force_threshold
        )
        air_reward = self._feet.update(feet, self.control_dt)
        terms = reward_terms(
            cfg, self.control_dt, v_b, w_b, g_b, tau, qdd, a[None], self._action[None], air_reward, thighs
        )
        self.last_reward_terms = {k: float(v[0]) for k, v in terms.items()}
        reward = sum(self.last_reward_terms.values())
        self._action = a
        terminated = bool(base_contact[0]) and cfg.terminate_on_base_contact
        obs = observe(cfg, self._layout, rows, v_b, w_b, g_b, a[None])[0]
        info = {
            "base_height": float(x[self._layout.pos[2]]),
            "forward_velocity": float(v_b[0, 0]),
            "base_contact": bool(base_contact[0]),
        }
        return obs, float(reward), bool(terminated), info
