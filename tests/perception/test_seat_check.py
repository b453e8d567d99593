"""The seat check from the wrist camera's view after the release: a seated gear passes at any
heading, also through a real wrist camera's noise, depth scale and calibration error; one left
1 mm high, cocked beside its shaft, or missing fails; a view that does not see the shaft says
"unseen"."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from assembly.cameras import default_wrist_camera
from assembly.gearset import GEAR_NAMES, shaft_position_in_plate
from assembly.inspection import X_HT
from assembly.rgbd_sensor import D405
from assembly.scripted_motion import ScriptedInsertionConfig, down_pose
from assembly.world import WorldConfig, nominal_grasp, planar_pose
from perception.drake_scene import DrakeScene, SceneConfig
from perception.seat_check import SeatCheckConfig, check_seat

CAMERA = default_wrist_camera()
X_WP = planar_pose(*WorldConfig().plate_pose)
PARKED = RigidTransform([5.0, 5.0, 0.0])


def X_WS(gear):
    return X_WP @ RigidTransform(shaft_position_in_plate(gear))


@pytest.fixture(scope="module")
def scene():
    return DrakeScene(
        SceneConfig(
            gears={g: (0.3, 0.0, 0.0) for g in GEAR_NAMES},
            plate_pose=WorldConfig().plate_pose,
            occluders={"hand": "hand"},
        )
    )


def look(scene, gear, X_SG, heading=np.pi / 2, X_WT=None, X_CE=None, scale=None):
    """The others seated, `gear` at X_SG on its shaft, the open hand retreated above it; with X_CE
    the camera really sits at X_CE from where the robot believes it, and its depth comes through
    the D405 with that depth `scale`."""
    for g in GEAR_NAMES:
        X = X_WS(g) if g != gear else PARKED if X_SG is None else X_WS(g) @ X_SG
        scene.plant.SetFreeBodyPose(scene._plant_context, scene.bodies[g], X)
    if X_WT is None:
        up = nominal_grasp(gear).translation()[2] + ScriptedInsertionConfig().retreat_height
        X_WT = down_pose(X_WS(gear).translation() + [0.0, 0.0, up], heading)
    scene.set_occluder_pose("hand", X_WT @ X_HT.inverse())
    X_WC = X_WT @ X_HT.inverse() @ CAMERA.X_PC
    if X_CE is None:
        return check_seat(scene.render(CAMERA, X_WC), gear, X_WS(gear))
    obs = scene.render(CAMERA, X_WC @ X_CE)
    obs.depth = D405.depth(obs.depth, obs.intrinsics.fy, np.random.default_rng(0), scale)
    obs.X_WC = X_WC
    return check_seat(obs, gear, X_WS(gear))


@pytest.mark.parametrize("gear", GEAR_NAMES)
def test_a_seated_gear_passes_at_any_heading_and_yaw(scene, gear):
    for heading, yaw in ((np.pi / 2, 0.0), (0.3, 0.7)):
        check = look(scene, gear, RigidTransform(RotationMatrix.MakeZRotation(yaw), [0, 0, 0]), heading)
        assert check.verdict == "seated", check.reason
        assert abs(check.height_m) < 1e-4 and check.inliers > 0.99
    # seated but tilted by 2 degrees within the bore's clearance still passes
    assert look(scene, gear, RigidTransform(RollPitchYaw(np.radians(2), 0, 0), [0, 0, 0])).verdict == "seated"


@pytest.mark.parametrize("gear", GEAR_NAMES)
def test_a_real_wrist_cameras_noise_scale_and_calibration_error_do_not_unseat_a_seated_gear(scene, gear):
    # errors of twice the D405's std: 1 mm of mounting shift along each axis, 0.2 deg, 2 % scale
    for shift, angle, scale in (
        ((1e-3, 0, 0), (0.2, 0, 0), 1.02),
        ((-1e-3, 1e-3, 0), (0, -0.2, 0.2), 0.98),
        ((0, -1e-3, 1e-3), (0, 0, 0), 1.02),
    ):
        X_CE = RigidTransform(RollPitchYaw(np.radians(angle)), shift)
        for heading in (np.pi / 2, 0.3):
            seated = look(scene, gear, RigidTransform(), heading, X_CE=X_CE, scale=scale)
            assert seated.verdict == "seated", seated.reason
            high = look(scene, gear, RigidTransform([0.0, 0.0, 0.001]), heading, X_CE=X_CE, scale=scale)
            assert high.verdict == "unseated", high.reason


@pytest.mark.parametrize("gear", GEAR_NAMES)
def test_a_high_cocked_or_missing_gear_fails(scene, gear):
    high = look(scene, gear, RigidTransform([0.0, 0.0, 0.001]))
    assert high.verdict == "unseated" and high.height_m == pytest.approx(0.001, abs=2e-4), high.reason
    cocked = look(scene, gear, RigidTransform(RollPitchYaw(0, np.radians(2), 0), [0.003, 0.0, 0.001]))
    assert cocked.verdict == "unseated", cocked.reason
    missing = look(scene, gear, None)
    assert missing.verdict == "unseated" and missing.height_m < -0.01, missing.reason


def test_a_view_without_the_shaft_is_unseen_and_bad_input_is_named(scene):
    away = down_pose(np.array([0.3, -0.3, 0.2]), 0.0)
    check = look(scene, "medium", RigidTransform(), X_WT=away)
    assert check.verdict == "unseen" and np.isnan(check.height_m) and "fewer than" in check.reason
    obs = scene.render(CAMERA, away @ X_HT.inverse() @ CAMERA.X_PC)
    with pytest.raises(ValueError, match="unknown gear"):
        check_seat(obs, "huge", X_WS("small"))
    with pytest.raises(ValueError, match="tolerance"):
        SeatCheckConfig(tolerance=0.0)
