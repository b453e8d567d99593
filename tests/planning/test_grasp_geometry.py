"""The planner's grasp geometry against Drake's transforms: the grasp error a pick produces is
X_TG of assembly.world.grasp_with_error, and aiming for an error produces it."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from assembly.world import grasp_with_error
from planning.grasp import aim_tool, grasp_error


def _X_WG(pose):
    return RigidTransform(RotationMatrix.MakeZRotation(pose[2]), [pose[0], pose[1], 0.0])


def _X_WT(tool, height):
    return RigidTransform(
        RotationMatrix.MakeZRotation(tool[2]) @ RotationMatrix.MakeXRotation(np.pi), [tool[0], tool[1], height]
    )


@pytest.mark.parametrize("seed", range(5))
def test_grasp_error_is_the_gear_pose_in_the_tool_frame(seed):
    rng = np.random.default_rng(seed)
    pose = np.array([rng.uniform(0.3, 0.6), rng.uniform(-0.2, 0.2), rng.uniform(-np.pi, np.pi)])
    tool = pose + np.array([rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, 0.2)])
    xi = grasp_error(pose, tool)[0]
    X_TG = grasp_with_error("medium", *xi)
    # the gear's pose in the world through the tool, at the grasp's height
    X_WG = _X_WT(tool, 0.0) @ X_TG
    expected = _X_WG(pose)
    np.testing.assert_allclose(X_WG.translation()[:2], expected.translation()[:2], atol=1e-12)
    np.testing.assert_allclose(
        RollPitchYaw(X_WG.rotation()).vector(), RollPitchYaw(expected.rotation()).vector(), atol=1e-9
    )


def test_aim_tool_inverts_grasp_error_and_yaw_wraps_to_the_period():
    pose = np.array([0.45, -0.1, 0.3])
    xi = np.array([0.0012, -0.0007, 0.05])
    np.testing.assert_allclose(grasp_error(pose, aim_tool(pose, xi))[0], xi, atol=1e-12)
    period = 2 * np.pi / 20
    repeat = pose + [0, 0, 3 * period]  # the same gear, three teeth round
    np.testing.assert_allclose(grasp_error(repeat, aim_tool(pose, xi), period)[0], xi, atol=1e-12)
    # an aimed yaw beyond half a pitch: the class member near it, not the one near zero
    far = np.array([0.0, 0.0, -0.212])
    got = grasp_error(repeat, aim_tool(pose, far), period, yaw_centre=far[2])[0]
    np.testing.assert_allclose(got, far, atol=1e-12)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="expected finite"):
        grasp_error([[0, 0, np.nan]], [0, 0, 0])
    with pytest.raises(ValueError, match="period"):
        grasp_error([0, 0, 0], [0, 0, 0], period=0.0)
    with pytest.raises(ValueError, match="expected finite"):
        aim_tool([0, 0], [0, 0, 0])
