"""ADR (learning/samplers/adr.py): bounds move the right way, stay in the box, boundary sampling works."""

import json
import math
import pickle

import numpy as np
import pytest

from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from learning.samplers.adr import ADRConfig, ADRSampler

J_T = 10.0


def _space() -> ParamSpace:
    # Non-centred nominal on y so that "clipped at the nominal point" and "at the centre" differ.
    return ParamSpace((Param("mass", 0.0, 20.0, "kg"), Param("friction", -1.0, 1.0, "1", nominal=0.5)))


def _rows_at(s: ADRSampler, dim: int, side: str, k: int) -> np.ndarray:
    """k rows with dimension `dim` pinned to its current bound and the others at the interval middles."""
    rows = np.tile(0.5 * (s.lo + s.hi), (k, 1))
    rows[:, dim] = s.lo[dim] if side == "low" else s.hi[dim]
    return rows


def _feed(s: ADRSampler, dim: int, side: str, value: float) -> dict:
    """Fill the queue of one bound with `value` (one full queue)."""
    m = s.config.queue_length
    return s.update(_rows_at(s, dim, side, m), np.full(m, value))


def test_defaults_follow_the_paper_appendix():
    s = ADRSampler(_space(), J_T)
    assert isinstance(s, Sampler)
    assert s.t_plus == J_T and s.t_minus == 0.5 * J_T
    np.testing.assert_allclose(s.delta, [2.0, 0.2])  # 0.1 x range
    assert s.config.boundary_prob == 0.5
    # Starts around the nominal point with a small positive width.
    np.testing.assert_allclose(s.lo, [10.0 - 0.5, 0.5 - 0.05])
    np.testing.assert_allclose(s.hi, [10.0 + 0.5, 0.5 + 0.05])


@pytest.mark.parametrize("dim", [0, 1])
@pytest.mark.parametrize("side", ["low", "high"])
def test_good_returns_at_a_bound_expand_it_by_delta(dim, side):
    s = ADRSampler(_space(), J_T, {"queue_length": 4})
    lo0, hi0 = s.lo.copy(), s.hi.copy()
    # A queue that is not yet full changes nothing.
    s.update(_rows_at(s, dim, side, 3), np.full(3, J_T + 5))
    np.testing.assert_array_equal(s.lo, lo0)
    np.testing.assert_array_equal(s.hi, hi0)
    diag = s.update(_rows_at(s, dim, side, 1), np.array([J_T]))  # mean exactly t+: expands
    exp_lo, exp_hi = lo0.copy(), hi0.copy()
    if side == "low":
        exp_lo[dim] -= s.delta[dim]
    else:
        exp_hi[dim] += s.delta[dim]
    np.testing.assert_allclose(s.lo, exp_lo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.hi, exp_hi, rtol=0, atol=1e-12)
    assert diag["expanded"] == [[s.space.names[dim], side]] and diag["contracted"] == []
    assert s.queues[(dim, side)] == []  # cleared after the decision


@pytest.mark.parametrize("side", ["low", "high"])
def test_poor_returns_contract_and_stop_at_the_nominal_point(side):
    s = ADRSampler(_space(), J_T, {"queue_length": 3})
    for _ in range(3):
        _feed(s, 0, side, J_T)
    before = (s.lo[0], s.hi[0])
    diag = _feed(s, 0, side, 0.5 * J_T)  # mean exactly t-: contracts
    assert diag["contracted"] == [["mass", side]]
    if side == "low":
        assert math.isclose(s.lo[0], before[0] + 2.0) and s.hi[0] == before[1]
    else:
        assert math.isclose(s.hi[0], before[1] - 2.0) and s.lo[0] == before[0]
    for _ in range(10):
        _feed(s, 0, side, -100.0)
    bound = s.lo[0] if side == "low" else s.hi[0]
    assert bound == 10.0  # the nominal point: never past it, so never past the other bound
    assert s.lo[0] <= 10.0 <= s.hi[0]


def test_returns_between_the_thresholds_change_nothing_but_clear_the_queue():
    s = ADRSampler(_space(), J_T, {"queue_length": 5})
    lo0, hi0 = s.lo.copy(), s.hi.copy()
    for dim in range(2):
        for side in ("low", "high"):
            diag = _feed(s, dim, side, 0.75 * J_T)
            assert diag["expanded"] == [] and diag["contracted"] == []
            assert s.queues[(dim, side)] == []
    np.testing.assert_array_equal(s.lo, lo0)
    np.testing.assert_array_equal(s.hi, hi0)


def test_only_rows_on_a_bound_count_and_order_does_not_matter():
    s = ADRSampler(_space(), J_T, {"queue_length": 4})
    rng = np.random.default_rng(0)
    interior = s.lo + (s.hi - s.lo) * rng.uniform(0.1, 0.9, size=(50, 2))
    pinned = _rows_at(s, 1, "high", 4)
    xi = np.concatenate([interior, pinned])
    perm = rng.permutation(len(xi))
    diag = s.update(xi[perm], np.full(len(xi), J_T + 1)[perm])
    assert diag["n_boundary"] == 4
    assert diag["expanded"] == [["friction", "high"]]
    assert all(len(q) == 0 for q in s.queues.values())


def test_bounds_never_leave_the_box_under_any_return_sequence():
    space = _space()
    s = ADRSampler(space, J_T, {"queue_length": 2, "step_fraction": 0.3})
    rng = np.random.default_rng(1)
    for _ in range(200):
        xi = s.sample(40, rng)
        s.update(xi, rng.choice([0.0, 7.0, 20.0], size=40))
        assert np.all(space.low <= s.lo) and np.all(s.lo <= space.nominal())
        assert np.all(space.nominal() <= s.hi) and np.all(s.hi <= space.high)
        assert np.all(space.contains(xi))
    # Persistently good returns drive every bound exactly onto the box, not past it.
    for _ in range(100):
        s.update(s.sample(40, rng), np.full(40, 2 * J_T))
    np.testing.assert_array_equal(s.lo, space.low)
    np.testing.assert_array_equal(s.hi, space.high)
    assert math.isclose(s.entropy(), math.log(space.volume()))


def test_boundary_samples_hit_the_current_bounds_at_the_configured_rate():
    s = ADRSampler(_space(), J_T, {"boundary_prob": 0.3})
    n = 40_000
    xi = s.sample(n, np.random.default_rng(2))
    assert xi.shape == (n, 2) and np.all((xi >= s.lo) & (xi <= s.hi))
    at = {(i, side): xi[:, i] == (s.lo[i] if side == "low" else s.hi[i]) for i in range(2) for side in ("low", "high")}
    any_bound = np.any(np.stack(list(at.values())), axis=0)
    n_pinned_dims = sum(a.astype(int) for a in at.values())
    assert n_pinned_dims.max() == 1  # exactly one coordinate pinned per boundary sample
    se = math.sqrt(0.3 * 0.7 / n)
    assert abs(any_bound.mean() - 0.3) < 5 * se
    for hit in at.values():  # each of the 2d bounds equally often
        p = 0.3 / 4
        assert abs(hit.mean() - p) < 5 * math.sqrt(p * (1 - p) / n)
    # p_b = 0: plain uniform on the intervals; p_b = 1: every sample is a boundary sample.
    none = ADRSampler(_space(), J_T, {"boundary_prob": 0.0}).sample(1000, np.random.default_rng(3))
    assert not np.any((none == s.lo) | (none == s.hi))
    allb = ADRSampler(_space(), J_T, {"boundary_prob": 1.0}).sample(1000, np.random.default_rng(3))
    assert np.all(np.any((allb == s.lo) | (allb == s.hi), axis=1))


@pytest.mark.parametrize("init_width", [0.0, 0.05])
def test_not_nodr_in_disguise_good_returns_widen_the_sampled_range(init_width):
    space = _space()
    s = ADRSampler(space, J_T, {"init_width_fraction": init_width})
    rng = np.random.default_rng(4)
    first = s.sample(500, rng)
    h0 = s.entropy()
    if init_width == 0.0:
        assert h0 == -math.inf and np.all(first == space.nominal())
    for _ in range(25):
        xi = s.sample(200, rng)
        s.update(xi, np.full(200, J_T + 1.0))
    later = s.sample(5000, rng)
    span0 = first.max(0) - first.min(0)
    span1 = later.max(0) - later.min(0)
    assert np.all(span1 > span0 + 0.5 * (space.high - space.low))
    assert s.entropy() > h0
    assert s.n_expansions > 0 and s.n_contractions == 0


def test_poor_returns_shrink_towards_nominal():
    s = ADRSampler(_space(), J_T, {"init_width_fraction": 0.8})
    rng = np.random.default_rng(5)
    w0 = s.widths().copy()
    for _ in range(30):
        s.update(s.sample(200, rng), np.zeros(200))
    assert np.all(s.widths() < w0)
    np.testing.assert_array_equal(s.lo, _space().nominal())
    np.testing.assert_array_equal(s.hi, _space().nominal())
    assert s.entropy() == -math.inf


def test_thresholds_for_negative_and_zero_targets():
    neg = ADRSampler(_space(), -10.0, {"t_minus_ratio": 0.25})
    assert neg.t_plus == -10.0 and neg.t_minus == -17.5 and neg.t_minus < neg.t_plus
    pos = ADRSampler(_space(), 10.0, {"t_minus_ratio": 0.25})
    assert pos.t_minus == 2.5
    explicit = ADRSampler(_space(), 0.0, {"t_minus": -3.0})
    assert explicit.t_plus == 0.0 and explicit.t_minus == -3.0
    with pytest.raises(ValueError, match="t_minus <= t_plus"):
        ADRSampler(_space(), 0.0, {"t_minus": 3.0})


def test_log_prob_and_entropy_are_uniform_on_the_intervals():
    s = ADRSampler(_space(), J_T, {"init_width_fraction": 0.5})
    w = s.widths()
    assert math.isclose(s.entropy(), float(np.sum(np.log(w))))
    xi = s.sample(100, np.random.default_rng(6))
    np.testing.assert_allclose(s.log_prob(xi), -np.sum(np.log(w)))
    out = np.array([[s.hi[0] + 0.1, 0.5], [10.0, s.lo[1] - 1e-9]])
    assert np.all(s.log_prob(out) == -math.inf)
    assert s.log_prob(np.array([10.0, 0.5])).shape == (1,)
    with pytest.raises(ValueError):
        s.log_prob(np.array([[np.nan, 0.5]]))


def test_bad_input_is_rejected():
    s = ADRSampler(_space(), J_T)
    xi = s.sample(4, np.random.default_rng(7))
    with pytest.raises(ValueError, match="finite"):
        s.update(xi, np.array([1.0, np.nan, 2.0, 3.0]))
    with pytest.raises(ValueError, match="empty"):
        s.update(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ValueError, match="shape"):
        s.update(xi, np.ones((4, 1)))
    with pytest.raises(ValueError, match="shape"):
        s.update(xi[:, :1], np.ones(4))
    with pytest.raises(ValueError, match="outside"):
        s.update(np.array([[25.0, 0.0]]), np.ones(1))
    with pytest.raises(ValueError):
        s.sample(-1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown option"):
        ADRSampler(_space(), J_T, {"queue_len": 3})
    with pytest.raises(ValueError, match="boundary_prob"):
        ADRSampler(_space(), J_T, {"boundary_prob": 1.5})
    with pytest.raises(ValueError, match="success_threshold"):
        ADRSampler(_space(), math.nan)


def test_state_dict_round_trip_json_pickle_and_space_mismatch():
    s = ADRSampler(_space(), J_T, ADRConfig(queue_length=3))
    rng = np.random.default_rng(8)
    for _ in range(5):
        s.update(s.sample(30, rng), rng.uniform(0, 20, size=30))
    state = json.loads(json.dumps(s.state_dict()))
    t = ADRSampler(_space(), 0.0)
    t.load_state_dict(state)
    np.testing.assert_array_equal(t.lo, s.lo)
    np.testing.assert_array_equal(t.hi, s.hi)
    assert t.queues == s.queues and t.t_plus == s.t_plus and t.config == s.config
    np.testing.assert_array_equal(t.sample(10, np.random.default_rng(9)), s.sample(10, np.random.default_rng(9)))
    u = pickle.loads(pickle.dumps(s))
    np.testing.assert_array_equal(u.lo, s.lo)
    other = ParamSpace((Param("mass", 0.0, 30.0, "kg"), Param("friction", -1.0, 1.0, "1", nominal=0.5)))
    with pytest.raises(ValueError, match="ParamSpace"):
        ADRSampler(other, J_T).load_state_dict(state)
    with pytest.raises(ValueError, match="ADRSampler"):
        t.load_state_dict({**state, "type": "FullDR"})
    bad = dict(state, lo=[-5.0, 0.0])
    with pytest.raises(ValueError, match="bounds"):
        t.load_state_dict(bad)


def test_keyword_overrides_and_a_batch_with_no_boundary_rows_warns():
    s = ADRSampler(_space(), J_T, {"queue_length": 4}, boundary_prob=0.2)  # as make_sampler(**kwargs)
    assert s.config.queue_length == 4 and s.config.boundary_prob == 0.2
    lo0, hi0 = s.lo.copy(), s.hi.copy()
    interior = np.tile(0.5 * (s.lo + s.hi), (20, 1))  # e.g. a batch not drawn by this sampler
    with pytest.warns(UserWarning, match="boundary"):
        diag = s.update(interior, np.full(20, J_T + 1))
    assert diag["n_boundary"] == 0
    np.testing.assert_array_equal(s.lo, lo0)
    np.testing.assert_array_equal(s.hi, hi0)
