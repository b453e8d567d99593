"""ParamSpace: named, bounded parameters with units, unit-box normalization and clear errors."""

import math

import numpy as np
import pytest

from assembly.params import Param, ParamSpace


def _space() -> ParamSpace:
    return ParamSpace(
        (
            Param("pole_mass", 0.01, 20.0, "kg"),
            Param("friction", 0.0, 1.0, "1", nominal=0.1),
            Param("yaw", -0.393, 0.393, "rad"),
        )
    )


def test_param_nominal_defaults_to_box_centre():
    assert Param("x", -1.0, 3.0, "m").nominal == 1.0
    assert Param("x", -1.0, 3.0, "m", nominal=2.5).nominal == 2.5


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(name="x", low=1.0, high=1.0, unit="m"), "low < high"),
        (dict(name="x", low=2.0, high=1.0, unit="m"), "low < high"),
        (dict(name="x", low=float("nan"), high=1.0, unit="m"), "finite"),
        (dict(name="x", low=0.0, high=float("inf"), unit="m"), "finite"),
        (dict(name="x", low=0.0, high=1.0, unit="m", nominal=1.5), "nominal"),
        (dict(name="", low=0.0, high=1.0, unit="m"), "name"),
    ],
)
def test_param_rejects_bad_definitions(kwargs, fragment):
    with pytest.raises(ValueError, match=fragment):
        Param(**kwargs)


def test_space_basic_properties():
    s = _space()
    assert s.dim == 3
    assert s.names == ("pole_mass", "friction", "yaw")
    np.testing.assert_array_equal(s.low, [0.01, 0.0, -0.393])
    np.testing.assert_array_equal(s.high, [20.0, 1.0, 0.393])
    np.testing.assert_allclose(s.nominal(), [10.005, 0.1, 0.0])
    assert math.isclose(s.volume(), 19.99 * 1.0 * 0.786)


def test_space_rejects_duplicate_names_and_empty():
    with pytest.raises(ValueError, match="duplicate"):
        ParamSpace((Param("x", 0, 1, "m"), Param("x", 0, 2, "m")))
    with pytest.raises(ValueError, match="at least one"):
        ParamSpace(())


def test_normalize_round_trip_single_and_batch():
    s = _space()
    rng = np.random.default_rng(0)
    xi = rng.uniform(s.low, s.high, size=(50, 3))
    u = s.normalize(xi)
    assert u.shape == (50, 3)
    assert np.all((u >= 0) & (u <= 1))
    np.testing.assert_allclose(s.denormalize(u), xi, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.normalize(s.low), np.zeros(3))
    np.testing.assert_allclose(s.normalize(s.high), np.ones(3))
    single = s.normalize(xi[0])
    assert single.shape == (3,)
    np.testing.assert_allclose(s.denormalize(single), xi[0])


def test_contains():
    s = _space()
    assert s.contains(s.nominal()) is True
    assert s.contains(s.high) is True  # the box is closed
    np.testing.assert_array_equal(s.contains(np.array([s.nominal(), s.high + 1.0])), [True, False])


def test_validate_names_parameter_value_and_bounds():
    s = _space()
    bad = s.nominal()
    bad[1] = 1.7
    with pytest.raises(ValueError) as e:
        s.validate(bad)
    msg = str(e.value)
    assert "friction" in msg and "1.7" in msg and "[0, 1]" in msg
    batch = np.tile(s.nominal(), (4, 1))
    batch[2, 2] = -1.0
    with pytest.raises(ValueError) as e:
        s.validate(batch)
    msg = str(e.value)
    assert "yaw" in msg and "-0.393" in msg and "0.393" in msg and "rad" in msg and "row 2" in msg


def test_validate_rejects_nan_and_wrong_shape():
    s = _space()
    bad = s.nominal()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="pole_mass.*finite"):
        s.validate(bad)
    for shape in [(2,), (4,), (5, 2), (1, 2, 3), ()]:
        with pytest.raises(ValueError, match=r"expected shape \(3,\) or \(n, 3\)"):
            s.validate(np.zeros(shape))
    with pytest.raises(ValueError, match="shape"):
        s.normalize(np.zeros(2))


def test_validate_returns_float_copy():
    s = _space()
    xi = [1, 0, 0]
    out = s.validate(xi)
    assert out.dtype == np.float64 and out.shape == (3,)


def test_dict_round_trip_and_equality():
    s = _space()
    d = s.to_dict()
    s2 = ParamSpace.from_dict(d)
    assert s2 == s
    assert hash(s2) == hash(s)
    other = ParamSpace.from_dict({"params": [dict(p, high=p["high"] * 2) for p in d["params"]]})
    assert other != s
    diffs = s.diff(other)
    assert any("pole_mass" in x and "high" in x for x in diffs)
    assert s.diff(s2) == []


def test_from_dict_reports_malformed_input():
    with pytest.raises(ValueError, match="params"):
        ParamSpace.from_dict({"parameters": []})
    with pytest.raises(ValueError, match="unit"):
        ParamSpace.from_dict({"params": [{"name": "x", "low": 0, "high": 1}]})
