"""goflow/Toy2D-v0: the GoFlow paper's 2-D illustrative domain (position guessing under energy-dependent noise)."""

import math

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy import ndimage

import assembly  # noqa: F401  (registers the goflow/ ids)
from assembly.envs.toy2d import Toy2DEnv
from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR, NoDR

LAYOUTS = ["circle", "line"]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_env_checker_passes(layout):
    env = gymnasium.make("goflow/Toy2D-v0", layout=layout)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_registered_default_is_circle():
    env = gymnasium.make("goflow/Toy2D-v0")
    assert env.unwrapped.config.layout == "circle"
    assert env.unwrapped.control_dt > 0


@pytest.mark.parametrize("layout", LAYOUTS)
def test_same_seed_same_first_observation(layout):
    a, b = Toy2DEnv(layout=layout), Toy2DEnv(layout=layout)
    oa, ia = a.reset(seed=123)
    ob, ib = b.reset(seed=123)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["xi"], ib["xi"])
    oc, _ = a.reset(seed=124)
    assert not np.array_equal(oa, oc)


def test_info_contract_and_single_step_episode():
    env = Toy2DEnv()
    obs, info = env.reset(seed=0)
    assert obs.shape == (2,) and obs.dtype == np.float32
    assert info["xi"].shape == (2,)
    assert info["critic_obs"].shape == (4,)
    np.testing.assert_allclose(info["critic_obs"][:2], obs)
    np.testing.assert_allclose(info["critic_obs"][2:], env.space.normalize(info["xi"]), rtol=1e-6)
    obs2, reward, terminated, truncated, info2 = env.step(info["xi"].astype(np.float32))
    assert reward == 1.0 and terminated and not truncated and info2["success"]
    np.testing.assert_array_equal(info2["xi"], info["xi"])
    assert info2["critic_obs"].shape == (4,)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(info["xi"])


def test_fixed_xi_through_options_and_its_validation():
    env = Toy2DEnv()
    _, info = env.reset(seed=0, options={"xi": [0.3, -0.2]})
    np.testing.assert_array_equal(info["xi"], [0.3, -0.2])
    with pytest.raises(ValueError, match=r"'y'.*\[-1, 1\]"):
        env.reset(options={"xi": [0.0, 1.5]})
    with pytest.raises(ValueError, match="shape"):
        env.reset(options={"xi": [0.0, 0.1, 0.2]})
    with pytest.raises(ValueError, match="options"):
        env.reset(options={"ksi": [0.0, 0.0]})


def test_nonfinite_and_misshaped_actions_are_rejected():
    env = Toy2DEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))


def test_sampler_drives_xi_and_must_match_space():
    point = np.array([0.6, 0.0])
    env = Toy2DEnv(sampler=NoDR(Toy2DEnv().space, point=point))
    for seed in range(3):
        _, info = env.reset(seed=seed)
        np.testing.assert_array_equal(info["xi"], point)
    wrong = ParamSpace((Param("x", -2, 2, "m"), Param("y", -1, 1, "m")))
    with pytest.raises(ValueError, match="'x'.*low"):
        Toy2DEnv(sampler=FullDR(wrong))


def test_config_validation():
    with pytest.raises(ValueError, match="layout"):
        Toy2DEnv(layout="spiral")
    with pytest.raises(ValueError, match="sigma_min"):
        Toy2DEnv(sigma_min=0.5, sigma_max=0.1)
    with pytest.raises(ValueError, match="inside"):
        Toy2DEnv(layout="line", n_gaussians=9, spacing=0.5)
    with pytest.raises(TypeError, match="unknown"):
        Toy2DEnv(widht=0.1)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_energy_peaks_on_centres_and_noise_falls_with_energy(layout):
    env = Toy2DEnv(layout=layout)
    c = env.centers
    assert c.shape == (env.config.num_gaussians(), 2)
    e_c = env.energy(c)
    assert np.all(e_c >= 1.0 - 1e-9)
    far = np.array([[-0.99, 0.99], [0.99, -0.99]])
    assert np.all(env.energy(far) < 0.05)
    assert env.noise_scale(c).max() < env.noise_scale(far).min()
    np.testing.assert_allclose(env.noise_scale(far), env.config.sigma_max, rtol=0.05)
    assert env.energy(c[0]).shape == ()  # single point -> scalar


@pytest.mark.parametrize("layout", LAYOUTS)
def test_feasible_set_is_multimodal_and_nontrivial(layout):
    env = Toy2DEnv(layout=layout)
    assert np.all(env.feasible_set(env.centers))
    assert not env.feasible_set(np.zeros(2)) or layout == "line"
    g = np.linspace(-1, 1, 201)
    pts = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    feasible = env.feasible_set(pts)
    assert 0.02 < feasible.mean() < 0.5
    # One separate mode per Gaussian (what makes the domain a test of multimodal samplers).
    _, n_modes = ndimage.label(feasible.reshape(len(g), len(g)))
    assert n_modes == env.config.num_gaussians()


@pytest.mark.parametrize("layout", LAYOUTS)
def test_perfect_guesser_matches_analytic_feasible_set(layout):
    """The guesser that reports its observation succeeds with exactly success_probability(xi)."""
    env = Toy2DEnv(layout=layout)
    rng = np.random.default_rng(7)
    n = 3000
    # Half the xi on the feasible set (near the centres), half uniform on the box.
    near = env.centers[rng.integers(len(env.centers), size=n // 2)] + rng.normal(scale=0.05, size=(n // 2, 2))
    xis = np.clip(np.concatenate([near, rng.uniform(-1, 1, size=(n - n // 2, 2))]), -1, 1)
    wins = np.empty(n, dtype=bool)
    for i, xi in enumerate(xis):
        obs, _ = env.reset(seed=i, options={"xi": xi})
        _, ret, term, _, info = env.step(obs)
        wins[i] = ret >= env.success_threshold
        assert info["success"] == wins[i]
    p = env.success_probability(xis)
    feas = env.feasible_set(xis)
    assert feas.sum() > 300 and (~feas).sum() > 300
    for mask in (feas, ~feas):
        expected = p[mask].mean()
        se = math.sqrt(np.sum(p[mask] * (1 - p[mask]))) / mask.sum()
        assert abs(wins[mask].mean() - expected) < 4 * se + 1e-3
    level = env.config.feasible_level
    assert wins[feas].mean() >= level - 0.03
    assert wins[~feas].mean() < level - 0.2


def test_feasible_level_matches_rayleigh_radius():
    env = Toy2DEnv()
    cfg = env.config
    pts = np.random.default_rng(0).uniform(-1, 1, size=(2000, 2))
    sigma = env.noise_scale(pts)
    analytic = 1 - np.exp(-(cfg.tolerance**2) / (2 * sigma**2))
    np.testing.assert_allclose(env.success_probability(pts), analytic)
    np.testing.assert_array_equal(env.feasible_set(pts), analytic >= cfg.feasible_level)


def test_vector_env_runs():
    envs = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make("goflow/Toy2D-v0") for _ in range(3)])
    obs, info = envs.reset(seed=0)
    assert obs.shape == (3, 2) and info["critic_obs"].shape == (3, 4)
    envs.step(obs)
    envs.close()
