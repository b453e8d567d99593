"""The physical scene: table, gear plate with shafts, three gears and the Panda, added to a plant.

World frame W: origin at the Panda's base on the table top, z up, x pointing away from the robot.
Gear start poses and the plate pose are planar (x, y, yaw) on the table top.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    CollisionFilterDeclaration,
    GeometrySet,
    ProximityProperties,
    RoleAssign,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import (
    FixedOffsetFrame,
    Frame,
    ModelInstanceIndex,
    PdControllerGains,
    PrismaticJoint,
    RevoluteJoint,
    RigidBody,
    SpatialInertia,
)

from assembly.gear_meshes import gearset_model_paths
from assembly.gearset import (
    GEAR_NAMES,
    GEAR_THICKNESS,
    PLATE_SIZE,
    SEATED_HEIGHT_TOL,
    SEATED_LATERAL_TOL,
    gear_spec,
    shaft_position_in_plate,
)
from assembly.panda_model import (
    FINGER_MAX_WIDTH,
    HAND_FLANGE_YAW,
    HAND_TCP_OFFSET,
    Q_HOME,
    panda_model_paths,
)

# Table top extents in W [m] (the table model is 1.2 x 1.0 m centred at x = 0.35).
TABLE_X = (-0.25, 0.95)
TABLE_Y = (-0.5, 0.5)
# Where the Panda can place its hand above the table: radial distance from the base axis [m].
REACH_RADIUS = (0.25, 0.80)
# Targets may lie a little below the table top: the impedance then presses on it.
REACH_HEIGHT = (-0.05, 0.80)
# The hand is mounted on the flange rotated -pi/4 about the flange z axis (Franka's convention).
X_FLANGE_HAND = RigidTransform(RotationMatrix.MakeZRotation(HAND_FLANGE_YAW), np.zeros(3))
# Where gears may lie at the start of an assembly run: gear centres (x, y) in this rectangle [m].
# Checked for every gear at every point of it (33 x 51 grid, 72 points on each of its top and bottom
# tip circles projected): fully inside default_scene_camera()'s 640 x 480 image with at least 14.9 px
# to spare (the large gear at the corner (0.62, -0.23) is the tightest), and within REACH_RADIUS
# (0.30..0.66 m from the base). y stops at -0.23, not -0.28: the scene camera stands at y = -0.42,
# and there the large gear would leave the image by 35 px at x = 0.62 (10 px margin needs y >= -0.235).
PLACEMENT_X = (0.30, 0.62)
PLACEMENT_Y = (-0.23, 0.22)


def model_parser(plant: MultibodyPlant, auto_renaming: bool = False) -> Parser:
    """A Parser for our own models that cannot download anything: Drake's remote model package is
    removed from its package map, so a stray package:// reference fails instead of fetching.
    (drake 1.51: DRAKE_ALLOW_NETWORK=none would make the Parser constructor itself throw.)
    With auto_renaming, a model added again gets a numbered instance name (copies in one plant)."""
    parser = Parser(plant)
    parser.package_map().Remove("drake_models")
    parser.SetAutoRenaming(auto_renaming)
    return parser


def planar_pose(x: float, y: float, yaw: float, z: float = 0.0) -> RigidTransform:
    """RigidTransform of a frame at (x, y, z) rotated by yaw about world z."""
    return RigidTransform(RotationMatrix.MakeZRotation(yaw), [x, y, z])


@dataclass(frozen=True)
class ContactOverrides:
    """Contact properties of the gears, the plate and its shafts other than the model files'
    (assembly.gear_meshes): for simulating a contact the model gets wrong (sim2real).

    mu: Coulomb friction (static = dynamic) written on every gear, the plate and the shafts, so
        that a gear slides on its shaft or the plate at exactly mu (Drake combines two
        coefficients as 2 mu1 mu2 / (mu1 + mu2)); None keeps the files' (gear/shaft ~0.32).
    modulus_scale: the plate's and shafts' hydroelastic modulus (1e7 Pa) times this (the gears are
        rigid hydroelastic: the compliant side sets the contact stiffness).
    dissipation: Hunt-Crossley dissipation [s/m] written on the gears, the plate and the shafts;
        None keeps the files' 20 s/m.
    """

    mu: float | None = None
    modulus_scale: float = 1.0
    dissipation: float | None = None

    def __post_init__(self) -> None:
        for name in ("mu", "modulus_scale", "dissipation"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and (v > 0 if name != "dissipation" else v >= 0)):
                raise ValueError(
                    f"ContactOverrides.{name} = {v!r}; expected a finite number "
                    f"{'>= 0' if name == 'dissipation' else '> 0'}"
                )


@dataclass(frozen=True)
class GraspHold:
    """The held gear hangs from the tool on friction-limited springs instead of a weld.

    Three joints stand for how a two-finger grasp gives: a tilt about the finger-closing axis
    (tool y, through the tool origin between the pads), then slides along tool x (across the
    fingers) and tool z (along the gear's axis). Each is an implicit PD actuator whose force is
    capped at the limit (Drake's effort limit): below it the joint is a stiff spring, at it the
    gear slides at the limit (Coulomb friction). The spring's rest point follows a slipped gear
    (assembly.station.GraspAnchor), so a slip stays. Across-finger slide and roll about tool x
    are held by the pads' normal force and stay welded.
    """

    force_limit: float = 40.0  # [N] grip friction along tool x and z: 2 pads x mu 0.5 x 40 N grip
    torque_limit: float = 0.13  # [N m] about the finger axis: (2/3) x 5 mm patch radius x force_limit
    stiffness: float = 1.0e5  # [N/m] elastic grip before slip
    damping: float = 100.0  # [N s/m]
    rotational_stiffness: float = 20.0  # [N m/rad]
    rotational_damping: float = 0.05  # [N m s/rad]

    def __post_init__(self) -> None:
        for name in (
            "force_limit",
            "torque_limit",
            "stiffness",
            "damping",
            "rotational_stiffness",
            "rotational_damping",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"GraspHold.{name} = {v!r}; expected a finite number > 0")

    def limits(self) -> np.ndarray:
        """Effort limits of the (tilt [N m], slide x [N], slide z [N]) joints."""
        return np.array([self.torque_limit, self.force_limit, self.force_limit])

    def stiffnesses(self) -> np.ndarray:
        """Stiffnesses of the (tilt [N m/rad], slide x [N/m], slide z [N/m]) joints."""
        return np.array([self.rotational_stiffness, self.stiffness, self.stiffness])


@dataclass
class WorldConfig:
    """Where things stand on the table. Poses are (x [m], y [m], yaw [rad]) in W."""

    plate_pose: tuple[float, float, float] = (0.55, 0.0, np.pi / 2)
    gear_start_poses: dict[str, tuple[float, float, float]] = field(
        default_factory=lambda: {
            "large": (0.40, -0.15, 0.0),
            "medium": (0.40, -0.03, 0.0),
            "small": (0.40, 0.07, 0.0),
        }
    )
    gears: tuple[str, ...] = GEAR_NAMES
    # A gear already in the hand (welded to a grasp frame on the tool frame whose pose is a
    # Context parameter: Station.set_grasp). It must not also be in `gears`.
    held_gear: str | None = None
    # None: the held gear is welded (an ideal grasp); a GraspHold: held by friction-limited springs.
    grasp_hold: GraspHold | None = None
    # None: the contact properties of the model files; else the gears' and plate's overrides.
    contact: ContactOverrides | None = None
    q_arm_start: np.ndarray = field(default_factory=lambda: Q_HOME.copy())
    finger_width_start: float = FINGER_MAX_WIDTH

    def __post_init__(self) -> None:
        if self.held_gear is not None:
            gear_spec(self.held_gear)
            if self.held_gear in self.gears:
                raise ValueError(
                    f"held_gear {self.held_gear!r} is also in gears {self.gears}; a gear "
                    "is either on the table or in the hand"
                )
        if self.grasp_hold is not None and self.held_gear is None:
            raise ValueError("grasp_hold is set but held_gear is None; a hold needs a gear in the hand")
        for name in self.gears:
            gear_spec(name)
            if name not in self.gear_start_poses:
                raise ValueError(
                    f"gear {name!r} has no start pose; gear_start_poses has {sorted(self.gear_start_poses)}"
                )
        for name in self.gear_start_poses:
            gear_spec(name)
        validate_plate_pose(self.plate_pose)
        for name in self.gears:
            validate_gear_pose(
                name,
                self.gear_start_poses[name],
                self.plate_pose,
                {k: v for k, v in self.gear_start_poses.items() if k != name and k in self.gears},
            )


def _in_reach(x: float, y: float) -> bool:
    return REACH_RADIUS[0] <= np.hypot(x, y) <= REACH_RADIUS[1]


def validate_plate_pose(pose: tuple[float, float, float]) -> None:
    """ValueError unless the plate lies on the table and within the Panda's reach."""
    x, y, yaw = _finite_pose("plate_pose", pose)
    half = 0.5 * np.hypot(PLATE_SIZE[0], PLATE_SIZE[1])
    if not (TABLE_X[0] + half <= x <= TABLE_X[1] - half and TABLE_Y[0] + half <= y <= TABLE_Y[1] - half):
        raise ValueError(
            f"plate_pose {tuple(pose)} puts the plate off the table; expected x in "
            f"[{TABLE_X[0] + half:.3f}, {TABLE_X[1] - half:.3f}] and y in "
            f"[{TABLE_Y[0] + half:.3f}, {TABLE_Y[1] - half:.3f}] m"
        )
    for g in GEAR_NAMES:
        p = planar_pose(x, y, yaw) @ shaft_position_in_plate(g)
        if not _in_reach(p[0], p[1]):
            raise ValueError(
                f"plate_pose {tuple(pose)} puts the {g} shaft at distance "
                f"{np.hypot(p[0], p[1]):.3f} m from the robot base; expected "
                f"{REACH_RADIUS[0]}..{REACH_RADIUS[1]} m"
            )


def validate_gear_pose(
    name: str,
    pose: tuple[float, float, float],
    plate_pose: tuple[float, float, float],
    others: dict[str, tuple[float, float, float]] | None = None,
) -> None:
    """ValueError unless gear `name` at `pose` lies on the table, within reach, clear of the plate
    and of the other gears."""
    spec = gear_spec(name)
    x, y, _ = _finite_pose(f"{name} gear pose", pose)
    r = spec.tip_radius
    if not (TABLE_X[0] + r <= x <= TABLE_X[1] - r and TABLE_Y[0] + r <= y <= TABLE_Y[1] - r):
        raise ValueError(
            f"{name} gear pose {tuple(pose)} is outside the table; expected x in "
            f"[{TABLE_X[0] + r:.3f}, {TABLE_X[1] - r:.3f}] and y in "
            f"[{TABLE_Y[0] + r:.3f}, {TABLE_Y[1] - r:.3f}] m"
        )
    if not _in_reach(x, y):
        raise ValueError(
            f"{name} gear pose {tuple(pose)} is {np.hypot(x, y):.3f} m from the robot "
            f"base; expected {REACH_RADIUS[0]}..{REACH_RADIUS[1]} m (the Panda's reach)"
        )
    # Clearance to the plate: distance from the gear centre to the plate rectangle > radius + gripper.
    X_WP = planar_pose(*plate_pose)
    p_P = X_WP.inverse() @ np.array([x, y, 0.0])
    dx = max(abs(p_P[0]) - PLATE_SIZE[0] / 2, 0.0)
    dy = max(abs(p_P[1]) - PLATE_SIZE[1] / 2, 0.0)
    if np.hypot(dx, dy) < r + 0.02:
        raise ValueError(
            f"{name} gear pose {tuple(pose)} overlaps the gear plate; keep the gear "
            f"at least {r + 0.02:.3f} m (radius + 2 cm) from the plate's edge"
        )
    for other, q in (others or {}).items():
        d = np.hypot(x - q[0], y - q[1])
        need = r + gear_spec(other).tip_radius + 0.05
        if d < need:
            raise ValueError(
                f"{name} gear pose {tuple(pose)} is {d:.3f} m from the {other} gear; "
                f"expected at least {need:.3f} m so the open gripper fits between"
            )


def insertion_error(X_SW: RigidTransform, X_WG: RigidTransform) -> tuple[float, float]:
    """(lateral, signed height) [m] of gear frame G from its seated pose, given the inverse X_SW of
    its shaft frame's pose (precomputed by callers on a hot path)."""
    p = X_SW @ X_WG.translation()
    return float(np.hypot(p[0], p[1])), float(p[2])


def is_seated(lateral: float, height: float) -> bool:
    """The seated criterion (SEATED_LATERAL_TOL, SEATED_HEIGHT_TOL in assembly.gearset)."""
    return lateral < SEATED_LATERAL_TOL and abs(height) < SEATED_HEIGHT_TOL


def validate_tool_target(X_WT: RigidTransform) -> None:
    """ValueError unless a hand (tool) target lies inside the Panda's workspace above the table."""
    p = X_WT.translation()
    if not np.all(np.isfinite(p)):
        raise ValueError(f"tool target position {p} is not finite")
    r = np.hypot(p[0], p[1])
    if not (REACH_RADIUS[0] <= r <= REACH_RADIUS[1] and REACH_HEIGHT[0] <= p[2] <= REACH_HEIGHT[1]):
        raise ValueError(
            f"tool target {np.round(p, 4).tolist()} is outside the workspace; expected "
            f"radial distance {REACH_RADIUS[0]}..{REACH_RADIUS[1]} m from the base and "
            f"height {REACH_HEIGHT[0]}..{REACH_HEIGHT[1]} m relative to the table top"
        )


def _finite_pose(what: str, pose) -> np.ndarray:
    arr = np.asarray(pose, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} = {pose!r}; expected three finite numbers (x [m], y [m], yaw [rad])")
    return arr


def random_gear_poses(
    rng: np.random.Generator,
    plate_pose: tuple[float, float, float] = WorldConfig().plate_pose,
    gears: tuple[str, ...] = GEAR_NAMES,
    max_tries: int = 1000,
) -> dict[str, tuple[float, float, float]]:
    """Random start poses (x, y, yaw) for `gears`, placed one after the other in the given order:
    x, y uniform in PLACEMENT_X x PLACEMENT_Y, yaw uniform in [-pi, pi), drawn again until
    `validate_gear_pose` accepts the gear against the plate at `plate_pose` and the gears already
    placed. Deterministic for a given generator state. ValueError on a bad rng, gear name or
    max_tries; RuntimeError if a gear finds no valid pose in `max_tries` draws."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(
            f"rng is {type(rng).__name__}; expected a numpy.random.Generator (np.random.default_rng(seed))"
        )
    if isinstance(max_tries, bool) or not isinstance(max_tries, (int, np.integer)) or max_tries < 1:
        raise ValueError(f"max_tries = {max_tries!r}; expected an integer >= 1")
    for name in gears:
        gear_spec(name)
    if len(set(gears)) != len(gears):
        raise ValueError(f"gears = {tuple(gears)}; expected each gear at most once")
    poses: dict[str, tuple[float, float, float]] = {}
    for name in gears:
        for _ in range(max_tries):
            pose = (
                float(rng.uniform(*PLACEMENT_X)),
                float(rng.uniform(*PLACEMENT_Y)),
                float(rng.uniform(-np.pi, np.pi)),
            )
            try:
                validate_gear_pose(name, pose, plate_pose, poses)
            except ValueError:
                continue
            poses[name] = pose
            break
        else:
            raise RuntimeError(
                f"no valid pose for the {name} gear in {max_tries} draws from the "
                f"placement region x {PLACEMENT_X}, y {PLACEMENT_Y} m (plate at "
                f"{tuple(plate_pose)}, already placed: {sorted(poses)})"
            )
    return poses


@dataclass
class HeldGear:
    """A gear welded to the hand through `grasp_frame`, whose pose in the tool frame (X_TG) is a
    Context parameter: the grasp, with its error, can change per episode without a rebuild.

    With a GraspHold, `grasp_frame` is a frame on the gear whose pose in the gear frame is the
    inverse X_GT of the grasp (the hold's joints at zero put the tool there), and `hold_instance`
    holds the hold's joints (tilt, slide x, slide z) and their PD actuators."""

    name: str
    instance: ModelInstanceIndex
    grasp_frame: FixedOffsetFrame
    hold_instance: ModelInstanceIndex | None = None


def nominal_grasp(gear: str, grasp_depth: float = 0.006) -> RigidTransform:
    """X_TG of a centred grasp: the tool `grasp_depth` below the gear's top face, gear z up
    (the tool's z points down)."""
    gear_spec(gear)
    return RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.0, 0.0, GEAR_THICKNESS - grasp_depth])


def grasp_with_error(gear: str, x: float, y: float, yaw: float) -> RigidTransform:
    """X_TG of a grasp off the nominal one by (x, y) along the tool's x and y axes [m] and by yaw
    about the gear's axis [rad]."""
    X = nominal_grasp(gear)
    return RigidTransform(X.rotation() @ RotationMatrix.MakeZRotation(yaw), X.translation() + np.array([x, y, 0.0]))


def add_held_gear(
    plant: MultibodyPlant, gear: str, tool: Frame, hold: GraspHold | None = None, auto_renaming: bool = False
) -> HeldGear:
    """Add gear `gear` welded to a new grasp frame on `tool` (initially the nominal grasp), or
    hanging from `tool` on the joints of `hold` (GraspHold). With auto_renaming, the gear's model
    instance is numbered when the plant already holds one (copies in one plant)."""
    instance = model_parser(plant, auto_renaming).AddModels(str(gearset_model_paths()[gear]))[0]
    (index,) = plant.GetBodyIndices(instance)
    if hold is None:
        grasp = plant.AddFrame(FixedOffsetFrame(f"grasp_{gear}", tool, nominal_grasp(gear)))
        plant.WeldFrames(grasp, plant.get_body(index).body_frame(), RigidTransform())
        return HeldGear(gear, instance, grasp)
    held = plant.AddModelInstance(f"grasp_hold_{gear}")
    tiny = SpatialInertia.SolidSphereWithMass(1e-4, 1e-3)  # massless links would leave M singular
    links = [plant.AddRigidBody(f"grasp_hold_link{i}", held, tiny) for i in (1, 2)]
    grasp = plant.AddFrame(
        FixedOffsetFrame(f"grasp_{gear}", plant.get_body(index).body_frame(), nominal_grasp(gear).inverse(), held)
    )
    joints = [
        plant.AddJoint(RevoluteJoint("grasp_tilt", tool, links[0].body_frame(), [0.0, 1.0, 0.0])),
        plant.AddJoint(PrismaticJoint("grasp_slide_x", links[0].body_frame(), links[1].body_frame(), [1.0, 0.0, 0.0])),
        plant.AddJoint(PrismaticJoint("grasp_slide_z", links[1].body_frame(), grasp, [0.0, 0.0, 1.0])),
    ]
    damping = (hold.rotational_damping, hold.damping, hold.damping)
    for joint, limit, kp, kd in zip(joints, hold.limits(), hold.stiffnesses(), damping):
        actuator = plant.AddJointActuator(joint.name(), joint, float(limit))
        actuator.set_controller_gains(PdControllerGains(p=float(kp), d=float(kd)))
    return HeldGear(gear, instance, grasp, held)


@dataclass
class WorldModels:
    """Handles to what `add_world` put into the plant."""

    arm: ModelInstanceIndex
    hand: ModelInstanceIndex
    table: ModelInstanceIndex
    plate: ModelInstanceIndex
    gears: dict[str, ModelInstanceIndex]
    X_WP: RigidTransform  # plate pose
    held: HeldGear | None = None

    def X_WS(self, gear: str) -> RigidTransform:
        """Pose of gear's shaft frame: on the shaft axis at the plate top, axes parallel to the plate."""
        return self.X_WP @ RigidTransform(shaft_position_in_plate(gear))


def add_panda(
    plant: MultibodyPlant, X_WBase: RigidTransform | None = None
) -> tuple[ModelInstanceIndex, ModelInstanceIndex]:
    """Add the Panda arm (welded at X_WBase) and its hand (welded to the flange); returns both."""
    arm_urdf, hand_urdf = panda_model_paths()
    parser = model_parser(plant)
    arm = parser.AddModels(str(arm_urdf))[0]
    hand = parser.AddModels(str(hand_urdf))[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0", arm), X_WBase or RigidTransform())
    plant.WeldFrames(plant.GetFrameByName("panda_link8", arm), plant.GetFrameByName("panda_hand", hand), X_FLANGE_HAND)
    return arm, hand


def tool_frame(plant: MultibodyPlant, hand: ModelInstanceIndex):
    """The tool-centre-point frame T: between the finger pads, z along the approach direction."""
    return plant.GetFrameByName("panda_hand_tcp", hand)


def add_world(plant: MultibodyPlant, scene_graph: SceneGraph | None, config: WorldConfig) -> WorldModels:
    """Add table, plate, gears and Panda to an unfinalized plant; set their default poses."""
    paths = gearset_model_paths()
    parser = model_parser(plant)
    table = parser.AddModels(str(paths["table"]))[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("table", table), RigidTransform())
    plate = parser.AddModels(str(paths["plate"]))[0]
    X_WP = planar_pose(*config.plate_pose)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("gear_plate", plate), X_WP)
    gears = {}
    for name in config.gears:
        gears[name] = parser.AddModels(str(paths[name]))[0]
        body = gear_body(plant, gears[name])
        plant.SetDefaultFloatingBaseBodyPose(body, planar_pose(*config.gear_start_poses[name]))
    arm, hand = add_panda(plant)
    held = None
    if config.held_gear is not None:
        held = add_held_gear(plant, config.held_gear, tool_frame(plant, hand), config.grasp_hold)
    w = float(np.clip(config.finger_width_start, 0.0, FINGER_MAX_WIDTH))
    _set_default_joint_positions(plant, arm, np.asarray(config.q_arm_start, dtype=float))
    _set_default_joint_positions(plant, hand, np.array([w / 2, w / 2]))
    if scene_graph is not None:
        extra = [held.instance] if held is not None else []
        _filter_collisions(plant, scene_graph, [arm, hand] + extra, list(gears.values()) + extra)
        if config.contact is not None:
            _override_contact(plant, scene_graph, [plate] + list(gears.values()) + extra, config.contact)
    return WorldModels(arm=arm, hand=hand, table=table, plate=plate, gears=gears, X_WP=X_WP, held=held)


def _set_default_joint_positions(plant: MultibodyPlant, instance: ModelInstanceIndex, q: np.ndarray) -> None:
    """Default positions of an instance's one-dof joints, in joint order (works pre-finalize)."""
    joints = [plant.get_joint(j) for j in plant.GetJointIndices(instance) if plant.get_joint(j).num_positions() == 1]
    if len(q) != len(joints):
        raise ValueError(f"{len(q)} positions given for {len(joints)} joints {[j.name() for j in joints]}")
    for joint, value in zip(joints, q):
        joint.set_default_positions([float(value)])


def gear_body(plant: MultibodyPlant, instance: ModelInstanceIndex) -> RigidBody:
    """The single rigid body of a gear model instance (its frame is the gear frame G)."""
    (index,) = plant.GetBodyIndices(instance)
    return plant.get_body(index)


def _override_contact(plant: MultibodyPlant, scene_graph: SceneGraph, instances, overrides: ContactOverrides) -> None:
    """Rewrite the proximity properties of the instances' collision geometries (ContactOverrides)."""
    inspector = scene_graph.model_inspector()
    for inst in instances:
        for b in plant.GetBodyIndices(inst):
            for gid in plant.GetCollisionGeometriesForBody(plant.get_body(b)):
                props = ProximityProperties(inspector.GetProximityProperties(gid))
                if overrides.mu is not None:
                    props.UpdateProperty(
                        "material", "coulomb_friction", CoulombFriction(float(overrides.mu), float(overrides.mu))
                    )
                if overrides.dissipation is not None:
                    props.UpdateProperty("material", "hunt_crossley_dissipation", float(overrides.dissipation))
                if overrides.modulus_scale != 1.0 and props.HasProperty("hydroelastic", "hydroelastic_modulus"):
                    modulus = props.GetProperty("hydroelastic", "hydroelastic_modulus")
                    props.UpdateProperty(
                        "hydroelastic", "hydroelastic_modulus", float(modulus * overrides.modulus_scale)
                    )
                scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)


def _filter_collisions(plant: MultibodyPlant, scene_graph: SceneGraph, robot, gears) -> None:
    """No robot self-collision (a held gear counts as part of the robot: its grasp is ideal);
    gears never touch each other (two rigid meshes: Drake's hydroelastic contact does not support
    rigid-rigid pairs; docs/models.md#sources)."""

    def geometries(instances) -> GeometrySet:
        ids = []
        for inst in instances:
            for b in plant.GetBodyIndices(inst):
                ids += plant.GetCollisionGeometriesForBody(plant.get_body(b))
        return GeometrySet(ids)

    manager = scene_graph.collision_filter_manager()
    manager.Apply(CollisionFilterDeclaration().ExcludeWithin(geometries(robot)))
    manager.Apply(CollisionFilterDeclaration().ExcludeWithin(geometries(gears)))


__all__ = [
    "ContactOverrides",
    "GraspHold",
    "HAND_TCP_OFFSET",
    "HeldGear",
    "WorldConfig",
    "WorldModels",
    "add_held_gear",
    "add_world",
    "add_panda",
    "gear_body",
    "insertion_error",
    "is_seated",
    "model_parser",
    "grasp_with_error",
    "nominal_grasp",
    "planar_pose",
    "tool_frame",
    "validate_gear_pose",
    "validate_plate_pose",
    "validate_tool_target",
    "PLACEMENT_X",
    "PLACEMENT_Y",
    "random_gear_poses",
]
