"""Every registered sampler keeps the Sampler protocol and the one constructor signature."""

import inspect
import json

import numpy as np
import pytest

from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from goflow_common.errors import UnknownOptionError
from learning.estimation.distributions import TruncNormalProduct
from learning.samplers.registry import METHODS, SAMPLERS, make_sampler, sampler_class, sampler_config

SPACE = ParamSpace((Param("m", 0.5, 5.0, "kg"), Param("c", 0.0, 1.0, "N s/m")))
J_T = 10.0
#: Small settings per sampler so that the test is quick; every sampler also builds from None.
FAST = {
    "goflow": {"steps": 2, "entropy_samples": 64, "kl_samples": 64, "kl_pool": 128, "report_samples": 256},
    "lsdr": {"steps": 2},
    "doraemon": {"maxiter": 5},
    "estimated": {"distribution": TruncNormalProduct(np.array([0.3, 0.6]), np.array([0.1, 0.2])).to_dict()},
}


@pytest.fixture(params=list(SAMPLERS))
def name(request):
    return request.param


def _make(name, **extra):
    return make_sampler(name, SPACE, J_T, {**FAST.get(name, {}), **extra})


def test_one_constructor_signature(name):
    params = list(inspect.signature(sampler_class(name)).parameters)
    assert params == ["space", "success_threshold", "config", "overrides"], params


def test_protocol_invariants(name):
    s = _make(name)
    assert isinstance(s, Sampler)
    rng = np.random.default_rng(0)
    xi = s.sample(64, rng)
    assert xi.shape == (64, 2) and SPACE.contains(xi).all()
    lp = s.log_prob(xi)
    assert lp.shape == (64,) and not np.isnan(lp).any()
    assert s.log_prob(np.array([[9.0, 0.5]]))[0] == -np.inf  # outside the box
    state = json.loads(json.dumps(s.state_dict()))  # JSON-serializable
    assert state["type"] == type(s).__name__ and state["space"] == SPACE.to_dict()
    diag = s.update(xi, np.linspace(0.0, 20.0, 64))
    assert diag["n"] == 64


def test_a_reloaded_sampler_samples_the_same_points(name):
    s = _make(name)
    s.update(s.sample(32, np.random.default_rng(1)), np.linspace(0.0, 20.0, 32))
    fresh = _make(name)
    fresh.load_state_dict(s.state_dict())
    a = s.sample(16, np.random.default_rng(5))
    b = fresh.sample(16, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)


def test_unknown_options_are_refused_before_any_work(name):
    with pytest.raises(UnknownOptionError, match=r"unknown option\(s\) \['no_such_option'\]"):
        sampler_config(name, {"no_such_option": 1})
    with pytest.raises(ValueError, match="unknown sampler 'sac'"):
        make_sampler("sac", SPACE, J_T)


def test_weights_are_config_fields():
    g = make_sampler("goflow", SPACE, J_T, {"alpha": 0.3, "beta": 0.0})
    assert (g.alpha, g.beta) == (0.3, 0.0) and g.config.alpha == 0.3
    assert make_sampler("lsdr", SPACE, J_T, {"alpha": 2.0}).alpha == 2.0
    with pytest.raises(ValueError, match="alpha = -1"):
        make_sampler("goflow", SPACE, J_T, {"alpha": -1})


def test_methods_that_compare_with_j_t_need_it():
    for name in ("adr", "doraemon"):
        with pytest.raises(ValueError, match="success_threshold"):
            make_sampler(name, SPACE, None)
    assert set(METHODS) == {"nodr", "fulldr", "adr", "lsdr", "doraemon", "goflow"}


def test_an_env_refuses_a_sampler_of_another_space():
    import gymnasium

    import assembly  # noqa: F401

    env = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make("goflow/Toy2D-v0")])
    with pytest.raises(ValueError, match="ParamSpace differs"):
        env.set_attr("sampler", make_sampler("fulldr", SPACE))
    with pytest.raises(TypeError, match="must implement"):
        env.unwrapped.envs[0].unwrapped.sampler = object()
    env.close()
