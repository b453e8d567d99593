"""A lean Drake scene (table, gear plate, gears, optional gear markers) rendered by Drake's
RenderEngineVtk from any camera pose: synthetic observations for tests and calibration, and the
per-hypothesis baseline renderer of the speed benchmark.

Optional extras (perception/scenes.py uses them): named lighting setups (one VTK renderer each, all
in the same SceneGraph, so the gears are moved once for every lighting), free occluder bodies (a
Panda hand, copies of the gears) that are parked far out of view until placed, and label images.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    Box,
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    LightParameter,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import RigidBody
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo

from assembly.cameras import RENDERER, CameraConfig, add_renderer
from assembly.gear_meshes import gearset_model_paths
from assembly.gearset import GEAR_NAMES, gear_spec
from assembly.panda_model import FINGER_MAX_WIDTH, panda_model_paths
from assembly.world import gear_body, model_parser, planar_pose
from perception.gear_model import marker_box
from perception.observation import Intrinsics, Observation


# The lighting every scene has: Drake's default (no lights given: one white headlight along the
# camera's optical axis), rendered by the renderer named assembly.cameras.RENDERER.
DEFAULT_LIGHTING = "default"
# Occluder kinds besides the gear names (a copy of that gear): the Panda hand with its fingers.
HAND_OCCLUDER = "hand"
# Each finger of an occluder hand is this far from the hand's axis [m]: open, as the station starts.
HAND_FINGER_OPENING = FINGER_MAX_WIDTH / 2
# Where unused free bodies wait: far beyond every camera's far plane, below the table.
PARKED = RigidTransform([50.0, 50.0, -50.0])


@dataclass
class SceneConfig:
    """What stands on the table: gears by name at (x, y, yaw), which of them carry a marker, and
    whether the gear plate is there (at its WorldConfig pose).

    lightings: extra named lighting setups, each a tuple of Drake LightParameters rendered by its
    own VTK renderer (the "default" setup, Drake's camera headlight, is always there); occluders:
    free bodies by name, each of a kind: "hand" (the committed Panda hand model, fingers open)
    or a gear name (a copy of that gear, e.g. one carried in the hand); they start parked
    far out of view."""

    gears: dict[str, tuple[float, float, float]] = field(default_factory=lambda: {"large": (0.40, -0.15, 0.0)})
    marked: tuple[str, ...] = ()
    plate_pose: tuple[float, float, float] | None = None
    lightings: dict[str, tuple[LightParameter, ...]] = field(default_factory=dict)
    occluders: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in list(self.gears) + list(self.marked):
            gear_spec(name)
        for name in self.marked:
            if name not in self.gears:
                raise ValueError(f"marked gear {name!r} is not in the scene's gears {list(self.gears)}")
        for name, lights in self.lightings.items():
            if name == DEFAULT_LIGHTING or not isinstance(name, str) or not name:
                raise ValueError(
                    f"lighting name {name!r}; expected a non-empty name other than "
                    f"{DEFAULT_LIGHTING!r} (Drake's default headlight)"
                )
            if not lights or not all(isinstance(light, LightParameter) for light in lights):
                raise ValueError(
                    f"lighting {name!r} = {lights!r}; expected a non-empty tuple of pydrake.geometry.LightParameter"
                )
        kinds = (HAND_OCCLUDER,) + GEAR_NAMES
        for name, kind in self.occluders.items():
            if kind not in kinds or name in self.gears:
                raise ValueError(
                    f"occluder {name!r} of kind {kind!r}; expected a kind in {kinds} "
                    f"and a name that is not one of the scene's gears {list(self.gears)}"
                )


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
            plant.WeldFrames(
                plant.world_frame(), plant.GetFrameByName("gear_plate", plate), planar_pose(*self.config.plate_pose)
            )
        self.bodies = {}
        for name in self.config.gears:
            self.bodies[name] = gear_body(plant, parser.AddModels(str(paths[name]))[0])
            if name in self.config.marked:
                size, X_GM, rgba = marker_box(name)
                plant.RegisterVisualGeometry(self.bodies[name], X_GM, Box(*size), f"{name}_marker", np.array(rgba))
        self.occluder_bodies: dict[str, RigidBody] = {}
        if self.config.occluders:
            self._add_occluders(plant)
        plant.Finalize()
        add_renderer(scene_graph)
        self._renderers = {DEFAULT_LIGHTING: RENDERER}
        for name, lights in self.config.lightings.items():
            self._renderers[name] = f"{RENDERER}_{name}"
            scene_graph.AddRenderer(
                self._renderers[name], MakeRenderEngineVtk(RenderEngineVtkParams(lights=list(lights)))
            )
        self.plant, self.scene_graph = plant, scene_graph
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self.context)
        self._sg_context = scene_graph.GetMyContextFromRoot(self.context)
        for name, pose in self.config.gears.items():
            self.set_gear_pose(name, pose)
        for name in self.occluder_bodies:
            self.set_occluder_pose(name, None)

    def _add_occluders(self, plant) -> None:
        """Free occluder bodies from the committed models: the Panda hand (with its fingers, open)
        and copies of gears (auto-renamed model instances)."""
        parser = model_parser(plant)
        parser.SetAutoRenaming(True)
        for name, kind in self.config.occluders.items():
            if kind == HAND_OCCLUDER:
                instance = parser.AddModels(str(panda_model_paths()[1]))[0]
                self.occluder_bodies[name] = plant.GetBodyByName("panda_hand", instance)
                for joint in ("panda_finger_joint1", "panda_finger_joint2"):
                    plant.GetJointByName(joint, instance).set_default_positions([HAND_FINGER_OPENING])
            else:
                instance = parser.AddModels(str(gearset_model_paths()[kind]))[0]
                self.occluder_bodies[name] = gear_body(plant, instance)

    @property
    def lightings(self) -> tuple[str, ...]:
        """Names of the lighting setups this scene renders ("default" first)."""
        return tuple(self._renderers)

    def set_gear_pose(self, name: str, pose: tuple[float, float, float] | None) -> None:
        """Place gear `name` flat on the table at (x, y, yaw); None parks it far out of view."""
        if name not in self.bodies:
            raise ValueError(f"gear {name!r} is not in this scene; it has {list(self.bodies)}")
        X = PARKED if pose is None else planar_pose(*pose)
        self.plant.SetFreeBodyPose(self._plant_context, self.bodies[name], X)

    def set_occluder_pose(self, name: str, X_WO: RigidTransform | None) -> None:
        """Place occluder `name` (its body frame: the hand frame, or a gear frame) at X_WO; None
        parks it far out of view."""
        if name not in self.occluder_bodies:
            raise ValueError(f"occluder {name!r} is not in this scene; it has {list(self.occluder_bodies)}")
        self.plant.SetFreeBodyPose(self._plant_context, self.occluder_bodies[name], PARKED if X_WO is None else X_WO)

    def label(self, name: str) -> int:
        """The render label of gear `name`'s body (its pixels in `render_labels`)."""
        if name not in self.bodies:
            raise ValueError(f"gear {name!r} is not in this scene; it has {list(self.bodies)}")
        return int(self.bodies[name].index())

    def render(self, camera: CameraConfig, X_WC: RigidTransform, lighting: str = DEFAULT_LIGHTING) -> Observation:
        """Colour and depth seen by `camera` (intrinsics and clipping) placed at X_WC, lit by the
        named lighting setup."""
        return self.render_info(camera.info(), camera.near, camera.far, X_WC, lighting)

    def _core(self, info: CameraInfo, near: float, far: float, lighting: str) -> RenderCameraCore:
        if lighting not in self._renderers:
            raise ValueError(f"lighting {lighting!r} is not in this scene; it has {list(self._renderers)}")
        return RenderCameraCore(self._renderers[lighting], info, ClippingRange(near, far), RigidTransform())

    def render_info(
        self, info: CameraInfo, near: float, far: float, X_WC: RigidTransform, lighting: str = DEFAULT_LIGHTING
    ) -> Observation:
        """Colour and depth of a pinhole camera with intrinsics `info` (e.g. a crop of a larger
        camera: same focal lengths, shifted principal point) and clipping range [near, far]."""
        core = self._core(info, near, far, lighting)
        query = self.scene_graph.get_query_output_port().Eval(self._sg_context)
        world = self.scene_graph.world_frame_id()
        color = query.RenderColorImage(ColorRenderCamera(core, False), world, X_WC)
        depth = query.RenderDepthImage(DepthRenderCamera(core, DepthRange(near, far)), world, X_WC)
        return Observation(
            color.data[:, :, :3].copy(), depth.data[:, :, 0].copy(), Intrinsics.from_camera_info(info), X_WC
        )

    def render_labels(self, info: CameraInfo, near: float, far: float, X_WC: RigidTransform) -> np.ndarray:
        """(H, W) int render labels (a body's label is its index; `label(gear)`) seen by a pinhole
        camera with intrinsics `info` at X_WC (lighting plays no part)."""
        core = self._core(info, near, far, DEFAULT_LIGHTING)
        query = self.scene_graph.get_query_output_port().Eval(self._sg_context)
        labels = query.RenderLabelImage(ColorRenderCamera(core, False), self.scene_graph.world_frame_id(), X_WC)
        return labels.data[:, :, 0].astype(np.int32)


def crop_info(info: CameraInfo, u0: int, u1: int, v0: int, v1: int) -> CameraInfo:
    """The intrinsics of the pixel window [u0, u1) x [v0, v1) of a camera."""
    if not (0 <= u0 < u1 <= info.width() and 0 <= v0 < v1 <= info.height()):
        raise ValueError(f"crop [{u0}, {u1}) x [{v0}, {v1}) is not inside the {info.width()} x {info.height()} image")
    return CameraInfo(u1 - u0, v1 - v0, info.focal_x(), info.focal_y(), info.center_x() - u0, info.center_y() - v0)
