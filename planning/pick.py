"""The pick with the real fingers, simulated: the grasp error it actually leaves against the one
the grasp geometry predicts from where the pick aimed (planning.grasp).

The station's scripted pick (assembly.scripted_motion) descends over the believed gear position,
closes the fingers on the gear's tip circle along the world x axis (tool heading +-pi/2: the
fingers close along the tool's y axis) and lifts. Contact and friction decide where the gear ends
up in the hand: the fingers push it towards their centre along their closing direction, so the
grasp error the insertion skill sees is not simply truth minus aim (docs/planning.md, "The pick").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from assembly.gearset import gear_spec
from assembly.scripted_motion import (
    ScriptedInsertionConfig,
    append_pick_and_insert,
    start_keyframe_plan,
    KeyframePlayer,
)
from assembly.station import StationConfig, build_station, drive_station
from assembly.world import WorldConfig, planar_pose
from planning.grasp import grasp_error


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


__all__ = ["PickConfig", "PickResult", "held_grasp_error", "simulate_pick"]
