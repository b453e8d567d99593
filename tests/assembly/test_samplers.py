"""NoDR and FullDR on the Sampler protocol: statistics, densities, validation and checkpoints."""

import math

import numpy as np
import pytest

from assembly.params import Param, ParamSpace
from assembly.samplers import FullDR, NoDR, Sampler, check_update_inputs


def _space() -> ParamSpace:
    return ParamSpace((Param("mass", 0.01, 20.0, "kg"), Param("friction", 0.0, 1.0, "1")))


@pytest.fixture(params=["nodr", "fulldr"])
def sampler(request):
    return NoDR(_space()) if request.param == "nodr" else FullDR(_space())


def test_protocol_is_runtime_checkable(sampler):
    assert isinstance(sampler, Sampler)
    assert sampler.space == _space()


def test_samples_are_inside_box_with_right_shape(sampler):
    xi = sampler.sample(1000, np.random.default_rng(0))
    assert xi.shape == (1000, 2) and xi.dtype == np.float64
    assert np.all(sampler.space.contains(xi))
    assert sampler.sample(0, np.random.default_rng(0)).shape == (0, 2)


def test_sample_rejects_bad_arguments(sampler):
    with pytest.raises(ValueError, match="n"):
        sampler.sample(-1, np.random.default_rng(0))
    with pytest.raises(TypeError, match="Generator"):
        sampler.sample(3, 0)


def test_nodr_is_the_box_centre_by_default():
    s = NoDR(_space())
    np.testing.assert_allclose(s.point, [10.005, 0.5])
    xi = s.sample(5, np.random.default_rng(1))
    np.testing.assert_array_equal(xi, np.tile(s.point, (5, 1)))
    lp = s.log_prob(np.array([s.point, [1.0, 0.5]]))
    assert lp.shape == (2,) and lp[0] == math.inf and lp[1] == -math.inf
    assert s.entropy() == -math.inf


def test_nodr_custom_point_is_validated():
    np.testing.assert_array_equal(NoDR(_space(), point=[1.0, 0.2]).point, [1.0, 0.2])
    with pytest.raises(ValueError, match="friction"):
        NoDR(_space(), point=[1.0, 2.0])


def test_fulldr_statistics():
    s = FullDR(_space())
    xi = s.sample(200_000, np.random.default_rng(2))
    width = s.space.high - s.space.low
    centre = (s.space.high + s.space.low) / 2
    # Monte Carlo standard error of the mean: width / sqrt(12 n); allow 5 of them.
    se = width / math.sqrt(12 * len(xi))
    assert np.all(np.abs(xi.mean(0) - centre) < 5 * se)
    np.testing.assert_allclose(xi.var(0), width**2 / 12, rtol=0.02)


def test_fulldr_density_and_entropy():
    s = FullDR(_space())
    vol = s.space.volume()
    assert math.isclose(s.entropy(), math.log(vol))
    inside = s.sample(10, np.random.default_rng(3))
    np.testing.assert_allclose(s.log_prob(inside), -math.log(vol))
    assert s.log_prob(np.array([[25.0, 0.5]]))[0] == -math.inf
    # The density integrates to one: midpoint rule on a grid covering twice the box.
    lo, hi = s.space.low - 0.5 * (s.space.high - s.space.low), s.space.high + 0.5 * (s.space.high - s.space.low)
    m = 400
    axes = [lo[i] + (np.arange(m) + 0.5) * (hi[i] - lo[i]) / m for i in range(2)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
    cell = np.prod((hi - lo) / m)
    assert math.isclose(np.exp(s.log_prob(grid)).sum() * cell, 1.0, rel_tol=1e-9)
    # ... and by Monte Carlo with a uniform proposal over the larger box.
    u = np.random.default_rng(4).uniform(lo, hi, size=(100_000, 2))
    est = np.exp(s.log_prob(u)).mean() * np.prod(hi - lo)
    assert abs(est - 1.0) < 0.03


def test_log_prob_rejects_nan_and_wrong_shape(sampler):
    with pytest.raises(ValueError, match="finite"):
        sampler.log_prob(np.array([[np.nan, 0.5]]))
    with pytest.raises(ValueError, match="shape"):
        sampler.log_prob(np.zeros((3, 5)))
    assert sampler.log_prob(sampler.space.nominal()).shape == (1,)


def test_update_is_a_validated_no_op(sampler):
    rng = np.random.default_rng(5)
    xi = FullDR(_space()).sample(8, rng)
    before = sampler.state_dict()
    diag = sampler.update(xi, rng.normal(size=8))
    assert isinstance(diag, dict) and diag["n"] == 8
    assert sampler.state_dict() == before


@pytest.mark.parametrize(
    "xi_shape, returns, fragment",
    [
        ((0, 2), np.zeros(0), "empty"),
        ((4, 2), np.array([0.0, 1.0, np.nan, 2.0]), "finite"),
        ((4, 2), np.array([0.0, np.inf, 1.0, 2.0]), "finite"),
        ((4, 2), np.zeros(3), "returns"),
        ((4, 2), np.zeros((4, 1)), "returns"),
        ((4, 3), np.zeros(4), "shape"),
        ((2,), np.zeros(1), "shape"),
    ],
)
def test_update_rejects_bad_batches(sampler, xi_shape, returns, fragment):
    xi = np.full(xi_shape, 0.5)
    with pytest.raises(ValueError, match=fragment):
        sampler.update(xi, returns)


def test_update_rejects_xi_outside_box(sampler):
    with pytest.raises(ValueError, match="mass"):
        sampler.update(np.array([[30.0, 0.5]]), np.array([1.0]))


def test_check_update_inputs_returns_clean_arrays():
    xi, ret = check_update_inputs(_space(), [[1.0, 0.5], [2.0, 0.1]], [1, 2])
    assert xi.shape == (2, 2) and ret.shape == (2,) and ret.dtype == np.float64


def test_state_dict_round_trip():
    s = NoDR(_space(), point=[3.0, 0.25])
    t = NoDR(_space())
    t.load_state_dict(s.state_dict())
    np.testing.assert_array_equal(t.point, [3.0, 0.25])
    f = FullDR(_space())
    g = FullDR(_space())
    g.load_state_dict(f.state_dict())
    assert g.entropy() == f.entropy()


def test_load_state_dict_detects_space_mismatch(sampler):
    other_space = ParamSpace((Param("mass", 0.01, 10.0, "kg"), Param("friction", 0.0, 1.0, "1")))
    other = type(sampler)(other_space)
    with pytest.raises(ValueError, match="mass.*high"):
        sampler.load_state_dict(other.state_dict())


def test_load_state_dict_detects_wrong_sampler_type():
    with pytest.raises(ValueError, match="FullDR"):
        NoDR(_space()).load_state_dict(FullDR(_space()).state_dict())
