"""GoFlowSampler: identity start, exact truncated density, updates toward high returns, guards, checkpoints.

Updates use fewer Monte Carlo samples than the defaults (10^4) to keep the suite fast on two cores;
the estimator is the same.
"""

import copy
import json
import math
import pickle

import numpy as np
import pytest
import torch
from scipy.stats import truncnorm

from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR, Sampler
from learning.samplers.goflow import GoFlowSampler
from learning.samplers.goflow_config import GoFlowConfig
from learning.samplers.gradient_update import standardize_returns
from learning.samplers.spline_flow import build_spline_flow

FAST = GoFlowConfig(
    entropy_samples=512, kl_samples=512, steps=60, mode="paper"
)  # the paper's update; modes: test_goflow_modes.py
SIGMA = GoFlowConfig().base_scale


@pytest.fixture(autouse=True)
def _one_thread():
    """Small tensors: one thread is faster and steadier on shared cores."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def _space(d: int = 2) -> ParamSpace:
    params = [
        Param("offset", -1.0, 1.0, "m"),
        Param("mass", 0.0, 20.0, "kg"),
        Param("friction", 0.0, 1.0, "1"),
        Param("yaw", -0.4, 0.4, "rad"),
        Param("gain", 10.0, 300.0, "N/m"),
    ]
    return ParamSpace(tuple(params[:d]))


def _init_logpdf(space: ParamSpace, xi: np.ndarray) -> np.ndarray:
    """Log density of the intended initial distribution: N(0, sigma^2) truncated to [-5, 5]^d in box coordinates."""
    half = (space.high - space.low) / 10.0
    y = (xi - space.center()) / half
    return truncnorm(-5 / SIGMA, 5 / SIGMA, scale=SIGMA).logpdf(y).sum(axis=1) - np.log(half).sum()


# -- protocol, initial distribution, densities ----------------------------------------------------------


@pytest.mark.parametrize("d", [1, 2, 3, 5])
def test_identity_start_in_every_dimension(d):
    space = _space(d)
    s = GoFlowSampler(space, config=FAST)
    assert isinstance(s, Sampler)
    xi = s.sample(500, np.random.default_rng(d))
    assert xi.shape == (500, d) and np.all(space.contains(xi))
    lp = s.log_prob(xi)
    assert np.all(np.isfinite(lp))
    np.testing.assert_allclose(lp, _init_logpdf(space, xi), atol=2e-4)  # exactly the truncated base
    expected_h = (
        d * truncnorm(-5 / SIGMA, 5 / SIGMA, scale=SIGMA).entropy() + np.log((space.high - space.low) / 10).sum()
    )
    assert abs(s.entropy() - expected_h) < 0.05 * d
    diag = s.update(xi[:64], np.random.default_rng(0).random(64))  # one short update works in any dimension
    assert diag["skipped_steps"] == 0 and not diag["reverted"] and math.isfinite(diag["entropy"])
    assert np.all(np.isfinite(s.log_prob(s.sample(100, np.random.default_rng(1)))))


def test_log_prob_inside_finite_outside_minus_inf_and_shapes():
    space = _space(2)
    s = GoFlowSampler(space, config=FAST)
    pts = np.array([[0.0, 10.0], [-1.0, 0.0], [1.0, 20.0], [1.01, 10.0], [0.0, -1e-9], [-3.0, 50.0]])
    lp = s.log_prob(pts)
    assert lp.shape == (6,)
    assert np.all(np.isfinite(lp[:3])) and np.all(lp[3:] == -np.inf)
    assert s.log_prob(np.array([0.0, 10.0])).shape == (1,)
    with pytest.raises(ValueError):
        s.log_prob(np.array([[np.nan, 1.0]]))
    with pytest.raises(ValueError):
        s.log_prob(np.zeros((3, 3)))
    assert s.sample(0, np.random.default_rng(0)).shape == (0, 2)
    with pytest.raises(ValueError):
        s.sample(-1, np.random.default_rng(0))
    with pytest.raises(TypeError):
        s.sample(3, 0)


def test_one_dimension_starts_smooth():
    """d = 1: zuko's NSF has random raw spline parameters there; ours start at the identity."""
    space = _space(1)
    s = GoFlowSampler(space, config=FAST)
    grid = np.linspace(space.low[0], space.high[0], 2001)[:, None]
    dens = np.exp(s.log_prob(grid))
    ratio = dens.max() / dens.min()
    assert ratio < math.exp(12.5 / SIGMA**2) * 1.001  # the truncated Gaussian's centre/edge ratio (7.4)
    assert np.all(np.abs(np.diff(dens)) < 0.01 * dens.max())  # no spikes on a fine grid
    assert abs(np.trapezoid(dens, grid[:, 0]) - 1.0) < 1e-3


@pytest.mark.parametrize("d", [1, 3])
def test_spline_flow_is_zukos_nsf(d):
    """Our spline (softmax as exp / sum) has zuko NSF's modules, and its density and inverse on any
    parameters (here random, scaled up to steep splines) within float32 rounding."""
    import zuko

    torch.manual_seed(0)
    reference = zuko.flows.NSF(features=d, transforms=3, hidden_features=(64, 64), bins=8)
    ours = build_spline_flow(d, 3, (64, 64), 8)
    assert ours.state_dict().keys() == reference.state_dict().keys()
    with torch.no_grad():
        for p in reference.parameters():
            p.mul_(3.0)
    ours.load_state_dict(reference.state_dict())
    x = torch.rand(2000, d) * 10 - 5
    with torch.no_grad():
        reference64 = copy.deepcopy(reference).double()
        exact = reference64().log_prob(x.double())
        err_ours = (ours().log_prob(x).double() - exact).abs().max().item()
        err_zuko = (reference().log_prob(x).double() - exact).abs().max().item()
        z = torch.randn(2000, d)
        inverse_gap = (ours().transform.inv(z) - reference().transform.inv(z)).abs().max().item()
    assert err_ours < max(10 * err_zuko, 1e-3)
    assert inverse_gap < 1e-3


def test_same_rng_gives_same_samples():
    s = GoFlowSampler(_space(2), config=FAST)
    a = s.sample(50, np.random.default_rng(7))
    b = s.sample(50, np.random.default_rng(7))
    c = s.sample(50, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


# -- updates ---------------------------------------------------------------------------------------


DISK_CENTRE, DISK_RADIUS = np.array([0.7, 0.3]), 0.2  # in unit-box coordinates


def _disk_returns(space, xi):
    return (np.linalg.norm(space.normalize(xi) - DISK_CENTRE, axis=1) < DISK_RADIUS).astype(float)


@pytest.fixture(scope="module")
def disk_runs():
    """Three GoFlow rounds on the validation protocol (uniform-box batches), R = 1 inside a disk."""
    torch.set_num_threads(1)
    space = _space(2)
    batches = []
    rng = np.random.default_rng(0)
    for _ in range(3):
        xi = rng.uniform(space.low, space.high, size=(256, 2))
        batches.append((xi, _disk_returns(space, xi)))
    runs = {}
    for alpha in (0.1, 1.0):
        s = GoFlowSampler(space, alpha=alpha, beta=1.0, config=FAST)
        before = {
            "entropy": s.entropy(),
            "lp": s.log_prob(space.denormalize(DISK_CENTRE))[0],
            "mass": _disk_returns(space, s.sample(4000, np.random.default_rng(1))).mean(),
        }
        diags = [s.update(xi, r) for xi, r in batches]
        after = {
            "entropy": s.entropy(),
            "lp": s.log_prob(space.denormalize(DISK_CENTRE))[0],
            "mass": _disk_returns(space, s.sample(4000, np.random.default_rng(1))).mean(),
        }
        runs[alpha] = (s, before, after, diags)
    return space, runs


@pytest.mark.parametrize("alpha", [0.1, 1.0])
def test_update_moves_density_toward_high_returns(disk_runs, alpha):
    space, runs = disk_runs
    _, before, after, diags = runs[alpha]
    assert after["lp"] > before["lp"] + 0.3
    assert after["mass"] > before["mass"] + 0.1  # initial mass in the disk ~0.17
    for dg in diags:
        assert dg["skipped_steps"] == 0 and not dg["reverted"] and dg["returns_have_signal"]
        assert all(math.isfinite(dg[k]) for k in ("loss", "entropy", "kl", "entropy_objective"))


def test_entropy_keeps_width_and_grows_with_alpha(disk_runs):
    space, runs = disk_runs
    h_small, h_large = runs[0.1][2]["entropy"], runs[1.0][2]["entropy"]
    disk_entropy = math.log(math.pi * DISK_RADIUS**2 * space.volume())  # uniform on the disk
    assert h_large > disk_entropy + 0.3  # alpha = 1 stays wider than the high-return set
    assert h_large > h_small + 0.3  # same data, more entropy weight, more entropy


def test_log_prob_stays_normalized_after_training(disk_runs):
    """The box is invariant under zuko's splines, so the exact normalizer holds after training too."""
    space, runs = disk_runs
    s = runs[0.1][0]
    n = 200
    a, b = np.meshgrid(np.linspace(-1, 1, n), np.linspace(0, 20, n), indexing="ij")
    dens = np.exp(s.log_prob(np.stack([a.ravel(), b.ravel()], axis=1))).reshape(n, n)
    integral = np.trapezoid(np.trapezoid(dens, b[0], axis=1), a[:, 0])
    assert abs(integral - 1.0) < 0.02
    # and entropy() agrees with the density: -E[log p] over fresh samples
    xi = s.sample(4000, np.random.default_rng(3))
    assert abs(-s.log_prob(xi).mean() - s.entropy()) < 0.1


@pytest.mark.parametrize("mode", ["paper", "entropy"])
def test_all_equal_and_extreme_returns_stay_finite(mode):
    space = _space(2)
    cfg = GoFlowConfig(entropy_samples=256, kl_samples=256, steps=15, mode=mode, proposal_samples=512)
    s = GoFlowSampler(space, config=cfg)
    rng = np.random.default_rng(4)
    xi = rng.uniform(space.low, space.high, size=(64, 2))
    for returns in (
        np.full(64, 5.0),
        np.where(np.arange(64) % 2, 1e6, -1e6),
        np.full(64, 1e300),
        np.r_[1e300, np.zeros(63)],
        np.array([-1e306] * 32 + [1e306] * 32),
    ):
        diag = s.update(xi, returns)
        assert not diag["reverted"] and diag["skipped_steps"] == 0
        assert all(math.isfinite(diag[k]) for k in ("loss", "entropy", "kl", "mean_return"))
        lp = s.log_prob(s.sample(200, rng))
        assert np.all(np.isfinite(lp))
    assert all(torch.isfinite(p).all() for p in s._flow.parameters())
    one = s.update(xi[:1], [3.0])  # a batch of one: no return signal of its own
    assert math.isfinite(one["loss"])
    if mode == "paper":  # the paper's update sees only this batch; the others keep their evidence
        assert not one["returns_have_signal"]


def test_standardize_returns():
    z, ok = standardize_returns(np.array([2.0, 2.0, 2.0]))
    assert not ok and np.all(z == 0)
    z, ok = standardize_returns(np.array([1e308, -1e308, 0.0]))
    assert ok and np.all(np.isfinite(z)) and abs(z.mean()) < 1e-12 and abs(z.std() - 1) < 1e-12


def test_bad_update_inputs_raise():
    space = _space(2)
    s = GoFlowSampler(space, config=FAST)
    xi = np.array([[0.0, 10.0], [0.5, 5.0]])
    with pytest.raises(ValueError, match="finite"):
        s.update(xi, [1.0, np.nan])
    with pytest.raises(ValueError, match="finite"):
        s.update(xi, [np.inf, 0.0])
    with pytest.raises(ValueError, match="empty"):
        s.update(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ValueError, match="mass"):
        s.update(np.array([[0.0, 25.0]]), [1.0])
    with pytest.raises(ValueError):
        s.update(xi, [1.0])
    assert s.n_updates == 0


@pytest.mark.parametrize("mode", ["paper", "entropy"])
def test_non_finite_parameters_revert_to_the_previous_flow(monkeypatch, mode):
    space = _space(2)
    s = GoFlowSampler(
        space, config=GoFlowConfig(entropy_samples=128, kl_samples=128, steps=3, mode=mode, proposal_samples=256)
    )
    xi = np.random.default_rng(5).uniform(space.low, space.high, size=(32, 2))
    before = s.log_prob(xi)
    original_step = torch.optim.Adam.step

    def poisoned_step(self, *args, **kwargs):  # an optimizer step that leaves a parameter NaN
        out = original_step(self, *args, **kwargs)
        with torch.no_grad():
            self.param_groups[0]["params"][0].view(-1)[0] = math.nan
        return out

    monkeypatch.setattr(torch.optim.Adam, "step", poisoned_step)
    diag = s.update(xi, np.arange(32.0))
    assert diag["reverted"] and diag["skipped_steps"] >= 1  # steps after the poisoning have a NaN loss
    np.testing.assert_array_equal(s.log_prob(xi), before)
    assert math.isfinite(diag["entropy"]) and math.isfinite(diag["kl"])


def test_constructor_validation():
    with pytest.raises(ValueError):
        GoFlowSampler(_space(2), alpha=-1.0)
    with pytest.raises(ValueError):
        GoFlowSampler(_space(2), beta=math.nan)
    with pytest.raises(ValueError):
        GoFlowConfig(steps=0)
    with pytest.raises(ValueError):
        GoFlowConfig(base_scale=0.0)


# -- checkpoints -----------------------------------------------------------------------------------


def test_state_dict_round_trip_and_resume_reproduces():
    space = _space(2)
    rng = np.random.default_rng(6)
    batches = [(x := rng.uniform(space.low, space.high, size=(64, 2)), _disk_returns(space, x)) for _ in range(2)]
    cfg = GoFlowConfig(entropy_samples=256, kl_samples=256, steps=10)
    a = GoFlowSampler(space, alpha=0.5, config=cfg)
    a.update(*batches[0])
    state = json.loads(json.dumps(a.state_dict()))  # JSON-serializable
    assert state["type"] == "GoFlowSampler" and state["space"] == space.to_dict()
    b = GoFlowSampler(space, config=cfg)  # other alpha: restored from the state
    b.load_state_dict(state)
    probe = rng.uniform(space.low, space.high, size=(100, 2))
    np.testing.assert_array_equal(a.log_prob(probe), b.log_prob(probe))
    assert b.alpha == 0.5 and b.n_updates == 1 and a.entropy() == b.entropy()
    np.testing.assert_array_equal(a.sample(20, np.random.default_rng(9)), b.sample(20, np.random.default_rng(9)))
    a.update(*batches[1])
    b.update(*batches[1])  # resumed run reproduces the uninterrupted one
    np.testing.assert_array_equal(a.log_prob(probe), b.log_prob(probe))
    c = GoFlowSampler.from_state_dict(json.loads(json.dumps(a.state_dict())))
    np.testing.assert_array_equal(a.log_prob(probe), c.log_prob(probe))


def test_load_state_dict_refuses_mismatches():
    space = _space(2)
    s = GoFlowSampler(space, config=FAST)
    other_space = ParamSpace((Param("offset", -1.0, 1.0, "m"), Param("mass", 0.0, 25.0, "kg")))
    with pytest.raises(ValueError, match="ParamSpace"):
        GoFlowSampler(other_space, config=FAST).load_state_dict(s.state_dict())
    with pytest.raises(ValueError):
        s.load_state_dict(FullDR(space).state_dict())
    with pytest.raises(ValueError, match="architecture"):
        GoFlowSampler(space, config=GoFlowConfig(hidden_features=(32, 32))).load_state_dict(s.state_dict())
    bad = s.state_dict()
    key = next(k for k, v in bad["flow"].items() if v["dtype"] == "float32")
    bad["flow"][key]["data"][0] = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        s.load_state_dict(bad)


def test_pickle_round_trip():
    space = _space(3)
    s = GoFlowSampler(space, alpha=0.7, beta=0.2, config=GoFlowConfig(entropy_samples=128, kl_samples=128, steps=5))
    xi = np.random.default_rng(8).uniform(space.low, space.high, size=(32, 3))
    s.update(xi, xi[:, 0])
    t = pickle.loads(pickle.dumps(s))
    np.testing.assert_array_equal(s.log_prob(xi), t.log_prob(xi))
    np.testing.assert_array_equal(s.sample(10, np.random.default_rng(2)), t.sample(10, np.random.default_rng(2)))
    assert (t.alpha, t.beta, t.n_updates, t.config) == (0.7, 0.2, 1, s.config)
