"""Eq. 6 and Eq. 7 with the shipped medium insert skill: a belief concentrated where the flow is
dense and V high passes, a wide or shifted one fails, and the estimate is monotone in eta and
eps; the thresholds file is data, checked on load.

The centre is the median of the flow's draws that pass Eq. 7 pointwise. The flow's own median
need not pass: the critic's V > V_T region and the measured feasible set the flow covers overlap
only in part (docs/planning.md)."""

import json

import numpy as np
import pytest

from learning.skill_file import load_skill
from planning.precondition import InsertPrecondition, PreconditionConfig, insert_precondition, load_value_thresholds


@pytest.fixture(scope="module")
def skill():
    return load_skill("insert", "medium")


@pytest.fixture(scope="module")
def pre(skill):
    return insert_precondition("medium", PreconditionConfig(eta=0.9, eps=1.0), skill=skill)


@pytest.fixture(scope="module")
def centre(skill, pre):
    draws = skill.sampler.sample(4096, np.random.default_rng(0))
    return np.median(draws[pre.succeeds(draws)], axis=0)


def belief(centre, std_xy, shift=0.0, n=512, seed=0):
    rng = np.random.default_rng(seed)
    xi = centre + rng.standard_normal((n, 3)) * [std_xy, std_xy, 0.005]
    xi[:, 0] += shift
    return xi


def test_sharp_belief_at_the_flow_passes_wide_or_shifted_fails(pre, centre):
    assert pre.holds(belief(centre, 2e-4)), pre.probability(belief(centre, 2e-4))
    assert pre.probability(belief(centre, 5e-3)) < 0.5
    assert pre.probability(belief(centre, 2e-4, shift=6e-3)) < 0.1
    assert not pre.holds(belief(centre, 5e-3))


def test_monotone_in_eps_and_eta(skill, pre, centre):
    xi = belief(centre, 1.5e-3)
    probs = [
        InsertPrecondition(skill, pre.value_threshold, PreconditionConfig(eps=e), pre.s0).probability(xi)
        for e in (0.0, 1.0, 10.0, 100.0, 1000.0)
    ]
    assert all(a >= b for a, b in zip(probs, probs[1:])), probs
    value_only = InsertPrecondition(skill, pre.value_threshold, PreconditionConfig(eps=None), pre.s0)
    assert value_only.probability(xi) >= probs[1]  # Eq. 7 only adds a factor to Eq. 6
    p = pre.probability(xi)
    holds = [
        InsertPrecondition(skill, pre.value_threshold, PreconditionConfig(eta=eta), pre.s0).holds(xi)
        for eta in (0.0, p - 0.05, p + 0.05, 0.99)
    ]
    assert holds == sorted(holds, reverse=True) and holds[0] and not holds[-1]


def test_grasp_errors_outside_the_box_never_pass(pre):
    assert pre.probability(np.array([[0.2, 0.0, 0.0], [0.0, 0.0, 2.0]])) == 0.0


def test_bad_input_is_named(skill, pre, tmp_path):
    with pytest.raises(ValueError, match="eta"):
        PreconditionConfig(eta=1.5)
    with pytest.raises(ValueError, match="eps"):
        PreconditionConfig(eps=-1.0)
    with pytest.raises(ValueError, match="expected finite"):
        pre.probability(np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="value_threshold"):
        InsertPrecondition(skill, float("nan"), s0=pre.s0)
    with pytest.raises(FileNotFoundError, match="value-threshold"):
        load_value_thresholds(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"thresholds": {"medium": NaN}}')
    with pytest.raises(Exception, match="NaN"):
        load_value_thresholds(bad)
    odd = tmp_path / "odd.json"
    odd.write_text(json.dumps({"thresholds": {"medium": "high"}}))
    with pytest.raises(Exception, match="finite number"):
        load_value_thresholds(odd)
    with pytest.raises(ValueError, match="no value threshold"):
        insert_precondition("medium", thresholds=_only_small(tmp_path), skill=skill)


def _only_small(tmp_path):
    path = tmp_path / "small.json"
    path.write_text(json.dumps({"thresholds": {"small": 7.0}}))
    return path
