"""DORAEMON (learning/samplers/doraemon.py): the IS estimator against plain Monte Carlo, the constrained
entropy step, the inverted step, the trust region, shapes, bad input and checkpoints."""

import json
import math
import pickle

import numpy as np
import pytest
from scipy import stats

from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR, Sampler
from learning.samplers.doraemon import DORAEMONSampler, _Problem, beta_entropy, beta_kl

J_T = 1.0


def _space() -> ParamSpace:
    return ParamSpace((Param("mass", 0.0, 20.0, "kg"), Param("friction", -1.0, 1.0, "1")))


def _returns_band(space: ParamSpace, xi: np.ndarray, half_width: float = 0.2) -> np.ndarray:
    """Return 2 (success) where the normalized mass lies within half_width of the centre, else 0."""
    u = space.normalize(xi)
    return np.where(np.abs(u[:, 0] - 0.5) < half_width, 2.0, 0.0)


def _returns_right(space: ParamSpace, xi: np.ndarray, cut: float = 0.52) -> np.ndarray:
    """Success when the normalized mass exceeds `cut` (a region the initial bump barely covers)."""
    return np.where(space.normalize(xi)[:, 0] > cut, 2.0, 0.0)


def _with_params(a, b, **config) -> DORAEMONSampler:
    s = DORAEMONSampler(_space(), J_T, config or None)
    s.a, s.b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return s


def _kl(p: DORAEMONSampler, q: DORAEMONSampler) -> float:
    return float(np.sum(beta_kl(p.a, p.b, q.a, q.b)))


def test_defaults_and_densities():
    s = DORAEMONSampler(_space(), J_T)
    assert isinstance(s, Sampler)
    assert s.config.eps == 0.05 and s.config.alpha == 0.5
    np.testing.assert_array_equal(s.a, [100.0, 100.0])
    np.testing.assert_array_equal(s.b, [100.0, 100.0])
    # Entropy and log density in parameter units, against scipy's affine-mapped Beta.
    width = np.array([20.0, 2.0])
    exp_h = sum(stats.beta(100, 100, loc=lo, scale=w).entropy() for lo, w in zip([0.0, -1.0], width))
    assert math.isclose(s.entropy(), exp_h, rel_tol=1e-10)
    xi = s.sample(50, np.random.default_rng(0))
    exp_lp = stats.beta(100, 100, loc=0.0, scale=20.0).logpdf(xi[:, 0]) + stats.beta(
        100, 100, loc=-1.0, scale=2.0
    ).logpdf(xi[:, 1])
    np.testing.assert_allclose(s.log_prob(xi), exp_lp, rtol=1e-10)
    assert s.log_prob(np.array([[21.0, 0.0]]))[0] == -math.inf
    u = _with_params([1.0, 1.0], [1.0, 1.0])  # uniform: matches FullDR
    np.testing.assert_allclose(u.log_prob(xi), FullDR(_space()).log_prob(xi))
    assert math.isclose(u.entropy(), FullDR(_space()).entropy())
    # Closed forms used by the optimizer.
    assert math.isclose(float(beta_entropy(3.0, 2.0)), stats.beta(3, 2).entropy(), rel_tol=1e-12)
    grid = np.linspace(1e-6, 1 - 1e-6, 200_001)
    p, q = stats.beta(3.0, 2.0).pdf(grid), stats.beta(1.5, 4.0).pdf(grid)
    assert math.isclose(float(beta_kl(3.0, 2.0, 1.5, 4.0)), np.trapezoid(p * np.log(p / q), grid), rel_tol=1e-4)


@pytest.mark.parametrize("proposal", ["self", "uniform"])
def test_importance_sampled_success_rate_equals_plain_monte_carlo(proposal):
    """The IS estimate of p' 's success rate from samples of q equals the MC success rate of p'."""
    space = _space()
    rng = np.random.default_rng(1)
    target = _with_params([2.0, 3.0], [5.0, 3.0])  # p'
    if proposal == "self":
        q = _with_params([3.0, 2.0], [3.0, 2.5])
        xi_q = q.sample(40_000, rng)
        log_q = q.log_prob(xi_q)
    else:  # e.g. the GoFlow validation batch on the uniform box
        xi_q = FullDR(space).sample(40_000, rng)
        log_q = FullDR(space).log_prob(xi_q)
    r_q = _returns_band(space, xi_q)
    w_s = np.exp(target.log_prob(xi_q) - log_q) * (r_q >= J_T)
    assert w_s.shape == (40_000,)
    se_is = w_s.std() / math.sqrt(len(w_s))
    est = target.success_rate_estimate(xi_q, r_q, proposal_log_prob=log_q)
    assert math.isclose(est, w_s.mean(), rel_tol=1e-12)
    xi_p = target.sample(200_000, rng)
    mc = float(np.mean(_returns_band(space, xi_p) >= J_T))
    se_mc = math.sqrt(mc * (1 - mc) / len(xi_p))
    exact = stats.beta(2.0, 5.0).cdf(0.7) - stats.beta(2.0, 5.0).cdf(0.3)
    assert abs(est - mc) < 4 * math.hypot(se_is, se_mc)
    assert abs(est - exact) < 4 * se_is and abs(mc - exact) < 4 * se_mc
    # The optimizer's internal estimate is the same number.
    u = np.clip(space.normalize(xi_q), 1e-12, 1 - 1e-12)
    prob = _Problem(
        0.8, 110.0, q_a := np.ones(2), q_a.copy(), u, log_q + math.log(space.volume()), (r_q >= J_T).astype(float)
    )
    assert math.isclose(prob.values(prob.theta_of(target.a, target.b))[2], est, rel_tol=1e-9)
    # With the sampler's own samples and no proposal given, the estimate is the plain success fraction.
    own = target.sample(1000, rng)
    r_own = _returns_band(space, own)
    assert math.isclose(target.success_rate_estimate(own, r_own), float(np.mean(r_own >= J_T)), rel_tol=1e-9)


def test_update_estimate_matches_monte_carlo_of_the_new_distribution():
    space = _space()
    rng = np.random.default_rng(2)
    s = _with_params([6.0, 6.0], [6.0, 6.0], eps=0.1)
    xi = s.sample(4000, rng)
    r = _returns_band(space, xi)
    diag = s.update(xi, r)
    w_s = np.exp(s.log_prob(xi) - _with_params([6.0, 6.0], [6.0, 6.0]).log_prob(xi)) * (r >= J_T)
    assert math.isclose(diag["est_success_rate"], w_s.mean(), rel_tol=1e-9)
    mc = float(np.mean(_returns_band(space, s.sample(100_000, rng)) >= J_T))
    assert abs(diag["est_success_rate"] - mc) < 4 * w_s.std() / math.sqrt(len(w_s)) + 0.005


def test_entropy_grows_under_the_success_constraint_and_kl_stays_in_the_trust_region():
    space = _space()
    rng = np.random.default_rng(3)
    eps, alpha = 0.1, 0.5
    s = DORAEMONSampler(space, J_T, {"eps": eps, "alpha": alpha})
    entropies = [s.entropy()]
    true_rates = []
    for _ in range(14):
        old = _with_params(s.a.copy(), s.b.copy())
        xi = s.sample(600, rng)
        diag = s.update(xi, _returns_band(space, xi))
        kl = _kl(old, s)
        assert kl <= eps + 1e-12 and math.isclose(kl, diag["kl_step"], rel_tol=1e-9, abs_tol=1e-12)
        if diag["status"] in ("feasible", "inverted+feasible"):
            assert diag["est_success_rate"] >= alpha - 2e-4
        entropies.append(s.entropy())
        true_rates.append(float(np.mean(_returns_band(space, s.sample(20_000, rng)) >= J_T)))
    # Entropy rises from the narrow start towards the widest distribution the constraint allows.
    assert entropies[-1] > entropies[0] + 3.0
    assert all(b >= a - 1e-9 for a, b in zip(entropies[:8], entropies[1:9]))  # monotone while unconstrained
    # The band holds 40% of the uniform box: full uniform is infeasible, and the true success rate of the
    # learned distribution stays near alpha (within sampling noise of the 600-episode batches).
    assert s.entropy() < FullDR(space).entropy() - 0.01
    assert min(true_rates) > alpha - 0.08
    # The irrelevant dimension (friction) is spread out much more than the constrained one.
    assert s.a[1] + s.b[1] < s.a[0] + s.b[0]


def test_inverted_step_raises_the_success_rate_when_below_alpha():
    space = _space()
    rng = np.random.default_rng(4)
    s = DORAEMONSampler(space, J_T)  # Beta(100, 100): about 28% of its mass has normalized mass > 0.52
    rate0 = float(np.mean(_returns_right(space, s.sample(50_000, rng)) >= J_T))
    assert rate0 < s.config.alpha
    old = _with_params(s.a.copy(), s.b.copy())
    xi = s.sample(800, rng)
    diag = s.update(xi, _returns_right(space, xi))
    assert diag["status"] in ("inverted_only", "inverted+feasible")
    assert diag["success_rate"] < s.config.alpha and diag["est_success_rate"] > diag["success_rate"] + 0.05
    assert _kl(old, s) <= s.config.eps + 1e-12
    rate1 = float(np.mean(_returns_right(space, s.sample(50_000, rng)) >= J_T))
    assert rate1 > rate0 + 0.05
    assert s.a[0] / (s.a[0] + s.b[0]) > 0.5  # the mean moved into the success region


def test_degenerate_batches_keep_the_distribution():
    space = _space()
    rng = np.random.default_rng(5)
    s = DORAEMONSampler(space, J_T)
    xi = s.sample(64, rng)
    diag = s.update(xi, np.zeros(64))  # nobody succeeds: J(p') = 0 for all p'
    assert diag["status"] == "no_success"
    np.testing.assert_array_equal(s.a, [100.0, 100.0])
    diag = s.update(xi, np.full(64, 5.0))  # everyone succeeds: a pure entropy step of size eps
    assert diag["status"] == "feasible" and diag["entropy"] > DORAEMONSampler(space, J_T).entropy()
    assert diag["kl_step"] <= s.config.eps + 1e-12


def test_gradients_match_finite_differences():
    space = _space()
    rng = np.random.default_rng(6)
    s = _with_params([3.0, 2.0], [2.5, 4.0])
    xi = s.sample(300, rng)
    u = np.clip(space.normalize(xi), 1e-12, 1 - 1e-12)
    log_q = s.log_prob(xi) + math.log(space.volume())
    prob = _Problem(0.8, 110.0, s.a.copy(), s.b.copy(), u, log_q, (_returns_band(space, xi) >= J_T).astype(float))
    theta = prob.theta_of(np.array([2.0, 2.5]), np.array([3.0, 1.5]))
    h = 1e-6
    for fun, grad in (
        (lambda t: prob.fun(t)[0], prob.fun(theta)[1]),
        (prob.kl_fun, prob.kl_jac(theta)[0]),
        (prob.j_fun, prob.j_jac(theta)[0]),
    ):
        grad = np.array(grad, copy=True)
        assert grad.shape == (4,)
        num = np.array([(fun(theta + h * e) - fun(theta - h * e)) / (2 * h) for e in np.eye(4)])
        np.testing.assert_allclose(grad, num, rtol=1e-5, atol=1e-7)


def test_shapes_are_explicit_no_n_by_n_broadcasting():
    space = _space()
    s = DORAEMONSampler(space, J_T)
    rng = np.random.default_rng(7)
    xi = s.sample(2, rng)  # n == d, where an (n,1)-vs-(n,) mix-up would still "work"
    diag = s.update(xi, np.array([2.0, 0.0]))
    assert np.asarray(diag["a"]).shape == (2,)
    xi = s.sample(5, rng)
    assert s.log_prob(xi).shape == (5,)
    with pytest.raises(ValueError, match="shape"):
        s.update(xi, np.ones((5, 1)))  # (N, 1) returns
    with pytest.raises(ValueError, match="proposal_log_prob"):
        s.update(xi, np.ones(5), proposal_log_prob=np.zeros((5, 1)))
    with pytest.raises(ValueError, match="proposal"):
        s.update(xi, np.ones(5), proposal_log_prob=np.array([0.0, 0.0, -np.inf, 0.0, 0.0]))


def test_bad_input_is_rejected():
    s = DORAEMONSampler(_space(), J_T)
    xi = s.sample(4, np.random.default_rng(8))
    with pytest.raises(ValueError, match="finite"):
        s.update(xi, np.array([1.0, np.inf, 2.0, 3.0]))
    with pytest.raises(ValueError, match="finite"):
        s.update(xi, np.array([1.0, np.nan, 2.0, 3.0]))
    with pytest.raises(ValueError, match="empty"):
        s.update(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ValueError, match="shape"):
        s.update(xi.T, np.ones(2))
    with pytest.raises(ValueError, match="shape"):
        s.update(xi, np.ones(3))
    with pytest.raises(ValueError):
        s.log_prob(np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="unknown option"):
        DORAEMONSampler(_space(), J_T, {"epsilon": 0.1})
    with pytest.raises(ValueError, match="alpha"):
        DORAEMONSampler(_space(), J_T, {"alpha": 1.5})
    np.testing.assert_array_equal(s.a, [100.0, 100.0])  # nothing changed


def test_state_dict_round_trip_json_pickle_and_space_mismatch():
    space = _space()
    s = DORAEMONSampler(space, J_T, {"eps": 0.1})
    rng = np.random.default_rng(9)
    xi = s.sample(200, rng)
    s.update(xi, _returns_band(space, xi))
    state = json.loads(json.dumps(s.state_dict()))
    t = DORAEMONSampler(space, 0.0)
    t.load_state_dict(state)
    np.testing.assert_array_equal(t.a, s.a)
    np.testing.assert_array_equal(t.b, s.b)
    assert t.config == s.config and t.success_threshold == J_T and t.n_updates == 1
    np.testing.assert_array_equal(t.sample(5, np.random.default_rng(1)), s.sample(5, np.random.default_rng(1)))
    u = pickle.loads(pickle.dumps(s))
    np.testing.assert_array_equal(u.a, s.a)
    other = ParamSpace((Param("mass", 0.0, 20.0, "kg"), Param("friction", -1.0, 2.0, "1")))
    with pytest.raises(ValueError, match="ParamSpace"):
        DORAEMONSampler(other, J_T).load_state_dict(state)
    with pytest.raises(ValueError, match="DORAEMONSampler"):
        t.load_state_dict({**state, "type": "ADRSampler"})
    with pytest.raises(ValueError, match="positive"):
        t.load_state_dict({**state, "a": [-1.0, 2.0]})


def test_uniform_proposal_config_and_keyword_overrides():
    space = _space()
    rng = np.random.default_rng(10)
    xi = FullDR(space).sample(3000, rng)  # a validation batch, uniform on the box
    r = _returns_band(space, xi)
    explicit = DORAEMONSampler(space, J_T, {"eps": 0.1})
    d1 = explicit.update(xi, r, proposal_log_prob=FullDR(space).log_prob(xi))
    configured = DORAEMONSampler(space, J_T, {"eps": 0.3}, eps=0.1, proposal="uniform")  # keywords win
    assert configured.config.eps == 0.1 and configured.config.proposal == "uniform"
    d2 = configured.update(xi, r)
    np.testing.assert_allclose(configured.a, explicit.a, rtol=1e-9)
    assert math.isclose(d1["success_rate"], d2["success_rate"], rel_tol=1e-9)
    # The IS estimate of the start distribution's success rate is its true rate (about 1 for the bump),
    # within the (large: narrow target, uniform proposal) standard error of the estimator.
    w_s = np.exp(DORAEMONSampler(space, J_T).log_prob(xi) - FullDR(space).log_prob(xi)) * (r >= J_T)
    assert math.isclose(d1["success_rate"], w_s.mean(), rel_tol=1e-9)
    assert abs(d1["success_rate"] - 1.0) < 4 * w_s.std() / math.sqrt(len(w_s))
    with pytest.raises(ValueError, match="proposal"):
        DORAEMONSampler(space, J_T, proposal="validation")
