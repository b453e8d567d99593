"""goflow/Quadrotor-v0: Drake quadrotor flying to a random goal, with randomized mass."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import assembly  # noqa: F401  (registers the goflow/ ids)
from assembly.envs.base import quaternion_rotation
from assembly.envs.quadrotor import QuadrotorEnv


@pytest.fixture(scope="module")
def env():
    e = QuadrotorEnv()
    yield e
    e.close()


def position_controller(env, mass, kp=8.0, kd=5.0, kr=200.0, kw=25.0, a_max=8.0):
    """PD on position -> desired thrust vector; PD on attitude -> body torques; mixed into rotor thrusts."""
    c = env.config
    inertia = np.array(c.inertia) * mass / c.nominal_mass
    P, S = env.rotor_positions, env.rotor_spin
    mixer = np.linalg.inv(np.vstack([np.ones(4), P[:, 1], -P[:, 0], S * c.moment_ratio]))

    def act(state):
        R = quaternion_rotation(state[:4])
        p, w_b, v = state[4:7], R.T @ state[7:10], state[10:13]
        a = kp * (env.goal - p) - kd * v
        n = np.linalg.norm(a[:2])
        if n > a_max:
            a[:2] *= a_max / n
        f = mass * (a + np.array([0.0, 0.0, 9.81]))
        z_b = R[:, 2]
        e_b = R.T @ np.cross(z_b, f / np.linalg.norm(f))
        thrusts = mixer @ np.r_[f @ z_b, inertia * (kr * e_b - kw * w_b)]
        return (2.0 * np.clip(thrusts, 0.0, c.max_rotor_thrust) / c.max_rotor_thrust - 1.0).astype(np.float32)

    return act


def episode_return(env, mass, seed):
    env.reset(seed=seed, options={"xi": [mass]})
    act = position_controller(env, mass)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(act(env.plant_state))
        done = term or trunc
    return info["episode_return"], info["success"]


def test_env_checker_passes():
    env = gymnasium.make("goflow/Quadrotor-v0")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_task_constants(env):
    assert env.control_dt == pytest.approx(0.02)
    assert env.max_episode_steps == 100
    assert env.success_threshold == 15.0
    assert env.space.names == ("mass",)
    np.testing.assert_array_equal(env.space.low, [0.01])
    np.testing.assert_array_equal(env.space.high, [20.0])
    assert env.config.max_rotor_thrust == pytest.approx(1.9 * 0.775 * 9.81 / 4)
    assert env.config.max_hover_mass == pytest.approx(1.4725)
    with pytest.raises(TypeError, match="unknown"):
        QuadrotorEnv(mas=1.0)


def test_same_seed_same_first_observation(env):
    other = QuadrotorEnv()
    oa, ia = env.reset(seed=11)
    ob, ib = other.reset(seed=11)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["xi"], ib["xi"])
    np.testing.assert_array_equal(env.goal, other.goal)
    oc, _ = env.reset(seed=12)
    assert not np.array_equal(oa, oc)


def test_info_shapes_and_truncation(env):
    obs, info = env.reset(seed=0)
    assert obs.shape == (12,) and info["xi"].shape == (1,) and info["critic_obs"].shape == (13,)
    for k in range(env.max_episode_steps):
        obs, r, term, trunc, info = env.step(np.zeros(4, dtype=np.float32))
        assert not term
        assert trunc == (k == env.max_episode_steps - 1)
        assert info["critic_obs"].shape == (13,) and env.observation_space.contains(obs)
    assert "episode_return" in info and "success" in info


def test_a_diverging_step_is_reported_not_scored(env):
    """Bang-bang thrusts on a 30 g drone: in this episode the discrete step diverges at 1.76 s
    (body rate 2e4 rad/s, then without bound; a training run logged an episode return of -4e10).
    It must end truncated with info["sim_error"], its return bounded, and the env must go on."""
    rng = np.random.default_rng(67)
    env.reset(seed=67, options={"xi": [0.03]})
    hold = rng.choice([-1.0, 1.0], size=4)
    for _ in range(env.max_episode_steps):
        if rng.random() < 0.3:
            hold = rng.choice([-1.0, 1.0], size=4)
        _, reward, term, trunc, info = env.step(hold.astype(np.float32))
        if term or trunc:
            break
    assert trunc and not term and env._k < env.max_episode_steps
    assert "max_angular_rate" in info["sim_error"] and "0.03 kg" in info["sim_error"]
    assert reward == 0.0 and -1e5 < info["episode_return"] < 0.0 and not info["success"]
    env.reset(seed=0)
    assert env.step(np.zeros(4, dtype=np.float32))[3] is False


def test_a_spinning_state_is_a_failed_step(env):
    """The check itself, on a forced state: 2e4 rad/s at the nominal mass (damping takes ~12 % off
    per step there), so it holds whatever the floating-point detail of a divergence."""
    env.reset(seed=0, options={"xi": [0.775]})
    v = env.plant_state[7:]
    v[:3] = (2e4, 0.0, 0.0)  # world-frame body rate [rad/s]
    env._plant.SetVelocities(env._plant_context, v)
    _, reward, term, trunc, info = env.step(np.zeros(4, dtype=np.float32))
    assert trunc and not term and "max_angular_rate" in info["sim_error"]
    assert reward == 0.0 and info["episode_return"] == 0.0
    with pytest.raises(ValueError, match="max_angular_rate"):
        QuadrotorEnv(max_angular_rate=0.0)


def test_bad_xi_and_actions(env):
    with pytest.raises(ValueError, match=r"'mass'.*\[0.01, 20\] kg"):
        env.reset(options={"xi": [25.0]})
    with pytest.raises(ValueError, match=r"'mass'.*\[0.01, 20\] kg"):
        env.reset(options={"xi": [0.0]})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))


def test_heavier_body_falls_faster(env):
    hover_nominal = 2 * (0.775 * 9.81 / 4) / env.config.max_rotor_thrust - 1  # hover action at 0.775 kg
    actions = np.full((10, 4), hover_nominal)
    nominal = env.bare_rollout([0.775], actions)
    heavy = env.bare_rollout([1.2], actions)
    light = env.bare_rollout([0.5], actions)
    assert abs(nominal[-1, 6] - 0.5) < 1e-3  # hovers
    assert heavy[-1, 6] < 0.45 and light[-1, 6] > 0.55  # heavier sinks, lighter climbs
    assert heavy[-1, 12] < nominal[-1, 12] < light[-1, 12]  # vertical velocities


def test_controller_reaches_threshold_when_feasible_and_not_when_too_heavy(env):
    feasible = [episode_return(env, 0.775, seed) for seed in range(4)]
    assert np.mean([r for r, _ in feasible]) >= env.success_threshold
    assert sum(s for _, s in feasible) >= 2
    too_heavy = [episode_return(env, 3.0, seed) for seed in range(2)]  # > max_hover_mass: cannot lift off
    assert not any(s for _, s in too_heavy)


def test_bare_rollout_matches_env_step(env):
    xi = np.array([0.9])
    actions = np.random.default_rng(2).uniform(-0.2, 0.4, size=(30, 4)).astype(np.float32)
    env.reset(seed=4, options={"xi": xi})
    stepped = []
    for a in actions:
        env.step(a)
        stepped.append(env.plant_state)
    np.testing.assert_array_equal(env.bare_rollout(xi, actions), np.array(stepped))
