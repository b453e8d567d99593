"""Inspection: inspect(gear), a free-space motion that brings the wrist camera close above a gear,
looking straight down at it, and holds still there so the camera can take a sharp picture.

The motion is planned as tool-frame keyframes (`assembly.scripted_motion`) and played by
`KeyframePlayer` through the impedance controller, like every scripted motion of the station.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from assembly.cameras import CameraConfig, default_wrist_camera
from assembly.gearset import GEAR_THICKNESS, gear_spec
from assembly.panda_model import HAND_TCP_OFFSET
from assembly.scripted_motion import KeyframePlan, KeyframePlayer, segment_time, start_keyframe_plan
from assembly.station import Station, StationConfig, build_station, drive_station

__all__ = ["InspectConfig", "InspectRun", "X_HT", "append_inspect", "inspect_tool_pose", "run_inspect"]

# Tool frame T (panda_hand_tcp) in the hand frame H: HAND_TCP_OFFSET along the hand's z.
X_HT = RigidTransform([0.0, 0.0, HAND_TCP_OFFSET])


@dataclass
class InspectConfig:
    """camera_height: the wrist camera's height above the gear's top face [m]; speed: mean tool
    speed [m/s]; min_segment: shortest move [s]; settle: still time before the picture [s]."""

    camera_height: float = 0.17
    speed: float = 0.15
    min_segment: float = 0.8
    settle: float = 0.6
    finger_clearance: float = 0.02  # fingertips (tool frame) above the gears' top faces [m]
    settle_tolerance: float = 0.002  # the picture waits until the tool is this close [m] ...
    max_wait: float = 4.0  # ... or this long after the planned picture time [s]

    def __post_init__(self) -> None:
        if not 0.03 <= self.camera_height <= 0.6:
            raise ValueError(
                f"camera_height = {self.camera_height}; expected 0.03..0.6 m above "
                "the gear (closer than the camera's near plane makes no picture)"
            )
        for name in ("speed", "min_segment", "settle", "finger_clearance", "settle_tolerance", "max_wait"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"InspectConfig.{name} = {getattr(self, name)}; expected > 0")


def inspect_tool_pose(
    gear_xy: tuple[float, float],
    camera: CameraConfig | None = None,
    config: InspectConfig | None = None,
    yaw: float = 0.0,
) -> RigidTransform:
    """Tool pose X_WT that puts the wrist camera `config.camera_height` above the gear's top face
    with its optical axis through the gear's axis; the hand points down, turned `yaw` about
    world z. The camera is tilted on the hand, so the hand tilts to make the view vertical."""
    camera = camera or default_wrist_camera()
    config = config or InspectConfig()
    X_TC = X_HT.inverse() @ camera.X_PC
    # Orientation: the camera's optical axis points straight down, its image x along world
    # (cos yaw, sin yaw); then R_WT = R_WC R_CT.
    R_WC = RotationMatrix.MakeZRotation(yaw) @ RotationMatrix.MakeXRotation(np.pi)
    R_WT = R_WC @ X_TC.rotation().inverse()
    p_WC = np.array([gear_xy[0], gear_xy[1], GEAR_THICKNESS + config.camera_height])
    p_WT = p_WC - R_WT @ X_TC.translation()
    return RigidTransform(R_WT, p_WT)


def append_inspect(
    plan: KeyframePlan,
    gear: str,
    gear_xy: tuple[float, float],
    camera: CameraConfig | None = None,
    config: InspectConfig | None = None,
) -> float:
    """Append inspect(gear) to `plan` (from its last keyframe): move to the inspection pose above
    the believed gear position `gear_xy` and hold still. Returns the time of the picture."""
    gear_spec(gear)
    config = config or InspectConfig()
    if not plan.keyframes:
        raise ValueError("plan has no start keyframe; begin it with start_keyframe_plan(X_WT_now, width)")
    last = plan.keyframes[-1]
    R = last.X_WT.rotation().matrix()
    current_yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    target = inspect_tool_pose(gear_xy, camera, config, yaw=_camera_yaw(current_yaw, camera))
    low = GEAR_THICKNESS + config.finger_clearance
    if target.translation()[2] < low:
        raise ValueError(
            f"camera_height = {config.camera_height} m puts the fingertips at "
            f"z = {target.translation()[2]:.3f} m, below {low:.3f} m (the gears' tops "
            f"+ finger_clearance); raise camera_height"
        )
    plan.append(
        segment_time(last.X_WT, target, config.speed, config.min_segment), target, last.width, f"{gear}: inspect"
    )
    plan.append(config.settle, target, last.width, f"{gear}: hold for the picture")
    return plan.end_time


def _camera_yaw(tool_yaw: float, camera: CameraConfig | None) -> float:
    """The camera image yaw that keeps the hand at (about) its current yaw about world z."""
    camera = camera or default_wrist_camera()
    X_TC = X_HT.inverse() @ camera.X_PC
    # With the tool pointing down at yaw psi, the camera's x axis lies at psi + the camera's
    # in-plane angle on the tool (its x axis seen from above, mirrored by the tool's flip).
    down = RotationMatrix.MakeZRotation(tool_yaw) @ RotationMatrix.MakeXRotation(np.pi)
    x_C = (down @ X_TC.rotation()).matrix()[:, 0]
    return float(np.arctan2(x_C[1], x_C[0]))


@dataclass
class InspectRun:
    """A station that has played inspect(gear): its simulator (at the picture time) and plan."""

    station: Station
    simulator: Simulator
    plan: KeyframePlan
    picture_time: float

    @property
    def root_context(self):
        return self.simulator.get_context()


def run_inspect(
    gear: str,
    gear_xy: tuple[float, float],
    station_config: StationConfig | None = None,
    config: InspectConfig | None = None,
) -> InspectRun:
    """Build a station, play inspect(gear) from the start configuration towards the believed
    `gear_xy` and simulate to the picture time."""
    station_config = station_config or StationConfig()
    station = build_station(station_config)
    world = station_config.world
    X_WT0 = station.controller.tool_pose(np.asarray(world.q_arm_start, dtype=float))
    plan = start_keyframe_plan(X_WT0, world.finger_width_start)
    wrist = station_config.cameras.wrist
    t = append_inspect(plan, gear, gear_xy, wrist, config)
    simulator = Simulator(drive_station(station, KeyframePlayer(plan)))
    simulator.Initialize()
    simulator.AdvanceTo(t)
    # The impedance controller lags its target; wait (up to max_wait) until the tool is there.
    config = config or InspectConfig()
    target = plan.keyframes[-1].X_WT.translation()
    context = simulator.get_context()
    while (
        np.linalg.norm(station.tool_pose(context).translation() - target) > config.settle_tolerance
        and context.get_time() < t + config.max_wait
    ):
        simulator.AdvanceTo(context.get_time() + 0.1)
    return InspectRun(station, simulator, plan, context.get_time())
