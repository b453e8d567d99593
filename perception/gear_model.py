"""What perception knows about a gear: its visual mesh, colour and optional marker, and a top-view
height map of that mesh (our own orthographic z-buffer) that the ray caster marches through.

A gear resting flat on the table is a height field: every vertical line through it crosses one
upward-facing surface (top face, bore chamfer, marker) and the solid fills everything below it
down to the table. So the first hit of any ray is found by marching the ray through the height
map, and the map is exact up to its texel size.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from pydrake.math import RigidTransform
from scipy import ndimage

from assembly.gear_meshes import gearset_model_paths, read_obj
from assembly.gearset import GEAR_BORE_CHAMFER, GEAR_BORE_RADIUS, GEAR_THICKNESS, gear_spec

# The symmetry-breaking marker: a white bar on the top face, radially outward along the gear's +x
# (tooth 0), 3 mm wide, 0.3 mm proud of the face.
MARKER_WIDTH = 0.003
MARKER_HEIGHT = 0.0003
MARKER_RGBA = (0.95, 0.95, 0.95, 1.0)
TEXEL = 5e-5  # height-map texel [m]: 0.05 mm
_SUBPIXEL_BITS = 8  # cv2 fixed-point bits when filling triangles


def marker_box(gear: str) -> tuple[tuple[float, float, float], RigidTransform, tuple]:
    """(box size, pose X_GM of its centre in the gear frame, rgba) of gear `gear`'s marker: it runs
    from the bore chamfer's outer edge to the tooth roots along +x."""
    spec = gear_spec(gear)
    r0, r1 = GEAR_BORE_RADIUS + GEAR_BORE_CHAMFER, spec.root_radius
    size = (r1 - r0, MARKER_WIDTH, MARKER_HEIGHT)
    return size, RigidTransform([0.5 * (r0 + r1), 0.0, GEAR_THICKNESS + 0.5 * MARKER_HEIGHT]), MARKER_RGBA


@dataclass(frozen=True)
class HeightMap:
    """The gear's top surface sampled on a square grid in the gear frame G.

    Texel (i, j) covers x in [x0 + j*texel, x0 + (j+1)*texel) and likewise y with row i.
    height: (n, n) top of the solid [m], -1 where there is no gear (the bore, between teeth);
    normal: (n, n, 3) unit normal of the top surface; albedo: (n, n, 3) diffuse colour;
    wall_normal: (n, n, 2) horizontal outward normal of the nearest side wall (for rays that
    enter through a wall).
    """

    texel: float
    x0: float
    height: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    wall_normal: np.ndarray

    @property
    def size(self) -> int:
        """Texels per side."""
        return self.height.shape[0]

    @property
    def top(self) -> float:
        """Highest point of the solid [m]."""
        return float(self.height.max())


@dataclass(frozen=True)
class GearModel:
    """A gear's mesh (vertices (V, 3), faces (F, 3)) in its frame G with a diffuse colour per face;
    `symmetry` is how many times the model repeats in one turn (the tooth count, 1 when marked)."""

    name: str
    marked: bool
    vertices: np.ndarray
    faces: np.ndarray
    face_albedo: np.ndarray
    symmetry: int
    tip_radius: float

    @property
    def period(self) -> float:
        """Yaw after which the model looks the same [rad]."""
        return 2.0 * np.pi / self.symmetry

    def height_map(self, texel: float = TEXEL) -> HeightMap:
        """The model's top-view height map (cached per texel size)."""
        return _height_map(self.name, self.marked, texel)


def _box_triangles(size, X: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward triangles of a box of `size` centred at pose X."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    v = (X.rotation().matrix() @ (0.5 * corners * np.asarray(size)).T).T + X.translation()
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = [[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads]
    return v, np.array(f, np.int64)


@lru_cache(maxsize=None)
def gear_model(gear: str, marked: bool = False) -> GearModel:
    """The model of gear `gear` from its committed visual mesh and colour (plus its marker)."""
    spec = gear_spec(gear)
    mesh = read_obj(gearset_model_paths()[gear].parent / "meshes" / f"gear_{gear}_visual.obj")
    vertices, faces = mesh.vertices, mesh.faces
    albedo = np.tile(np.asarray(spec.rgba[:3], np.float32), (len(faces), 1))
    if marked:
        size, X_GM, rgba = marker_box(gear)
        mv, mf = _box_triangles(size, X_GM)
        faces = np.vstack([faces, mf + len(vertices)])
        vertices = np.vstack([vertices, mv])
        albedo = np.vstack([albedo, np.tile(np.asarray(rgba[:3], np.float32), (len(mf), 1))])
    return GearModel(
        gear,
        marked,
        vertices,
        faces,
        albedo,
        1 if marked else spec.teeth,
        float(np.max(np.hypot(vertices[:, 0], vertices[:, 1]))),
    )


@lru_cache(maxsize=None)
def _height_map(gear: str, marked: bool, texel: float) -> HeightMap:
    """Orthographic z-buffer of the model's upward-facing triangles seen from +z: each texel gets
    the triangle drawn last in ascending order of height (a height field's upward faces do not
    overlap in projection, so this is its top surface); heights come from each triangle's plane."""
    model = gear_model(gear, marked)
    v, f = model.vertices, model.faces
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    up = np.nonzero(n[:, 2] > 1e-6)[0]
    up = up[np.argsort((a[up, 2] + b[up, 2] + c[up, 2]) / 3.0, kind="stable")]
    x0 = -(model.tip_radius + 4 * texel)
    size = int(np.ceil(-2 * x0 / texel))
    owner = np.full((size, size), -1, np.int32)
    scale = (1 << _SUBPIXEL_BITS) / texel
    # cv2 fills whole texels whose centres lie inside; texel centres sit at x0 + (j + 0.5) texel.
    for k in up:
        pts = np.round((v[f[k], :2] - x0) * scale - 0.5 * (1 << _SUBPIXEL_BITS)).astype(np.int32)
        cv2.fillConvexPoly(owner, pts, int(k), lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    centres = x0 + (np.arange(size) + 0.5) * texel
    X, Y = np.meshgrid(centres, centres)
    hit = owner >= 0
    k = owner[hit]
    nk = n[k]
    # Plane through vertex a with normal n: z = a_z - (n_x (x - a_x) + n_y (y - a_y)) / n_z.
    z = a[k, 2] - (nk[:, 0] * (X[hit] - a[k, 0]) + nk[:, 1] * (Y[hit] - a[k, 1])) / nk[:, 2]
    height = np.full((size, size), -1.0, np.float32)
    height[hit] = z
    normal = np.zeros((size, size, 3), np.float32)
    normal[hit] = nk
    albedo = np.zeros((size, size, 3), np.float32)
    albedo[hit] = model.face_albedo[k]
    # Side walls are vertical: their outward normal is minus the gradient of the (smoothed)
    # footprint, which is exact enough for shading.
    soft = ndimage.gaussian_filter(hit.astype(np.float32), sigma=2.0)
    gy, gx = np.gradient(soft)
    g = np.hypot(gx, gy) + 1e-12
    wall = np.stack([-gx / g, -gy / g], axis=-1).astype(np.float32)
    return HeightMap(texel, float(x0), height, normal, albedo, wall)
