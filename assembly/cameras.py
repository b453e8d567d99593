"""RGB-D cameras of the station: a fixed scene camera and a wrist camera on the Panda's hand."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    FrameId,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
    SceneGraph,
)
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo, RgbdSensor

from assembly.gearset import GEAR_THICKNESS

RENDERER = "vtk"
# A gear's top face above the table [m], where an extrinsic error's shift is taken.
GEAR_TOP = GEAR_THICKNESS


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> RigidTransform:
    """Pose of a camera at `eye` whose optical axis (+z) points at `target`; image rows (+y) point
    down, i.e. away from `up`."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return RigidTransform(RotationMatrix(np.column_stack([x, y, z])), eye)


@dataclass
class CameraConfig:
    """A pinhole RGB-D camera rigidly attached to a parent frame (the world or a body)."""

    name: str
    X_PC: RigidTransform
    width: int = 640
    height: int = 480
    fov_y: float = np.deg2rad(45.0)
    near: float = 0.02
    far: float = 3.0

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(
                f"camera {self.name!r}: image size {self.width}x{self.height}; "
                "expected positive width and height in pixels"
            )
        if not 0 < self.fov_y < np.pi:
            raise ValueError(f"camera {self.name!r}: fov_y = {self.fov_y}; expected (0, pi) rad")
        if not 0 < self.near < self.far:
            raise ValueError(f"camera {self.name!r}: near {self.near}, far {self.far}; expected 0 < near < far [m]")

    def info(self) -> CameraInfo:
        return CameraInfo(self.width, self.height, self.fov_y)


def default_scene_camera() -> CameraConfig:
    """Above the table, from the robot's right-front, looking down at the plate and the gears;
    from this side the arm does not hide the plate while it inserts."""
    return CameraConfig("scene", look_at([0.78, -0.42, 0.45], [0.48, -0.04, 0.0]))


def default_wrist_camera() -> CameraConfig:
    """On the hand, beside the fingers, looking along the approach direction (hand +z)."""
    # Hand frame: z along the fingers, y the closing direction. Mounted 6 cm off-axis along hand x,
    # tilted 15 degrees toward the fingertips so the grasp region sits mid-image.
    X_HC = RigidTransform(RotationMatrix.MakeYRotation(-np.deg2rad(15.0)), [0.06, 0.0, 0.04])
    return CameraConfig("wrist", X_HC, fov_y=np.deg2rad(60.0), near=0.01, far=1.5)


@dataclass
class CamerasConfig:
    """Which cameras the station carries."""

    scene: CameraConfig | None = field(default_factory=default_scene_camera)
    wrist: CameraConfig | None = field(default_factory=default_wrist_camera)


def extrinsic_error(translation_std: float, rotation_std: float, rng: np.random.Generator) -> RigidTransform:
    """A random error X_CE of a camera's extrinsics, in the camera frame: a rotation of N(0,
    `rotation_std`) [rad] about each axis and a translation of N(0, `translation_std`) [m] along
    each. The camera's true pose is then X_PC @ X_CE where the robot believes X_PC."""
    if not (np.isfinite(translation_std) and translation_std >= 0 and np.isfinite(rotation_std) and rotation_std >= 0):
        raise ValueError(
            f"extrinsic error std ({translation_std}, {rotation_std}); expected (translation [m], rotation [rad]) >= 0"
        )
    return RigidTransform(RollPitchYaw(rng.normal(0.0, rotation_std, 3)), rng.normal(0.0, translation_std, 3))


def with_extrinsic_error(config: CameraConfig, X_CE: RigidTransform) -> CameraConfig:
    """`config` mounted at X_PC @ X_CE: the camera as it really is when the robot believes
    `config`."""
    return replace(config, X_PC=config.X_PC @ X_CE)


def extrinsic_error_on_table(
    X_WC: RigidTransform, point: np.ndarray, translation_std: float, rotation_std: float, samples: int = 256
) -> np.ndarray:
    """How far an extrinsic error of the given std moves where the camera believed at X_WC places a
    world `point` on the horizontal plane through it: the point seen by the true camera X_WC @ X_CE
    along the same pixel ray, re-intersected with that plane from the believed camera. Returns the
    2 x 2 covariance [m^2] of the x-y shift (Monte Carlo over `samples` fixed-seed errors)."""
    p = np.asarray(point, float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"point {point}; expected a finite world point (x, y, z) [m]")
    if translation_std == 0 and rotation_std == 0:
        return np.zeros((2, 2))
    rng = np.random.default_rng(0)
    c = X_WC.translation()
    shifts = []
    for _ in range(samples):
        X_CE = extrinsic_error(translation_std, rotation_std, rng)
        ray_C = (X_WC @ X_CE).inverse().multiply(p)  # the pixel's ray in the camera frame
        ray_W = X_WC.rotation().multiply(ray_C)  # as the robot interprets it
        if abs(ray_W[2]) < 1e-9:
            continue
        s = (p[2] - c[2]) / ray_W[2]
        shifts.append((c + s * ray_W)[:2] - p[:2])
    return np.cov(np.asarray(shifts).T)


def with_extrinsic_std(
    X_WC: RigidTransform, mean: np.ndarray, std: np.ndarray, extrinsic_std: tuple[float, float]
) -> np.ndarray:
    """A table pose estimate's std (x, y, yaw) with the uncertainty of the camera's extrinsics
    added: `extrinsic_std` (translation [m], rotation [rad]) std moves where the camera believed at
    X_WC places a gear's top at `mean` (x, y, yaw; the top GEAR_TOP above the table) on the table
    (extrinsic_error_on_table) and turns it in yaw by the rotation's std."""
    t_std, r_std = extrinsic_std
    if t_std == 0 and r_std == 0:
        return np.asarray(std, float)
    cov = extrinsic_error_on_table(X_WC, np.array([mean[0], mean[1], GEAR_TOP]), t_std, r_std)
    return np.sqrt(np.asarray(std, float) ** 2 + np.array([cov[0, 0], cov[1, 1], r_std**2]))


def add_renderer(scene_graph: SceneGraph) -> None:
    """Register Drake's VTK renderer (headless through EGL/OSMesa) once."""
    if not scene_graph.HasRenderer(RENDERER):
        scene_graph.AddRenderer(RENDERER, MakeRenderEngineVtk(RenderEngineVtkParams()))


def add_camera(builder: DiagramBuilder, scene_graph: SceneGraph, parent: FrameId, config: CameraConfig) -> RgbdSensor:
    """Add an RgbdSensor named config.name attached to `parent`, rendering with the VTK engine."""
    add_renderer(scene_graph)
    core = RenderCameraCore(RENDERER, config.info(), ClippingRange(config.near, config.far), RigidTransform())
    sensor = builder.AddSystem(
        RgbdSensor(
            parent,
            config.X_PC,
            ColorRenderCamera(core, False),
            DepthRenderCamera(core, DepthRange(config.near, config.far)),
        )
    )
    sensor.set_name(f"camera_{config.name}")
    builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
    return sensor
