"""goflow/Ant-v0: the Drake quadruped with a per-episode torso mass."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import assembly  # noqa: F401  (registers the goflow/ ids)
from assembly.envs.ant import NOMINAL_TORSO_MASS, SEED_J_T, AntConfig, AntEnv
from assembly.samplers import NoDR


@pytest.fixture(scope="module")
def env():
    e = AntEnv()
    yield e
    e.close()


def _actions(n, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, 8)).astype(np.float32)


def test_env_checker_passes():
    env = gymnasium.make("goflow/Ant-v0")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_task_definition(env):
    assert env.control_dt == pytest.approx(1 / 64)
    assert env.max_episode_steps == round(2.0 / env.control_dt) == 128
    # J_T: the seed's 700 over 119 steps of 1/60 s, rescaled to our 2 s episodes.
    assert env.success_threshold == pytest.approx(SEED_J_T * 120 / 119)
    assert env.space.names == ("torso_mass",) and env.space.units == ("kg",)
    np.testing.assert_array_equal(env.space.low, [0.01])
    np.testing.assert_array_equal(env.space.high, [20.0])
    assert NOMINAL_TORSO_MASS == pytest.approx(0.4839, abs=1e-4)  # the seed's "midpoint"
    assert env.plant.num_actuated_dofs() == 8


def test_same_seed_same_first_observation(env):
    other = AntEnv()
    oa, ia = env.reset(seed=123)
    ob, ib = other.reset(seed=123)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["xi"], ib["xi"])
    oc, _ = env.reset(seed=124)
    assert not np.array_equal(oa, oc)
    other.close()


def test_info_contract_and_mass_in_context(env):
    obs, info = env.reset(seed=0, options={"xi": [3.0]})
    assert obs.shape == (27,) and obs.dtype == np.float32
    assert info["xi"].shape == (1,) and info["xi"][0] == 3.0
    assert info["critic_obs"].shape == (28,)
    np.testing.assert_allclose(info["critic_obs"][:27], obs)
    np.testing.assert_allclose(info["critic_obs"][27], (3.0 - 0.01) / (20.0 - 0.01), rtol=1e-6)
    assert env.torso_mass() == pytest.approx(3.0)
    # The rotational inertia scales with the mass (same unit inertia).
    torso = env.plant.GetBodyByName("torso")
    ctx = env.plant.GetMyContextFromRoot(env._context)
    g = torso.CalcSpatialInertiaInBodyFrame(ctx).get_unit_inertia().CopyToFullMatrix3()
    g0 = torso.default_spatial_inertia().get_unit_inertia().CopyToFullMatrix3()
    np.testing.assert_allclose(g, g0)
    _, _, _, _, info2 = env.step(np.zeros(8, dtype=np.float32))
    assert info2["critic_obs"].shape == (28,) and info2["xi"][0] == 3.0


def test_xi_out_of_box_and_bad_actions_raise(env):
    with pytest.raises(ValueError, match=r"torso_mass.*\[0\.01, 20\] kg"):
        env.reset(options={"xi": [25.0]})
    with pytest.raises(ValueError, match="shape"):
        env.reset(options={"xi": [1.0, 2.0]})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan] + [0.0] * 7))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.inf] + [0.0] * 7))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(7))


def test_config_validation():
    with pytest.raises(TypeError, match="unknown"):
        AntEnv(time_stp=0.01)
    with pytest.raises(ValueError, match="integer multiple"):
        AntConfig(time_step=0.01, control_dt=0.015)
    with pytest.raises(ValueError, match="contact_approximation"):
        AntConfig(contact_approximation="magic")


def test_heavier_torso_changes_the_physics(env):
    acts = _actions(40, seed=1)
    final = {}
    for mass in (0.5, 15.0):
        env.reset(seed=5, options={"xi": [mass]})
        heights = []
        for a in acts:
            obs, *_ = env.step(a)
            heights.append(obs[0])
        final[mass] = (env.state(), np.array(heights))
    assert not np.allclose(final[0.5][0], final[15.0][0], atol=1e-3)
    # The heavy torso sits lower on average under the same torques.
    assert final[15.0][1].mean() < final[0.5][1].mean()


def test_zero_torque_stands_healthy_and_truncates_at_time_limit(env):
    env.reset(seed=0, options={"xi": [NOMINAL_TORSO_MASS]})
    zero = np.zeros(8, dtype=np.float32)
    for k in range(env.max_episode_steps):
        obs, reward, terminated, truncated, info = env.step(zero)
        assert not terminated, f"fell at step {k}: torso height {obs[0]:.3f} m"
        assert info["healthy"]
        assert truncated == (k == env.max_episode_steps - 1)
    assert obs[0] > env.config.termination_height
    assert "episode_return" in info and info["success"] is False  # standing still is no success
    with pytest.raises(RuntimeError, match="reset"):
        env.step(zero)


def test_bare_rollout_equals_env_step(env):
    acts = _actions(25, seed=3)
    env.reset(seed=11, options={"xi": [2.5]})
    for a in acts:
        env.step(a)
    stepped = env.state()
    bare = env.bare_rollout([2.5], acts, seed=11)
    np.testing.assert_array_equal(bare, stepped)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(acts[0])


@pytest.mark.parametrize("make, xi", [(AntEnv, [1.0]), ("anymal", None)])
def test_simulation_error_ends_episode_truncated(make, xi):
    if make == "anymal":  # the other quadruped: same failure path
        from assembly.envs.anymal import NOMINAL_BASE_MASS, AnymalEnv

        make, xi = AnymalEnv, [NOMINAL_BASE_MASS, 0.0, 0.0, 0.0, 0.0]
    env = make()
    env.reset(seed=0, options={"xi": xi})
    real = env._simulator

    class Failing:
        def AdvanceTo(self, t):
            raise RuntimeError("solver diverged")

    env._simulator = Failing()
    try:
        obs, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
    finally:
        env._simulator = real
    assert truncated and not terminated and "solver diverged" in info["sim_error"]


def test_sampler_drives_xi():
    env = AntEnv(sampler=NoDR(AntEnv().space, point=[7.0]))
    _, info = env.reset(seed=0)
    assert info["xi"][0] == 7.0 and env.torso_mass() == pytest.approx(7.0)
