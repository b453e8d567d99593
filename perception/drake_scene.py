"""A lean Drake scene (table, gear plate, gears, optional gear markers) rendered by Drake's
RenderEngineVtk from any camera pose: synthetic observations for tests and calibration, and the
per-hypothesis baseline renderer of the speed benchmark."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    Box, ClippingRange, ColorRenderCamera, DepthRange, DepthRenderCamera, RenderCameraCore,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo

from assembly.cameras import RENDERER, CameraConfig, add_renderer
from assembly.gear_meshes import gearset_model_paths
from assembly.gearset import gear_spec
from assembly.world import gear_body, model_parser, planar_pose
from perception.gear_model import marker_box
from perception.observation import Intrinsics, Observation


@dataclass
class SceneConfig:
    """What stands on the table: gears by name at (x, y, yaw), which of them carry a marker, and
    whether the gear plate is there (at its WorldConfig pose)."""

    gears: dict[str, tuple[float, float, float]] = field(
        default_factory=lambda: {"large": (0.40, -0.15, 0.0)})
    marked: tuple[str, ...] = ()
    plate_pose: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in list(self.gears) + list(self.marked):
            gear_spec(name)
        for name in self.marked:
            if name not in self.gears:
                raise ValueError(f"marked gear {name!r} is not in the scene's gears {list(self.gears)}")


class DrakeScene:
    """The scene of a SceneConfig in a MultibodyPlant + SceneGraph with the VTK renderer."""

    def __init__(self, config: SceneConfig | None = None) -> None:
        self.config = config or SceneConfig()
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.0), builder)
        paths = gearset_model_paths()
        parser = model_parser(plant)
        table = parser.AddModels(str(paths["table"]))[0]
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("table", table), RigidTransform())
        if self.config.plate_pose is not None:
            plate = parser.AddModels(str(paths["plate"]))[0]
            plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("gear_plate", plate),
                             planar_pose(*self.config.plate_pose))
        self.bodies = {}
        for name in self.config.gears:
            self.bodies[name] = gear_body(plant, parser.AddModels(str(paths[name]))[0])
            if name in self.config.marked:
                size, X_GM, rgba = marker_box(name)
                plant.RegisterVisualGeometry(self.bodies[name], X_GM, Box(*size), f"{name}_marker",
                                             np.array(rgba))
        plant.Finalize()
        add_renderer(scene_graph)
        self.plant, self.scene_graph = plant, scene_graph
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self.context)
        self._sg_context = scene_graph.GetMyContextFromRoot(self.context)
        for name, pose in self.config.gears.items():
            self.set_gear_pose(name, pose)

    def set_gear_pose(self, name: str, pose: tuple[float, float, float]) -> None:
        """Place gear `name` flat on the table at (x, y, yaw)."""
        if name not in self.bodies:
            raise ValueError(f"gear {name!r} is not in this scene; it has {list(self.bodies)}")
        self.plant.SetFreeBodyPose(self._plant_context, self.bodies[name], planar_pose(*pose))

    def render(self, camera: CameraConfig, X_WC: RigidTransform) -> Observation:
        """Colour and depth seen by `camera` (intrinsics and clipping) placed at X_WC."""
        return self.render_info(camera.info(), camera.near, camera.far, X_WC)

    def render_info(self, info: CameraInfo, near: float, far: float, X_WC: RigidTransform
                    ) -> Observation:
        """Colour and depth of a pinhole camera with intrinsics `info` (e.g. a crop of a larger
        camera: same focal lengths, shifted principal point) and clipping range [near, far]."""
        core = RenderCameraCore(RENDERER, info, ClippingRange(near, far), RigidTransform())
        query = self.scene_graph.get_query_output_port().Eval(self._sg_context)
        world = self.scene_graph.world_frame_id()
        color = query.RenderColorImage(ColorRenderCamera(core, False), world, X_WC)
        depth = query.RenderDepthImage(DepthRenderCamera(core, DepthRange(near, far)), world, X_WC)
        return Observation(color.data[:, :, :3].copy(), depth.data[:, :, 0].copy(),
                           Intrinsics.from_camera_info(info), X_WC)


def crop_info(info: CameraInfo, u0: int, u1: int, v0: int, v1: int) -> CameraInfo:
    """The intrinsics of the pixel window [u0, u1) x [v0, v1) of a camera."""
    if not (0 <= u0 < u1 <= info.width() and 0 <= v0 < v1 <= info.height()):
        raise ValueError(f"crop [{u0}, {u1}) x [{v0}, {v1}) is not inside the "
                         f"{info.width()} x {info.height()} image")
    return CameraInfo(u1 - u0, v1 - v0, info.focal_x(), info.focal_y(),
                      info.center_x() - u0, info.center_y() - v0)
