"""goflow/GearInsertion-v0: the grasp error is real, contact decides, both variants agree."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import assembly  # noqa: F401  (registers the ids)
from assembly.envs.base import SimulationError
from assembly.envs.gear_insertion import GearInsertionEnv
from assembly.samplers import FullDR, NoDR

DOWN = np.array([0.0, 0.0, -1.0, 0.0])


@pytest.fixture(scope="module")
def fast():
    return gymnasium.make("goflow/GearInsertion-v0", gear="medium", variant="fast").unwrapped


@pytest.fixture(scope="module")
def panda():
    return gymnasium.make("goflow/GearInsertion-v0", gear="medium", variant="panda").unwrapped


def _push_down(env, xi, steps=None):
    env.reset(seed=0, options={"xi": xi})
    total, info = 0.0, {}
    for _ in range(steps or env.max_episode_steps):
        _, reward, terminated, truncated, info = env.step(DOWN)
        total += reward
        if terminated or truncated:
            break
    return total, info


def test_env_checker(fast):
    check_env(fast, skip_render_check=True)


def test_spaces_and_contract(fast):
    obs, info = fast.reset(seed=3)
    assert obs.shape == (80,) and fast.observation_space.contains(obs)
    assert fast.space.names == ("x", "y", "yaw")
    np.testing.assert_allclose(fast.space.high, [0.05, 0.05, 0.393])
    assert info["xi"].shape == (3,) and fast.space.contains(info["xi"])
    assert info["critic_obs"].shape == (83,)
    assert fast.control_dt == pytest.approx(0.04) and fast.max_episode_steps == 100
    assert fast.success_threshold == 50.0


def test_same_seed_same_start(fast):
    a, ia = fast.reset(seed=11)
    b, ib = fast.reset(seed=11)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ia["xi"], ib["xi"])


def test_grasp_error_moves_gear_in_hand(fast):
    fast.reset(seed=0, options={"xi": [0.0, 0.0, 0.0]})
    centred = fast._sim.gear_pose()
    fast.reset(seed=0, options={"xi": [0.01, -0.02, 0.3]})
    off = fast._sim.gear_pose()
    # Same tool pose, gear displaced by 2.2 cm and turned by 0.3 rad about its axis.
    np.testing.assert_allclose(
        np.linalg.norm(off.translation() - centred.translation()), np.hypot(0.01, 0.02), atol=1e-9
    )
    angle = (centred.rotation().inverse() @ off.rotation()).ToAngleAxis().angle()
    assert angle == pytest.approx(0.3, abs=1e-9)


@pytest.mark.parametrize("variant", ["fast", "panda"])
def test_contact_decides(variant, fast, panda):
    env = fast if variant == "fast" else panda
    ret, info = _push_down(env, [0.0, 0.0, 0.0])
    assert info["success"] and info["seated"], (ret, info)
    # 4 mm off: beyond the chamfers' capture range; pushing straight down leaves the gear on the
    # shaft top, 2 cm above its seat.
    ret, info = _push_down(env, [0.004, 0.0, 0.0])
    assert not info["success"] and ret < 10.0  # shaping only, about 6 (J_T = 50)
    lateral, height = env.insertion_error()
    assert height > 0.015


def test_progress_is_credited_at_once(fast):
    """Lowering the gear earns its progress term in the same steps; hovering earns none of it."""

    def run(action, steps=10):
        fast.reset(seed=0, options={"xi": [0.02, 0.0, 0.0]})
        d0 = np.hypot(*fast.insertion_error())
        rewards = [fast.step(action)[1] for _ in range(steps)]
        return d0 - np.hypot(*fast.insertion_error()), rewards

    gained_hover, r_hover = run(np.zeros(4))
    gained_down, r_down = run(DOWN)
    assert abs(gained_hover) < 0.001 and gained_down > 0.003  # down 5 mm onto the shaft top
    progress = fast.config.progress_weight * (gained_down - gained_hover)
    assert sum(r_down) - sum(r_hover) > 0.9 * progress


def test_failed_episodes_still_rank_grasp_errors(fast):
    """The coarse shaping term orders failures by distance, across the whole grasp-error box."""
    returns = [_push_down(fast, [x, 0.0, 0.0])[0] for x in (0.005, 0.02, 0.045)]
    assert returns[0] > returns[1] + 0.5 > returns[2] + 1.0, returns
    assert max(returns) < fast.success_threshold


def test_variants_agree_on_a_small_error(fast, panda):
    xi = [0.0015, 0.001, 0.2]
    returns = [_push_down(env, xi)[0] for env in (fast, panda)]
    assert returns[0] >= 50 and returns[1] >= 50
    assert abs(returns[0] - returns[1]) < 10.0


def test_bad_input(fast):
    with pytest.raises(ValueError, match=r"'x'.*bounds"):
        fast.reset(options={"xi": [0.2, 0.0, 0.0]})
    with pytest.raises(ValueError, match="shape"):
        fast.reset(options={"xi": [0.0, 0.0]})
    fast.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        fast.step(np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="unknown gear"):
        GearInsertionEnv(gear="huge")
    with pytest.raises(ValueError, match="variant"):
        GearInsertionEnv(variant="slow")
    with pytest.raises(ValueError, match="ParamSpace differs"):
        GearInsertionEnv(sampler=FullDR(GearInsertionEnv(grasp_xy=0.02).space))


def test_failed_physics_step_truncates(fast, monkeypatch):
    fast.reset(seed=0)

    def fail(target, duration):
        raise SimulationError("solver diverged")

    monkeypatch.setattr(fast._sim, "advance", fail)
    obs, reward, terminated, truncated, info = fast.step(DOWN)
    assert truncated and not terminated and info["sim_error"] == "solver diverged"
    with pytest.raises(RuntimeError, match="reset"):
        fast.step(DOWN)


def test_nodr_sampler_fixes_xi():
    env = GearInsertionEnv()
    env.sampler = NoDR(env.space)
    _, info = env.reset(seed=5)
    np.testing.assert_array_equal(info["xi"], [0.0, 0.0, 0.0])


def test_bare_rollout_matches_env(fast):
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(15, 4))
    xi = np.array([0.001, -0.002, 0.1])
    fast.reset(seed=0, options={"xi": xi})
    for a in actions:
        fast.step(a)
    via_env = fast.tool_pose()
    np.testing.assert_allclose(fast.bare_rollout(xi, actions), via_env, atol=1e-12)
