"""Batched vector envs (N copies in one Drake plant) against N single envs in a SyncVectorEnv:
same seeds and actions give the same xi, endings and trajectories (within the stated tolerance
where the solver couples the copies); bad num_envs, xi and failing copies are handled."""

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import assembly  # noqa: F401  (registers the ids)
from assembly.envs import VECTOR_ENVS
from goflow_common.errors import InputError

# Largest |difference| of observations over 1.5 episodes of random actions. One copy is the single
# env exactly; with N copies SAP solves one problem whose convergence test is over all copies, so
# each copy's step is solved to a slightly different point (measured: Cartpole 4e-5).
TOLERANCE = {
    "goflow/Cartpole-v0": 1e-3,
    "goflow/Quadrotor-v0": 1e-3,
    "goflow/GearInsertion-v0": 1e-3,
    # measured over seeds 11-13, with the kwargs below: Ant 9e-5, Anymal 1.4e-3 (joint rates)
    "goflow/Ant-v0": 1e-3,
    "goflow/Anymal-v0": 1e-2,
}
# Env kwargs of the comparison (both sides): shorter episodes where random torques make the walkers
# chaotic over a whole one (Ant: 3e-8 at step 1, 2.6 by 2.75 s) or the test slow (Anymal), and
# falls that end copies at different steps (Ant), so copies also restart alone.
KWARGS = {"goflow/Ant-v0": {"t_max": 0.5, "termination_height": 0.47}, "goflow/Anymal-v0": {"t_max": 2.0}}
IDS = sorted(VECTOR_ENVS)


def _pair(env_id: str, n: int, kwargs: dict | None = None):
    kwargs = KWARGS.get(env_id, {}) if kwargs is None else kwargs
    batched = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    sync = gymnasium.vector.SyncVectorEnv(
        [lambda: gymnasium.make(env_id, **kwargs) for _ in range(n)], autoreset_mode=AutoresetMode.SAME_STEP
    )
    return batched, sync


def _compare(env_id: str, n: int, tolerance: float, kwargs: dict | None = None) -> None:
    batched, sync = _pair(env_id, n, kwargs)
    assert batched.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    o1, i1 = batched.reset(seed=11)
    o2, i2 = sync.reset(seed=11)
    np.testing.assert_array_equal(i1["xi"], i2["xi"])
    np.testing.assert_allclose(o1, o2, atol=tolerance)
    rng = np.random.default_rng(0)
    steps = int(1.5 * sync.envs[0].unwrapped.max_episode_steps)
    ended = 0
    for _ in range(steps):
        a = rng.uniform(-1.0, 1.0, size=batched.action_space.shape).astype(np.float32)
        o1, r1, te1, tr1, i1 = batched.step(a)
        o2, r2, te2, tr2, i2 = sync.step(a)
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        np.testing.assert_allclose(o1, o2, atol=tolerance)
        np.testing.assert_array_equal(i1["xi"], i2["xi"])  # the next episodes drew the same xi
        np.testing.assert_allclose(i1["critic_obs"], i2["critic_obs"], atol=tolerance)
        if (te1 | tr1).any():
            ended += 1
            f1, f2 = i1["final_info"], i2["final_info"]
            done = te1 | tr1
            for key in ("xi", "episode_return", "success", "critic_obs"):
                np.testing.assert_array_equal(f1["_" + key], f2["_" + key])
                np.testing.assert_allclose(
                    np.asarray(f1[key][done], float), np.asarray(f2[key][done], float), atol=tolerance * steps
                )
            for i in np.flatnonzero(done):
                np.testing.assert_allclose(i1["final_obs"][i], i2["final_obs"][i], atol=tolerance)
    assert ended >= 1


@pytest.mark.parametrize("env_id", IDS)
def test_one_copy_is_the_single_env_exactly(env_id):
    _compare(env_id, 1, 0.0)


@pytest.mark.parametrize("copies, tolerance", [(1, 0.0), (3, 1e-3)])
def test_gear_copies_sensing_the_wrench_see_their_single_envs_noise_and_bias(copies, tolerance):
    # the same per-copy generator draws xi, the sensor's bias and its noise in the single env's order
    _compare("goflow/GearInsertion-v0", copies, tolerance, {"sensing": "wrench"})


@pytest.mark.parametrize("env_id", IDS)
def test_copies_follow_their_single_envs(env_id):
    _compare(env_id, 4, TOLERANCE[env_id])


@pytest.mark.parametrize("n", [0, -1, 2.5, True])
def test_bad_num_envs_is_refused(n):
    with pytest.raises(InputError, match="num_envs"):
        gymnasium.make_vec(IDS[0], num_envs=n, vectorization_mode="vector_entry_point")


def test_xi_outside_the_box_for_one_copy_names_it():
    env = gymnasium.make_vec("goflow/Cartpole-v0", num_envs=3, vectorization_mode="vector_entry_point")
    xi = np.tile(env.space.center(), (3, 1))
    xi[2, 0] = 1e3  # pole mass far outside [0.01, 20] kg
    with pytest.raises(ValueError, match="copy 2"):
        env.reset(seed=0, options={"xi": xi})


def test_a_copy_that_fails_is_reported_and_the_others_step_on():
    env = gymnasium.make_vec("goflow/Cartpole-v0", num_envs=3, vectorization_mode="vector_entry_point")
    twin = gymnasium.make_vec("goflow/Cartpole-v0", num_envs=3, vectorization_mode="vector_entry_point")
    env.reset(seed=5)
    twin.reset(seed=5)
    state = env._get_state(np.array([1]))
    state[0, 5] = 1e300  # copy 1's pole spins at an absurd rate: its step overflows
    env._set_state(np.array([1]), state)
    a = np.zeros((3, 1), dtype=np.float32)
    obs, reward, terminated, truncated, info = env.step(a)
    expected = twin.step(a)[0]
    assert truncated.tolist() == [False, True, False]
    assert "copy 1" in info["final_info"]["sim_error"][1]
    assert info["final_info"]["_sim_error"].tolist() == [False, True, False]
    np.testing.assert_allclose(obs[[0, 2]], expected[[0, 2]], atol=TOLERANCE["goflow/Cartpole-v0"])
    assert np.isfinite(obs).all() and np.isfinite(reward).all()
    env.step(a)  # the failed copy was reset and steps on


def test_set_attr_sampler_reaches_every_copy():
    from assembly.samplers import NoDR

    env = gymnasium.make_vec("goflow/Cartpole-v0", num_envs=3, vectorization_mode="vector_entry_point")
    env.set_attr("sampler", NoDR(env.space))
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["xi"], np.tile(info["xi"][0], (3, 1)))
    with pytest.raises(AttributeError, match="only 'sampler'"):
        env.set_attr("control_dt", 1.0)


def test_gear_copies_in_contact_agree_with_single_envs_in_outcome():
    """Under contact the solver's coupling perturbs each copy by its convergence tolerance, and the
    chamfer contact amplifies it: trajectories separate, but outcomes agree (measured: 8 and 16
    pushes from grasp errors within 3 mm, returns within 1.1 % of ~100, every success the same)."""
    env_id, n, kwargs = "goflow/GearInsertion-v0", 8, {"grasp_xy": 0.003, "grasp_yaw": 0.3}
    batched = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    sync = gymnasium.vector.SyncVectorEnv(
        [lambda: gymnasium.make(env_id, **kwargs) for _ in range(n)], autoreset_mode=AutoresetMode.SAME_STEP
    )
    batched.reset(seed=1)
    sync.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(sync.envs[0].unwrapped.max_episode_steps):
        a = rng.uniform(-1.0, 1.0, size=(n, 4))
        a[:, :2] *= 0.3
        a[:, 2] = -1.0  # press down while wandering a little, as an inserting policy does
        _, _, _, tr1, i1 = batched.step(a)
        _, _, _, tr2, i2 = sync.step(a)
    assert tr1.all() and tr2.all()
    f1, f2 = i1["final_info"], i2["final_info"]
    np.testing.assert_array_equal(f1["success"], f2["success"])
    np.testing.assert_allclose(f1["episode_return"], f2["episode_return"], rtol=0.03)
