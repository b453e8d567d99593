"""render_mode="rgb_array" for the Drake envs: Drake's VTK renderer (RenderEngineVtk, headless)
drawing an env's SceneGraph through one camera.

Everything here changes the env's SceneGraph in its Context only (a renderer, perception roles,
visual-only geometry), and only when the env is made with a render mode: the plant, the diagram
and the physics are the same with and without rendering (tests/assembly/test_env_render.py checks
bit-identical trajectories). Only geometry with a perception role is drawn; `show_collision_geometry`
gives one to the collision shapes of bodies that have no visual of their own, and `add_visual`
adds shapes that exist only in the image (a cart's box, a goal marker).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydrake.common import MemoryFile
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    GeometryId,
    GeometryInstance,
    InMemoryMesh,
    LightParameter,
    MakeRenderEngineVtk,
    Mesh,
    PerceptionProperties,
    RenderCameraCore,
    RenderEngineVtkParams,
    Rgba,
    Role,
    Shape,
)
from pydrake.math import RigidTransform
from pydrake.systems.sensors import CameraInfo

from assembly.cameras import look_at

__all__ = ["RENDERER", "CameraView", "SceneRenderer", "scene_graph_of"]

RENDERER = "goflow_render"  # the render engine's name in the SceneGraph (the station's cameras use "vtk")


@dataclass(frozen=True)
class CameraView:
    """A camera at `target + eye_offset` looking at `target` (world frame [m]), image rows pointing
    down (world +z up), vertical field of view `fov_y` [rad], image `width` x `height` pixels. A
    tracking render moves the target's x and y to the tracked point's (its z stays)."""

    target: tuple[float, float, float]
    eye_offset: tuple[float, float, float]
    fov_y: float = math.radians(45.0)
    near: float = 0.01  # [m]
    far: float = 100.0  # [m]
    width: int = 480
    height: int = 480

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"CameraView: image size {self.width}x{self.height}; expected positive pixel counts")
        if not 0.0 < self.fov_y < math.pi or not 0.0 < self.near < self.far:
            raise ValueError(
                f"CameraView: fov_y {self.fov_y}, near {self.near}, far {self.far}; "
                "expected 0 < fov_y < pi [rad] and 0 < near < far [m]"
            )


def scene_graph_of(diagram):
    """The one SceneGraph among `diagram`'s subsystems (ValueError if there is none or several)."""
    from pydrake.geometry import SceneGraph

    found = [s for s in diagram.GetSystems() if isinstance(s, SceneGraph)]
    if len(found) != 1:
        raise ValueError(f"expected one SceneGraph in the diagram, found {len(found)}")
    return found[0]


def render_params() -> RenderEngineVtkParams:
    """VTK's settings: a headlight (what VTK gives by default, dimmed) and a light from above, so that
    a floor seen at a grazing angle is not black."""
    return RenderEngineVtkParams(
        lights=[
            LightParameter(type="directional", frame="camera", direction=[0.0, 0.0, 1.0], intensity=0.6),
            LightParameter(type="directional", frame="world", direction=[0.3, 0.4, -1.0], intensity=0.7),
        ]
    )


def _perception(rgba: Sequence[float]) -> PerceptionProperties:
    props = PerceptionProperties()
    props.AddProperty("phong", "diffuse", Rgba(*rgba))
    return props


def checker_mesh(cell: float, cells: int) -> Mesh:
    """An in-memory OBJ of the dark squares of a `cells` x `cells` checkerboard of `cell` [m]
    squares centred on the origin in the plane z = 0, facing +z."""
    verts, faces = [], []
    half = 0.5 * cells * cell
    for i in range(cells):
        for j in range(cells):
            if (i + j) % 2:
                continue
            x0, y0 = -half + i * cell, -half + j * cell
            n = len(verts)
            verts += [(x0, y0), (x0 + cell, y0), (x0 + cell, y0 + cell), (x0, y0 + cell)]
            faces.append((n + 1, n + 2, n + 3, n + 4))
    text = "".join(f"v {x:.6f} {y:.6f} 0\n" for x, y in verts) + "vn 0 0 1\n"
    text += "".join(f"f {a}//1 {b}//1 {c}//1 {d}//1\n" for a, b, c, d in faces)
    return Mesh(InMemoryMesh(mesh_file=MemoryFile(text, ".obj", "goflow_checker.obj")))


class SceneRenderer:
    """One camera's colour image of a SceneGraph, rendered through the env's own Context.

    `scene_graph` and `root_context` are the env's (the diagram's root Context the simulator
    advances); `source_id` is the geometry source visual-only shapes are registered under (the
    plant's). Construction adds the VTK render engine to the Context's copy of the SceneGraph.
    """

    def __init__(self, scene_graph, root_context, source_id, view: CameraView) -> None:
        self.view = view
        self._sg = scene_graph
        self._context = scene_graph.GetMyMutableContextFromRoot(root_context)
        self._source = source_id
        scene_graph.AddRenderer(self._context, RENDERER, MakeRenderEngineVtk(render_params()))
        core = RenderCameraCore(
            RENDERER,
            CameraInfo(view.width, view.height, view.fov_y),
            ClippingRange(view.near, view.far),
            RigidTransform(),
        )
        self._camera = ColorRenderCamera(core, False)
        self._added: set[GeometryId] = set()  # the image-only shapes of add_visual
        self._checker: tuple[GeometryId, Mesh, float, float] | None = None  # (id, shape, period, z)
        self._checker_at: tuple[float, float] | None = None

    def _inspector(self):
        return self._sg.get_query_output_port().Eval(self._context).inspector()

    def add_visual(self, frame_id, shape: Shape, X_FG: RigidTransform, rgba: Sequence[float], name: str) -> GeometryId:
        """Register `shape` at X_FG in frame `frame_id` (a body's frame, or the world frame) with a
        perception role only, named "image::{name}": it is drawn, and takes no part in contact."""
        gid = self._sg.RegisterGeometry(
            self._context, self._source, frame_id, GeometryInstance(X_FG, shape, f"image::{name}")
        )
        self._sg.AssignRole(self._context, self._source, gid, _perception(rgba))
        self._added.add(gid)
        return gid

    def move_visual(self, gid: GeometryId, shape: Shape, X_FG: RigidTransform) -> None:
        """Give a visual-only geometry (`add_visual`) a new shape and pose in its frame."""
        self._sg.ChangeShape(self._context, self._source, gid, shape, X_FG)

    def show_collision_geometry(self, rgba: Sequence[float], names: dict[str, Sequence[float]] | None = None) -> None:
        """Draw the collision geometry of every frame that has no perception geometry of the model's
        own (shapes of `add_visual` do not count): colour `names[name]` for a geometry named so (its
        SceneGraph name, or the part after "::"), else `rgba`. Collision shapes a body's own visual
        already covers are left undrawn."""
        inspector = self._inspector()
        names = names or {}
        for frame in inspector.GetAllFrameIds():
            if set(inspector.GetGeometries(frame, Role.kPerception)) - self._added:
                continue
            for gid in inspector.GetGeometries(frame, Role.kProximity):
                name = inspector.GetName(gid)
                color = names.get(name, names.get(name.split("::")[-1], rgba))
                self._sg.AssignRole(self._context, self._source_of(inspector, gid), gid, _perception(color))

    def _source_of(self, inspector, gid: GeometryId):
        owner = inspector.GetOwningSourceName(gid)
        return next(s for s in inspector.GetAllSourceIds() if inspector.GetName(s) == owner)

    def add_checker_floor(
        self, cell: float, cells: int = 24, rgba: Sequence[float] = (0.25, 0.25, 0.25, 1.0), z: float = 0.001
    ) -> None:
        """Dark squares of a checkerboard (`cells` x `cells` squares of `cell` [m]) just above the
        floor at height z [m]; a tracking render keeps them under the target, shifted by whole
        periods so the pattern stays fixed on the ground and shows the motion."""
        shape = checker_mesh(cell, cells)
        gid = self.add_visual(self._sg.world_frame_id(), shape, RigidTransform([0.0, 0.0, z]), rgba, "checker")
        self._checker, self._checker_at = (gid, shape, 2.0 * cell, z), (0.0, 0.0)

    def render(self, track: ArrayLike | None = None) -> NDArray[np.uint8]:
        """The colour image (height, width, 3) uint8 of the scene in the Context's current state;
        `track` (a world point [m]) moves the view's target to its x and y."""
        v = self.view
        target = np.array(v.target, dtype=np.float64)
        if track is not None:
            target[:2] = np.asarray(track, dtype=np.float64)[:2]
        if self._checker is not None:
            gid, shape, period, z = self._checker
            at = (period * round(target[0] / period), period * round(target[1] / period))
            if at != self._checker_at:
                self.move_visual(gid, shape, RigidTransform([at[0], at[1], z]))
                self._checker_at = at
        X_WC = look_at(target + np.asarray(v.eye_offset, dtype=np.float64), target)
        query = self._sg.get_query_output_port().Eval(self._context)
        image = query.RenderColorImage(self._camera, self._sg.world_frame_id(), X_WC)
        return np.array(image.data[:, :, :3], dtype=np.uint8)
