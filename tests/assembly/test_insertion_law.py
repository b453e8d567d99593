"""One observation/action law for the insertion policy: the env's observations and impedance
targets are those of assembly.insertion_law fed with the env's own tool poses, so the shipped
policy gives the same action from a history built outside the env (as the planner builds it)."""

import numpy as np
import pytest

from assembly.envs.gear_insertion import GearInsertionEnv
from assembly.insertion_law import InsertionLaw, PoseHistory
from goflow_common.errors import InputError
from learning.skill_file import load_skill


def test_env_and_law_agree_step_by_step():
    skill = load_skill("insert", "medium")
    env = GearInsertionEnv(gear="medium", variant="fast")
    obs, _ = env.reset(seed=0, options={"xi": np.array([0.001, -0.001, 0.05])})
    outside = PoseHistory(env.law)  # what a controller outside the env keeps
    outside.reset(env.tool_pose())
    for _ in range(6):
        np.testing.assert_array_equal(obs, outside.observation())
        action = skill.act(outside.observation())
        np.testing.assert_array_equal(action, skill.act(obs))
        pose = env.tool_pose()
        np.testing.assert_array_equal(env._target(action), env.law.target(action, pose))
        obs, *_ = env.step(action)
        outside.push(env.tool_pose())
    env.close()


def test_target_stays_in_the_workspace_and_actions_are_clipped():
    law = InsertionLaw((0.5, 0.0, 0.1, 0.3), (0.003, 0.003, 0.02, 0.05), (0.06, 0.06, 0.06, 0.6), 10, 0.04)
    far = np.array([0.9, 0.0, 0.1, 0.3])
    np.testing.assert_allclose(law.target([0, 0, 0, 0], far), [0.56, 0.0, 0.1, 0.3])
    np.testing.assert_allclose(law.target([5, 0, 0, 0], law.seated), law.target([1, 0, 0, 0], law.seated))
    np.testing.assert_allclose(law.relative([0.5, 0.0, 0.1, 0.3 + 2 * np.pi]), 0.0, atol=1e-12)


def test_bad_law_is_named():
    with pytest.raises(InputError, match="seated"):
        InsertionLaw((0.5, 0.0, np.nan, 0.0), (1, 1, 1, 1), (1, 1, 1, 1), 10, 0.04)
    with pytest.raises(InputError, match="control_dt"):
        InsertionLaw((0.5, 0.0, 0.1, 0.0), (1, 1, 1, 1), (1, 1, 1, 1), 10, 0.0)
