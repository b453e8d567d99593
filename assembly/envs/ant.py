"""goflow/Ant-v0: a torque-controlled quadruped (MuJoCo-Ant layout) built in Drake; xi = torso mass.

Run forward (+x) for t_max = 2 s. The robot is our own model, built with MultibodyPlant API calls
(no files, no downloads) from the numbers of IsaacGymEnvs' nv_ant.xml: discrete plant, point
contact, `lagged`, 1/128 s steps, 2 per action (control_dt = 1/64 s, 128 steps). Reward terms and
weights are the GoFlow seed's (its Isaac Lab Ant task), each scaled to a rate, so the return does
not depend on the control rate.

- xi: torso mass [0.01, 20] kg.
- Observation (27, float32): torso height, torso quaternion (w, x, y, z), 8 joint angles, torso
  linear and angular velocity (world frame), 8 joint rates. Joint order hip_1, ankle_1, ...,
  hip_4, ankle_4 for the legs front-left, front-right, back-left, back-right.
- Action (8,): normalized joint torques in [-1, 1] (clipped), times 7.5 N m; same joint order.
- Termination (a fall) when the torso is below 0.31 m; success: return >= J_T = 705.9, the
  seed's 700 re-derived for our reward.

Derivation (the seed's task as read from the authors' code, our choices, J_T): docs/env_models.md#ant;
measured speed: docs/envs.md#ant.

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025, appendix A.1 (box, J_T); github.com/aidan-curtis/goflow at 294d0ee3
(goflow/environments/ant/); IsaacGymEnvs assets/mjcf/nv_ant.xml.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import ParamEnv, SimulationError
from assembly.envs.batched import rowwise_dot
from goflow_common.checks import check_choice, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from assembly.envs.drake_sim import PlantAccess, SceneRendering, advance, point_contact_properties, quiet_drake
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler

__all__ = [
    "AntConfig",
    "AntEnv",
    "AntLayout",
    "AntModel",
    "NOMINAL_TORSO_MASS",
    "SEED_J_T",
    "add_ant",
    "add_ground",
    "ant_layout",
    "exclude_self_contact",
    "initial_row",
    "observe",
    "plant_config",
    "step_reward",
]

# -- the seed's task (docs/env_models.md#ant names the files these come from) --------------------
SEED_J_T = 700.0  # paper appendix A.1 (the code's yaml says 650)
SEED_CONTROL_DT = 1.0 / 60.0  # [s] Isaac Lab sim dt 1/120 s x decimation 2
SEED_EPISODE_STEPS = 119  # rewarded steps before Isaac Lab's time-out (max_episode_length - 1)

# -- the robot (IsaacGymEnvs nv_ant.xml numbers) ------------------------------------------------
DENSITY = 5.0  # [kg/m^3] every geom
TORSO_RADIUS = 0.25  # [m]
LIMB_RADIUS = 0.08  # [m] every capsule
AUX = 0.2  # [m] torso centre -> hip, per axis
THIGH = 0.2  # [m] hip -> ankle, per axis
SHIN = 0.4  # [m] ankle -> foot tip (capsule axis end), per axis
HIP_LIMIT = math.radians(40.0)  # [rad] |hip yaw|
ANKLE_RANGE = (math.radians(30.0), math.radians(100.0))  # [rad] ankle magnitude range
JOINT_DAMPING = 0.1  # [N m s/rad]
ARMATURE = 0.01  # [kg m^2] reflected rotor inertia per joint
# legs and the signs (x, y) of their direction from the torso centre
LEGS = ("front_left", "front_right", "back_left", "back_right")
_LEG_SIGNS = {
    "front_left": (1.0, 1.0),
    "front_right": (-1.0, 1.0),
    "back_left": (-1.0, -1.0),
    "back_right": (1.0, -1.0),
}
# nv_ant: ankle_1 axis (-1, 1, 0) range [30, 100]; ankle_2 (1, 1, 0) [-100, -30];
# ankle_3 (-1, 1, 0) [-100, -30]; ankle_4 (1, 1, 0) [30, 100] deg.
_ANKLE = {
    "front_left": ((-1.0, 1.0, 0.0), 1.0),
    "front_right": ((1.0, 1.0, 0.0), -1.0),
    "back_left": ((-1.0, 1.0, 0.0), -1.0),
    "back_right": ((1.0, 1.0, 0.0), 1.0),
}
INITIAL_ANKLE = 0.785  # [rad] magnitude (Isaac Lab ANT_CFG default joint_pos)


def _torso_mass_nominal() -> float:
    sphere = 4.0 / 3.0 * math.pi * TORSO_RADIUS**3
    length = AUX * math.sqrt(2.0)
    capsule = math.pi * LIMB_RADIUS**2 * length + 4.0 / 3.0 * math.pi * LIMB_RADIUS**3
    return DENSITY * (sphere + 4.0 * capsule)


NOMINAL_TORSO_MASS = _torso_mass_nominal()  # [kg] 0.4839, the seed's "midpoint"


@dataclass(frozen=True)
class AntConfig:
    """Simulation, actuation, reward and episode settings of the Drake ant (SI units)."""

    # Time step, measured on this machine (one core; lagged unless noted; reference 1/1024 s; 12
    # rollouts: zero torque for 2 s, and 0.25 s of random torques, at torso masses 0.48, 5, 20 kg):
    #   step      bare real-time factor   standing height error   0.25 s position error
    #   1/512 s   14x                     1.3 mm                  16 mm
    #   1/256 s   14-22x                  18 mm (similar: 2.7)    25 mm
    #   1/128 s   35-38x                  8 mm                    35 mm
    #   1/64 s    57x                     20 mm                   50 mm
    # 1/128 s keeps the errors at the level of the random-torque rollouts' own sensitivity (even
    # 1/512 s differs by 16 mm) at 2.5x the speed of 1/256 s; "similar" is ~10 % faster, equally
    # accurate. Random-torque rollouts are chaotic over 2 s (flips), so only short horizons compare.
    time_step: float = 1.0 / 128.0  # [s] plant discrete step
    control_dt: float = 1.0 / 64.0  # [s] one action; an integer multiple of time_step
    t_max: float = 2.0  # [s] episode length (seed: 2 s)
    contact_approximation: str = "lagged"  # "lagged" | "similar" | "sap" | "tamsi"
    friction: float = 1.0  # Coulomb friction, static = dynamic (seed ground: 1.0)
    point_stiffness: float = 5.0e4  # [N/m] point-contact stiffness (about 4 mm sag for a 20 kg torso)
    hunt_crossley_dissipation: float = 10.0  # [s/m]
    effort_limit: float = 7.5  # [N m] seed: action_scale 0.5 x joint gear 15
    initial_height: float = 0.5  # [m] torso centre at reset (seed: 0.5)
    reset_noise_scale: float = 0.01  # joint angles [rad], height [m] (uniform); velocities (normal)
    termination_height: float = 0.31  # [m] unhealthy below this torso height (seed: 0.31)
    terminate_when_unhealthy: bool = True
    # reward (seed weights, per 1/60 s; scaled by control_dt * 60 except progress and death)
    progress_weight: float = 120.0  # [1/m] seed: 1 / sim_dt per metre
    alive_reward: float = 0.5
    up_weight: float = 0.1
    heading_weight: float = 0.5
    actions_cost: float = 0.005
    energy_cost: float = 0.05
    dof_vel_scale: float = 0.2
    joint_limit_cost: float = 1.0
    death_cost: float = -2.0
    success_threshold: float | None = None  # J_T; None: the seed's 700 re-derived (see module doc)

    def __post_init__(self) -> None:
        for name in ("time_step", "control_dt", "t_max", "point_stiffness", "effort_limit", "initial_height"):
            check_number(getattr(self, name), f"AntConfig.{name}", 0.0, low_open=True)
        for name in ("friction", "hunt_crossley_dissipation", "reset_noise_scale", "termination_height"):
            check_number(getattr(self, name), f"AntConfig.{name}", 0.0)
        for name in (
            "progress_weight",
            "alive_reward",
            "up_weight",
            "heading_weight",
            "actions_cost",
            "energy_cost",
            "dof_vel_scale",
            "joint_limit_cost",
            "death_cost",
        ):
            check_number(getattr(self, name), f"AntConfig.{name}")
        if self.success_threshold is not None:
            check_number(self.success_threshold, "AntConfig.success_threshold")
        check_choice(self.terminate_when_unhealthy, (True, False), "AntConfig.terminate_when_unhealthy")
        ratio = self.control_dt / self.time_step
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise InputError(
                f"Ant: control_dt ({self.control_dt:g} s) must be an integer multiple of "
                f"time_step ({self.time_step:g} s)"
            )
        check_choice(
            self.contact_approximation, ("lagged", "similar", "sap", "tamsi"), "AntConfig.contact_approximation"
        )
        if self.initial_height <= self.termination_height:
            raise InputError(
                f"Ant: initial_height {self.initial_height} m must exceed termination_height "
                f"{self.termination_height} m"
            )

    @property
    def rate_scale(self) -> float:
        """control_dt / the seed's 1/60 s: the factor on every per-step reward rate."""
        return self.control_dt / SEED_CONTROL_DT

    def j_t(self) -> float:
        """J_T for this config: the seed's 700 scaled to our episode length (docs/env_models.md#ant)."""
        if self.success_threshold is not None:
            return float(self.success_threshold)
        return SEED_J_T * self.t_max / (SEED_EPISODE_STEPS * SEED_CONTROL_DT)


def plant_config(config: AntConfig):
    """The MultibodyPlantConfig of the ant's plant (discrete step, point contact, approximation)."""
    from pydrake.multibody.plant import MultibodyPlantConfig

    return MultibodyPlantConfig(
        time_step=config.time_step, contact_model="point", discrete_contact_approximation=config.contact_approximation
    )


@dataclass(frozen=True)
class AntModel:
    """One ant added to a plant by `add_ant`."""

    torso: Any  # RigidBody (the floating base)
    joints: tuple[Any, ...]  # RevoluteJoints hip_1, ankle_1, ..., hip_4, ankle_4
    actuators: tuple[Any, ...]  # their JointActuators, same order
    torso_inertia: Any  # the torso's SpatialInertia at the nominal mass, about its origin
    geometries: tuple[Any, ...]  # the robot's collision GeometryIds


def _props(config: AntConfig):
    return point_contact_properties(config.point_stiffness, config.hunt_crossley_dissipation, config.friction)


def add_ant(plant, config: AntConfig, instance=None) -> AntModel:
    """Add one ant (torso, legs, joints, motors, collision and visual geometry) to an unfinalized
    plant, in model instance `instance` (default: the plant's default instance), its torso free."""
    from pydrake.geometry import Capsule, Sphere
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.multibody.tree import RevoluteJoint, SpatialInertia, default_model_instance

    instance = default_model_instance() if instance is None else instance

    def capsule_pose(end: np.ndarray) -> RigidTransform:
        """Pose of a Drake capsule (axis z) spanning the segment from the origin to `end`."""
        z = end / np.linalg.norm(end)
        return RigidTransform(RotationMatrix.MakeFromOneVector(z, 2), 0.5 * end)

    def capsule_inertia(end: np.ndarray) -> SpatialInertia:
        """Spatial inertia about the body origin of a solid capsule from the origin to `end`."""
        length = float(np.linalg.norm(end))
        m_cm = SpatialInertia.SolidCapsuleWithDensity(DENSITY, LIMB_RADIUS, length, end / length)
        return m_cm.Shift(-0.5 * end)

    # Torso: sphere + four fixed aux capsules (one rigid body, as in the seed's asset).
    aux_ends = [np.array([sx * AUX, sy * AUX, 0.0]) for sx, sy in (_LEG_SIGNS[leg] for leg in LEGS)]
    m_torso = SpatialInertia.SolidSphereWithDensity(DENSITY, TORSO_RADIUS)
    for end in aux_ends:
        m_torso += capsule_inertia(end)
    torso = plant.AddRigidBody("torso", instance, m_torso)
    geometries = [
        plant.RegisterCollisionGeometry(torso, RigidTransform(), Sphere(TORSO_RADIUS), "torso", _props(config))
    ]
    plant.RegisterVisualGeometry(torso, RigidTransform(), Sphere(TORSO_RADIUS), "torso", [0.9, 0.4, 0.1, 1])
    for i, end in enumerate(aux_ends):
        shape = Capsule(LIMB_RADIUS, float(np.linalg.norm(end)))
        geometries.append(
            plant.RegisterCollisionGeometry(torso, capsule_pose(end), shape, f"aux_{i + 1}", _props(config))
        )
        plant.RegisterVisualGeometry(torso, capsule_pose(end), shape, f"aux_{i + 1}", [0.2, 0.8, 0.2, 1])

    joints, actuators = [], []
    for i, leg in enumerate(LEGS):
        sx, sy = _LEG_SIGNS[leg]
        thigh_end = np.array([sx * THIGH, sy * THIGH, 0.0])
        shin_end = np.array([sx * SHIN, sy * SHIN, 0.0])
        thigh = plant.AddRigidBody(f"{leg}_thigh", instance, capsule_inertia(thigh_end))
        shin = plant.AddRigidBody(f"{leg}_shin", instance, capsule_inertia(shin_end))
        for body, end in ((thigh, thigh_end), (shin, shin_end)):
            shape = Capsule(LIMB_RADIUS, float(np.linalg.norm(end)))
            geometries.append(
                plant.RegisterCollisionGeometry(body, capsule_pose(end), shape, body.name(), _props(config))
            )
            plant.RegisterVisualGeometry(body, capsule_pose(end), shape, body.name(), [0.8, 0.2, 0.2, 1])
        hip_frame = plant.AddFrame(_fixed_frame(f"{leg}_hip_parent", torso.body_frame(), RigidTransform(aux_ends[i])))
        hip = plant.AddJoint(
            RevoluteJoint(
                f"hip_{i + 1}", hip_frame, thigh.body_frame(), [0.0, 0.0, 1.0], -HIP_LIMIT, HIP_LIMIT, JOINT_DAMPING
            )
        )
        axis, sign = _ANKLE[leg]
        lo, hi = ANKLE_RANGE if sign > 0 else (-ANKLE_RANGE[1], -ANKLE_RANGE[0])
        ankle_frame = plant.AddFrame(_fixed_frame(f"{leg}_ankle_parent", thigh.body_frame(), RigidTransform(thigh_end)))
        ankle = plant.AddJoint(
            RevoluteJoint(f"ankle_{i + 1}", ankle_frame, shin.body_frame(), np.asarray(axis), lo, hi, JOINT_DAMPING)
        )
        for joint in (hip, ankle):
            act = plant.AddJointActuator(f"{joint.name()}_motor", joint, config.effort_limit)
            act.set_default_rotor_inertia(ARMATURE)
            act.set_default_gear_ratio(1.0)
            joints.append(joint)
            actuators.append(act)
    return AntModel(torso, tuple(joints), tuple(actuators), m_torso, tuple(geometries))


def add_ground(plant, config: AntConfig) -> Any:
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


def exclude_self_contact(scene_graph, model: AntModel) -> None:
    """Only the ground touches an ant: no self-collisions (legs may pass through each other)."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(list(model.geometries)))
    )


def _build(config: AntConfig):
    """The Drake diagram (plant + scene graph) of the ant on a ground plane; returns handles."""
    from pydrake.multibody.plant import AddMultibodyPlant
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(plant_config(config), builder)
    model = add_ant(plant, config)
    add_ground(plant, config)
    plant.Finalize()
    exclude_self_contact(scene_graph, model)
    diagram = builder.Build()
    return diagram, plant, model.torso, list(model.joints), list(model.actuators), model.torso_inertia


def _fixed_frame(name, parent_frame, X):
    from pydrake.multibody.tree import FixedOffsetFrame

    return FixedOffsetFrame(name, parent_frame, X)


@dataclass(frozen=True)
class AntLayout:
    """Where one ant's coordinates sit in its row of [q; v] (ordered as the single env's plant
    state), its joints' limits and default pose: what the per-step math of `AntEnv` and
    `AntVectorEnv` reads."""

    nq: int  # positions in the row (velocities follow)
    quat: NDArray[np.int64]  # torso quaternion w, x, y, z
    pos: NDArray[np.int64]  # torso position x, y, z
    joint_q: NDArray[np.int64]  # the 8 joint angles, joint order
    joint_v: NDArray[np.int64]  # the 8 joint rates, joint order
    obs: NDArray[np.int64]  # the observation's gather: z, quat, joints, v_lin, w, joint rates
    q_mid: NDArray[np.float64]  # joint range centres [rad]
    q_half: NDArray[np.float64]  # joint range half widths [rad]
    q_default: NDArray[np.float64]  # joint angles at reset, before noise [rad]


def ant_layout(plant, model: AntModel, columns: NDArray[np.int64]) -> AntLayout:
    """The layout of `model`'s row, for a finalized plant whose state [q; v] the row gathers at
    `columns` (all of [q; v] for a plant holding one ant)."""
    nq_plant = plant.num_positions()
    where = {int(c): k for k, c in enumerate(columns)}
    nq = sum(1 for c in columns if c < nq_plant)

    def rows(plant_indices) -> NDArray[np.int64]:
        return np.array([where[int(i)] for i in plant_indices], dtype=np.int64)

    fb_q = model.torso.floating_positions_start()
    fb_v = nq_plant + model.torso.floating_velocities_start_in_v()
    quat, pos = rows(range(fb_q, fb_q + 4)), rows(range(fb_q + 4, fb_q + 7))
    v_ang, v_lin = rows(range(fb_v, fb_v + 3)), rows(range(fb_v + 3, fb_v + 6))
    joint_q = rows(j.position_start() for j in model.joints)
    joint_v = rows(nq_plant + j.velocity_start() for j in model.joints)
    lower = np.array([j.position_lower_limit() for j in model.joints])
    upper = np.array([j.position_upper_limit() for j in model.joints])
    q_default = np.zeros(len(model.joints))
    for i, leg in enumerate(LEGS):
        q_default[2 * i + 1] = _ANKLE[leg][1] * INITIAL_ANKLE
    return AntLayout(
        nq,
        quat,
        pos,
        joint_q,
        joint_v,
        np.concatenate([pos[2:], quat, joint_q, v_lin, v_ang, joint_v]),
        0.5 * (upper + lower),
        0.5 * (upper - lower),
        q_default,
    )


def initial_row(config: AntConfig, layout: AntLayout, width: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """An ant's reset state row (`width` = its nq + nv): default pose at initial_height, with the
    reset noise drawn from rng (joint angles, height, then every velocity), joints clipped to
    their ranges."""
    s = config.reset_noise_scale
    row = np.zeros(width)
    row[layout.quat] = [1.0, 0.0, 0.0, 0.0]
    row[layout.pos] = [0.0, 0.0, config.initial_height]
    row[layout.joint_q] = layout.q_default
    if s > 0:
        row[layout.joint_q] += rng.uniform(-s, s, size=len(layout.joint_q))
        row[layout.pos[2]] += rng.uniform(-s, s)
        row[layout.nq :] += s * rng.standard_normal(width - layout.nq)
    row[layout.joint_q] = np.clip(row[layout.joint_q], layout.q_mid - layout.q_half, layout.q_mid + layout.q_half)
    return row


def observe(layout: AntLayout, rows: NDArray[np.float64]) -> NDArray[np.float32]:
    """Observations (N, 27) of state rows (N, nq + nv): the quaternion normalized."""
    obs = rows[:, layout.obs]
    quat = obs[:, 1:5]
    obs[:, 1:5] = quat / np.sqrt(rowwise_dot(quat, quat))[:, None]
    return obs.astype(np.float32)


def step_reward(
    config: AntConfig,
    layout: AntLayout,
    x_before: NDArray[np.float64],
    rows: NDArray[np.float64],
    actions: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.bool_], dict[str, NDArray]]:
    """Rewards (N,), terminations (N,) and the info arrays (x_position, forward_progress,
    torso_height, healthy) of one control step: torso x before it (N,), state rows after it (N,
    nq + nv), the clipped actions (N, 8)."""
    cfg, a = config, actions
    w, qx, qy, qz = rows[:, layout.quat].T
    n2 = w * w + qx * qx + qy * qy + qz * qz
    # z-component of the torso's z axis; x-component of its x axis (heading toward the +x target).
    up_proj = 1.0 - 2.0 * (qx * qx + qy * qy) / n2
    heading_proj = 1.0 - 2.0 * (qy * qy + qz * qz) / n2
    height = rows[:, layout.pos[2]]
    dx = rows[:, layout.pos[0]] - x_before
    at_limit = np.count_nonzero(np.abs(rows[:, layout.joint_q] - layout.q_mid) > 0.98 * layout.q_half, axis=1)
    heading = cfg.heading_weight * np.where(heading_proj > 0.8, 1.0, heading_proj / 0.8)
    rate = (
        cfg.alive_reward
        + np.where(up_proj > 0.93, cfg.up_weight, 0.0)
        + heading
        - cfg.actions_cost * rowwise_dot(a, a)
        - cfg.energy_cost * cfg.dof_vel_scale * np.abs(a * rows[:, layout.joint_v]).sum(axis=1)
        - cfg.joint_limit_cost * at_limit
    )
    reward = cfg.progress_weight * dx + cfg.rate_scale * rate
    unhealthy = height < cfg.termination_height
    terminated = unhealthy & cfg.terminate_when_unhealthy
    reward = np.where(terminated, cfg.death_cost, reward)
    info = {
        "x_position": rows[:, layout.pos[0]].copy(),
        "forward_progress": dx,
        "torso_height": height.copy(),
        "healthy": ~unhealthy,
    }
    return reward, terminated, info


class AntEnv(SceneRendering, PlantAccess, ParamEnv):
    """Run forward for 2 s with a quadruped whose torso mass xi is drawn per episode."""

    def __init__(
        self,
        config: AntConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = cfg = config_with_overrides(AntConfig, config, overrides, "AntEnv")
        self.space = ParamSpace((Param("torso_mass", 0.01, 20.0, "kg"),))
        super().__init__(self.space, sampler)
        self._set_timing(cfg.control_dt, cfg.t_max, cfg.j_t())
        self._init_render(render_mode)

        from pydrake.systems.analysis import Simulator

        # Silence Drake's "half spaces are not supported for deformable contact" (we have none).
        with quiet_drake():
            (self._diagram, self._plant, self._torso, self._joints, self._actuators, m_torso) = _build(cfg)
            self._simulator = Simulator(self._diagram)
            self._simulator.Initialize()
        plant = self._plant
        self._com0 = np.asarray(m_torso.get_com())
        self._unit_inertia0 = m_torso.get_unit_inertia()
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._actuation_port = plant.get_actuation_input_port()
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        # Where the torso (quaternion wxyz, position xyz; angular then linear velocity, both in the
        # world frame) and the joints sit in the plant's state x = [q; v].
        model = AntModel(self._torso, tuple(self._joints), tuple(self._actuators), m_torso, ())
        self._layout = ant_layout(plant, model, np.arange(self._nq + self._nv))
        # The actuation vector is ordered by actuator index; map action i (joint i) onto it.
        self._u_index = np.array([a.input_start() for a in self._actuators])
        self._u = np.zeros(plant.num_actuated_dofs())
        self._k = 0  # control steps taken in this episode (time = k * control_dt)
        self._state = np.zeros(self._nq + self._nv)

        obs_dim = 1 + 4 + 8 + 3 + 3 + 8
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(8,), dtype=np.float32)

    # -- model ----------------------------------------------------------------------------------

    def torso_mass(self) -> float:
        """The torso mass currently set in the Context [kg]."""
        return float(self._torso.get_mass(self._plant_context))

    def _set_initial_state(self, xi: NDArray[np.float64]) -> None:
        """Set the torso mass and the (noisy) default pose in the reused Context; time 0."""
        from pydrake.multibody.tree import SpatialInertia

        mass = float(xi[0])
        # Mass and rotational inertia scale together (same unit inertia, same COM).
        self._torso.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(mass, self._com0, self._unit_inertia0)
        )
        self._context.SetTime(0.0)
        x = initial_row(self.config, self._layout, self._nq + self._nv, self.np_random)
        self._plant.SetPositionsAndVelocities(self._plant_context, x)
        self._u[:] = 0.0
        self._actuation_port.FixValue(self._plant_context, self._u)
        self._simulator.Initialize()
        self._k = 0
        self._state = x

    def _advance(self, action: NDArray[np.float64], clipped: bool = False) -> NDArray[np.float64]:
        """Apply normalized torques (clipped to [-1, 1]) for one control step; return [q; v]."""
        self._u[self._u_index] = (action if clipped else np.clip(action, -1.0, 1.0)) * self.config.effort_limit
        self._actuation_port.FixValue(self._plant_context, self._u)
        self._k += 1
        advance(self._simulator, self._k * self.control_dt, f"AntEnv (torso mass {self._xi_value():g} kg)")
        x = np.array(self._plant.GetPositionsAndVelocities(self._plant_context))
        if not np.all(np.isfinite(x)):
            raise SimulationError(
                f"AntEnv: non-finite state at t = {self._k * self.control_dt:g} s (torso mass {self._xi_value():g} kg)"
            )
        return x

    def _xi_value(self) -> float:
        return float("nan") if self._xi is None else float(self._xi[0])

    def _observe(self, x: NDArray[np.float64]) -> NDArray[np.float32]:
        return observe(self._layout, x[None])[0]

    # -- rendering ------------------------------------------------------------------------------

    def _make_renderer(self):
        """A camera behind and to the right of the torso, following it over a checkered floor."""
        from assembly.envs.rendering import CameraView, SceneRenderer, scene_graph_of

        view = CameraView(target=(0.0, 0.0, 0.3), eye_offset=(-1.2, -3.0, 1.5))
        r = SceneRenderer(scene_graph_of(self._diagram), self._context, self._plant.get_source_id(), view)
        r.add_checker_floor(0.5)
        return r

    def _render_track(self) -> NDArray[np.float64]:
        return self._plant.EvalBodyPoseInWorld(self._plant_context, self._torso).translation()

    # -- ParamEnv -------------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        self._set_initial_state(xi)
        return self._observe(self._state)

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        a = np.clip(action, -1.0, 1.0)
        x_before = self._state[self._layout.pos[0]]
        x = self._advance(a, clipped=True)
        self._state = x
        reward, terminated, extra = step_reward(self.config, self._layout, np.array([x_before]), x[None], a[None])
        info = {key: float(value[0]) for key, value in extra.items()}
        info["healthy"] = bool(extra["healthy"][0])
        return self._observe(x), float(reward[0]), bool(terminated[0]), info

    # -- benchmark helper ----------------------------------------------------------------------

    def bare_rollout(self, xi: ArrayLike, actions: ArrayLike, seed: int | None = None) -> NDArray[np.float64]:
        """Reset to xi (as reset(seed=seed, options={"xi": xi}) would) and advance the bare Drake
        simulator through `actions` (n, 8), without rewards, observations or gym bookkeeping.
        Returns the final plant state [q; v]; equal to env.state() after the same reset and steps.
        Stops early (like the env would not) only on a SimulationError, which propagates.
        The env's episode is finished afterwards: call reset() before step()."""
        import gymnasium

        xi_arr = self.validate_xi(xi, what="bare_rollout xi")
        acts = np.asarray(actions, dtype=np.float64)
        if acts.ndim != 2 or acts.shape[1] != 8 or not np.all(np.isfinite(acts)):
            raise ValueError(f"bare_rollout: actions must be a finite (n, 8) array, got shape {acts.shape}")
        gymnasium.Env.reset(self, seed=seed)
        self._done = True  # the gym episode (if any) is over
        self._xi = xi_arr
        self._set_initial_state(xi_arr)
        for a in acts:
            self._advance(a)
        return self.state()
