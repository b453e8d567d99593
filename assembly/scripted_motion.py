"""Scripted motions: open-loop keyframe plans of the tool pose and gripper width, and the system
that plays them.

A `KeyframePlan` is a list of timed tool-frame keyframes (`Keyframe`); `append_*` functions add a
motion to a plan from its last keyframe, and `KeyframePlayer` plays a plan through the impedance
controller as minimum-jerk segments. `append_pick_and_insert` scripts the gearbox's pick-and-insert
(approach, grasp a gear from the table, transport, align above its shaft, insert under impedance,
release, retreat); `assembly.inspection` adds the wrist-camera inspect motion.

A scripted motion is open loop: it plans from where it *believes* the gear is. Compliance and the
chamfers absorb small errors; larger ones make it fail, which is what trained skills
(`learning.skill_file`) are for. "Skill" in goflow means only such a trained policy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import Context, LeafSystem

from assembly.gearset import GEAR_THICKNESS, SHAFT_HEIGHT, gear_spec
from assembly.panda_model import FINGER_MAX_WIDTH
from assembly.world import nominal_grasp, validate_tool_target

__all__ = [
    "Keyframe",
    "KeyframePlan",
    "KeyframePlayer",
    "ScriptedInsertionConfig",
    "append_move",
    "append_pick",
    "append_pick_and_insert",
    "append_place",
    "append_return",
    "carry_height",
    "down_pose",
    "grasp_tool_pose",
    "gripper_widths",
    "min_jerk",
    "sample_plan",
    "start_keyframe_plan",
]


@dataclass
class ScriptedInsertionConfig:
    """Geometry and timing of the scripted pick-and-insert motion (SI units)."""

    grasp_depth: float = 0.006  # tool frame this far below the gear's top face when grasping
    approach_height: float = 0.08  # above the gear top before descending to grasp
    transport_clearance: float = 0.03  # gear bottom above the shaft tops while moving
    align_height: float = 0.004  # gear bottom above the shaft top before inserting
    insert_overshoot: float = 0.006  # insertion target below seated: the impedance pushes down
    open_margin: float = 0.012  # open width beyond the gear's tip diameter
    squeeze: float = 0.02  # commanded width below the tip diameter: sets the grasp force
    speed: float = 0.15  # mean free-space speed of the tool [m/s] (min-jerk peak is 1.9x)
    insert_speed: float = 0.01  # mean speed while inserting [m/s]
    min_segment: float = 0.5  # shortest free-space move [s]
    pause: float = 0.4  # rest before descending, before grasping and before inserting [s]
    gripper_time: float = 0.5  # to open or close [s]
    settle_time: float = 0.3  # pause after arriving at the insertion target [s]
    retreat_height: float = 0.08

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"ScriptedInsertionConfig.{name} = {value}; expected a finite value >= 0")
        for name in ("speed", "insert_speed", "gripper_time"):
            if getattr(self, name) <= 0:
                raise ValueError(f"ScriptedInsertionConfig.{name} must be > 0")


@dataclass
class Keyframe:
    """A tool pose and gripper width to reach at time t."""

    t: float
    X_WT: RigidTransform
    width: float
    label: str


@dataclass
class KeyframePlan:
    """Timed keyframes of one or more scripted motions, and per gear the [start, release] times of
    its pick-and-insert."""

    keyframes: list[Keyframe] = field(default_factory=list)
    gear_intervals: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def end_time(self) -> float:
        return self.keyframes[-1].t if self.keyframes else 0.0

    def append(self, duration: float, X_WT: RigidTransform, width: float, label: str) -> None:
        """Reach X_WT and `width` `duration` seconds after the last keyframe."""
        validate_tool_target(X_WT)
        self.keyframes.append(Keyframe(self.end_time + duration, X_WT, width, label))


# Mean tool turn rate of a free-space move [rad/s]: a min-jerk segment peaks at 1.875x, below
# the Panda's 2.61 rad/s wrist joint limit (docs/planning.md: faster turns left the tool 14 mm
# behind its command and the fingers landed on the gear).
TURN_RATE = 1.0


def segment_time(
    X_from: RigidTransform, X_to: RigidTransform, speed: float, min_segment: float, turn_rate: float = TURN_RATE
) -> float:
    """The duration of a free-space move [s]: the longer of distance / `speed` [m/s] and turn
    angle / `turn_rate` [rad/s], at least `min_segment`."""
    d = float(np.linalg.norm(X_to.translation() - X_from.translation()))
    angle = float((X_from.rotation().inverse() @ X_to.rotation()).ToAngleAxis().angle())
    return max(d / speed, angle / turn_rate, min_segment)


def append_move(
    plan: KeyframePlan, target: RigidTransform, width: float, label: str, speed: float, min_segment: float
) -> None:
    """A free-space move to `target` at mean tool speed `speed` [m/s] and turn rate TURN_RATE,
    at least `min_segment` [s] (segment_time)."""
    plan.append(segment_time(plan.keyframes[-1].X_WT, target, speed, min_segment), target, width, label)


def down_pose(p: np.ndarray, yaw: float) -> RigidTransform:
    """Tool pose at p with the approach axis (tool z) pointing down, rotated by yaw about world z."""
    return RigidTransform(RotationMatrix.MakeZRotation(yaw) @ RotationMatrix.MakeXRotation(np.pi), p)


def _grasp_yaw(current: RigidTransform) -> float:
    """Fingers close along world x (the tip circle is round, so any direction grasps it); of the
    two symmetric yaws pick the one nearest the hand's current yaw so the wrist does not wind up."""
    current_yaw = np.arctan2(current.rotation().matrix()[1, 0], current.rotation().matrix()[0, 0])
    candidates = np.array([np.pi / 2, -np.pi / 2])
    diffs = np.abs(np.angle(np.exp(1j * (candidates - current_yaw))))
    return float(candidates[np.argmin(diffs)])


def gripper_widths(gear: str, config: ScriptedInsertionConfig) -> tuple[float, float]:
    """(open, closed) finger widths commanded for `gear`: open clears its tip circle by
    open_margin, closed squeezes it by `squeeze` (which sets the grasp force)."""
    spec = gear_spec(gear)
    return (min(2 * spec.tip_radius + config.open_margin, FINGER_MAX_WIDTH), 2 * spec.tip_radius - config.squeeze)


def grasp_tool_pose(gear: str, X_WG: RigidTransform, yaw: float, config: ScriptedInsertionConfig) -> RigidTransform:
    """The tool pose at which the fingers close on `gear` lying at X_WG, tool heading `yaw`."""
    grasp_z = nominal_grasp(gear, config.grasp_depth).translation()[2]  # tool height above the gear bottom
    return down_pose(X_WG.translation() + [0, 0, grasp_z], yaw)


def append_pick(
    plan: KeyframePlan,
    gear: str,
    X_WG_believed: RigidTransform,
    yaw: float,
    carry_z: float,
    config: ScriptedInsertionConfig,
    descend_speed: float | None = None,
) -> None:
    """Append a pick of `gear` believed at X_WG_believed with the tool heading `yaw`: approach
    from above, descend, close the fingers, lift to tool height `carry_z`. `descend_speed` [m/s]:
    the mean tool speed of the descent and the lift (None: config.speed, as the approach)."""
    if not plan.keyframes:
        raise ValueError("plan has no start keyframe; begin it with start_keyframe_plan(X_WT_now, width)")
    c = config
    if descend_speed is None:
        descend_speed = c.speed
    elif isinstance(descend_speed, bool) or not (np.isfinite(descend_speed) and descend_speed > 0):
        raise ValueError(f"descend_speed = {descend_speed!r}; expected None or a speed > 0 m/s")
    open_w, closed_w = gripper_widths(gear, c)
    p_G = X_WG_believed.translation()
    above_gear = down_pose(p_G + [0, 0, GEAR_THICKNESS + c.approach_height], yaw)
    at_gear = grasp_tool_pose(gear, X_WG_believed, yaw, c)
    lifted = down_pose(np.array([p_G[0], p_G[1], carry_z]), yaw)
    append_move(plan, above_gear, open_w, f"{gear}: approach", c.speed, c.min_segment)
    plan.append(c.pause, above_gear, open_w, f"{gear}: steady above gear")
    append_move(plan, at_gear, open_w, f"{gear}: descend", descend_speed, c.min_segment)
    plan.append(c.pause, at_gear, open_w, f"{gear}: steady at gear")
    plan.append(c.gripper_time, at_gear, closed_w, f"{gear}: grasp")
    plan.append(0.2, at_gear, closed_w, f"{gear}: hold")
    append_move(plan, lifted, closed_w, f"{gear}: lift", descend_speed, c.min_segment)


def append_place(
    plan: KeyframePlan, gear: str, X_WT_place: RigidTransform, carry_z: float, config: ScriptedInsertionConfig
) -> None:
    """Append putting a held `gear` down with the tool at X_WT_place (e.g. where append_pick held
    it, so the gear lands where it lay): straight up to tool height `carry_z`, across, down,
    open the fingers, up clear of the gear."""
    if not plan.keyframes:
        raise ValueError("plan has no start keyframe; begin it with start_keyframe_plan(X_WT_now, width)")
    c = config
    open_w, closed_w = gripper_widths(gear, c)
    here, p = plan.keyframes[-1].X_WT, X_WT_place.translation()
    append_move(
        plan,
        RigidTransform(here.rotation(), [*here.translation()[:2], carry_z]),
        closed_w,
        f"{gear}: lift",
        c.speed,
        c.min_segment,
    )
    append_move(
        plan,
        RigidTransform(X_WT_place.rotation(), [p[0], p[1], carry_z]),
        closed_w,
        f"{gear}: carry back",
        c.speed,
        c.min_segment,
    )
    append_move(plan, X_WT_place, closed_w, f"{gear}: put down", c.speed, c.min_segment)
    plan.append(c.gripper_time, X_WT_place, open_w, f"{gear}: release")
    append_move(
        plan,
        RigidTransform(X_WT_place.rotation(), p + [0, 0, GEAR_THICKNESS + c.approach_height]),
        open_w,
        f"{gear}: clear",
        c.speed,
        c.min_segment,
    )


def carry_height(gear: str, X_WS: RigidTransform, config: ScriptedInsertionConfig) -> float:
    """Tool height while carrying `gear`: its bottom `transport_clearance` above the shaft tops."""
    grasp_z = nominal_grasp(gear, config.grasp_depth).translation()[2]
    return float(X_WS.translation()[2] + SHAFT_HEIGHT + config.transport_clearance + grasp_z)


def append_pick_and_insert(
    plan: KeyframePlan, gear: str, X_WG_believed: RigidTransform, X_WS: RigidTransform, config: ScriptedInsertionConfig
) -> None:
    """Append one pick-and-insert of `gear` to `plan`, starting from its last keyframe.

    X_WG_believed: where the script believes the gear is (frame G at the bore axis, bottom face).
    X_WS: the shaft frame (on the axis at the plate top).
    """
    if not plan.keyframes:
        raise ValueError("plan has no start keyframe; begin it with start_keyframe_plan(X_WT_now, width)")
    c = config
    start = plan.end_time
    yaw = _grasp_yaw(plan.keyframes[-1].X_WT)
    open_w, closed_w = gripper_widths(gear, c)
    grasp_z = nominal_grasp(gear, c.grasp_depth).translation()[2]  # tool height above the gear bottom
    p_S = X_WS.translation()
    carry_z = carry_height(gear, X_WS, c)
    append_pick(plan, gear, X_WG_believed, yaw, carry_z, c)
    above_shaft = down_pose(np.array([p_S[0], p_S[1], carry_z]), yaw)
    aligned = down_pose(p_S + [0, 0, SHAFT_HEIGHT + c.align_height + grasp_z], yaw)
    pushed = down_pose(p_S + [0, 0, grasp_z - c.insert_overshoot], yaw)
    retreat = down_pose(p_S + [0, 0, grasp_z + c.retreat_height], yaw)

    def move(target: RigidTransform, width: float, label: str, speed: float = c.speed) -> None:
        append_move(plan, target, width, label, speed, c.min_segment)

    move(above_shaft, closed_w, f"{gear}: transport")
    move(aligned, closed_w, f"{gear}: align")
    plan.append(c.pause, aligned, closed_w, f"{gear}: steady above shaft")
    move(pushed, closed_w, f"{gear}: insert", speed=c.insert_speed)
    plan.append(c.settle_time, pushed, closed_w, f"{gear}: settle")
    plan.append(c.gripper_time, pushed, open_w, f"{gear}: release")
    plan.gear_intervals[gear] = (start, plan.end_time)
    move(retreat, open_w, f"{gear}: retreat")


def append_return(plan: KeyframePlan, X_WT: RigidTransform, config: ScriptedInsertionConfig) -> None:
    """Append a free-space move back to X_WT (e.g. the start pose), keeping the gripper as is."""
    last = plan.keyframes[-1]
    plan.append(segment_time(last.X_WT, X_WT, config.speed, config.min_segment), X_WT, last.width, "return")


def start_keyframe_plan(X_WT_now: RigidTransform, width_now: float) -> KeyframePlan:
    """A plan whose first keyframe holds the current tool pose and gripper width at t = 0."""
    return KeyframePlan([Keyframe(0.0, X_WT_now, width_now, "start")])


def min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk progress s(tau) and its first two derivatives on [0, 1] (rest at both ends)."""
    tau = min(max(tau, 0.0), 1.0)
    return (tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau) ** 2, 60 * tau * (1 - tau) * (1 - 2 * tau))


def sample_plan(
    plan: KeyframePlan, t: float, times: np.ndarray | None = None
) -> tuple[RigidTransform, np.ndarray, np.ndarray, float]:
    """Desired tool pose, spatial velocity and acceleration ([w; v], [alpha; a] in W) and gripper
    width of `plan` at time t: a minimum-jerk move (straight line, slerp for rotation) between
    keyframes, at rest at each; the last keyframe is held. `times`: the keyframes' times, if
    known (plan needs at least two keyframes)."""
    times = np.array([k.t for k in plan.keyframes]) if times is None else times
    k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    a, b = plan.keyframes[k], plan.keyframes[k + 1]
    duration = b.t - a.t
    s, ds, dds = min_jerk((t - a.t) / duration)
    R_ab = a.X_WT.rotation().inverse() @ b.X_WT.rotation()
    aa = R_ab.ToAngleAxis()
    R = a.X_WT.rotation() @ RotationMatrix(AngleAxis(s * aa.angle(), aa.axis()))
    dp = b.X_WT.translation() - a.X_WT.translation()
    p = a.X_WT.translation() + s * dp
    w = a.X_WT.rotation() @ (aa.axis() * aa.angle())
    twist = np.concatenate([w, dp])
    width = a.width + min(max((t - a.t) / duration, 0.0), 1.0) * (b.width - a.width)
    return RigidTransform(R, p), twist * ds / duration, twist * dds / duration**2, width


class KeyframePlayer(LeafSystem):
    """Plays a KeyframePlan: outputs "X_WT_desired" (abstract RigidTransform), its velocity
    "V_WT_desired" and acceleration "A_WT_desired" (6 each, [w; v] in W) and "gripper_width" (1).
    Each segment between keyframes is a minimum-jerk move (straight line, slerp for rotation) that
    starts and ends at rest; the last keyframe is held."""

    def __init__(self, plan: KeyframePlan) -> None:
        super().__init__()
        if len(plan.keyframes) < 2:
            raise ValueError("a KeyframePlan needs at least two keyframes to play")
        self.plan = plan
        self._times = np.array([k.t for k in plan.keyframes])
        if np.any(np.diff(self._times) <= 0):
            raise ValueError("KeyframePlan keyframe times must increase strictly")
        self.DeclareAbstractOutputPort("X_WT_desired", lambda: AbstractValue.Make(RigidTransform()), self._calc_pose)
        self.DeclareVectorOutputPort("V_WT_desired", 6, lambda c, o: o.SetFromVector(self.sample(c.get_time())[1]))
        self.DeclareVectorOutputPort("A_WT_desired", 6, lambda c, o: o.SetFromVector(self.sample(c.get_time())[2]))
        self.DeclareVectorOutputPort("gripper_width", 1, lambda c, o: o.SetFromVector([self.sample(c.get_time())[3]]))

    def sample(self, t: float) -> tuple[RigidTransform, np.ndarray, np.ndarray, float]:
        """Desired tool pose, spatial velocity and acceleration ([w; v], [alpha; a] in W) and
        gripper width at time t (sample_plan)."""
        return sample_plan(self.plan, t, self._times)

    def _calc_pose(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self.sample(context.get_time())[0])
