"""goflow/Cartpole-v0: Drake cart-pole balance with randomized pole mass, cart mass and slider friction."""

import math

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy.linalg import solve_continuous_are

import assembly  # noqa: F401  (registers the goflow/ ids)
from assembly.envs.cartpole import CartpoleEnv
from assembly.samplers import NoDR

NOMINAL = np.array([1.0, 1.0, 0.0])  # the seed robot's masses [kg], no slider friction


@pytest.fixture(scope="module")
def env():
    e = CartpoleEnv()
    yield e
    e.close()


def lqr_policy(env, xi):
    """LQR on the cart-pole linearized upright (no friction), from the plant state."""
    c = env.config
    m, M, l, b = xi[0], xi[1], c.pole_com, c.slider_damping
    inertia = m / 12.0 * (0.04**2 + c.pole_length**2)
    minv = np.linalg.inv(np.array([[M + m, m * l], [m * l, inertia + m * l * l]]))
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2:, :2] = minv @ np.array([[0.0, 0.0], [0.0, m * 9.81 * l]])
    A[2:, 2:] = minv @ np.array([[-b, 0.0], [0.0, 0.0]])
    B = np.zeros((4, 1))
    B[2:, 0] = minv @ np.array([1.0, 0.0])
    Q, R = np.diag([1.0, 50.0, 0.1, 1.0]), np.array([[1e-3]])
    K = np.linalg.solve(R, B.T @ solve_continuous_are(A, B, Q, R))

    def act(state):
        theta = (state[2] + math.pi) % (2 * math.pi) - math.pi
        s = np.array([state[0], theta, state[3], state[5]])
        return np.clip(-(K @ s) / c.max_force, -1.0, 1.0).astype(np.float32)

    return act


def test_env_checker_passes():
    env = gymnasium.make("goflow/Cartpole-v0")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_task_constants(env):
    assert env.control_dt == pytest.approx(1 / 60)
    assert env.max_episode_steps == 120
    assert env.success_threshold == 54.0
    assert env.space.names == ("pole_mass", "cart_mass", "slider_friction")
    np.testing.assert_array_equal(env.space.low, [0.01, 0.01, 0.0])
    np.testing.assert_array_equal(env.space.high, [20.0, 20.0, 1.0])
    with pytest.raises(TypeError, match="unknown"):
        CartpoleEnv(max_forse=10.0)
    assert CartpoleEnv(max_force=50.0).config.max_force == 50.0


def test_same_seed_same_first_observation(env):
    other = CartpoleEnv()
    oa, ia = env.reset(seed=5)
    ob, ib = other.reset(seed=5)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["xi"], ib["xi"])
    oc, ic = env.reset(seed=6)
    assert not np.array_equal(oa, oc) and not np.array_equal(ia["xi"], ic["xi"])


def test_info_shapes_and_truncation(env):
    obs, info = env.reset(seed=0)
    assert obs.shape == (5,) and info["xi"].shape == (3,) and info["critic_obs"].shape == (8,)
    for k in range(env.max_episode_steps):
        obs, r, term, trunc, info = env.step(np.zeros(1, dtype=np.float32))
        assert not term
        assert trunc == (k == env.max_episode_steps - 1)
        assert info["critic_obs"].shape == (8,) and env.observation_space.contains(obs)
    assert "episode_return" in info and "success" in info
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1))


def test_bad_xi_and_actions(env):
    with pytest.raises(ValueError, match=r"'pole_mass'.*\[0.01, 20\] kg"):
        env.reset(options={"xi": [25.0, 1.0, 0.1]})
    with pytest.raises(ValueError, match=r"'slider_friction'.*\[0, 1\]"):
        env.reset(options={"xi": [1.0, 1.0, -0.1]})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan]))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.inf]))


def test_xi_changes_the_physics(env):
    actions = np.random.default_rng(0).uniform(-1, 1, size=(60, 1))
    start = np.array([0.0, 0.1499, 0.2, 0.0, 0.0, 0.0])
    light = env.bare_rollout([1.0, 1.0, 0.0], actions, initial_state=start)
    heavy = env.bare_rollout([5.0, 1.0, 0.0], actions, initial_state=start)
    assert np.abs(light[:, [0, 2]] - heavy[:, [0, 2]]).max() > 0.1  # cart and pole paths differ
    # Coulomb friction: a heavy cart with mu = 1 (friction up to ~390 N) cannot be moved by 100 N.
    push = np.ones((60, 1))
    free = env.bare_rollout([10.0, 10.0, 0.0], push, initial_state=np.r_[0.0, 0.149, 0.0, 0, 0, 0])
    stuck = env.bare_rollout([10.0, 10.0, 1.0], push, initial_state=np.r_[0.0, 0.149, 0.0, 0, 0, 0])
    assert free[-1, 0] > 0.5 and abs(stuck[-1, 0]) < 1e-3


def test_lqr_reaches_threshold_at_nominal_and_fails_when_stuck(env):
    returns = []
    for xi, seed in [(NOMINAL, 0), (NOMINAL, 1), (np.array([2.0, 1.0, 0.2]), 2)]:
        act = lqr_policy(env, xi)
        env.reset(seed=seed, options={"xi": xi})
        done = False
        while not done:
            _, _, term, trunc, info = env.step(act(env.plant_state))
            done = term or trunc
        returns.append(info["episode_return"])
        assert info["success"]
    assert min(returns) >= env.success_threshold
    # Heavy masses with full friction: the cart cannot move and the pole falls.
    xi = np.array([10.0, 10.0, 1.0])
    act = lqr_policy(env, xi)
    env.reset(seed=0, options={"xi": xi})
    done = False
    while not done:
        _, _, term, trunc, info = env.step(act(env.plant_state))
        done = term or trunc
    assert not info["success"]


def test_bare_rollout_matches_env_step(env):
    xi = np.array([2.0, 3.0, 0.3])
    actions = np.random.default_rng(1).uniform(-1, 1, size=(40, 1)).astype(np.float32)
    env.reset(seed=3, options={"xi": xi})
    stepped = []
    for a in actions:
        env.step(a)
        stepped.append(env.plant_state)
    bare = env.bare_rollout(xi, actions)
    np.testing.assert_array_equal(bare, np.array(stepped))


def test_sampler_drives_xi():
    point = np.array([3.0, 4.0, 0.25])
    env = CartpoleEnv(sampler=NoDR(CartpoleEnv().space, point=point))
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["xi"], point)
    np.testing.assert_allclose(info["critic_obs"][5:], env.space.normalize(point), rtol=1e-6)


def test_end_stops_hold_the_cart(env):
    states = env.bare_rollout([0.01, 0.01, 0.0], np.ones((120, 1)), initial_state=np.r_[0.0, 0.15, 0.0, 0, 0, 0])
    assert states[:, 0].max() < env.config.slider_limit + 0.02
    assert states[-1, 0] > env.config.slider_limit - 0.05
