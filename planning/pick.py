"""The pick with the real fingers, simulated: the grasp error it actually leaves against the one
the grasp geometry predicts from where the pick aimed (planning.grasp).

The station's scripted pick (assembly.scripted_motion) descends over the believed gear position,
closes the fingers on the gear's tip circle along the world x axis (tool heading +-pi/2: the
fingers close along the tool's y axis) and lifts. Contact and friction decide where the gear ends
up in the hand: the fingers push it towards their centre along their closing direction, so the
grasp error the insertion skill sees is not simply truth minus aim (docs/planning.md, "The pick").

The pick's tool heading is free up to the gear's symmetry: turning it by a multiple of the tooth
pitch (pi included: every gear has an even tooth count, and the fingers are symmetric) leaves the
grasp error the planner aimed for unchanged. `reachable_pick` uses that freedom where the open
fingers would touch the plate or another gear (next to the plate they did: the tool bounced up to
2 mm off its grasp pose), and slows the descent and the lift near the robot's base, where the
arm folds through its shoulder singularity (joints 1 and 3 aligned) on the way down: at the free
motions' speed the null-space motion there swung joints 1, 3, 5 and 7 and the tool ended up to
0.1 m from the grasp pose, depending on a posture the planner does not measure; slowly, the
controller tracks through it (docs/planning.md, "Reach").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from assembly.gearset import PLATE_SIZE, gear_spec, shaft_position_in_plate
from assembly.panda_model import PAD_SIZE
from assembly.reach import turns_by_size
from assembly.scripted_motion import (
    KeyframePlayer,
    ScriptedInsertionConfig,
    append_pick_and_insert,
    gripper_widths,
    start_keyframe_plan,
)
from assembly.station import StationConfig, build_station, drive_station
from assembly.world import WorldConfig, planar_pose
from planning.grasp import aim_tool, grasp_error


@dataclass(frozen=True)
class PickResult:
    """One simulated pick: the gear's true and believed poses (x, y, yaw), the tool pose the pick
    aimed at (x, y, heading), the grasp error predicted from the aim (`xi_aimed`) and the one
    measured after the lift (`xi_held`; yaw modulo the tooth pitch), whether the gear was lifted,
    and a physics failure if one happened."""

    gear: str
    truth: NDArray[np.float64]
    believed: NDArray[np.float64]
    tool: NDArray[np.float64]
    xi_aimed: NDArray[np.float64]
    xi_held: NDArray[np.float64] | None
    lifted: bool
    sim_error: str = ""


@dataclass
class PickConfig:
    """The station and the scripted motion the pick runs with; `lift_settle` [s] after the lift
    keyframe before the grasp is measured."""

    motion: ScriptedInsertionConfig = field(default_factory=ScriptedInsertionConfig)
    time_step: float = 0.008
    lift_settle: float = 0.3


def held_grasp_error(X_WT: RigidTransform, X_WG: RigidTransform, period: float) -> NDArray[np.float64]:
    """The grasp error (x, y, yaw) of a gear at X_WG held by a tool at X_WT: X_TG read as
    assembly.world.grasp_with_error writes it (Rx(pi) Rz(yaw), (x, y, h)); yaw modulo `period`."""
    X_TG = X_WT.inverse() @ X_WG
    R = (RotationMatrix.MakeXRotation(np.pi).inverse() @ X_TG.rotation()).matrix()
    yaw = np.arctan2(R[1, 0], R[0, 0])
    yaw = (yaw + period / 2) % period - period / 2
    return np.array([*X_TG.translation()[:2], yaw])


def simulate_pick(
    gear: str, truth: tuple[float, float, float], believed: tuple[float, float, float], config: PickConfig | None = None
) -> PickResult:
    """Pick `gear` lying at `truth` with the scripted pick aimed at `believed` (only x and y
    matter: the fingers close on the round tip circle) in a station holding only that gear and
    the plate; measure the grasp after the lift."""
    config = config or PickConfig()
    spec = gear_spec(gear)
    truth_a, believed_a = np.asarray(truth, float), np.asarray(believed, float)
    if truth_a.shape != (3,) or believed_a.shape != (3,):
        raise ValueError(f"truth {truth!r}, believed {believed!r}; expected (x, y, yaw) each")
    world = WorldConfig(gears=(gear,), gear_start_poses={gear: tuple(truth_a)})
    station = build_station(StationConfig(world=world, time_step=config.time_step))
    X_WT0 = station.controller.tool_pose(np.asarray(world.q_arm_start, dtype=float))
    plan = start_keyframe_plan(X_WT0, world.finger_width_start)
    append_pick_and_insert(plan, gear, planar_pose(*believed_a), station.models.X_WS(gear), config.motion)
    lift = next(k for k in plan.keyframes if k.label == f"{gear}: lift")
    grasp = next(k for k in plan.keyframes if k.label == f"{gear}: grasp")
    m = grasp.X_WT.rotation().matrix()
    tool = np.array([*grasp.X_WT.translation()[:2], np.arctan2(m[1, 0], m[0, 0])])
    period = 2 * np.pi / spec.teeth
    xi_aimed = grasp_error(truth_a, tool, period)[0]
    simulator = Simulator(drive_station(station, KeyframePlayer(plan)))
    simulator.Initialize()
    root = simulator.get_context()
    try:
        simulator.AdvanceTo(lift.t + config.lift_settle)
    except RuntimeError as exc:  # a failed physics step is reported, not hidden
        return PickResult(
            gear,
            truth_a,
            believed_a,
            tool,
            xi_aimed,
            None,
            False,
            f"simulation failed at t = {root.get_time():.3f} s: {exc}",
        )
    X_WG = station.gear_pose(root, gear)
    lifted = bool(X_WG.translation()[2] > 0.01)
    xi_held = held_grasp_error(station.tool_pose(root), X_WG, period) if lifted else None
    return PickResult(gear, truth_a, believed_a, tool, xi_aimed, xi_held, lifted)


# The open fingers seen from above, in the tool frame: each finger (pad, body and rail slider)
# spans FINGER_DEPTH along the closing axis (tool y) beyond its inner face at half the open width,
# and FINGER_HALF_WIDTH either side of it along tool x (assembly.panda_model's finger geometry).
FINGER_DEPTH = 0.020
FINGER_HALF_WIDTH = 0.011
assert PAD_SIZE[0] / 2 <= FINGER_HALF_WIDTH


@dataclass(frozen=True)
class PickReachConfig:
    """How `reachable_pick` adapts the pick. `enabled` False: the default heading and speed, as
    before; `finger_clearance` [m]: the open fingers' footprint must keep this far from the plate
    and the other gears; `turn_step` [rad]: the headings tried are this far apart (rounded to a
    multiple of the gear's tooth pitch), up to `max_turn` [rad] either way from the default;
    `near_base_radius` [m]: a pick whose tool is closer than this to the base axis descends and
    lifts at `near_base_speed` [m/s] (mean tool speed; the approach keeps the free motions')."""

    enabled: bool = True
    finger_clearance: float = 0.003
    turn_step: float = math.pi / 10
    max_turn: float = math.pi
    near_base_radius: float = 0.40
    near_base_speed: float = 0.02

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise ValueError(f"PickReachConfig.enabled = {self.enabled!r}; expected True or False")
        for name, low, high in (
            ("finger_clearance", 0.0, 0.05),
            ("turn_step", 0.0, math.pi),
            ("max_turn", 0.0, math.pi),
            ("near_base_radius", 0.0, 1.0),
            ("near_base_speed", 0.0, 1.0),
        ):
            v = getattr(self, name)
            ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
            if not (ok and (low < v <= high or (name in ("finger_clearance", "near_base_radius") and v == 0))):
                raise ValueError(f"PickReachConfig.{name} = {v!r}; expected a number in [{low}, {high}]")


def plate_pose_from_shaft(gear: str, X_WS: RigidTransform) -> tuple[float, float, float]:
    """The plate's planar pose (x, y, yaw) from the pose of `gear`'s shaft frame."""
    X_WP = X_WS @ RigidTransform(shaft_position_in_plate(gear)).inverse()
    R = X_WP.rotation().matrix()
    return (float(X_WP.translation()[0]), float(X_WP.translation()[1]), float(np.arctan2(R[1, 0], R[0, 0])))


def _point_segment(x: NDArray[np.float64], p0: NDArray[np.float64], p1: NDArray[np.float64]) -> float:
    d = p1 - p0
    t = float(np.clip((x - p0) @ d / (d @ d), 0.0, 1.0))
    return float(np.linalg.norm(x - (p0 + t * d)))


def _separated(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    """Whether an edge of convex polygon `a` (corners counter-clockwise) has all of `b` outside."""
    for i in range(len(a)):
        e = a[(i + 1) % len(a)] - a[i]
        if np.min((b - a[i]) @ np.array([e[1], -e[0]])) > 0:
            return True
    return False


def _rectangle_distance(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Distance between two rectangles (corners (4, 2) each, counter-clockwise) in the plane; 0 if
    they overlap."""
    if not (_separated(a, b) or _separated(b, a)):
        return 0.0
    return min(_point_segment(x, p[i], p[(i + 1) % 4]) for p, o in ((a, b), (b, a)) for x in o for i in range(4))


def _point_rectangle_distance(x: NDArray[np.float64], a: NDArray[np.float64]) -> float:
    """Distance from point `x` to rectangle `a` (corners (4, 2), counter-clockwise); 0 inside."""
    if not _separated(a, x[None]):
        return 0.0
    return min(_point_segment(x, a[i], a[(i + 1) % 4]) for i in range(4))


def _rectangle(centre: ArrayLike, axis_x: ArrayLike, half_x: float, half_y: float) -> NDArray[np.float64]:
    ax = np.asarray(axis_x, float)
    ay = np.array([-ax[1], ax[0]])
    c = np.asarray(centre, float)
    return np.array([c + sx * half_x * ax + sy * half_y * ay for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))])


def finger_clearance(
    gear: str,
    tool: ArrayLike,
    plate_pose: tuple[float, float, float] | None,
    others: Mapping[str, tuple[float, float]] | None = None,
    motion: ScriptedInsertionConfig | None = None,
) -> float:
    """The open fingers' distance [m] in the plane, at a pick of `gear` with the tool at `tool` =
    (x, y, heading), to the plate at `plate_pose` (None: no plate) and to the tip circles of the
    gears `others` (name -> (x, y)); 0 where they overlap, inf with nothing around."""
    motion = motion or ScriptedInsertionConfig()
    x, y, h = np.asarray(tool, float)
    open_w, _ = gripper_widths(gear, motion)
    along, closing = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    d = open_w / 2 + FINGER_DEPTH / 2
    fingers = [_rectangle((x, y) + s * d * closing, along, FINGER_HALF_WIDTH, FINGER_DEPTH / 2) for s in (1, -1)]
    best = math.inf
    if plate_pose is not None:
        px, py, pyaw = plate_pose
        plate = _rectangle((px, py), (math.cos(pyaw), math.sin(pyaw)), PLATE_SIZE[0] / 2, PLATE_SIZE[1] / 2)
        best = min(best, *(_rectangle_distance(f, plate) for f in fingers))
    for name, (ox, oy) in (others or {}).items():
        r = gear_spec(name).tip_radius
        for f in fingers:
            best = min(best, max(_point_rectangle_distance(np.array([ox, oy], float), f) - r, 0.0))
    return float(best)


def pick_headings(gear: str, config: PickReachConfig | None = None) -> list[float]:
    """The heading turns tried, ordered by size (0 first, then +-step, +-2 step, ...): multiples of
    the tooth pitch about `config.turn_step` apart, up to `config.max_turn` (a turn of pi once)."""
    config = config or PickReachConfig()
    pitch = gear_spec(gear).tooth_pitch_angle
    return turns_by_size(pitch * max(1, round(config.turn_step / pitch)), config.max_turn)


def reachable_pick(
    gear: str,
    pose: ArrayLike,
    aim: ArrayLike,
    tool: ArrayLike,
    *,
    plate_pose: tuple[float, float, float] | None = None,
    others: Mapping[str, tuple[float, float]] | None = None,
    motion: ScriptedInsertionConfig | None = None,
    config: PickReachConfig | None = None,
) -> tuple[NDArray[np.float64], float | None]:
    """The tool pose (x, y, heading) and the descent speed (append_pick's descend_speed) for picking `gear` believed at `pose`
    (x, y, yaw) with the aimed grasp error `aim` (x, y, yaw), from `tool`, the planner's default
    (aim_tool at some heading): the same grasp error at the first heading in `pick_headings` order
    whose open fingers keep `config.finger_clearance` from the plate at `plate_pose` and the gears
    `others` (name -> (x, y)) (failing all, the clearest), and `config.near_base_speed` for a
    tool within `config.near_base_radius` of the base axis (else None: `motion.speed`)."""
    config = config or PickReachConfig()
    motion = motion or ScriptedInsertionConfig()
    spec = gear_spec(gear)
    p, e, t0 = (np.asarray(v, float) for v in (pose, aim, tool))
    for name, v in (("pose", p), ("aim", e), ("tool", t0)):
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"{name} = {v.tolist()}; expected finite (x [m], y [m], yaw [rad])")
    pitch = spec.tooth_pitch_angle
    k = (p[2] - e[2] - t0[2]) / pitch
    if abs(k - round(k)) > 1e-6 or not np.allclose(grasp_error(p, t0, pitch, e[2])[0][:2], e[:2], atol=1e-9):
        raise ValueError(
            f"tool {t0.tolist()} does not hold a {gear} gear at {p.tolist()} with grasp error {e.tolist()}; "
            "expected aim_tool(pose, aim) turned by a multiple of the tooth pitch"
        )
    if not config.enabled:
        return t0, None
    best, best_clear = t0, -math.inf
    for turn in pick_headings(gear, config):
        candidate = aim_tool(p, (e[0], e[1], p[2] - (t0[2] + turn)))
        clear = finger_clearance(gear, candidate, plate_pose, others, motion)
        if clear >= config.finger_clearance:
            best = candidate
            break
        if clear > best_clear:
            best, best_clear = candidate, clear
    slow = math.hypot(best[0], best[1]) < config.near_base_radius and motion.speed > config.near_base_speed
    return best, config.near_base_speed if slow else None


__all__ = [
    "PickConfig",
    "PickReachConfig",
    "PickResult",
    "finger_clearance",
    "held_grasp_error",
    "pick_headings",
    "plate_pose_from_shaft",
    "reachable_pick",
    "simulate_pick",
]
