"""LSDRSampler: the seed's initial Gaussian, truncation, normalized densities, updates, checkpoints."""

import json
import math
import pickle

import numpy as np
import pytest
import torch
from scipy import stats

from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR, Sampler
from learning.samplers.lsdr import LSDRSampler
from learning.samplers.lsdr import LSDRConfig, kl_uniform_gaussian


def _space() -> ParamSpace:
    return ParamSpace((Param("offset", -1.0, 1.0, "m"), Param("mass", 0.0, 20.0, "kg")))


def _grid_integral(s: LSDRSampler, n: int = 400) -> float:
    lo, hi = s.space.low, s.space.high
    a, b = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n), indexing="ij")
    dens = np.exp(s.log_prob(np.stack([a.ravel(), b.ravel()], axis=1))).reshape(n, n)
    return float(np.trapezoid(np.trapezoid(dens, b[0], axis=1), a[:, 0]))


def test_initial_gaussian_is_the_seeds():
    space = _space()
    s = LSDRSampler(space)
    assert isinstance(s, Sampler)
    np.testing.assert_allclose(s.mean(), space.center())
    np.testing.assert_allclose(s.covariance(), np.diag((space.high - space.low) / 10.0))  # appendix A.2
    custom = LSDRSampler(space, config=LSDRConfig(init_variance=(0.01, 4.0)))
    np.testing.assert_allclose(custom.covariance(), np.diag([0.01, 4.0]))


def test_truncation_keeps_samples_in_box_and_matches_truncated_normal():
    # 0.1 m wide: the seed's initial variance (0.01 m^2) is a std of the full width, so most of the
    # Gaussian's mass lies outside and truncation matters
    space = ParamSpace((Param("grasp_x", -0.05, 0.05, "m"),))
    s = LSDRSampler(space)
    assert 0.3 < s.truncation_mass() < 0.45
    xi = s.sample(20_000, np.random.default_rng(0))
    assert xi.shape == (20_000, 1) and np.all(space.contains(xi))
    ref = stats.truncnorm(-0.5, 0.5, loc=0.0, scale=0.1)
    assert stats.kstest(xi[:, 0], ref.cdf).pvalue > 1e-3
    np.testing.assert_allclose(s.log_prob(xi[:50]), ref.logpdf(xi[:50, 0]), rtol=1e-9)
    assert abs(s.entropy() - ref.entropy()) < 1e-9
    assert np.all(s.log_prob(np.array([[0.06], [-0.051]])) == -np.inf)


def test_log_prob_integrates_to_one_before_and_after_updates():
    space = _space()
    s = LSDRSampler(space, alpha=0.5)
    assert abs(_grid_integral(s) - 1.0) < 2e-3
    rng = np.random.default_rng(1)
    for _ in range(3):  # correlated returns give a non-diagonal covariance
        xi = rng.uniform(space.low, space.high, size=(256, 2))
        u = space.normalize(xi)
        s.update(xi, -np.abs(u[:, 0] - u[:, 1]))
    assert abs(s.chol[1, 0]) > 1e-3  # full covariance learned
    assert abs(_grid_integral(s) - 1.0) < 5e-3
    xi = s.sample(20_000, np.random.default_rng(2))
    assert abs(-s.log_prob(xi).mean() - s.entropy()) < 0.03  # entropy() matches -E[log p]


def test_kl_uniform_closed_form_matches_monte_carlo():
    mu = torch.tensor([0.3, 0.6], dtype=torch.float64)
    chol = torch.tensor([[0.2, 0.0], [0.05, 0.3]], dtype=torch.float64)
    u = torch.rand(400_000, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    mvn = torch.distributions.MultivariateNormal(mu, scale_tril=chol)
    assert abs(float(kl_uniform_gaussian(mu, chol)) - float(-mvn.log_prob(u).mean())) < 5e-3


DISK_CENTRE, DISK_RADIUS = np.array([0.7, 0.3]), 0.2


def _disk_returns(space, xi):
    return (np.linalg.norm(space.normalize(xi) - DISK_CENTRE, axis=1) < DISK_RADIUS).astype(float)


def _disk_run(alpha):
    space = _space()
    s = LSDRSampler(space, alpha=alpha, config=LSDRConfig(init_variance=(0.2, 20.0)))  # std 0.22 of each width
    rng = np.random.default_rng(3)
    centre = space.denormalize(DISK_CENTRE)
    before = (s.log_prob(centre)[0], _disk_returns(space, s.sample(4000, np.random.default_rng(4))).mean(), s.entropy())
    for _ in range(5):
        xi = rng.uniform(space.low, space.high, size=(256, 2))
        diag = s.update(xi, _disk_returns(space, xi))
        assert diag["skipped_steps"] == 0 and not diag["reverted"]
    after = (s.log_prob(centre)[0], _disk_returns(space, s.sample(4000, np.random.default_rng(4))).mean(), s.entropy())
    return s, before, after


def test_update_moves_toward_high_returns_while_keeping_entropy():
    space = _space()
    s, before, after = _disk_run(alpha=0.5)
    assert after[0] > before[0] + 0.5 and after[1] > before[1] + 0.1
    dist_before = np.linalg.norm(0.5 - DISK_CENTRE)
    assert np.linalg.norm(s.mu - DISK_CENTRE) < dist_before - 0.1  # the mean moved toward the disk
    disk_entropy = math.log(math.pi * DISK_RADIUS**2 * space.volume())
    assert after[2] > disk_entropy  # still wider than the high-return set
    _, _, after_small = _disk_run(alpha=0.05)
    assert after[2] > after_small[2]  # more entropy weight, more entropy (same data)


def test_all_equal_and_extreme_returns_and_bad_inputs():
    space = _space()
    s = LSDRSampler(space)
    xi = np.random.default_rng(5).uniform(space.low, space.high, size=(64, 2))
    for returns in (np.full(64, 2.0), np.where(np.arange(64) % 2, 1e6, -1e6), np.full(64, 1e300)):
        diag = s.update(xi, returns)
        assert not diag["reverted"] and math.isfinite(diag["loss"]) and math.isfinite(diag["entropy"])
        assert np.all(np.isfinite(s.log_prob(s.sample(100, np.random.default_rng(0)))))
    with pytest.raises(ValueError, match="finite"):
        s.update(xi[:2], [np.nan, 1.0])
    with pytest.raises(ValueError, match="empty"):
        s.update(np.zeros((0, 2)), [])
    with pytest.raises(ValueError):
        s.update(np.array([[2.0, 1.0]]), [1.0])
    with pytest.raises(ValueError):
        LSDRSampler(space, alpha=-1.0)
    with pytest.raises(ValueError):
        LSDRSampler(space, config=LSDRConfig(init_variance=(1.0,)))


def test_state_dict_pickle_and_mismatch():
    space = _space()
    s = LSDRSampler(space, alpha=0.3)
    xi = np.random.default_rng(6).uniform(space.low, space.high, size=(128, 2))
    s.update(xi, xi[:, 0] * xi[:, 1])
    state = json.loads(json.dumps(s.state_dict()))
    t = LSDRSampler(space)
    t.load_state_dict(state)
    np.testing.assert_array_equal(s.log_prob(xi), t.log_prob(xi))
    assert t.alpha == 0.3 and t.entropy() == s.entropy()
    np.testing.assert_array_equal(s.sample(10, np.random.default_rng(1)), t.sample(10, np.random.default_rng(1)))
    p = pickle.loads(pickle.dumps(s))
    np.testing.assert_array_equal(s.log_prob(xi), p.log_prob(xi))
    np.testing.assert_array_equal(LSDRSampler.from_state_dict(state).log_prob(xi), s.log_prob(xi))
    other = ParamSpace((Param("offset", -1.0, 1.0, "m"), Param("mass", 0.0, 10.0, "kg")))
    with pytest.raises(ValueError, match="ParamSpace"):
        LSDRSampler(other).load_state_dict(state)
    with pytest.raises(ValueError):
        t.load_state_dict(FullDR(space).state_dict())
    bad = dict(state, chol=[[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ValueError):
        t.load_state_dict(bad)
