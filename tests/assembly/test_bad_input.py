"""Bad input gets a clear error naming the value and what was expected."""

import numpy as np
import pytest

from assembly.demo import AssemblyConfig
from assembly.gearset import gear_spec
from assembly.scripted_motion import (
    ScriptedInsertionConfig,
    append_pick_and_insert,
    down_pose,
    start_keyframe_plan,
)
from assembly.station import StationConfig, build_station
from assembly.world import WorldConfig, planar_pose, validate_tool_target


def test_unknown_gear_name():
    with pytest.raises(ValueError, match=r"unknown gear 'huge'.*small.*medium.*large"):
        gear_spec("huge")
    with pytest.raises(ValueError, match="unknown gear 'tiny'"):
        AssemblyConfig(order=("tiny",))
    with pytest.raises(ValueError, match="unknown gear 'tiny'"):
        WorldConfig(gears=("tiny",))


def test_unknown_gear_in_station_queries():
    station = build_station(StationConfig(world=WorldConfig(gears=("medium",)), cameras=_no_cameras()))
    context = station.diagram.CreateDefaultContext()
    with pytest.raises(ValueError, match="unknown gear 'shaft9'"):
        station.insertion_error(context, "shaft9")
    with pytest.raises(ValueError, match=r"gear 'large' is not in this station.*medium"):
        station.gear_pose(context, "large")


def _no_cameras():
    from assembly.cameras import CamerasConfig

    return CamerasConfig(scene=None, wrist=None)


@pytest.mark.parametrize(
    "pose,message",
    [
        ((2.0, 0.0, 0.0), "outside the table"),
        ((0.40, -0.6, 0.0), "outside the table"),
        ((0.05, 0.05, 0.0), "from the robot base"),
        ((0.55, 0.0, 0.0), "overlaps the gear plate"),
        ((0.40, float("nan"), 0.0), "three finite numbers"),
    ],
)
def test_gear_pose_off_the_table(pose, message):
    poses = dict(WorldConfig().gear_start_poses, medium=pose)
    with pytest.raises(ValueError, match=message) as info:
        WorldConfig(gear_start_poses=poses)
    assert "medium" in str(info.value)


def test_gears_too_close_to_each_other():
    poses = dict(WorldConfig().gear_start_poses, small=(0.40, -0.01, 0.0))
    with pytest.raises(ValueError, match="from the medium gear|from the small gear"):
        WorldConfig(gear_start_poses=poses)


def test_plate_off_the_table():
    with pytest.raises(ValueError, match=r"plate_pose .* off the table"):
        WorldConfig(plate_pose=(1.5, 0.0, 0.0))


@pytest.mark.parametrize("p", [[1.2, 0.0, 0.2], [0.4, 0.0, 1.5], [0.05, 0.0, 0.3], [0.4, 0.0, -0.2]])
def test_target_outside_workspace(p):
    with pytest.raises(ValueError, match="outside the workspace"):
        validate_tool_target(down_pose(np.array(p), 0.0))


def test_scripted_insertion_rejects_unreachable_shaft():
    plan = start_keyframe_plan(down_pose(np.array([0.3, 0.0, 0.4]), 0.0), 0.08)
    with pytest.raises(ValueError, match="outside the workspace"):
        append_pick_and_insert(
            plan, "medium", planar_pose(0.4, 0.0, 0.0), planar_pose(1.5, 0.0, 0.0), ScriptedInsertionConfig()
        )


def test_bad_configs():
    with pytest.raises(ValueError, match="time_step"):
        StationConfig(time_step=0.5)
    with pytest.raises(ValueError, match="contact_model"):
        StationConfig(contact_model="rigid")
    with pytest.raises(ValueError, match="insert_speed"):
        ScriptedInsertionConfig(insert_speed=0.0)


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "env_id, option, value, message",
    [
        (
            "goflow/GearInsertion-v0",
            "action_scale",
            [NAN] * 4,
            r"GearInsertionConfig\.action_scale must be finite; 4 entries are not \(first: flat index 0 = nan\)",
        ),
        (
            "goflow/GearInsertion-v0",
            "action_scale",
            [0.003, 0.003, 0.02],
            r"GearInsertionConfig\.action_scale has shape \(3,\); expected \(4,\)",
        ),
        (
            "goflow/GearInsertion-v0",
            "workspace",
            [0.06, 0.06, 0.06, 0.0],
            r"GearInsertionConfig\.workspace = \[0\.06, 0\.06, 0\.06, 0\.0\]; expected 4 numbers > 0",
        ),
        (
            "goflow/GearInsertion-v0",
            "success_threshold",
            NAN,
            r"GearInsertionConfig\.success_threshold = nan; expected a finite number",
        ),
        ("goflow/Cartpole-v0", "success_threshold", NAN, r"CartpoleConfig\.success_threshold = nan; expected a finite"),
        ("goflow/Cartpole-v0", "rew_alive", INF, r"CartpoleConfig\.rew_alive = inf; expected a finite number"),
        ("goflow/Quadrotor-v0", "success_threshold", NAN, r"QuadrotorConfig\.success_threshold = nan; expected"),
        (
            "goflow/Quadrotor-v0",
            "start_position",
            [0.0, 0.0, NAN],
            r"QuadrotorConfig\.start_position must be finite; 1 entries are not \(first: flat index 2 = nan\)",
        ),
        ("goflow/Quadrotor-v0", "inertia", [0.0015, 0.0025, INF], r"QuadrotorConfig\.inertia must be finite"),
        ("goflow/Ant-v0", "success_threshold", NAN, r"AntConfig\.success_threshold = nan; expected a finite number"),
        ("goflow/Ant-v0", "death_cost", NAN, r"AntConfig\.death_cost = nan; expected a finite number"),
    ],
)
def test_env_options_are_checked_with_value_and_expectation(env_id, option, value, message):
    import gymnasium

    import assembly.envs  # noqa: F401 (registers the goflow/ ids)
    from goflow_common.errors import InputError

    with pytest.raises(InputError, match=message) as info:
        gymnasium.make(env_id, **{option: value})
    assert "\n" not in str(info.value)
