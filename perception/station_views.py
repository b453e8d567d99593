"""Station views: an `Observation` rendered by one of the station's cameras at a given state.

`perception.observation` defines what an observation is (images, intrinsics, camera pose); this
module reads one off a built `assembly.station.Station` ("scene" on the world, "wrist" on the hand).
"""

from __future__ import annotations

from pydrake.systems.framework import Context

from assembly.station import Station
from perception.observation import Intrinsics, Observation

__all__ = ["camera_pose", "observation_from_images", "observe"]


def camera_pose(station: Station, root: Context, camera: str):
    """World pose X_WC of station camera `camera` ('scene' on the world, 'wrist' on the hand)."""
    cameras = {c.name: c for c in (station.config.cameras.scene, station.config.cameras.wrist) if c}
    if camera not in cameras:
        raise ValueError(f"the station has no camera {camera!r}; it has {sorted(cameras)}")
    config = cameras[camera]
    if config is station.config.cameras.scene:
        return config.X_PC
    hand = station.plant.GetBodyByName("panda_hand", station.models.hand)
    return station.plant.EvalBodyPoseInWorld(station.plant_context(root), hand) @ config.X_PC


def observe(station: Station, root: Context, camera: str) -> Observation:
    """The RGB-D image of station camera `camera` at the state in `root` (the commanded
    station's root context)."""
    X_WC = camera_pose(station, root, camera)
    context = station.diagram.GetMyContextFromRoot(root)
    config = station.config.cameras.scene if camera == "scene" else station.config.cameras.wrist
    return observation_from_images(
        station.diagram.GetOutputPort(f"{camera}_rgb").Eval(context),
        station.diagram.GetOutputPort(f"{camera}_depth").Eval(context),
        config,
        X_WC,
    )


def observation_from_images(rgb_image, depth_image, config, X_WC) -> Observation:
    """An Observation from a Drake RGBA image and 32-bit depth image of the camera `config`
    (assembly.cameras.CameraConfig) at world pose X_WC."""
    rgb = rgb_image.data[:, :, :3].copy()
    depth = depth_image.data[:, :, 0].copy()
    return Observation(rgb, depth, Intrinsics.from_camera_info(config.info()), X_WC)
