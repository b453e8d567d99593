"""Inspection: inspect(gear), a free-space motion that brings the wrist camera close above a gear,
looking straight down at it, and holds still there so the camera can take a sharp picture.

The motion is planned as tool-frame keyframes (`assembly.scripted_motion`) and played by
`KeyframePlayer` through the impedance controller, like every scripted motion of the station.

The camera's turn about the vertical is free (the view looks straight down either way), so the
inspect pose is chosen reachable: `inspect_yaw` keeps the hand's current yaw where the controller
gets there with every joint clear of its limits, and otherwise turns the view to the nearest yaw
that does, as predicted by `assembly.reach.QuasiStaticTracker` (near the base, the hand's
start yaw folds joint 4 onto its limit and the tool stopped up to 60 mm short; docs/planning.md,
"Reach").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from assembly.cameras import CameraConfig, default_wrist_camera
from assembly.gearset import GEAR_THICKNESS, gear_spec
from assembly.panda_model import HAND_TCP_OFFSET
from assembly.reach import predicted_posture, shared_tracker, turns_by_size
from assembly.scripted_motion import KeyframePlan, KeyframePlayer, segment_time, start_keyframe_plan
from assembly.station import Station, StationConfig, build_station, drive_station

__all__ = [
    "InspectConfig",
    "InspectRun",
    "X_HT",
    "append_inspect",
    "inspect_tool_pose",
    "inspect_yaw",
    "run_inspect",
]

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
    # The view's yaw: the hand's current one unless the controller would end with a joint within
    # joint_clearance [rad] of its limit there; then the nearest of the yaws yaw_step apart that
    # keeps that clearance (None: always the current yaw, as before).
    joint_clearance: float | None = 0.15
    yaw_step: float = np.pi / 12

    def __post_init__(self) -> None:
        if not 0.03 <= self.camera_height <= 0.6:
            raise ValueError(
                f"camera_height = {self.camera_height}; expected 0.03..0.6 m above "
                "the gear (closer than the camera's near plane makes no picture)"
            )
        for name in ("speed", "min_segment", "settle", "finger_clearance", "settle_tolerance", "max_wait", "yaw_step"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"InspectConfig.{name} = {getattr(self, name)}; expected > 0")
        if self.yaw_step > np.pi:
            raise ValueError(f"InspectConfig.yaw_step = {self.yaw_step}; expected 0 < yaw_step <= pi rad")
        c = self.joint_clearance
        if c is not None and not (np.isfinite(c) and 0 <= c <= 1.0):
            raise ValueError(f"InspectConfig.joint_clearance = {c}; expected None or 0..1 rad")


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
    q_start: np.ndarray | None = None,
) -> float:
    """Append inspect(gear) to `plan` (from its last keyframe): move to the inspection pose above
    the believed gear position `gear_xy` (its yaw by `inspect_yaw`; `q_start` the arm's joint
    positions at the last keyframe, if known) and hold still. Returns the time of the picture."""
    gear_spec(gear)
    config = config or InspectConfig()
    if not plan.keyframes:
        raise ValueError("plan has no start keyframe; begin it with start_keyframe_plan(X_WT_now, width)")
    last = plan.keyframes[-1]
    yaw = inspect_yaw(last.X_WT, gear_xy, camera, config, q_start)
    target = inspect_tool_pose(gear_xy, camera, config, yaw=yaw)
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


def inspect_yaw(
    X_WT_from: RigidTransform,
    gear_xy: tuple[float, float],
    camera: CameraConfig | None = None,
    config: InspectConfig | None = None,
    q_start: np.ndarray | None = None,
) -> float:
    """The camera yaw of the inspect pose for a move from tool pose `X_WT_from`: the one that keeps
    the hand's yaw, unless the controller (QuasiStaticTracker, from `q_start`, or where a move
    from the start posture Q_HOME to X_WT_from leaves the arm) would end it with a joint within
    `config.joint_clearance` of a limit or the tool short of the pose; then, of the yaws
    `config.yaw_step` apart ordered by their turn from it, the first that ends clear, or failing
    all, the one ending farthest from the limits."""
    config = config or InspectConfig()
    R = X_WT_from.rotation().matrix()
    keep = _camera_yaw(float(np.arctan2(R[1, 0], R[0, 0])), camera)
    if config.joint_clearance is None:
        return keep
    tracker = shared_tracker()
    if q_start is None:
        q_start = predicted_posture(X_WT_from)
    else:
        q_start = np.asarray(q_start, dtype=float)
        if q_start.shape != (7,) or not np.all(np.isfinite(q_start)):
            raise ValueError(f"q_start = {q_start!r}; expected 7 finite joint positions")
    best, best_margin = keep, -np.inf
    for turn in turns_by_size(config.yaw_step, np.pi):
        yaw = float(np.angle(np.exp(1j * (keep + turn))))
        q, error = tracker.track(q_start, inspect_tool_pose(gear_xy, camera, config, yaw=yaw))
        margin = float(tracker.margin(q).min()) if error < 5e-4 else -np.inf
        if margin >= config.joint_clearance:
            return yaw
        if margin > best_margin:
            best, best_margin = yaw, margin
    return best


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
