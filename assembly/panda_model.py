"""Our own Franka Emika Panda arm + hand model: a generator for URDF files and OBJ visual meshes.

Nothing here is downloaded or copied: the kinematics come from Franka's published DH table, the
inertial parameters from the published identification of Gaz et al. (RA-L 2019), and every mesh is
built from primitives (trimesh cylinders and capsules, our own rounded boxes). The generated files
live in ``assembly/models/panda`` and are committed; ``python -m assembly.panda_model`` regenerates
them byte for byte on any machine: each primitive is rounded to the written precision and put in
canonical order (``assembly.gear_meshes.canonical_mesh``) before smooth shading, and the shaded mesh
again before it is written.

Frames follow the usual franka_description convention (each ``panda_linkI`` frame is Craig's
modified-DH frame I), so published per-link COMs and inertias apply without change.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import Literal, Sequence

import numpy as np
import trimesh

from assembly.gear_meshes import canonical_mesh

__all__ = [
    "ARM_JOINT_NAMES",
    "ARM_MASS",
    "FINGER_FORCE_MAX",
    "FINGER_FORCE_PEAK",
    "FINGER_JOINT_MAX",
    "FINGER_JOINT_NAMES",
    "FINGER_MAX_WIDTH",
    "FINGER_VELOCITY_MAX",
    "HAND_FLANGE_YAW",
    "HAND_TCP_OFFSET",
    "JOINT_DAMPING",
    "Q_HOME",
    "Q_MAX",
    "Q_MIN",
    "REFLECTED_INERTIA",
    "TAU_MAX",
    "V_MAX",
    "panda_model_paths",
    "write_panda_models",
]

# --------------------------------------------------------------------------------------------
# Kinematics and limits
# --------------------------------------------------------------------------------------------

# Franka Control Interface docs, "Denavit-Hartenberg parameters" (Craig's modified convention):
# row I holds a_{I-1}, d_I, alpha_{I-1} of joint I; row 8 is the fixed flange (panda_link8).
DH_A: np.ndarray = np.array([0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088, 0.0])
DH_D: np.ndarray = np.array([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0, 0.107])
DH_ALPHA: np.ndarray = np.array(
    [0.0, -math.pi / 2, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, math.pi / 2, 0.0]
)

ARM_JOINT_NAMES: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
ARM_LINK_NAMES: tuple[str, ...] = tuple(f"panda_link{i}" for i in range(9))
FINGER_JOINT_NAMES: tuple[str, str] = ("panda_finger_joint1", "panda_finger_joint2")

# Franka datasheet / FCI docs "Limits for Panda": joint position, velocity and torque limits.
Q_MIN: np.ndarray = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX: np.ndarray = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
V_MAX: np.ndarray = np.array([2.175] * 4 + [2.61] * 3)
TAU_MAX: np.ndarray = np.array([87.0] * 4 + [12.0] * 3)
# The usual "ready" pose: elbow bent, flange pointing down.
Q_HOME: np.ndarray = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])

# Franka Hand datasheet: 80 mm stroke (40 mm per finger), 70 N continuous / 140 N peak grasp force.
FINGER_MAX_WIDTH: float = 0.08
FINGER_JOINT_MAX: float = FINGER_MAX_WIDTH / 2
FINGER_FORCE_MAX: float = 70.0
FINGER_FORCE_PEAK: float = 140.0
# Finger joint velocity limit as in franka_ros franka_description (hand.xacro): 0.2 m/s.
FINGER_VELOCITY_MAX: float = 0.2

# franka_description: hand fixed to the flange rotated -pi/4 about z; fingers slide at 58.4 mm;
# the TCP sits 103.4 mm along hand z (Franka's default end-effector frame).
HAND_FLANGE_YAW: float = -math.pi / 4
HAND_TCP_OFFSET: float = 0.1034
FINGER_JOINT_Z: float = 0.0584

# --------------------------------------------------------------------------------------------
# Dynamics
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Inertial:
    """Mass [kg], COM [m] in the link frame, inertia about the COM (link axes) [kg m^2]."""

    mass: float
    com: tuple[float, float, float]
    # (ixx, ixy, ixz, iyy, iyz, izz)
    inertia: tuple[float, float, float, float, float, float]


# Links 1..7: C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca, "Dynamic
# Identification of the Franka Emika Panda Robot With Retrieval of Feasible Parameters Using
# Penalty-Based Optimization", IEEE RA-L 4(4), 2019, supplementary material tables VIII-IX, as
# transcribed in the authors' repository (marcocognetti/FrankaEmikaPandaDynModel,
# matlab/ConvertDynPars2VREP/DynPars2VREP.m) and in franka_ros franka_description
# robots/common/inertial.yaml. Inertias are barycentric with axes parallel to the link frame.
# Link 1's COM z is unidentifiable (joint 1 is vertical): the authors' script lists 0, franka_ros
# lists -0.04762 (inside the link body); we take franka_ros's value. Link 1's large ixx/iyy are
# the published (unidentifiable, but physically feasible) values and do not affect the dynamics
# of a base welded upright. All seven pass the triangle inequality as published (no fix needed).
# Link 0 is not identified in the paper: its values are franka_ros's inertial.yaml ones (it is
# welded to the world, so they only matter for completeness).
_ARM_INERTIALS: tuple[_Inertial, ...] = (
    _Inertial(0.629769, (-0.041018, -0.00014, 0.049974), (0.00315, 8.2904e-07, 0.00015, 0.00388, 8.2299e-06, 0.004285)),
    _Inertial(4.970684, (0.003875, 0.002081, -0.04762), (0.70337, -0.000139, 0.006772, 0.70661, 0.019169, 0.009117)),
    _Inertial(0.646926, (-0.003141, -0.02872, 0.003495), (0.007962, -0.003925, 0.010254, 0.02811, 0.000704, 0.025995)),
    _Inertial(
        3.228604, (0.027518, 0.039252, -0.066502), (0.037242, -0.004761, -0.011396, 0.036155, -0.012805, 0.01083)
    ),
    _Inertial(3.587895, (-0.05317, 0.104419, 0.027454), (0.025853, 0.007796, -0.001332, 0.019552, 0.008641, 0.028323)),
    _Inertial(
        1.225946, (-0.011953, 0.041065, -0.038437), (0.035549, -0.002117, -0.004037, 0.029474, 0.000229, 0.008627)
    ),
    _Inertial(
        1.666555, (0.060149, -0.014117, -0.010517), (0.001964, 0.000109, -0.001158, 0.004354, 0.000341, 0.005433)
    ),
    _Inertial(
        0.735522, (0.010517, -0.004252, 0.061597), (0.012516, -0.000428, -0.001196, 0.010027, -0.000741, 0.004815)
    ),
)
ARM_MASS: float = float(sum(link.mass for link in _ARM_INERTIALS))

# Hand and fingers: franka_ros franka_description robots/common/inertial.yaml (hand 0.73 kg,
# fingers 0.015 kg each with the inertia listed there). Deviation: franka_ros puts the finger COM
# at the joint origin; we put it at the centre of our finger body (the mass is what matters).
_HAND_INERTIAL = _Inertial(0.73, (-0.01, 0.0, 0.03), (0.001, 0.0, 0.0, 0.0025, 0.0, 0.0017))
_FINGER_MASS = 0.015
_FINGER_INERTIA = (2.375e-06, 0.0, 0.0, 2.375e-06, 0.0, 7.5e-07)

# Joint friction identified by Gaz et al. 2019 (same source, FrictionTorque): per joint
# tau_f(v) = A / (1 + exp(-alpha (v + v0))) - A / (1 + exp(-alpha v0)), rows A, v0, alpha.
_FRICTION_A = np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489])
_FRICTION_V0 = np.array([0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526])
_FRICTION_ALPHA = np.array([5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336])
_DAMPING_REFERENCE_SPEED = 1.0  # rad/s


def _viscous_equivalent(speed: float) -> np.ndarray:
    """Secant viscous coefficient [N m s/rad] of the identified friction at +-speed (averaged)."""

    def tau_f(v: float) -> np.ndarray:
        sig = lambda x: 1.0 / (1.0 + np.exp(-x))  # noqa: E731
        return _FRICTION_A * (sig(_FRICTION_ALPHA * (v + _FRICTION_V0)) - sig(_FRICTION_ALPHA * _FRICTION_V0))

    return (np.abs(tau_f(speed)) + np.abs(tau_f(-speed))) / (2.0 * speed)


# Modest viscous damping: the secant slope of Gaz et al.'s identified friction at 1 rad/s
# (about 0.15..0.63 N m s/rad). It dissipates what the real friction dissipates at working speed
# without the stiff sigmoid (whose slope at rest is ~2 N m s/rad), rounded to 3 decimals.
JOINT_DAMPING: np.ndarray = np.round(_viscous_equivalent(_DAMPING_REFERENCE_SPEED), 3)

# Reflected rotor inertia [kg m^2] per axis as provided by Franka for the FR3 (quoted in Drake's
# manipulation/models/franka_description/README.md). Franka publishes no split into rotor inertia
# and gear ratio, and Drake only uses the product rotor_inertia * gear_ratio^2, so we write
# gear_ratio = 1 and rotor_inertia = the reflected inertia. Deviation: FR3 values on a Panda.
REFLECTED_INERTIA: np.ndarray = np.array(
    [0.605721456, 0.605721456, 0.462474144, 0.462474144, 0.205544064, 0.205544064, 0.205544064]
)

# --------------------------------------------------------------------------------------------
# Geometry tables
# --------------------------------------------------------------------------------------------

Vec3 = tuple[float, float, float]
Color = Literal["white", "dark"]
_RGBA: dict[str, str] = {"white": "0.95 0.95 0.95 1", "dark": "0.25 0.25 0.25 1"}


@dataclasses.dataclass(frozen=True)
class _Part:
    """One primitive of a link, in the link frame.

    kind "cylinder"/"capsule": the axis runs from a to b (a capsule's caps extend r beyond them);
    kind "box": a is the centre, b the full extents, r the corner rounding of the visual mesh.
    collide: whether the primitive is also a collision geometry.
    """

    kind: Literal["cylinder", "capsule", "box"]
    a: Vec3
    b: Vec3
    r: float
    color: Color = "white"
    collide: bool = True


def _cyl(a: Vec3, b: Vec3, r: float, color: Color = "white", collide: bool = True) -> _Part:
    return _Part("cylinder", a, b, r, color, collide)


def _cap(a: Vec3, b: Vec3, r: float) -> _Part:
    return _Part("capsule", a, b, r)


def _ring(a: Vec3, b: Vec3, r: float) -> _Part:
    """A dark, visual-only disk (joint cap or seam ring)."""
    return _Part("cylinder", a, b, r, "dark", False)


def _box(center: Vec3, extents: Vec3, rounding: float, color: Color = "white", collide: bool = True) -> _Part:
    return _Part("box", center, extents, rounding, color, collide)


# Shapes per arm link, in the link frame, laid out after the Panda's silhouette: the base with
# its rear connector box, the shoulder column, the upper arm, the elbow, the forearm with its
# offset strut, the wrist and the flange. Radii are of the real housings (~110-120 mm).
_ARM_PARTS: tuple[tuple[_Part, ...], ...] = (
    (  # link0: base
        _cyl((0, 0, 0), (0, 0, 0.14), 0.07),
        _box((-0.065, 0, 0.05), (0.13, 0.13, 0.10), 0.02),
        _ring((0, 0, 0.135), (0, 0, 0.141), 0.0715),
    ),
    (  # link1: shoulder column up to the joint-2 housing (axis +y)
        _cyl((0, 0, -0.193), (0, 0, 0), 0.06),
        _cyl((0, -0.065, 0), (0, 0.065, 0), 0.06),
        _ring((0, 0.065, 0), (0, 0.07, 0), 0.05),
        _ring((0, -0.07, 0), (0, -0.065, 0), 0.05),
        _ring((0, 0, -0.193), (0, 0, -0.187), 0.0615),
    ),
    (  # link2: lower half of the upper arm (along -y)
        _cyl((0, 0, 0), (0, -0.2, 0), 0.06),
        _ring((0, -0.203, 0), (0, -0.197, 0), 0.0615),
    ),
    (  # link3: upper half of the upper arm, bending out to the elbow at x = 0.0825
        _cyl((0, 0, -0.116), (0, 0, -0.03), 0.06),
        _cap((0, 0, -0.03), (0.0825, 0, 0), 0.055),
    ),
    (  # link4: elbow housing (axis z) and the bridge towards the forearm
        _cyl((0, 0, -0.06), (0, 0, 0.06), 0.06),
        _cap((0, 0, 0), (-0.0825, 0.09, 0), 0.055),
        _ring((0, 0, 0.06), (0, 0, 0.065), 0.05),
        _ring((0, 0, -0.065), (0, 0, -0.06), 0.05),
    ),
    (  # link5: forearm drum near the elbow, offset strut, joint-6 bearing (axis +y)
        _cyl((0, 0, -0.31), (0, 0, -0.19), 0.06),
        _cap((0, 0.065, -0.22), (0, 0.065, -0.05), 0.042),
        _cyl((0, 0.055, 0), (0, 0.10, 0), 0.05),
        _ring((0, 0.10, 0), (0, 0.105, 0), 0.042),
        _ring((0, 0, -0.193), (0, 0, -0.187), 0.0615),
    ),
    (  # link6: wrist housing (axis z) and the arm out to joint 7 at x = 0.088
        _cyl((0, 0, -0.055), (0, 0, 0.05), 0.055),
        _cap((0, 0, 0), (0.088, 0, 0), 0.045),
        _ring((0, 0, 0.05), (0, 0, 0.055), 0.045),
    ),
    (  # link7: joint-7 housing and the flange
        _cyl((0, 0, -0.05), (0, 0, 0.085), 0.055),
        _cyl((0, 0, 0.085), (0, 0, 0.107), 0.045, "dark"),
    ),
    (),  # link8: the flange frame (no geometry; the hand covers it)
)

# Hand (panda_hand frame: z along the approach, fingers close along y). The palm spans z from
# the flange disk to the finger rails at FINGER_JOINT_Z; the TCP is at HAND_TCP_OFFSET.
_PALM_EXTENTS: Vec3 = (0.062, 0.2, 0.05)
_FLANGE_DISK_Z = FINGER_JOINT_Z - _PALM_EXTENTS[2]
_HAND_PARTS: tuple[_Part, ...] = (
    _box((0, 0, FINGER_JOINT_Z - _PALM_EXTENTS[2] / 2), _PALM_EXTENTS, 0.012, collide=False),
    _cyl((0, 0, 0), (0, 0, _FLANGE_DISK_Z), 0.04, "dark", collide=False),
)
# Palm collision box: the palm plus the flange disk, rigid hydroelastic.
_PALM_COLLISION_CENTER: Vec3 = (0.0, 0.0, FINGER_JOINT_Z / 2)
_PALM_COLLISION_SIZE: Vec3 = (_PALM_EXTENTS[0], _PALM_EXTENTS[1], FINGER_JOINT_Z)

# Finger (left finger frame, origin at the joint on the hand's y = 0 plane when closed; its
# inner side faces -y). Finger pad: 18 mm wide (x), 8 mm along the closing direction, 20 mm
# tall, centred at the TCP height, inner face on the finger frame's y = 0 plane.
PAD_SIZE: Vec3 = (0.018, 0.008, 0.020)
_PAD_CENTER_Z = HAND_TCP_OFFSET - FINGER_JOINT_Z
_FINGER_TIP_Z = _PAD_CENTER_Z + PAD_SIZE[2] / 2
_PAD_CENTER: Vec3 = (0.0, PAD_SIZE[1] / 2, _PAD_CENTER_Z)
_FINGER_BODY_Y = (PAD_SIZE[1], 0.020)  # y range of the rigid finger body
_FINGER_BODY_CENTER: Vec3 = (0.0, sum(_FINGER_BODY_Y) / 2, _FINGER_TIP_Z / 2)
_FINGER_BODY_SIZE: Vec3 = (0.020, _FINGER_BODY_Y[1] - _FINGER_BODY_Y[0], _FINGER_TIP_Z)
_FINGER_PARTS: tuple[_Part, ...] = (
    _box(_FINGER_BODY_CENTER, _FINGER_BODY_SIZE, 0.002, "dark", collide=False),
    _box((0.0, 0.019, 0.006), (0.022, 0.022, 0.012), 0.002, "dark", collide=False),  # rail slider
    _box(_PAD_CENTER, PAD_SIZE, 0.001, "dark", collide=False),
)

# Contact parameters. Finger pads: compliant hydroelastic (Drake's Hydroelastic Contact User Guide:
# modulus ~1e7 Pa, Hunt-Crossley 10-50 s/m, margin 1e-4 m; docs/models.md#sources); rubber-like
# friction ~1.
PAD_HYDROELASTIC_MODULUS = 5.0e6
PAD_RESOLUTION_HINT = 0.004
PAD_HUNT_CROSSLEY = 20.0
PAD_FRICTION = 1.0
HYDROELASTIC_MARGIN = 1.0e-4
HAND_FRICTION = 0.5  # palm and finger bodies: hard plastic / anodised aluminium, a typical 0.5

# --------------------------------------------------------------------------------------------
# Small numeric helpers
# --------------------------------------------------------------------------------------------


def _f(x: float) -> str:
    """Deterministic short float text for URDF attributes (10 significant digits, no '-0')."""
    s = f"{float(x):.10g}"
    return "0" if s in ("-0", "0") else s


def _vec(v: Sequence[float]) -> str:
    return " ".join(_f(x) for x in v)


def _rot_z_to(direction: np.ndarray) -> np.ndarray:
    """Rotation matrix taking +z onto the unit vector `direction` (minimal rotation)."""
    d = direction / np.linalg.norm(direction)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ d)
    if c > 1.0 - 1e-12:
        return np.eye(3)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(z, d)
    s = float(np.linalg.norm(axis))
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def _rpy(rot: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r)) of a rotation matrix."""
    pitch = math.atan2(-rot[2, 0], math.hypot(rot[0, 0], rot[1, 0]))
    if abs(math.cos(pitch)) < 1e-9:
        return np.array([0.0, pitch, math.atan2(-rot[0, 1], rot[1, 1])])
    roll = math.atan2(rot[2, 1], rot[2, 2])
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    return np.array([roll, pitch, yaw])


def _clean(v: np.ndarray) -> np.ndarray:
    """Round away float noise (1e-12) so that 1e-17 and -0 never reach the text."""
    out = np.round(np.asarray(v, dtype=float), 12)
    out[out == 0.0] = 0.0
    return out


# --------------------------------------------------------------------------------------------
# Meshes
# --------------------------------------------------------------------------------------------

_SECTIONS = 32  # facets around a cylinder or capsule
_CAPSULE_COUNT = (24, 12)
_BOX_EDGE_SEGMENTS = 2  # facets along the quarter circle of a rounded box's edges and corners
# Edges between faces meeting at less than this are smoothed (the rounded boxes' 45 degree facets);
# a cylinder's rim (90 degrees) stays sharp.
_SMOOTH_ANGLE = math.radians(50)
# Decimals of the written OBJ values: positions [m] (1 micrometre) and unit normals (%.6f).
_OBJ_DECIMALS = 6


def _segment_transform(a: Vec3, b: Vec3) -> tuple[np.ndarray, float]:
    """Homogeneous transform putting a z-aligned primitive centred at 0 onto segment a-b."""
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    tf = np.eye(4)
    tf[:3, :3] = _rot_z_to(pb - pa)
    tf[:3, 3] = (pa + pb) / 2
    return tf, float(np.linalg.norm(pb - pa))


def _rounded_box(extents: Vec3, rounding: float) -> trimesh.Trimesh:
    """Box centred at the origin with its edges and corners rounded, built by a fixed construction.

    Each of the cube's six faces is a grid of (2n + 2)^2 vertices, n = _BOX_EDGE_SEGMENTS: along
    each grid axis the outward direction turns from the neighbouring face's normal to this face's
    normal in n equal angles, then again from this face's normal to the opposite neighbour's; each
    half of the grid is pushed out to its own side by the half extents less `rounding`, so the
    middle rows are the flat parts. No convex hull is involved (qhull's triangulation of coplanar
    points depends on its build); the vertices that neighbouring faces share coincide up to float
    noise and are merged when the mesh is put in canonical form.

    Arguments:
        extents: full size (x, y, z) [m].
        rounding: radius of the rounded edges and corners [m], more than 0 and less than half of
            every extent.

    Returns:
        The triangle mesh (outward winding), shared vertices not yet merged.
    """
    half = np.asarray(extents, float) / 2 - rounding
    if not rounding > 0 or np.any(half <= 0):
        raise ValueError(f"rounding = {rounding}; expected 0 < rounding < half of every extent {extents}")
    n = _BOX_EDGE_SEGMENTS
    slopes = np.tan(np.linspace(-math.pi / 4, 0.0, n + 1))
    slopes[0], slopes[-1] = -1.0, 0.0
    slopes = np.concatenate([slopes, -slopes[::-1]])  # tangent of the angle from the face normal
    sides = np.repeat([-1.0, 1.0], n + 1)  # which half of the grid (towards which neighbour)
    m = 2 * n + 2
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    k = i[:-1, :-1] * m + j[:-1, :-1]  # lower-left corner of each grid quad
    quads = [k, k + m, k + m + 1, k + 1]  # counter-clockwise seen from outside
    vertices, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            b, c = (axis + 1) % 3, (axis + 2) % 3
            if sign < 0:  # keep (b, c, outward normal) right-handed
                b, c = c, b
            direction = np.zeros((m, m, 3))
            direction[..., axis], direction[..., b], direction[..., c] = sign, slopes[i], slopes[j]
            direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
            offset = np.zeros((m, m, 3))
            offset[..., axis] = sign * half[axis]
            offset[..., b], offset[..., c] = sides[i] * half[b], sides[j] * half[c]
            base = len(vertices) * m * m
            vertices.append((offset + rounding * direction).reshape(-1, 3))
            p00, p10, p11, p01 = (base + q for q in quads)
            faces += [np.stack([p00, p10, p11], -1).reshape(-1, 3), np.stack([p00, p11, p01], -1).reshape(-1, 3)]
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def _part_mesh(part: _Part) -> trimesh.Trimesh:
    """Triangle mesh of one primitive, in the link frame."""
    if part.kind == "box":
        mesh = _rounded_box(part.b, part.r)
        mesh.apply_translation(part.a)
        return mesh
    tf, length = _segment_transform(part.a, part.b)
    if part.kind == "cylinder":
        return trimesh.creation.cylinder(radius=part.r, height=length, sections=_SECTIONS, transform=tf)
    return trimesh.creation.capsule(height=length, radius=part.r, count=list(_CAPSULE_COUNT), transform=tf)


def _canonical_part_mesh(part: _Part, rotation_z: float = 0.0) -> trimesh.Trimesh:
    """`_part_mesh` rotated by `rotation_z` about z, in canonical form (`canonical_mesh`): rounded
    to the written precision and in a fixed order before smooth shading, whose graph steps sort."""
    mesh = _part_mesh(part)
    if rotation_z:
        mesh.apply_transform(trimesh.transformations.rotation_matrix(rotation_z, [0, 0, 1]))
    vertices, faces = canonical_mesh(mesh.vertices, mesh.faces, _OBJ_DECIMALS)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def _obj_text(parts: Sequence[_Part], rotation_z: float = 0.0) -> str:
    """Wavefront OBJ text of the smooth-shaded union of `parts` (see `_smooth_obj_text`)."""
    mesh = trimesh.util.concatenate([_canonical_part_mesh(p, rotation_z) for p in parts])
    mesh = trimesh.graph.smooth_shade(mesh, angle=_SMOOTH_ANGLE)
    return _smooth_obj_text(mesh.vertices, mesh.vertex_normals, mesh.faces)


def _smooth_obj_text(positions: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> str:
    """Wavefront OBJ text of a smooth-shaded mesh, the same for any order of its vertices and faces.

    The (position, normal) rows and the faces are put in `canonical_mesh` form at _OBJ_DECIMALS,
    then written with a fixed %.6f format, one `vn` per `v` and faces as `f i//i j//j k//k`.

    Arguments:
        positions: (N, 3) vertex positions [m].
        normals: (N, 3) unit vertex normals.
        faces: (M, 3) vertex indices, counter-clockwise seen from outside.

    Returns:
        The file text (newline-terminated lines).
    """
    rows, faces = canonical_mesh(np.hstack([positions, normals]), faces, _OBJ_DECIMALS)
    lines = ["# generated by assembly/panda_model.py; do not edit"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in rows[:, :3]]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in rows[:, 3:]]
    lines += ["f " + " ".join(f"{i + 1}//{i + 1}" for i in face) for face in faces]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# URDF text
# --------------------------------------------------------------------------------------------


def _inertial_xml(inertial: _Inertial) -> list[str]:
    ixx, ixy, ixz, iyy, iyz, izz = inertial.inertia
    return [
        "    <inertial>",
        f'      <origin xyz="{_vec(inertial.com)}" rpy="0 0 0"/>',
        f'      <mass value="{_f(inertial.mass)}"/>',
        f'      <inertia ixx="{_f(ixx)}" ixy="{_f(ixy)}" ixz="{_f(ixz)}" iyy="{_f(iyy)}"'
        f' iyz="{_f(iyz)}" izz="{_f(izz)}"/>',
        "    </inertial>",
    ]


def _visual_xml(mesh_file: str, color: Color, rpy: Vec3 = (0.0, 0.0, 0.0)) -> list[str]:
    return [
        "    <visual>",
        f'      <origin xyz="0 0 0" rpy="{_vec(rpy)}"/>',
        f'      <geometry><mesh filename="meshes/{mesh_file}"/></geometry>',
        f'      <material name="panda_{color}"><color rgba="{_RGBA[color]}"/></material>',
        "    </visual>",
    ]


def _proximity_xml(props: dict[str, float] | None, compliance: str | None) -> list[str]:
    if props is None and compliance is None:
        return []
    out = ["      <drake:proximity_properties>"]
    if compliance is not None:
        out.append(f"        <drake:{compliance}_hydroelastic/>")
    for key, value in (props or {}).items():
        out.append(f'        <drake:{key} value="{_f(value)}"/>')
    out.append("      </drake:proximity_properties>")
    return out


def _collision_xml(
    part: _Part, name: str, props: dict[str, float] | None = None, compliance: str | None = None
) -> list[str]:
    """URDF <collision> for a primitive (a rounded box collides as a plain box)."""
    if part.kind == "box":
        xyz, rpy = np.asarray(part.a, float), np.zeros(3)
        geometry = f'<box size="{_vec(part.b)}"/>'
    else:
        tf, length = _segment_transform(part.a, part.b)
        xyz, rpy = tf[:3, 3], _rpy(tf[:3, :3])
        geometry = f'<{part.kind} radius="{_f(part.r)}" length="{_f(length)}"/>'
    return [
        f'    <collision name="{name}">',
        f'      <origin xyz="{_vec(_clean(xyz))}" rpy="{_vec(_clean(rpy))}"/>',
        f"      <geometry>{geometry}</geometry>",
        *_proximity_xml(props, compliance),
        "    </collision>",
    ]


def _dh_joint_origin(row: int) -> tuple[np.ndarray, np.ndarray]:
    """URDF origin (xyz, rpy) of modified-DH row `row`: Rot_x(alpha) Trans_x(a) Trans_z(d)."""
    a, d, alpha = DH_A[row], DH_D[row], DH_ALPHA[row]
    xyz = np.array([a, -math.sin(alpha) * d, math.cos(alpha) * d])
    return _clean(xyz), _clean(np.array([alpha, 0.0, 0.0]))


def _transmission_xml(
    name: str, joint: str, actuator: str, rotor_inertia: float | None = None, gear_ratio: float | None = None
) -> list[str]:
    extra = []
    if rotor_inertia is not None:
        extra.append(f'      <drake:rotor_inertia value="{_f(rotor_inertia)}"/>')
    if gear_ratio is not None:
        extra.append(f'      <drake:gear_ratio value="{_f(gear_ratio)}"/>')
    return [
        f'  <transmission name="{name}">',
        "    <type>transmission_interface/SimpleTransmission</type>",
        f'    <joint name="{joint}">',
        "      <hardwareInterface>hardware_interface/EffortJointInterface</hardwareInterface>",
        "    </joint>",
        f'    <actuator name="{actuator}">',
        "      <hardwareInterface>hardware_interface/EffortJointInterface</hardwareInterface>",
        "      <mechanicalReduction>1</mechanicalReduction>",
        *extra,
        "    </actuator>",
        "  </transmission>",
    ]


def _header(robot: str) -> list[str]:
    return [
        '<?xml version="1.0" encoding="utf-8"?>',
        "<!-- Generated by assembly/panda_model.py (goflow); do not edit. Regenerate with",
        "     `python -m assembly.panda_model`. Sources of every number: see that module. -->",
        f'<robot name="{robot}" xmlns:drake="http://drake.mit.edu">',
    ]


def _link_visuals(stem: str, parts: Sequence[_Part], rotation_z: float = 0.0) -> tuple[list[str], dict[str, str]]:
    """Visual XML and {mesh file: OBJ text} for a link: one mesh per colour."""
    xml: list[str] = []
    meshes: dict[str, str] = {}
    for color in ("white", "dark"):
        chosen = [p for p in parts if p.color == color]
        if not chosen:
            continue
        file = f"{stem}.obj" if color == "white" else f"{stem}_{color}.obj"
        meshes[file] = _obj_text(chosen, rotation_z)
        xml += _visual_xml(file, color)
    return xml, meshes


def _arm_urdf() -> tuple[str, dict[str, str]]:
    """Text of panda_arm.urdf and the OBJ meshes it references."""
    lines = _header("panda_arm")
    meshes: dict[str, str] = {}
    for i, name in enumerate(ARM_LINK_NAMES):
        lines.append(f'  <link name="{name}">')
        if i < len(_ARM_INERTIALS):
            lines += _inertial_xml(_ARM_INERTIALS[i])
        visual, link_meshes = _link_visuals(f"link{i}", _ARM_PARTS[i])
        lines += visual
        meshes.update(link_meshes)
        for k, part in enumerate(p for p in _ARM_PARTS[i] if p.collide):
            lines += _collision_xml(part, f"{name}_collision{k}")
        lines.append("  </link>")
    for row in range(8):
        xyz, rpy = _dh_joint_origin(row)
        parent, child = ARM_LINK_NAMES[row], ARM_LINK_NAMES[row + 1]
        if row < 7:
            lines += [
                f'  <joint name="{ARM_JOINT_NAMES[row]}" type="revolute">',
                f'    <origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>',
                f'    <parent link="{parent}"/>',
                f'    <child link="{child}"/>',
                '    <axis xyz="0 0 1"/>',
                f'    <limit lower="{_f(Q_MIN[row])}" upper="{_f(Q_MAX[row])}"'
                f' effort="{_f(TAU_MAX[row])}" velocity="{_f(V_MAX[row])}"/>',
                f'    <dynamics damping="{_f(JOINT_DAMPING[row])}" friction="0"/>',
                "  </joint>",
            ]
        else:
            lines += [
                '  <joint name="panda_joint8" type="fixed">',
                f'    <origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>',
                f'    <parent link="{parent}"/>',
                f'    <child link="{child}"/>',
                "  </joint>",
            ]
    for row, joint in enumerate(ARM_JOINT_NAMES):
        lines += _transmission_xml(
            f"panda_tran{row + 1}",
            joint,
            f"panda_motor{row + 1}",
            rotor_inertia=float(REFLECTED_INERTIA[row]),
            gear_ratio=1.0,
        )
    # Links 5 and 7 (two apart across the wrist) touch only through our simplified shapes
    # (in ~9% of uniformly drawn configurations): filter that pair.
    for a, b in (("panda_link5", "panda_link7"),):
        group = f"wrist_{a[-1]}{b[-1]}"
        lines += [
            f'  <drake:collision_filter_group name="{group}">',
            f'    <drake:member link="{a}"/>',
            f'    <drake:member link="{b}"/>',
            f'    <drake:ignored_collision_filter_group name="{group}"/>',
            "  </drake:collision_filter_group>",
        ]
    lines.append("</robot>")
    return "\n".join(lines) + "\n", meshes


def _finger_link(name: str, sign: int) -> list[str]:
    """A finger link; sign +1 for the left finger (inner face towards -y), -1 for the right."""
    mirror = np.array([sign, sign, 1.0])  # rotation by pi about z for the right finger
    body_center = tuple(_clean(np.asarray(_FINGER_BODY_CENTER) * mirror))
    inertial = _Inertial(_FINGER_MASS, body_center, _FINGER_INERTIA)
    body = _box(body_center, _FINGER_BODY_SIZE, 0)
    pad = _box(tuple(_clean(np.asarray(_PAD_CENTER) * mirror)), PAD_SIZE, 0)
    pad_props = {
        "hydroelastic_modulus": PAD_HYDROELASTIC_MODULUS,
        "mesh_resolution_hint": PAD_RESOLUTION_HINT,
        "hydroelastic_margin": HYDROELASTIC_MARGIN,
        "hunt_crossley_dissipation": PAD_HUNT_CROSSLEY,
        "mu_dynamic": PAD_FRICTION,
        "mu_static": PAD_FRICTION,
    }
    return [
        f'  <link name="{name}">',
        *_inertial_xml(inertial),
        *_visual_xml("finger_dark.obj", "dark", (0.0, 0.0, math.pi if sign < 0 else 0.0)),
        *_collision_xml(body, f"{name}_body", {"mu_dynamic": HAND_FRICTION, "mu_static": HAND_FRICTION}, "rigid"),
        *_collision_xml(pad, f"{name}_pad", pad_props, "compliant"),
        "  </link>",
    ]


def _hand_urdf() -> tuple[str, dict[str, str]]:
    """Text of panda_hand.urdf and the OBJ meshes it references."""
    lines = _header("panda_hand")
    visual, meshes = _link_visuals("hand", _HAND_PARTS)
    _, finger_meshes = _link_visuals("finger", _FINGER_PARTS)
    meshes.update(finger_meshes)
    palm = _box(_PALM_COLLISION_CENTER, _PALM_COLLISION_SIZE, 0)
    lines += [
        '  <link name="panda_hand">',
        *_inertial_xml(_HAND_INERTIAL),
        *visual,
        *_collision_xml(palm, "panda_hand_palm", {"mu_dynamic": HAND_FRICTION, "mu_static": HAND_FRICTION}, "rigid"),
        "  </link>",
        *_finger_link("panda_leftfinger", +1),
        *_finger_link("panda_rightfinger", -1),
        '  <link name="panda_hand_tcp"/>',
        '  <joint name="panda_hand_tcp_joint" type="fixed">',
        f'    <origin xyz="0 0 {_f(HAND_TCP_OFFSET)}" rpy="0 0 0"/>',
        '    <parent link="panda_hand"/>',
        '    <child link="panda_hand_tcp"/>',
        "  </joint>",
    ]
    for joint, child, axis in zip(FINGER_JOINT_NAMES, ("panda_leftfinger", "panda_rightfinger"), ("0 1 0", "0 -1 0")):
        lines += [
            f'  <joint name="{joint}" type="prismatic">',
            f'    <origin xyz="0 0 {_f(FINGER_JOINT_Z)}" rpy="0 0 0"/>',
            '    <parent link="panda_hand"/>',
            f'    <child link="{child}"/>',
            f'    <axis xyz="{axis}"/>',
            f'    <limit lower="0" upper="{_f(FINGER_JOINT_MAX)}" effort="{_f(FINGER_FORCE_MAX)}"'
            f' velocity="{_f(FINGER_VELOCITY_MAX)}"/>',
            "  </joint>",
        ]
    for k, joint in enumerate(FINGER_JOINT_NAMES, start=1):
        lines += _transmission_xml(f"panda_finger_tran{k}", joint, f"panda_finger_motor{k}")
    lines.append("</robot>")
    return "\n".join(lines) + "\n", meshes


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------

DEFAULT_MODELS_DIR: pathlib.Path = pathlib.Path(__file__).resolve().parent / "models"


def panda_model_paths(models_dir: pathlib.Path | None = None) -> tuple[pathlib.Path, pathlib.Path]:
    """Paths (arm URDF, hand URDF) under `models_dir` (default: the committed assembly/models)."""
    root = pathlib.Path(models_dir) if models_dir is not None else DEFAULT_MODELS_DIR
    return root / "panda" / "panda_arm.urdf", root / "panda" / "panda_hand.urdf"


def write_panda_models(models_dir: pathlib.Path) -> list[pathlib.Path]:
    """Write the arm and hand URDFs and their OBJ meshes under models_dir/panda; return the paths."""
    arm_path, hand_path = panda_model_paths(models_dir)
    arm_text, arm_meshes = _arm_urdf()
    hand_text, hand_meshes = _hand_urdf()
    mesh_dir = arm_path.parent / "meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    files = {arm_path: arm_text, hand_path: hand_text}
    files.update({mesh_dir / name: text for name, text in {**arm_meshes, **hand_meshes}.items()})
    written = []
    for path in sorted(files):
        path.write_bytes(files[path].encode("utf-8"))
        written.append(path)
    return written


if __name__ == "__main__":
    for written_path in write_panda_models(DEFAULT_MODELS_DIR):
        print(written_path.relative_to(DEFAULT_MODELS_DIR.parent.parent))
