"""The pick with the real fingers: they centre the gear along their closing axis (tool y) and
leave the aimed error along tool x; the planner's aim on that slice is one the skill succeeds at."""

import numpy as np

from assembly.world import grasp_with_error
from planning.grasp import PICK_MODEL, picked_grasp_errors
from planning.pick import held_grasp_error, simulate_pick
from learning.skill_evaluation import rollout_return
from learning.skill_file import load_skill
from planning.precondition import best_aim, insert_precondition
from pydrake.math import RigidTransform, RotationMatrix


def test_held_grasp_error_reads_grasp_with_error():
    X_WT = RigidTransform(RotationMatrix.MakeZRotation(0.7) @ RotationMatrix.MakeXRotation(np.pi), [0.4, 0.1, 0.3])
    xi = np.array([0.002, -0.001, 0.05])
    X_WG = X_WT @ grasp_with_error("medium", *xi)
    np.testing.assert_allclose(held_grasp_error(X_WT, X_WG, 2 * np.pi), xi, atol=1e-12)


def test_fingers_centre_the_closing_axis_and_keep_the_other():
    truth = (0.45, -0.05, 0.4)
    result = simulate_pick("medium", truth, (truth[0] + 0.0015, truth[1] + 0.0025, 0.0))
    assert result.lifted and not result.sim_error
    # the fingers close along world x (tool heading +-pi/2): tool y
    assert abs(abs(result.tool[2]) - np.pi / 2) < 1e-9
    assert abs(result.xi_aimed[1]) > 1e-3 and abs(result.xi_held[1]) < 1e-4
    assert abs(result.xi_held[0] - result.xi_aimed[0]) < 5e-4
    assert abs(result.xi_held[2] - result.xi_aimed[2]) < 0.01


def test_pick_model_pins_the_closing_axis():
    rng = np.random.default_rng(0)
    poses = np.array([0.4, 0.0, 0.0]) + rng.normal(0, 0.002, (200, 3))
    xi = picked_grasp_errors("large", poses, (0.4, 0.0, np.pi / 2), 2 * np.pi / 40, rng)
    assert np.std(xi[:, 1]) < 5 * PICK_MODEL["large"]["closing"][1] and np.std(xi[:, 0]) > 1e-3


def test_best_aim_on_the_finger_slice_is_a_success():
    skill = load_skill("insert", "medium")
    pre = insert_precondition("medium", skill=skill)
    aim = best_aim(pre)
    assert aim[1] == 0.0 and pre.holds(aim[None])
    assert rollout_return(skill, aim) >= skill.success_threshold
