"""A gymnasium MuJoCo model (its MJCF file) as a Drake MultibodyPlant, with what Drake's parser
drops rebuilt, and the plant's state and MuJoCo's derived quantities in MuJoCo's conventions.

Drake's MuJoCo parser builds the bodies, inertias (from geoms), joints with their damping, limits
and `ref`, the actuators with their armature, and the collision geometry. It drops, and this
module rebuilds:
- joint `stiffness` / `springref`: a RevoluteSpring per joint;
- `contype` / `conaffinity` collision filtering (and MuJoCo's parent-child exclusion);
- the motor `gear`: Drake's actuation input is the joint torque, so the torque is gear x ctrl,
  with ctrl clamped to `ctrlrange` as MuJoCo clamps it, and the effort limit set to match;
- MuJoCo's friction rule (a pair uses the larger of its two geoms' coefficients) through
  per-geometry coefficients whose Drake combination 2ab/(a+b) gives the same pair value;
- `compiler settotalmass` (every body's mass and inertia scaled together);
- `option timestep` (read and returned; the plant step is the env's choice).
Fixed tendons are accepted only when inert (no stiffness, damping, limit or actuator), which is
the case of the Humanoid's two: they then exert no force, so leaving them out is exact.

The file is found in the installed gymnasium package, never downloaded. Differences from the
original that remain (contact model, frictionless self-contacts, integrator): docs/envs.md.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.envs.base import quaternion_rotation
from goflow_common.errors import InputError

__all__ = [
    "MjcfSpec",
    "MjcfPlant",
    "ContactSettings",
    "gymnasium_asset",
    "read_mjcf",
    "build_plant",
    "pair_friction",
    "drake_coefficient",
]

#: Drake's floor coefficient; each robot geometry's coefficient is solved so that Drake's pair
#: combination 2ab/(a+b) equals MuJoCo's pair value (any floor value above half the largest works).
FLOOR_FRICTION = 100.0


def gymnasium_asset(file_name: str) -> Path:
    """The path of `file_name` among the MuJoCo assets of the installed gymnasium package;
    InputError if gymnasium or the file is missing."""
    try:
        import gymnasium
    except ImportError as exc:  # pragma: no cover - a goflow dependency
        raise InputError("gymnasium is not installed; its MuJoCo assets hold the model files") from exc
    path = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / file_name
    if not path.is_file():
        raise InputError(
            f"MuJoCo model file {file_name!r} not found at {path} (gymnasium "
            f"{gymnasium.__version__}); expected one of gymnasium's MuJoCo assets"
        )
    return path


@dataclass(frozen=True)
class MjcfSpec:
    """What the MJCF file says beyond what Drake's parser uses (SI units, radians)."""

    path: Path
    timestep: float
    total_mass: float | None  # compiler settotalmass
    joints: tuple[str, ...]  # every joint, in file (qpos) order
    joint_types: dict[str, str]  # name -> free | slide | hinge
    stiffness: dict[str, tuple[float, float]]  # name -> (stiffness [N m/rad], springref [rad])
    bodies: tuple[str, ...]  # bodies in file order (world excluded)
    geoms: dict[str, dict[str, Any]]  # name -> body, contype, conaffinity, condim, friction
    actuators: tuple[tuple[str, str, float, float, float], ...]  # (name, joint, gear, ctrl lo, hi)
    floor: str  # the world geom the robot stands on
    parents: dict[str, str]  # body -> its parent body (top-level bodies absent: their parent is the world)


def _floats(text: str | None, n: int | None = None) -> list[float]:
    values = [float(v) for v in (text or "").split()]
    if n is not None and len(values) != n:
        raise InputError(f"expected {n} numbers, got {text!r}")
    return values


def read_mjcf(path: str | Path) -> MjcfSpec:
    """Parse the attributes Drake drops from an MJCF file (top-level defaults only; a file that
    uses default classes or non-inert tendons raises InputError naming them)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise InputError(f"cannot read MJCF file {path}: {exc}") from exc
    if root.find(".//*[@class]") is not None or root.find(".//*[@childclass]") is not None:
        raise InputError(f"{path.name}: MJCF default classes are not supported")
    compiler = root.find("compiler")
    degrees = compiler is None or compiler.get("angle", "degree") == "degree"
    angle = math.pi / 180.0 if degrees else 1.0
    total = None if compiler is None else compiler.get("settotalmass")
    total_mass = None if total is None else float(total)
    option = root.find("option")
    timestep = float(option.get("timestep", 0.002)) if option is not None else 0.002
    defaults: dict[str, dict[str, str]] = {}
    top = root.find("default")
    if top is not None:
        for child in top:
            defaults[child.tag] = dict(child.attrib)

    def attr(el: ET.Element, kind: str, name: str, default: str | None = None) -> str | None:
        return el.get(name, defaults.get(kind, {}).get(name, default))

    joints, joint_types, stiffness, bodies, geoms = [], {}, {}, [], {}
    world = root.find("worldbody")
    floor = None
    for geom in world.findall("geom"):
        floor = floor or geom.get("name")
        geoms[geom.get("name")] = _geom_entry(geom, attr, "world")
    parents = {}
    for body in world.iter("body"):
        bodies.append(body.get("name"))
        parents.update({child.get("name"): body.get("name") for child in body.findall("body")})
        for joint in body.findall("joint"):
            name = joint.get("name")
            joints.append(name)
            jtype = "free" if joint.tag == "freejoint" else attr(joint, "joint", "type", "hinge")
            joint_types[name] = jtype
            k = float(attr(joint, "joint", "stiffness", "0"))
            if k > 0.0:
                scale = angle if jtype == "hinge" else 1.0  # stiffness is per radian; springref in file units
                stiffness[name] = (k, float(attr(joint, "joint", "springref", "0")) * scale)
        for geom in body.findall("geom"):
            geoms[geom.get("name")] = _geom_entry(geom, attr, body.get("name"))
    if floor is None:
        raise InputError(f"{path.name}: no world geom to stand on")
    actuators = []
    act = root.find("actuator")
    for motor in [] if act is None else list(act):
        if motor.tag != "motor" or motor.get("joint") is None:
            raise InputError(f"{path.name}: actuator <{motor.tag}> is not a joint motor (unsupported)")
        lo, hi = _floats(attr(motor, "motor", "ctrlrange", "-inf inf"), 2)
        if attr(motor, "motor", "ctrllimited", "true") == "false":
            lo, hi = -math.inf, math.inf
        gear = _floats(motor.get("gear", "1"))[0]
        actuators.append((motor.get("name") or motor.get("joint"), motor.get("joint"), gear, lo, hi))
    for tendon in root.iter("fixed"):
        keys = set(tendon.attrib) - {"name"}
        if keys & {"stiffness", "damping", "limited", "range", "springlength", "frictionloss"}:
            raise InputError(f"{path.name}: tendon {tendon.get('name')!r} is not inert ({sorted(keys)}); unsupported")
        if act is not None and any(a.get("tendon") == tendon.get("name") for a in act):
            raise InputError(f"{path.name}: tendon {tendon.get('name')!r} is actuated; unsupported")
    return MjcfSpec(
        path,
        timestep,
        total_mass,
        tuple(joints),
        joint_types,
        stiffness,
        tuple(bodies),
        geoms,
        tuple(actuators),
        floor,
        parents,
    )


def _geom_entry(geom: ET.Element, attr, body: str) -> dict[str, Any]:
    if geom.get("name") is None:
        raise InputError("every MJCF geom needs a name (the Drake geometry is matched by it)")
    return {
        "body": body,
        "contype": int(attr(geom, "geom", "contype", "1")),
        "conaffinity": int(attr(geom, "geom", "conaffinity", "1")),
        "condim": int(attr(geom, "geom", "condim", "3")),
        "friction": _floats(attr(geom, "geom", "friction", "1 0.005 0.0001"))[0],
    }


#: MuJoCo's default contact time constant (geom solref[0]) [s], and gravity [m/s^2].
MUJOCO_TIMECONST = 0.02
GRAVITY = 9.81


@dataclass(frozen=True)
class ContactSettings:
    """Drake's contact model for a converted MJCF model. None: MuJoCo's contact time constant
    tc (0.02 s): the stiffness puts half the robot's mass M on a spring of period ~2 pi tc,
    k = (M / 2) / tc^2, critically damped at rest, d = 2 / (tc g) (docs/env_models.md#contact-stiffness)."""

    time_step: float  # [s] plant discrete step
    approximation: str = "lagged"  # lagged | similar | sap | tamsi
    point_stiffness: float | None = None  # [N/m]
    dissipation: float | None = None  # [s/m] Hunt-Crossley


@dataclass
class MjcfPlant:
    """The Drake diagram of an MJCF model and the maps between Drake's and MuJoCo's coordinates."""

    spec: MjcfSpec
    diagram: Any
    plant: Any
    scene_graph: Any
    bodies: list[Any]  # Drake bodies for spec.bodies, in order
    masses: NDArray[np.float64]  # their nominal masses [kg] (settotalmass applied)
    actuated: NDArray[np.int64]  # velocity index of each actuator's joint, in spec.actuators order
    gear: NDArray[np.float64]
    ctrl_low: NDArray[np.float64]
    ctrl_high: NDArray[np.float64]
    q_index: NDArray[np.int64]  # MuJoCo qpos[i] = q[q_index[i]] (free joints: see to_mujoco)
    v_index: NDArray[np.int64]
    free: bool  # the first joint is a free joint (MuJoCo's qpos xyz + quat, qvel lin + local ang)
    floor_friction: dict[Any, float] = field(default_factory=dict)  # GeometryId -> MuJoCo pair value
    geometry_ids: dict[str, Any] = field(default_factory=dict)  # geom name -> GeometryId
    joints: dict[str, Any] = field(default_factory=dict)  # joint name -> Drake joint

    def set_masses(self, context: Any, masses: NDArray[np.float64]) -> None:
        """Each body's mass in the plant Context `context` (its rotational inertia scales with it,
        as for a uniformly denser link; the centre of mass stays)."""
        for body, m in zip(self.bodies, masses):
            body.SetMass(context, float(m))

    def set_pair_friction(self, sg_context: Any, scale: float) -> None:
        """Every robot-floor pair's Coulomb coefficient times `scale`, in the SceneGraph Context."""
        from pydrake.geometry import ProximityProperties, RoleAssign
        from pydrake.multibody.plant import CoulombFriction

        inspector = self.scene_graph.model_inspector()
        for gid, pair in self.floor_friction.items():
            props = ProximityProperties(inspector.GetProximityProperties(gid))
            mu = drake_coefficient(pair * scale)
            props.UpdateProperty("material", "coulomb_friction", CoulombFriction(mu, mu))
            self.scene_graph.AssignRole(sg_context, self.plant.get_source_id(), gid, props, RoleAssign.kReplace)

    @property
    def nq(self) -> int:
        return self.plant.num_positions()

    def to_mujoco(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(qpos, qvel) in MuJoCo's order and conventions from Drake's state x = [q; v]."""
        q, v = x[: self.nq], x[self.nq :]
        qpos, qvel = q[self.q_index], v[self.v_index]
        if self.free:  # Drake q: quat wxyz, xyz; v: w_W, v_W. MuJoCo: xyz, quat; v_W, w_B
            quat = q[0:4] / np.linalg.norm(q[0:4])
            qpos[0:3], qpos[3:7] = q[4:7], quat
            qvel[0:3] = v[3:6]
            qvel[3:6] = quaternion_rotation(quat).T @ v[0:3]
        return qpos, qvel

    def from_mujoco(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float64]:
        """Drake's state x = [q; v] from MuJoCo's (qpos, qvel) (a free joint's quaternion is
        normalized, as MuJoCo does before using it)."""
        q = np.zeros(self.nq)
        v = np.zeros(self.plant.num_velocities())
        q[self.q_index] = qpos
        v[self.v_index] = qvel
        if self.free:
            quat = np.asarray(qpos[3:7], dtype=float) / np.linalg.norm(qpos[3:7])
            q[0:4], q[4:7] = quat, qpos[0:3]
            v[3:6] = qvel[0:3]
            v[0:3] = quaternion_rotation(quat) @ np.asarray(qvel[3:6])
        return np.concatenate([q, v])


def pair_friction(spec: MjcfSpec, geom: str) -> float:
    """MuJoCo's Coulomb coefficient between `geom` and the floor: the larger of the two."""
    return max(spec.geoms[geom]["friction"], spec.geoms[spec.floor]["friction"])


def drake_coefficient(pair: float) -> float:
    """The robot geometry's Drake coefficient whose combination with FLOOR_FRICTION is `pair`."""
    return pair * FLOOR_FRICTION / (2.0 * FLOOR_FRICTION - pair)


def build_plant(spec: MjcfSpec, contact: ContactSettings) -> MjcfPlant:
    """The Drake plant of `spec`'s file with the dropped features rebuilt (module docstring)."""
    from pydrake.geometry import (
        AddContactMaterial,
        CollisionFilterDeclaration,
        GeometrySet,
        ProximityProperties,
        Role,
        RoleAssign,
    )
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
    from pydrake.multibody.tree import RevoluteSpring
    from pydrake.systems.framework import DiagramBuilder

    from assembly.envs.drake_sim import quiet_drake

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(
            time_step=contact.time_step, contact_model="point", discrete_contact_approximation=contact.approximation
        ),
        builder,
    )
    with quiet_drake():  # the parser lists every attribute it drops; we rebuild them
        Parser(plant).AddModelsFromString(chained_joints_xml(spec.path), "xml")
    joints = {name: plant.GetJointByName(name) for name in spec.joints if spec.joint_types[name] != "free"}
    for name, (k, ref) in spec.stiffness.items():
        if spec.joint_types[name] != "hinge":
            raise InputError(f"{spec.path.name}: stiffness on {spec.joint_types[name]} joint {name!r} is unsupported")
        plant.AddForceElement(RevoluteSpring(joints[name], ref, k))
    bodies = [plant.GetBodyByName(name) for name in spec.bodies]
    masses = np.array([b.default_mass() for b in bodies])
    if spec.total_mass is not None:  # applied in the Context (set_masses): Drake has no default setter
        masses *= spec.total_mass / masses.sum()
    gear, lo, hi, act_joints = [], [], [], []
    for name, joint, g, c_lo, c_hi in spec.actuators:
        actuator = plant.GetJointActuatorByName(name) if plant.HasJointActuatorNamed(name) else None
        if actuator is None:
            actuator = next(
                a
                for a in (plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices())
                if a.joint().name() == joint
            )
        actuator.set_effort_limit(abs(g) * max(abs(c_lo), abs(c_hi)))
        gear.append(g), lo.append(c_lo), hi.append(c_hi), act_joints.append(joints[joint])
    plant.Finalize()
    if [plant.get_joint_actuator(i).joint().name() for i in plant.GetJointActuatorIndices()] != [
        a[1] for a in spec.actuators
    ]:
        raise InputError(f"{spec.path.name}: Drake's actuator order differs from the file's")

    # Contact: MuJoCo's pair friction through per-geometry coefficients, Drake's compliance.
    stiffness = contact.point_stiffness or 0.5 * masses.sum() / MUJOCO_TIMECONST**2
    dissipation = 2.0 / (MUJOCO_TIMECONST * GRAVITY) if contact.dissipation is None else contact.dissipation
    inspector = scene_graph.model_inspector()
    geometry_ids, floor_friction = {}, {}
    for gid in inspector.GetAllGeometryIds(Role.kProximity):
        name = inspector.GetName(gid).split("::")[-1]
        if name not in spec.geoms:
            raise InputError(f"{spec.path.name}: Drake geometry {name!r} has no MJCF geom")
        geometry_ids[name] = gid
        props = ProximityProperties(inspector.GetProximityProperties(gid))
        mu = FLOOR_FRICTION if name == spec.floor else drake_coefficient(pair_friction(spec, name))
        for key in ("coulomb_friction", "point_contact_stiffness", "hunt_crossley_dissipation"):
            if props.HasProperty("material", key):
                props.RemoveProperty("material", key)
        AddContactMaterial(
            dissipation=dissipation, point_stiffness=stiffness, friction=CoulombFriction(mu, mu), properties=props
        )
        scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)
        if name != spec.floor:
            floor_friction[gid] = pair_friction(spec, name)
    # MuJoCo's filter: a pair collides iff (contype1 & conaffinity2) | (contype2 & conaffinity1),
    # and never within one body or between a body and its parent (filterparent, world excepted).
    names = list(geometry_ids)
    parent = spec.parents
    declaration = CollisionFilterDeclaration()
    for i, a in enumerate(names):
        ga = spec.geoms[a]
        for b in names[i + 1 :]:
            gb = spec.geoms[b]
            collide = bool(ga["contype"] & gb["conaffinity"]) or bool(gb["contype"] & ga["conaffinity"])
            same = ga["body"] == gb["body"]
            family = "world" not in (ga["body"], gb["body"]) and (
                parent.get(ga["body"]) == gb["body"] or parent.get(gb["body"]) == ga["body"]
            )
            if not collide or same or family:
                declaration.ExcludeBetween(GeometrySet(geometry_ids[a]), GeometrySet(geometry_ids[b]))
    scene_graph.collision_filter_manager().Apply(declaration)
    diagram = builder.Build()

    free = spec.joint_types[spec.joints[0]] == "free"
    q_index, v_index = [], []
    if free:
        q_index, v_index = list(range(7)), list(range(6))
    for name in spec.joints:
        if spec.joint_types[name] == "free":
            continue
        q_index.append(joints[name].position_start())
        v_index.append(joints[name].velocity_start())
    actuated = np.array([j.velocity_start() for j in act_joints], dtype=np.int64)
    return MjcfPlant(
        spec,
        diagram,
        plant,
        scene_graph,
        bodies,
        masses,
        actuated,
        np.array(gear),
        np.array(lo),
        np.array(hi),
        np.array(q_index, dtype=np.int64),
        np.array(v_index, dtype=np.int64),
        free,
        floor_friction,
        geometry_ids,
        joints,
    )


def chained_joints_xml(path: Path) -> str:
    """The MJCF text of `path` with every body of several joints split into a chain of nested
    bodies, one joint each, at coincident frames (the outer ones massless, the original body
    innermost with the geoms and children). MuJoCo composes a body's joints in exactly this way;
    Drake's parser (1.51) rotates all but the last about the parent's origin instead of the
    joint's anchor, which moved the Humanoid's thighs by 3 cm at 0.3 rad of hip_x."""
    root = ET.parse(path).getroot()
    for body in list(root.find("worldbody").iter("body")):
        joints = [el for el in body if el.tag == "joint"]
        if len(joints) < 2:
            continue
        rest = [el for el in body if el.tag != "joint"]
        for el in list(body):
            body.remove(el)
        name = body.get("name")
        body.set("name", f"{name}__{joints[0].get('name')}")
        outer = body
        for i, joint in enumerate(joints):
            outer.append(joint)
            if i == len(joints) - 1:
                break
            inner = ET.SubElement(
                outer, "body", {"name": name if i == len(joints) - 2 else f"{name}__{joints[i + 1].get('name')}"}
            )
            outer = inner
        for el in rest:
            outer.append(el)
    return ET.tostring(root, encoding="unicode")
