"""Meshes and Drake model files (SDFormat 1.9) for the gear plate, its shafts, the three gears and the table.

Everything here is generated from the dimensions and frames in `assembly.gearset`; run

    python -m assembly.gear_meshes

to regenerate `assembly/models/gearset/` (byte-identical on any machine: vertices rounded to
`OBJ_DECIMALS` as soon as they are made, every written mesh put in the canonical vertex and face order
of `canonical_mesh`, fixed float formats, no timestamps).

Geometry and contact design (dimensions: IndustReal's gear assets, Tang et al., RSS 2023; contact:
Drake's Hydroelastic Contact User Guide; sources per fact: docs/models.md#sources):
  * Gear visual: an involute spur gear (module 1 mm, 20 degree pressure angle) with a chamfered bore;
    watertight, so that mass, centre of mass and inertia come from it at `GEAR_DENSITY`.
  * Gear collision: a lean rigid-hydroelastic annulus. The outside is a prism circumscribing the tip
    circle; the bore is a 32-sided prism whose inscribed radius is the 5 mm bore radius (so the 0.5 mm
    radial clearance over the 4.5 mm shaft is kept on every face), with 1 mm x 45 degree chamfers at
    both ends. The teeth are visual only: gear-to-gear contact is filtered by the station.
  * Plate: a compliant-hydroelastic 150 x 75 x 5 mm box; shafts: compliant-hydroelastic convex meshes
    (32-sided cylinders with their vertices on the 4.5 mm radius and a 1 mm top chamfer).
  * Table: a compliant-hydroelastic 1.2 x 1.0 x 0.05 m box whose top face is z = 0 of its model frame.
Rigid gears against compliant shafts/plate/table/fingers: Drake does not support rigid-rigid
hydroelastic pairs, which would fall back to point contact, where a mesh becomes its convex hull.
Plate and table collisions are convex box meshes and the collision prisms stay coarse, for speed
(measured: docs/models.md#contact-geometry-and-speed).
"""

from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass

import mapbox_earcut
import numpy as np
import trimesh

from assembly import gearset
from assembly.gearset import GearSpec

__all__ = [
    "GEAR_PRESSURE_ANGLE",
    "GEAR_COLLISION_SIDES",
    "BORE_COLLISION_SIDES",
    "SHAFT_COLLISION_SIDES",
    "SHAFT_BOTTOM_BELOW_PLATE_TOP",
    "TABLE_SIZE",
    "TABLE_CENTER_X",
    "PLATE_BODY_NAME",
    "TABLE_BODY_NAME",
    "ContactProperties",
    "GEAR_CONTACT",
    "PLATE_CONTACT",
    "SHAFT_CONTACT",
    "TABLE_CONTACT",
    "MassProperties",
    "OBJ_DECIMALS",
    "TriangleMesh",
    "canonical_mesh",
    "canonical_obj_geometry",
    "gear_body_name",
    "shaft_collision_name",
    "involute_outline",
    "gear_visual_mesh",
    "gear_collision_mesh",
    "shaft_mesh",
    "box_mesh",
    "write_obj",
    "read_obj",
    "write_gearset_models",
    "gearset_model_paths",
]

# --------------------------------------------------------------------------------------------------
# Constants of the generated models
# --------------------------------------------------------------------------------------------------

#: Standard involute pressure angle [rad] (ISO 53 basic rack).
GEAR_PRESSURE_ANGLE = math.radians(20.0)
#: Sides of the collision prism around the tip circle (circumscribed: never inside the tip circle).
GEAR_COLLISION_SIDES = 48
#: Sides of the collision bore prism (inscribed radius = bore radius).
BORE_COLLISION_SIDES = 32
#: Sides of the visual bore (a finer circle; vertices on the bore radius).
BORE_VISUAL_SIDES = 48
#: Sides of the shaft's convex collision mesh (vertices on the shaft radius).
SHAFT_COLLISION_SIDES = 32
#: Sides of the shaft's visual mesh.
SHAFT_VISUAL_SIDES = 64
#: The shafts reach this far into the plate below its top face [m] (no gap at the shaft foot).
SHAFT_BOTTOM_BELOW_PLATE_TOP = 0.001
#: Involute flank samples (per flank) and intermediate points on tip and root arcs of the visual gear.
FLANK_SAMPLES = 5
TIP_ARC_POINTS = 1
ROOT_ARC_POINTS = 2

#: Table top: 1.2 m (x) by 1.0 m (y) by 5 cm thick, centred at x = 0.35 m so that the robot base
#: (origin) and the workspace out to x ~ 0.75 m sit on it; top face at z = 0.
TABLE_SIZE = (1.2, 1.0, 0.05)
TABLE_CENTER_X = 0.35

PLATE_BODY_NAME = "gear_plate"
TABLE_BODY_NAME = "table"

# Densities of the parts that are welded to the world (their inertia only has to be plausible).
_PLATE_DENSITY = 2700.0  # aluminium [kg/m^3]
_SHAFT_DENSITY = 7850.0  # steel [kg/m^3]
_TABLE_DENSITY = 600.0  # wood [kg/m^3]

_PLATE_RGBA = (0.62, 0.64, 0.67, 1.0)  # grey metal
_SHAFT_RGBA = (0.80, 0.81, 0.83, 1.0)  # steel
_TABLE_RGBA = (0.62, 0.45, 0.28, 1.0)  # wood

# Output layout.
_SUBDIR = "gearset"
_MESH_SUBDIR = "meshes"
#: Decimals of the vertex coordinates [m] written to the gear-set OBJ files: 0.1 micrometre, far below
#: any feature size. Vertices are rounded to it before any step whose result depends on their order.
OBJ_DECIMALS = 7
_OBJ_FLOAT = f"%.{OBJ_DECIMALS}f"
_NORMAL_FLOAT = "%.6f"


@dataclass(frozen=True)
class ContactProperties:
    """Drake proximity properties of one collision geometry (written as `drake:` SDF elements).

    compliance: "rigid" or "compliant" hydroelastic.
    hydroelastic_modulus [Pa] and mesh_resolution_hint [m] are only written for compliant geometry.
    hunt_crossley_dissipation [s/m]; mu_dynamic, mu_static: Coulomb friction coefficients.
    """

    compliance: str
    mu_dynamic: float
    mu_static: float
    hunt_crossley_dissipation: float
    hydroelastic_modulus: float | None = None
    mesh_resolution_hint: float | None = None

    def __post_init__(self) -> None:
        if self.compliance not in ("rigid", "compliant"):
            raise ValueError(f"compliance must be 'rigid' or 'compliant', got {self.compliance!r}")
        if self.compliance == "compliant" and self.hydroelastic_modulus is None:
            raise ValueError("compliant hydroelastic geometry needs a hydroelastic_modulus")
        if self.mu_static < self.mu_dynamic:
            raise ValueError(f"mu_static ({self.mu_static}) must be >= mu_dynamic ({self.mu_dynamic})")


# Contact parameters (Drake's Hydroelastic Contact User Guide: modulus ~1e7 Pa, Hunt-Crossley
# 10-50 s/m; docs/models.md#sources).
# Friction: dry sliding of FDM-printed PLA on steel is measured in pin-on-disc tests (e.g. Palaniandy,
# Ismail & Yap, "Tribological behaviour of 3D printed PLA sliding against steel at different sliding
# speed", J. Phys.: Conf. Ser., 2023); reported coefficients scatter with print parameters, load and
# speed, and ~0.3-0.4 is the typical band for slow sliding, so the gears take 0.35 (dynamic) / 0.40
# (static) and the steel/aluminium parts 0.3. Drake combines two geometries' coefficients as
# 2 mu1 mu2 / (mu1 + mu2): gear on shaft or plate slides at ~0.32. It is a randomised parameter anyway.
# Drake ignores mesh_resolution_hint for convex meshes (it fans tetrahedra from the hull's centroid)
# and for boxes; the hints are written so that a swap to a primitive keeps a sensible resolution.
GEAR_CONTACT = ContactProperties("rigid", mu_dynamic=0.35, mu_static=0.40, hunt_crossley_dissipation=20.0)
PLATE_CONTACT = ContactProperties(
    "compliant",
    mu_dynamic=0.3,
    mu_static=0.3,
    hunt_crossley_dissipation=20.0,
    # The plate is only touched by flat gear bottoms: a coarse mesh suffices.
    hydroelastic_modulus=1e7,
    mesh_resolution_hint=0.01,
)
SHAFT_CONTACT = ContactProperties(
    "compliant",
    mu_dynamic=0.3,
    mu_static=0.3,
    hunt_crossley_dissipation=20.0,
    # ~1 mm resolution for a 4.5 mm shaft (Drake's 2 cm default is far too coarse; docs/models.md#sources).
    hydroelastic_modulus=1e7,
    mesh_resolution_hint=0.001,
)
TABLE_CONTACT = ContactProperties(
    "compliant",
    mu_dynamic=0.5,
    mu_static=0.5,
    hunt_crossley_dissipation=20.0,
    hydroelastic_modulus=1e7,
    mesh_resolution_hint=0.05,
)


def gear_body_name(name: str) -> str:
    """Name of the gear's model and of its single body (link), e.g. "gear_medium"."""
    return f"gear_{gearset.gear_spec(name).name}"


def shaft_collision_name(name: str) -> str:
    """Name of shaft `name`'s collision geometry in the gear plate model, e.g. "shaft_medium"."""
    return f"shaft_{gearset.gear_spec(name).name}"


# --------------------------------------------------------------------------------------------------
# Triangle meshes
# --------------------------------------------------------------------------------------------------


def canonical_mesh(vertices: np.ndarray, faces: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """The canonical form of an indexed triangle mesh: one vertex and face order for the same geometry.

    Every mesh writer of the generated models (gear set and Panda) goes through this function, so that
    a written file does not depend on the order in which a library or a CPU-specific sort produced the
    vertices and faces (trimesh's merging and graph steps use unstable sorts whose order of ties
    depends on numpy's SIMD dispatch), nor on float noise below the written precision.

    Steps: every vertex value is rounded to `decimals` (-0.0 becomes 0.0); vertices no face uses are
    dropped; vertex rows equal after rounding are merged; the rows are sorted lexicographically (first
    column first) and the faces re-indexed; each face is rotated so that its smallest index comes first
    (a cyclic shift: the winding, hence the normal, is kept); the faces are sorted lexicographically.
    The result is the same for any permutation of the vertices, of the faces and any cyclic rotation
    of each face's indices, and canonical_mesh of its own output returns it unchanged.

    Arguments:
        vertices: (N, D) vertex rows: the position (x, y, z), optionally followed by per-vertex
            attributes that travel with it (e.g. a normal: D = 6). Finite.
        faces: (M, 3) vertex indices (0-based) of the triangles.
        decimals: decimals every vertex value is rounded to (that of the written text, so that two
            rows that print alike are one vertex).

    Returns:
        (vertices, faces): the distinct rounded rows (K, D) in lexicographic order and the faces
        (M, 3, int64) as indices into them, in the canonical order. Raises ValueError for non-finite
        vertices, indices out of range, or a face whose corners merge when rounded.
    """
    rows = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if rows.ndim != 2 or rows.shape[1] < 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"vertices {rows.shape}, faces {faces.shape}; expected (N, D >= 3) and (M, 3)")
    if not np.all(np.isfinite(rows)):
        raise ValueError("vertices must be finite")
    if faces.size and (faces.min() < 0 or faces.max() >= len(rows)):
        raise ValueError(f"face indices must lie in [0, {len(rows)})")
    rows = np.round(rows, decimals) + 0.0  # round first: the order below sees only written values
    used = np.unique(faces)
    order = used[np.lexsort(rows[used].T[::-1])]  # first column is the primary key
    sorted_rows = rows[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(sorted_rows[1:] != sorted_rows[:-1], axis=1)
    new_index = np.full(len(rows), -1, dtype=np.int64)
    new_index[order] = np.cumsum(first) - 1
    out = new_index[faces]
    collapsed = (out[:, 0] == out[:, 1]) | (out[:, 1] == out[:, 2]) | (out[:, 2] == out[:, 0])
    if np.any(collapsed):
        raise ValueError(f"{int(collapsed.sum())} faces lose a corner when vertices are rounded to {decimals} decimals")
    shift = np.argmin(out, axis=1)[:, None]
    out = np.take_along_axis(out, (shift + np.arange(3)) % 3, axis=1)
    out = out[np.lexsort(out.T[::-1])]
    return sorted_rows[first], out


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle mesh: vertices (N, 3) in metres and faces (M, 3) of vertex indices, counter-
    clockwise seen from outside (outward normals)."""

    vertices: np.ndarray
    faces: np.ndarray

    def rounded(self, decimals: int = OBJ_DECIMALS) -> "TriangleMesh":
        """The same mesh with vertices rounded as written to OBJ (and -0.0 turned into 0.0)."""
        return TriangleMesh(np.round(self.vertices, decimals) + 0.0, self.faces)

    def canonical(self, decimals: int = OBJ_DECIMALS) -> "TriangleMesh":
        """The same mesh in the canonical vertex and face order of `canonical_mesh` (rounded to
        `decimals`; vertices that round alike merged; winding kept)."""
        return TriangleMesh(*canonical_mesh(self.vertices, self.faces, decimals))

    def to_trimesh(self) -> trimesh.Trimesh:
        """A trimesh.Trimesh with the same vertices and faces (no merging or reordering)."""
        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, process=False)

    def face_normals(self) -> np.ndarray:
        """Unit outward normals, one per face."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        n = np.cross(b - a, c - a)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


class _MeshBuilder:
    """Collects vertex rings (closed loops) and faces of a solid bounded by ring strips and caps."""

    def __init__(self) -> None:
        self._vertices: list[np.ndarray] = []
        self._faces: list[np.ndarray] = []
        self._count = 0

    def ring(self, xy: np.ndarray, z: float) -> np.ndarray:
        """Adds the closed loop `xy` (K, 2), counter-clockwise seen from +z, at height z; returns
        the indices of its vertices. The vertices are rounded to OBJ_DECIMALS here, before the cap
        triangulation sees them, so that float noise of the trigonometry (numpy's SIMD paths differ
        by CPU) cannot change a triangulation."""
        xyz = np.round(np.column_stack([xy, np.full(len(xy), z)]), OBJ_DECIMALS) + 0.0
        idx = np.arange(self._count, self._count + len(xy))
        self._vertices.append(xyz)
        self._count += len(xy)
        return idx

    def strip(self, lower: np.ndarray, upper: np.ndarray, facing_axis: bool) -> None:
        """Two triangles per quad (lower_k, lower_k+1, upper_k+1, upper_k) between two closed rings
        with the same vertex count, quad by quad. Normals point away from the z axis (an outer wall)
        unless `facing_axis` (a bore wall)."""
        a, b = lower, np.roll(lower, -1)
        c, d = np.roll(upper, -1), upper
        tris = np.stack([np.column_stack([a, b, c]), np.column_stack([a, c, d])], axis=1).reshape(-1, 3)
        self._faces.append(tris[:, ::-1] if facing_axis else tris)

    def cap(self, outer: np.ndarray, hole: np.ndarray | None, up: bool) -> None:
        """Triangulates the planar face bounded by ring `outer` (and ring `hole`, if any) with
        normals along +z if `up`, else -z (earcut: a polygon with one hole of V vertices in all
        gets V triangles)."""
        loops = [outer] if hole is None else [outer, hole]
        idx = np.concatenate(loops)
        xy = np.concatenate([self._vertices_of(loop)[:, :2] for loop in loops])
        ends = np.cumsum([len(loop) for loop in loops]).astype(np.uint32)
        tris = np.asarray(mapbox_earcut.triangulate_float64(xy, ends), dtype=np.int64).reshape(-1, 3)
        p = xy[tris]
        area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
            p[:, 2, 0] - p[:, 0, 0]
        )
        flip = (area2 < 0) if up else (area2 > 0)
        tris[flip] = tris[flip][:, ::-1]
        self._faces.append(idx[tris])

    def _vertices_of(self, ring: np.ndarray) -> np.ndarray:
        return np.concatenate(self._vertices)[ring]

    def build(self) -> TriangleMesh:
        """The mesh in canonical order (`canonical_mesh`), vertices at the OBJ precision: what is
        written is what mass properties are computed from, summed in a machine-independent order."""
        mesh = TriangleMesh(np.concatenate(self._vertices), np.concatenate(self._faces).astype(np.int64))
        return mesh.canonical()


def _regular_polygon(sides: int, circumradius: float, phase: float = 0.0) -> np.ndarray:
    """(sides, 2) vertices of a regular polygon, counter-clockwise, first vertex at angle `phase`."""
    angles = phase + 2.0 * np.pi * np.arange(sides) / sides
    return circumradius * np.column_stack([np.cos(angles), np.sin(angles)])


def _polar(radius: np.ndarray | float, angle: np.ndarray | float) -> np.ndarray:
    radius, angle = np.broadcast_arrays(np.asarray(radius, float), np.asarray(angle, float))
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


def _involute_function(pressure_angle: np.ndarray | float) -> np.ndarray:
    """inv(alpha) = tan(alpha) - alpha: polar angle of the involute point with pressure angle alpha."""
    return np.tan(pressure_angle) - pressure_angle


def involute_outline(
    spec: GearSpec,
    flank_samples: int = FLANK_SAMPLES,
    tip_points: int = TIP_ARC_POINTS,
    root_points: int = ROOT_ARC_POINTS,
) -> np.ndarray:
    """Closed outline (K, 2) of an involute spur gear, counter-clockwise, in the gear frame [m].

    Module `gearset.GEAR_MODULE`, 20 degree pressure angle, tooth thickness half the circular pitch on
    the pitch circle (the backlash is in the shaft spacing), tip radius `spec.tip_radius`, root radius
    `spec.root_radius`. Below the base circle a flank continues radially down to the root circle (no
    trochoidal fillet). Tooth 0 is centred on the +x axis.
    """
    base_radius = spec.pitch_radius * math.cos(GEAR_PRESSURE_ANGLE)
    tip, root = spec.tip_radius, spec.root_radius
    if not root < spec.pitch_radius < tip:
        raise ValueError(f"gear {spec.name!r}: need root < pitch < tip radius, got {root}, {spec.pitch_radius}, {tip}")
    # Flank half-angle from the tooth's centre line at radius r (>= base radius).
    half_at_pitch = np.pi / (2 * spec.teeth) + _involute_function(GEAR_PRESSURE_ANGLE)

    def half_angle(r: np.ndarray) -> np.ndarray:
        return half_at_pitch - _involute_function(np.arccos(np.minimum(base_radius / r, 1.0)))

    # Sample the involute uniformly in its roll angle (denser where it curves most).
    start = max(base_radius, root)
    roll = np.linspace(
        math.sqrt((start / base_radius) ** 2 - 1.0), math.sqrt((tip / base_radius) ** 2 - 1.0), flank_samples
    )
    flank_r = base_radius * np.sqrt(1.0 + roll**2)
    flank_half = half_angle(flank_r)
    if flank_half[-1] <= 0.0:
        raise ValueError(f"gear {spec.name!r}: teeth are pointed before the tip circle")
    if root < base_radius:  # radial segment from the root circle up to the base circle
        flank_r = np.concatenate([[root], flank_r])
        flank_half = np.concatenate([[flank_half[0]], flank_half])
    pitch_angle = spec.tooth_pitch_angle
    root_half = flank_half[0]
    if root_half >= 0.5 * pitch_angle:
        raise ValueError(f"gear {spec.name!r}: no space between teeth at the root circle")

    tip_frac = np.arange(1, tip_points + 1) / (tip_points + 1)
    tip_angles = -flank_half[-1] + 2.0 * flank_half[-1] * tip_frac
    root_frac = np.arange(1, root_points + 1) / (root_points + 1)
    root_angles = root_half + (pitch_angle - 2.0 * root_half) * root_frac
    one_tooth = np.concatenate(
        [
            _polar(flank_r, -flank_half),  # rising flank (clockwise side of the tooth)
            _polar(tip, tip_angles),  # tip land
            _polar(flank_r[::-1], flank_half[::-1]),  # falling flank
            _polar(root, root_angles),  # root land up to the next tooth
        ]
    )
    teeth = []
    for k in range(spec.teeth):
        c, s = math.cos(k * pitch_angle), math.sin(k * pitch_angle)
        teeth.append(one_tooth @ np.array([[c, s], [-s, c]]))
    return np.concatenate(teeth)


def _bored_prism(
    outer_xy: np.ndarray, bore_sides: int, bore_circumradius: float, chamfer_circumradius: float, bore_phase: float
) -> TriangleMesh:
    """A prism of height `GEAR_THICKNESS` over the outline `outer_xy`, with a bore: a regular
    `bore_sides`-gon prism of circumradius `bore_circumradius`, widened by 45 degree chamfers to
    `chamfer_circumradius` at both faces (z = 0 and z = GEAR_THICKNESS)."""
    h, ch = gearset.GEAR_THICKNESS, gearset.GEAR_BORE_CHAMFER
    builder = _MeshBuilder()
    outer_bottom = builder.ring(outer_xy, 0.0)
    outer_top = builder.ring(outer_xy, h)
    builder.strip(outer_bottom, outer_top, facing_axis=False)
    bore_profile = [
        (0.0, chamfer_circumradius),
        (ch, bore_circumradius),
        (h - ch, bore_circumradius),
        (h, chamfer_circumradius),
    ]
    bore = [builder.ring(_regular_polygon(bore_sides, r, bore_phase), z) for z, r in bore_profile]
    for lower, upper in zip(bore[:-1], bore[1:]):
        builder.strip(lower, upper, facing_axis=True)
    builder.cap(outer_bottom, bore[0], up=False)
    builder.cap(outer_top, bore[-1], up=True)
    return builder.build()


def gear_visual_mesh(spec: GearSpec) -> TriangleMesh:
    """Watertight visual mesh of gear `spec` in frame G (origin on the bore axis at the bottom face,
    z up): involute teeth, thickness GEAR_THICKNESS, bore GEAR_BORE_RADIUS with 45 degree chamfers."""
    r, ch = gearset.GEAR_BORE_RADIUS, gearset.GEAR_BORE_CHAMFER
    return _bored_prism(involute_outline(spec), BORE_VISUAL_SIDES, r, r + ch, bore_phase=0.0)


def gear_collision_mesh(spec: GearSpec) -> TriangleMesh:
    """Lean collision mesh of gear `spec` in frame G: a GEAR_COLLISION_SIDES-gon circumscribing the tip
    circle, and a BORE_COLLISION_SIDES-gon bore whose inscribed radius is GEAR_BORE_RADIUS (so the
    radial clearance to the shaft is never below 0.5 mm), chamfered at both ends."""
    n_out, n_bore = GEAR_COLLISION_SIDES, BORE_COLLISION_SIDES
    outer = _regular_polygon(n_out, spec.tip_radius / math.cos(math.pi / n_out), phase=math.pi / n_out)
    to_circum = 1.0 / math.cos(math.pi / n_bore)
    r, ch = gearset.GEAR_BORE_RADIUS, gearset.GEAR_BORE_CHAMFER
    return _bored_prism(outer, n_bore, r * to_circum, (r + ch) * to_circum, bore_phase=math.pi / n_bore)


def _convex_stack(rings: list[tuple[np.ndarray, float]]) -> TriangleMesh:
    """The closed solid through closed loops (K, 2) stacked at increasing heights z (each loop
    counter-clockwise seen from +z, all with the same vertex count): side strips plus two caps."""
    builder = _MeshBuilder()
    ids = [builder.ring(xy, z) for xy, z in rings]
    for lower, upper in zip(ids[:-1], ids[1:]):
        builder.strip(lower, upper, facing_axis=False)
    builder.cap(ids[0], None, up=False)
    builder.cap(ids[-1], None, up=True)
    return builder.build()


def shaft_mesh(sides: int) -> TriangleMesh:
    """A shaft in its frame S (origin on the axis at the plate's top face, z up): a regular `sides`-gon
    prism with its vertices on SHAFT_RADIUS, from SHAFT_BOTTOM_BELOW_PLATE_TOP below the plate top to
    SHAFT_HEIGHT above it, with a SHAFT_CHAMFER x 45 degree chamfer at the top. Convex."""
    r, h, ch = gearset.SHAFT_RADIUS, gearset.SHAFT_HEIGHT, gearset.SHAFT_CHAMFER
    profile = [(-SHAFT_BOTTOM_BELOW_PLATE_TOP, r), (h - ch, r), (h, r - ch)]
    return _convex_stack([(_regular_polygon(sides, radius), z) for z, radius in profile])


def box_mesh(size: tuple[float, float, float]) -> TriangleMesh:
    """A box of extents `size` centred at the origin: 8 vertices, 12 triangles."""
    hx, hy, hz = (0.5 * float(v) for v in size)
    rectangle = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return _convex_stack([(rectangle, -hz), (rectangle, hz)])


# --------------------------------------------------------------------------------------------------
# Mass properties
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MassProperties:
    """Mass [kg], centre of mass [m] and rotational inertia about the centre of mass [kg m^2], all
    expressed in the body frame."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray

    @staticmethod
    def of_mesh(
        mesh: TriangleMesh | trimesh.Trimesh, density: float, offset: np.ndarray | None = None
    ) -> "MassProperties":
        """Mass properties of a closed mesh of uniform `density`, translated by `offset`."""
        tm = mesh.to_trimesh() if isinstance(mesh, TriangleMesh) else mesh
        if not tm.is_volume:
            raise ValueError("mass properties need a closed, consistently oriented mesh")
        props = tm.mass_properties
        scale = density / props.density
        com = np.asarray(props.center_mass, float) + (0.0 if offset is None else np.asarray(offset, float))
        return MassProperties(float(props.mass) * scale, com, np.asarray(props.inertia, float) * scale)

    @staticmethod
    def combine(parts: list["MassProperties"]) -> "MassProperties":
        """The mass properties of rigidly joined parts (parallel-axis theorem)."""
        mass = sum(p.mass for p in parts)
        com = sum(p.mass * p.com for p in parts) / mass
        inertia = np.zeros((3, 3))
        for p in parts:
            d = p.com - com
            inertia += p.inertia + p.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return MassProperties(mass, com, inertia)


def _box_mass_properties(size: tuple[float, float, float], density: float, center: np.ndarray) -> MassProperties:
    return MassProperties.of_mesh(box_mesh(size), density, offset=center)


# --------------------------------------------------------------------------------------------------
# Writers: OBJ and SDFormat
# --------------------------------------------------------------------------------------------------


def _fixed(value: float, fmt: str) -> str:
    text = fmt % value
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text  # no "-0.000"


def write_obj(mesh: TriangleMesh, path: pathlib.Path, normals: bool = False) -> pathlib.Path:
    """Writes `mesh` as a Wavefront OBJ in canonical order (`canonical_mesh` at OBJ_DECIMALS) with
    fixed-precision floats: the same geometry gives the same bytes on any machine.

    Arguments:
        mesh: the triangle mesh (outward winding); any vertex and face order.
        path: the file to write (its folder is created).
        normals: also write per-face (flat) normals, numbered in order of first use and referenced
            as `f v//vn ...`.

    Returns:
        `path`.
    """
    mesh = mesh.canonical()
    lines = [
        f"# {path.name}: generated by assembly/gear_meshes.py; units: metres",
        f"# {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles",
    ]
    lines += ["v " + " ".join(_fixed(c, _OBJ_FLOAT) for c in v) for v in mesh.vertices]
    faces = mesh.faces + 1
    if normals:
        normal_text = [" ".join(_fixed(c, _NORMAL_FLOAT) for c in n) for n in mesh.face_normals()]
        unique: dict[str, int] = {}
        for text in normal_text:
            unique.setdefault(text, len(unique) + 1)
        lines += [f"vn {text}" for text in unique]
        lines += [f"f {a}//{n} {b}//{n} {c}//{n}" for (a, b, c), n in zip(faces, (unique[t] for t in normal_text))]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", newline="\n")
    return path


def read_obj(path: pathlib.Path) -> TriangleMesh:
    """Reads the vertices and triangles of an OBJ file as written by `write_obj` (normals ignored,
    vertices not merged or reordered)."""
    vertices, faces = [], []
    for line in pathlib.Path(path).read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(t) for t in line.split()[1:4]])
        elif line.startswith("f "):
            faces.append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
    return TriangleMesh(np.array(vertices, float), np.array(faces, np.int64))


def canonical_obj_geometry(path: pathlib.Path, decimals: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """The geometry of a triangle OBJ file, independent of how the file orders and indexes it.

    Each face corner becomes a row: its position, followed by its normal where the face references
    one (`f v//vn`); the rows and faces are then put in `canonical_mesh` form. Two files hold the
    same shaded geometry exactly when their results are equal.

    Arguments:
        path: an OBJ file of `v`, optional `vn` and triangular `f` lines (such as this project writes).
        decimals: rounding of the values read (default finer than any precision written here).

    Returns:
        (rows, faces): rows (K, 3) or (K, 6) and faces (M, 3), as `canonical_mesh` returns them.
    """
    positions, normals, corners = [], [], []
    for line in pathlib.Path(path).read_text().splitlines():
        if line.startswith("v "):
            positions.append([float(t) for t in line.split()[1:4]])
        elif line.startswith("vn "):
            normals.append([float(t) for t in line.split()[1:4]])
        elif line.startswith("f "):
            tokens = line.split()[1:]
            if len(tokens) != 3:
                raise ValueError(f"{path}: {line!r}; expected a triangle")
            for token in tokens:
                parts = token.split("/")
                corners.append((int(parts[0]) - 1, int(parts[2]) - 1 if len(parts) > 2 else -1))
    index = np.array(corners, dtype=np.int64).reshape(-1, 2)
    rows = np.asarray(positions, float)[index[:, 0]]
    if np.any(index[:, 1] >= 0):
        if np.any(index[:, 1] < 0):
            raise ValueError(f"{path}: some faces reference normals and some do not")
        rows = np.hstack([rows, np.asarray(normals, float)[index[:, 1]]])
    return canonical_mesh(rows, np.arange(len(rows)).reshape(-1, 3), decimals)


def _num(value: float) -> str:
    """Compact, deterministic text of a float for SDF (9 significant digits, no -0)."""
    text = f"{value:.9g}"
    return "0" if float(text) == 0.0 else text


def _vec(values) -> str:
    return " ".join(_num(float(v)) for v in values)


def _pose(xyz=(0.0, 0.0, 0.0)) -> str:
    return f"<pose>{_vec(xyz)} 0 0 0</pose>"


def _mesh_geometry(uri: str, convex: bool = False) -> str:
    convex_tag = "<drake:declare_convex/>" if convex else ""
    return f"<mesh><uri>{uri}</uri>{convex_tag}</mesh>"


def _box_geometry(size) -> str:
    return f"<box><size>{_vec(size)}</size></box>"


def _visual(name: str, geometry: str, rgba, xyz=(0.0, 0.0, 0.0)) -> str:
    return f"""
      <visual name="{name}">
        {_pose(xyz)}
        <geometry>{geometry}</geometry>
        <material><diffuse>{_vec(rgba)}</diffuse></material>
      </visual>"""


def _collision(name: str, geometry: str, contact: ContactProperties, xyz=(0.0, 0.0, 0.0)) -> str:
    props = [f"<drake:{contact.compliance}_hydroelastic/>"]
    if contact.compliance == "compliant":
        props.append(f"<drake:hydroelastic_modulus>{_num(contact.hydroelastic_modulus)}</drake:hydroelastic_modulus>")
        if contact.mesh_resolution_hint is not None:
            props.append(
                f"<drake:mesh_resolution_hint>{_num(contact.mesh_resolution_hint)}</drake:mesh_resolution_hint>"
            )
    props += [
        f"<drake:hunt_crossley_dissipation>{_num(contact.hunt_crossley_dissipation)}</drake:hunt_crossley_dissipation>",
        f"<drake:mu_dynamic>{_num(contact.mu_dynamic)}</drake:mu_dynamic>",
        f"<drake:mu_static>{_num(contact.mu_static)}</drake:mu_static>",
    ]
    body = "\n          ".join(props)
    return f"""
      <collision name="{name}">
        {_pose(xyz)}
        <geometry>{geometry}</geometry>
        <drake:proximity_properties>
          {body}
        </drake:proximity_properties>
      </collision>"""


def _inertial(props: MassProperties) -> str:
    inertia = props.inertia.copy()
    inertia[np.abs(inertia) < 1e-12 * np.trace(inertia)] = 0.0  # numerical noise off the diagonal
    com = np.where(np.abs(props.com) < 1e-12, 0.0, props.com)  # likewise (a symmetric gear: 1e-19 m)
    (ixx, ixy, ixz), (_, iyy, iyz), (_, _, izz) = inertia
    return (
        f"""
      <inertial>
        {_pose(com)}
        <mass>{_num(props.mass)}</mass>
        <inertia><ixx>{_num(ixx)}</ixx><ixy>{_num(ixy)}</ixy><ixz>{_num(ixz)}</ixz>"""
        f"<iyy>{_num(iyy)}</iyy><iyz>{_num(iyz)}</iyz><izz>{_num(izz)}</izz></inertia>\n"
        "      </inertial>"
    )


def _sdf_model(name: str, comment: str, elements: list[str]) -> str:
    """A one-link SDFormat 1.9 model whose link (named like the model) is at the model frame."""
    body = "".join(elements)
    return f"""<?xml version="1.0"?>
<!-- {comment}
     Generated by assembly/gear_meshes.py: do not edit; regenerate with
     `python -m assembly.gear_meshes`. -->
<sdf version="1.9" xmlns:drake="http://drake.mit.edu">
  <model name="{name}">
    <link name="{name}">{body}
    </link>
  </model>
</sdf>
"""


def _mesh_uri(filename: str) -> str:
    return f"{_MESH_SUBDIR}/{filename}"


def _gear_files(spec: GearSpec, out_dir: pathlib.Path) -> list[pathlib.Path]:
    name = gear_body_name(spec.name)
    visual, collision = gear_visual_mesh(spec), gear_collision_mesh(spec)
    visual_file, collision_file = f"{name}_visual.obj", f"{name}_collision.obj"
    paths = [
        write_obj(visual, out_dir / _MESH_SUBDIR / visual_file, normals=True),
        write_obj(collision, out_dir / _MESH_SUBDIR / collision_file),
    ]
    comment = (
        f"{spec.name} spur gear: {spec.teeth} teeth, module {gearset.GEAR_MODULE * 1e3:g} mm, "
        f"tip radius {spec.tip_radius * 1e3:g} mm. Link frame = gear frame G (origin on the bore "
        "axis at the bottom face, z up); tooth 0 centred on +x."
    )
    sdf = _sdf_model(
        name,
        comment,
        [
            _inertial(MassProperties.of_mesh(visual, gearset.GEAR_DENSITY)),
            _visual("visual", _mesh_geometry(_mesh_uri(visual_file)), spec.rgba),
            _collision("collision", _mesh_geometry(_mesh_uri(collision_file)), GEAR_CONTACT),
        ],
    )
    sdf_path = out_dir / f"{name}.sdf"
    sdf_path.write_text(sdf, newline="\n")
    return [sdf_path, *paths]


def _plate_files(out_dir: pathlib.Path) -> list[pathlib.Path]:
    visual_file, collision_file = "shaft_visual.obj", "shaft_collision.obj"
    plate_file = "plate_collision.obj"
    collision = shaft_mesh(SHAFT_COLLISION_SIDES)
    paths = [
        write_obj(shaft_mesh(SHAFT_VISUAL_SIDES), out_dir / _MESH_SUBDIR / visual_file, normals=True),
        write_obj(collision, out_dir / _MESH_SUBDIR / collision_file),
        write_obj(box_mesh(gearset.PLATE_SIZE), out_dir / _MESH_SUBDIR / plate_file),
    ]
    plate_center = np.array([0.0, 0.0, 0.5 * gearset.PLATE_SIZE[2]])
    shafts = {g: gearset.shaft_position_in_plate(g) for g in gearset.GEAR_NAMES}
    inertia = MassProperties.combine(
        [_box_mass_properties(gearset.PLATE_SIZE, _PLATE_DENSITY, plate_center)]
        + [MassProperties.of_mesh(collision, _SHAFT_DENSITY, offset=p) for p in shafts.values()]
    )
    elements = [
        _inertial(inertia),
        _visual("plate_visual", _box_geometry(gearset.PLATE_SIZE), _PLATE_RGBA, plate_center),
        _collision("plate_collision", _mesh_geometry(_mesh_uri(plate_file), convex=True), PLATE_CONTACT, plate_center),
    ]
    for g, p in shafts.items():
        elements.append(_visual(f"shaft_{g}_visual", _mesh_geometry(_mesh_uri(visual_file)), _SHAFT_RGBA, p))
    for g, p in shafts.items():
        elements.append(
            _collision(
                shaft_collision_name(g), _mesh_geometry(_mesh_uri(collision_file), convex=True), SHAFT_CONTACT, p
            )
        )
    comment = (
        "Gear plate with its three shafts. Link frame = plate frame P (origin at the centre of the "
        "bottom face, z up, shafts along +x). Weld it to the world."
    )
    sdf_path = out_dir / "gear_plate.sdf"
    sdf_path.write_text(_sdf_model(PLATE_BODY_NAME, comment, elements), newline="\n")
    return [sdf_path, *paths]


def _table_files(out_dir: pathlib.Path) -> list[pathlib.Path]:
    center = np.array([TABLE_CENTER_X, 0.0, -0.5 * TABLE_SIZE[2]])
    collision_file = "table_collision.obj"
    mesh_path = write_obj(box_mesh(TABLE_SIZE), out_dir / _MESH_SUBDIR / collision_file)
    comment = (
        f"Table top {TABLE_SIZE[0]:g} x {TABLE_SIZE[1]:g} x {TABLE_SIZE[2]:g} m, top face at z = 0, "
        f"centred at x = {TABLE_CENTER_X:g} m. Weld it to the world."
    )
    sdf = _sdf_model(
        TABLE_BODY_NAME,
        comment,
        [
            _inertial(_box_mass_properties(TABLE_SIZE, _TABLE_DENSITY, center)),
            _visual("visual", _box_geometry(TABLE_SIZE), _TABLE_RGBA, center),
            _collision("collision", _mesh_geometry(_mesh_uri(collision_file), convex=True), TABLE_CONTACT, center),
        ],
    )
    sdf_path = out_dir / "table.sdf"
    sdf_path.write_text(sdf, newline="\n")
    return [sdf_path, mesh_path]


def _default_models_dir() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parent / "models"


def gearset_model_paths(models_dir: pathlib.Path | None = None) -> dict[str, pathlib.Path]:
    """Paths of the gear set's SDF files under `models_dir / "gearset"` (default: assembly/models):
    keys "plate", "table" and the gear names "small", "medium", "large"."""
    out_dir = pathlib.Path(models_dir if models_dir is not None else _default_models_dir()) / _SUBDIR
    paths = {"plate": out_dir / "gear_plate.sdf", "table": out_dir / "table.sdf"}
    paths.update({g: out_dir / f"{gear_body_name(g)}.sdf" for g in gearset.GEAR_NAMES})
    return paths


def write_gearset_models(models_dir: pathlib.Path) -> list[pathlib.Path]:
    """Writes the gear plate (with shafts), the three gears and the table as SDFormat 1.9 models with
    their OBJ meshes under `models_dir / "gearset"`; returns the paths written (SDF files first)."""
    out_dir = pathlib.Path(models_dir) / _SUBDIR
    out_dir.mkdir(parents=True, exist_ok=True)
    written = _plate_files(out_dir) + _table_files(out_dir)
    for g in gearset.GEAR_NAMES:
        written += _gear_files(gearset.gear_spec(g), out_dir)
    return sorted(written, key=lambda p: (p.suffix != ".sdf", str(p)))


if __name__ == "__main__":
    for written_path in write_gearset_models(_default_models_dir()):
        print(written_path)
