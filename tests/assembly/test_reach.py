"""Reach near the robot's base: the inspect pose chosen reachable (assembly.inspection.inspect_yaw),
the controller's quasi-static model (assembly.reach.QuasiStaticTracker), and bad inputs."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from assembly.cameras import CamerasConfig, default_wrist_camera
from assembly.impedance import CartesianImpedanceController, ImpedanceGains
from assembly.reach import QuasiStaticTracker
from assembly.inspection import InspectConfig, append_inspect, inspect_tool_pose
from assembly.panda_model import Q_HOME, TAU_MAX
from assembly.scripted_motion import KeyframePlayer, ScriptedInsertionConfig, start_keyframe_plan
from assembly.station import StationConfig, build_station, drive_station, make_controller_plant
from assembly.world import WorldConfig

# The failure of issue 65: the small gear at x = 0.308 m, inspected from the start pose.
NEAR_BASE = (0.308, 0.0)


def _inspect(config: InspectConfig):
    station = build_station(StationConfig(world=WorldConfig(gears=()), cameras=CamerasConfig(scene=None, wrist=None)))
    plan = start_keyframe_plan(station.controller.tool_pose(Q_HOME), 0.08)
    t = append_inspect(plan, "small", NEAR_BASE, default_wrist_camera(), config)
    simulator = Simulator(drive_station(station, KeyframePlayer(plan)))
    simulator.Initialize()
    worst = np.inf
    context = simulator.get_context()
    for step in np.arange(0.1, t + 1e-9, 0.1):
        simulator.AdvanceTo(min(step, t))
        q = station.plant.GetPositions(station.plant_context(context), station.models.arm)
        worst = min(worst, float(station.controller.joint_limit_margin(q).min()))
    error = np.linalg.norm(station.tool_pose(context).translation() - plan.keyframes[-1].X_WT.translation())
    return error, worst


def test_near_base_inspection_reaches_within_1mm_with_joints_clear():
    error, worst = _inspect(InspectConfig())
    assert error < 1e-3, f"tool {1e3 * error:.2f} mm from the inspect pose"
    assert worst > 0.05, f"a joint came within {worst:.3f} rad of its limit"


def test_near_base_inspection_at_the_hands_yaw_stops_short():
    # The old choice (the hand's yaw kept): joint 4 runs onto its limit, the tool stops ~60 mm short.
    error, worst = _inspect(InspectConfig(joint_clearance=None))
    assert error > 0.02 and worst < 0.01


def test_tracker_predicts_the_limit_and_the_reachable_yaw():
    tracker = QuasiStaticTracker()
    camera = default_wrist_camera()
    q, error = tracker.track(Q_HOME, inspect_tool_pose(NEAR_BASE, camera, yaw=0.0))
    assert error > 0.02 and tracker.margin(q).min() < 1e-6  # joint 4 on its limit
    q, error = tracker.track(Q_HOME, inspect_tool_pose(NEAR_BASE, camera, yaw=math.pi))
    assert error < 1e-4 and tracker.margin(q).min() > 0.15


def test_far_inspection_keeps_the_hands_yaw():
    plan = start_keyframe_plan(
        build_station(StationConfig(world=WorldConfig(gears=()))).controller.tool_pose(Q_HOME), 0.08
    )
    append_inspect(plan, "small", (0.5, 0.15), default_wrist_camera())
    old = start_keyframe_plan(plan.keyframes[0].X_WT, 0.08)
    append_inspect(old, "small", (0.5, 0.15), default_wrist_camera(), InspectConfig(joint_clearance=None))
    assert plan.keyframes[-1].X_WT.IsExactlyEqualTo(old.keyframes[-1].X_WT)


def test_limit_torque_is_zero_outside_the_band_and_pushes_inside():
    plant, arm, tool = make_controller_plant()
    gains = ImpedanceGains(limit_stiffness=100.0, limit_margin=0.2)
    controller = CartesianImpedanceController(plant, arm, tool, gains, TAU_MAX, Q_HOME)
    np.testing.assert_array_equal(controller._limit_torque(Q_HOME), np.zeros(7))
    q = Q_HOME.copy()
    q[3] = -3.0218  # 0.05 rad above joint 4's lower limit: pushed up by 100 x 0.15
    np.testing.assert_allclose(controller._limit_torque(q)[3], 15.0, atol=1e-9)
    assert controller.joint_limit_margin(q)[3] == pytest.approx(0.05)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"nullspace_stiffness": -1.0}, "nullspace_stiffness"),
        ({"nullspace_damping": float("nan")}, "nullspace_damping"),
        ({"limit_stiffness": -5.0}, "limit_stiffness"),
        ({"limit_margin": 2.0}, "limit_margin"),
        ({"limit_margin": "0.1"}, "limit_margin"),
    ],
)
def test_bad_gains_give_one_line_errors(kwargs, match):
    with pytest.raises(ValueError, match=match) as info:
        ImpedanceGains(**kwargs)
    assert "\n" not in str(info.value)


def test_bad_posture_and_inspect_options_give_one_line_errors():
    plant, arm, tool = make_controller_plant()
    with pytest.raises(ValueError, match="q_nominal") as info:
        CartesianImpedanceController(plant, arm, tool, ImpedanceGains(), TAU_MAX, np.full(7, np.nan))
    assert "\n" not in str(info.value)
    for kwargs, match in (
        ({"joint_clearance": -0.1}, "joint_clearance"),
        ({"joint_clearance": float("nan")}, "joint_clearance"),
        ({"yaw_step": 0.0}, "yaw_step"),
        ({"yaw_step": 4.0}, "yaw_step"),
    ):
        with pytest.raises(ValueError, match=match) as info:
            InspectConfig(**kwargs)
        assert "\n" not in str(info.value)
    plan = start_keyframe_plan(inspect_tool_pose((0.5, 0.0)), 0.08)
    with pytest.raises(ValueError, match="q_start"):
        append_inspect(plan, "small", (0.5, 0.0), q_start=np.full(7, np.nan))


# -- the pick (planning.pick.reachable_pick) -------------------------------------------------------

PLATE = WorldConfig().plate_pose


def _pick_case(x, y, start, heading, pick):
    from benchmarks.reach import ReachCase, measure_case

    return measure_case(ReachCase("small", x, y, start, heading, 0.0, 0.3, 0.15, pick))


@pytest.mark.parametrize("start,heading", [("home", 1.414), ("home", 1.728)])
def test_near_base_pick_reaches_within_1mm(start, heading):
    # Issue 65: near the base the descent folds the arm through a near-singular posture; at the
    # free motions' speed the tool ended 1.4-106 mm from the grasp pose on the 5 x 5 grid.
    x, y = (0.3, -0.1175) if heading == 1.414 else (0.3, -0.005)
    old = _pick_case(x, y, start, heading, "default")
    assert old["pick_error_m"] > 1e-3
    new = _pick_case(x, y, start, heading, "reachable")
    assert new["pick_error_m"] < 1e-3, f"tool {1e3 * new['pick_error_m']:.2f} mm from the grasp pose"
    assert new["descend_speed"] < old["descend_speed"] and new["pick_heading"] == heading


def test_pick_next_to_the_plate_turns_the_fingers_off_it():
    from planning.pick import finger_clearance, reachable_pick

    tool = np.array([0.62, -0.005, math.pi / 2])  # the fingers close towards the plate's edge
    assert finger_clearance("small", tool, PLATE) == 0.0
    assert finger_clearance("small", [0.62, -0.005, 0.0], PLATE) > 0.02
    chosen, descend_speed = reachable_pick("small", tool, (0.0, 0.0, 0.0), tool, plate_pose=PLATE)
    assert finger_clearance("small", chosen, PLATE) >= 0.003 and chosen[2] != tool[2]
    assert descend_speed is None  # far from the base: the motion's own speed
    row = _pick_case(0.62, -0.005, "home", 1.728, "reachable")
    assert row["pick_error_m"] < 1e-3


def test_turned_tools_keep_the_aimed_grasp_error():
    from planning.grasp import aim_tool, grasp_error
    from planning.pick import pick_headings, reachable_pick

    pose, aim = np.array([0.45, 0.1, 0.7]), np.array([0.0025, -0.001, 0.05])
    for gear, teeth in (("small", 20), ("medium", 40), ("large", 60)):
        pitch = 2 * math.pi / teeth
        turns = pick_headings(gear)
        assert turns[0] == 0.0 and len(turns) == 20 and sum(abs(abs(t) - math.pi) < 1e-9 for t in turns) == 1
        for turn in turns:
            assert abs(turn / pitch - round(turn / pitch)) < 1e-9
            tool = aim_tool(pose, (aim[0], aim[1], pose[2] - (pose[2] - aim[2] + turn)))
            np.testing.assert_allclose(grasp_error(pose, tool, pitch, aim[2])[0], aim, atol=1e-12)
        # a plate right where the default fingers go: the turned tool still holds the aimed error
        tool0 = aim_tool(pose, aim)
        plate = (tool0[0] - math.sin(tool0[2]) * 0.06, tool0[1] + math.cos(tool0[2]) * 0.06, tool0[2])
        chosen, _ = reachable_pick(gear, pose, aim, tool0, plate_pose=plate)
        assert not np.allclose(chosen, tool0)
        np.testing.assert_allclose(grasp_error(pose, chosen, pitch, aim[2])[0], aim, atol=1e-12)


def test_plate_pose_from_a_shaft_and_clearance_to_other_gears():
    from planning.pick import finger_clearance, plate_pose_from_shaft

    station = build_station(StationConfig(world=WorldConfig(gears=()), cameras=CamerasConfig(scene=None, wrist=None)))
    for gear in ("small", "medium", "large"):
        np.testing.assert_allclose(plate_pose_from_shaft(gear, station.models.X_WS(gear)), PLATE, atol=1e-12)
    # a medium gear 5 cm (tip to tip) along the closing axis: the open fingers fit, 24 mm to spare
    tool = (0.4, 0.0, 0.0)  # closing axis along world y
    gap = finger_clearance("small", tool, None, {"medium": (0.4, 0.011 + 0.021 + 0.05)})
    assert gap == pytest.approx(0.05 - 0.006 - 0.020, abs=1e-9)
    assert finger_clearance("small", tool, None, {"medium": (0.4, 0.04)}) == 0.0
    assert finger_clearance("small", tool, None) == math.inf


def test_pick_reach_off_keeps_the_default_and_bad_inputs_give_one_line_errors():
    from planning.pick import PickReachConfig, reachable_pick

    tool = np.array([0.3, 0.0, math.pi / 2])
    motion = ScriptedInsertionConfig()
    chosen, speed = reachable_pick("small", tool, (0, 0, 0), tool, motion=motion, config=PickReachConfig(enabled=False))
    assert np.array_equal(chosen, tool) and speed is None
    assert reachable_pick("small", tool, (0, 0, 0), tool)[1] == PickReachConfig().near_base_speed
    for kwargs, match in (
        ({"enabled": 1}, "enabled"),
        ({"finger_clearance": -0.1}, "finger_clearance"),
        ({"turn_step": float("nan")}, "turn_step"),
        ({"turn_step": 0.0}, "turn_step"),
        ({"max_turn": 4.0}, "max_turn"),
        ({"near_base_radius": True}, "near_base_radius"),
        ({"near_base_speed": "0.03"}, "near_base_speed"),
    ):
        with pytest.raises(ValueError, match=match) as info:
            PickReachConfig(**kwargs)
        assert "\n" not in str(info.value)
    for args, match in (
        (("small", tool, (0, 0, 0), tool + [0, 0, 0.1]), "tooth pitch"),
        (("small", tool, (0.001, 0, 0), tool), "grasp error"),
        (("small", tool[:2], (0, 0, 0), tool), "pose"),
        (("small", tool, (0, 0, float("inf")), tool), "aim"),
        (("tiny", tool, (0, 0, 0), tool), "tiny"),
    ):
        with pytest.raises(ValueError, match=match) as info:
            reachable_pick(*args)
        assert "\n" not in str(info.value)
