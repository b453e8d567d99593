"""sim2real.station_logs: insertion logs with contact/grasp effects in the station's physics, their
open-loop replay, phase labels and the skill's success rate (full 4 s panda episodes, ~1-2 s each)."""

from __future__ import annotations

import numpy as np
import pytest

from goflow_common.errors import InputError
from sim2real.importers import load_log
from sim2real.log import PHASES, save_log, validate_log
from sim2real.station_logs import (
    check_station_effects,
    make_insertion_log,
    phase_residuals,
    replay_insertion,
    geometry_phases,
    skill_success,
    station_physics,
)

FRICTION = {"shaft_friction": {"mu": 1.0}}
XI = (0.0008, -0.0018, 0.04)  # inside the shipped medium skill's feasible set: it seats the gear nominally
CONTACT, INSERTION = PHASES.index("contact"), PHASES.index("insertion")


@pytest.fixture(scope="module")
def skill():
    from learning.skill_file import load_skill

    return load_skill("insert", "medium")


@pytest.fixture(scope="module")
def nominal(skill):
    return make_insertion_log({}, xi=XI, skill=skill)


@pytest.fixture(scope="module")
def friction(skill):
    return make_insertion_log(FRICTION, xi=XI, skill=skill)


def _first(log, phase):
    hits = np.flatnonzero(log.phase >= phase)
    return int(hits[0]) if len(hits) else log.n_samples


def test_log_contract_and_phases(nominal, tmp_path):
    log, success = nominal
    validate_log(log)
    back = load_log(save_log(log, tmp_path / "nominal.npz"))
    np.testing.assert_array_equal(back.tool_pose, log.tool_pose)
    assert back.meta["task"] == log.meta["task"]
    assert success and log.meta["success"]
    T = log.n_samples
    assert T == 501 and np.allclose(np.diff(log.time), 0.008)  # every physics step, 4 s
    for name, shape in (
        ("q", (T, 7)),
        ("dq", (T, 7)),
        ("tau", (T, 7)),
        ("tau_cmd", (T, 7)),
        ("tool_pose", (T, 4, 4)),
        ("tool_target", (T, 4, 4)),
        ("wrench", (T, 6)),
        ("gripper_width", (T,)),
        ("phase", (T,)),
    ):
        assert getattr(log, name).shape == shape, name
        assert np.all(np.isfinite(getattr(log, name))), name
    np.testing.assert_array_equal(log.tau, log.tau_cmd)
    assert log.meta["robot"] == "panda" and log.meta["end_effector"] == "hand+gear_medium"
    assert log.meta["torque_side"] == "motor" and log.meta["truth"] == {}
    task = log.meta["task"]
    assert task["gear"] == "medium" and np.allclose(task["xi"], XI) and task["skill"] == "insert-medium"
    # Phases never go back, start before contact and reach contact, then insertion.
    assert np.all(np.diff(log.phase) >= 0)
    assert log.phase[0] == PHASES.index("approach")
    assert 0 < _first(log, CONTACT) < _first(log, INSERTION) < T
    # Before contact nothing touches the gear; the seated gear is pressed on the plate.
    assert np.abs(log.wrench[: _first(log, CONTACT) - 1, :3]).max() < 0.1
    assert log.wrench[-1, 2] > 1.0


def test_shaft_friction_slows_the_descent(nominal, friction):
    (log0, ok0), (log1, ok1) = nominal, friction
    assert ok0 and not ok1 and log1.meta["truth"] == FRICTION
    # Same until the first contact; then the gear sticks on the shaft: insertion starts much later
    # and the tool stays higher while the skill pushes.
    k = _first(log0, CONTACT)
    np.testing.assert_allclose(log1.tool_pose[:k], log0.tool_pose[:k], atol=1e-9)
    assert _first(log1, INSERTION) > _first(log0, INSERTION) + 100
    t = int(np.searchsorted(log0.time, 1.5))
    assert log1.tool_pose[t, 2, 3] > log0.tool_pose[t, 2, 3] + 0.005


def test_replay_reproduces_with_true_effects_and_localises_the_gap(friction):
    log, _ = friction
    same = replay_insertion(log, FRICTION)
    np.testing.assert_allclose(same.time, log.time)
    r_true = phase_residuals(log, same)
    assert all(r["p"] < 1e-3 for r in r_true.values()), r_true
    assert same.meta["source"] == "replay" and same.meta["truth"] == FRICTION
    r_nom = phase_residuals(log, replay_insertion(log, {}))
    assert r_nom["approach"]["p"] < 1e-5 and r_nom["approach"]["tau"] < 1e-3
    assert r_nom["contact"]["z"] > 3e-3 and r_nom["contact"]["tau"] > 0.2
    assert r_nom["contact"]["z"] > 100 * r_true["contact"]["z"] + 1e-4


def test_grasp_slip_lets_the_gear_slide_up_in_the_hand(nominal, skill):
    log0, _ = nominal
    log, _ = make_insertion_log({"grasp_slip": {"mu_scale": 0.1}}, xi=XI, skill=skill)
    assert np.all(np.diff(log.phase) >= 0)
    k = _first(log0, CONTACT)
    np.testing.assert_allclose(log.tool_pose[:k, :3, 3], log0.tool_pose[:k, :3, 3], atol=2e-4)
    # The seated gear stops at the plate while the tool goes on down past it.
    assert log.tool_pose[-1, 2, 3] < log0.tool_pose[-1, 2, 3] - 0.001


def test_success_rate_drops_with_friction(skill):
    assert skill_success({}, episodes=1, seed=0, skill=skill, xi=XI) == 1.0
    assert skill_success(FRICTION, episodes=1, seed=0, skill=skill, xi=XI) == 0.0


def test_phase_rule():
    lateral = np.array([0.01, 0.003, 0.003, 0.003, 0.0005, 0.0005, 0.0005])
    height = np.array([0.05, 0.03, 0.0205, 0.0195, 0.015, 0.021, 0.0])  # a bounce back up stays insertion
    force = np.array([0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 5.0])
    np.testing.assert_array_equal(geometry_phases(lateral, height, force), [0, 1, 1, 2, 3, 3, 3])


def test_effects_map_to_physics():
    assert station_physics({}) == {"contact": None, "grasp_hold": None}
    assert station_physics({"shaft_friction": 0.0, "grasp_slip": 1.0}) == {"contact": None, "grasp_hold": None}
    p = station_physics(
        {
            "shaft_friction": 1.2,
            "hydroelastic_modulus": {"scale": 3.0},
            "hydroelastic_dissipation": {"d": 5.0},
            "grasp_slip": {"mu_scale": 0.5},
        }
    )
    assert (p["contact"].mu, p["contact"].modulus_scale, p["contact"].dissipation) == (1.2, 3.0, 5.0)
    assert p["grasp_hold"].force_limit == pytest.approx(20.0)
    assert check_station_effects({"shaft_friction": {}}) == {"shaft_friction": {"mu": 0.0}}


@pytest.mark.parametrize(
    "effects, words",
    [
        ({"shaft_fricton": {"mu": 1.0}}, ["shaft_fricton", "shaft_friction"]),
        ({"coulomb": {"fc": 1.0}}, ["coulomb", "station effect"]),
        ({"shaft_friction": {"k": 1.0}}, ["'k'", "mu"]),
        ({"shaft_friction": {"mu": 3.0}}, ["shaft_friction", "mu", "3.0", "[0.05, 1.5]"]),
        ({"grasp_slip": {"mu_scale": float("nan")}}, ["grasp_slip", "mu_scale", "nan"]),
        ({"hydroelastic_modulus": {"scale": True}}, ["hydroelastic_modulus", "scale", "True"]),
        ([("shaft_friction", 1.0)], ["effects", "mapping"]),
    ],
)
def test_bad_effects_raise_input_error(effects, words):
    with pytest.raises(InputError) as info:
        make_insertion_log(effects)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_bad_arguments_raise_input_error(nominal):
    log, _ = nominal
    with pytest.raises(InputError, match="variant"):
        make_insertion_log(FRICTION, variant="fast")
    with pytest.raises(InputError, match="task"):
        replay_insertion(type(log)(time=log.time, q=log.q, dq=log.dq, tool_target=log.tool_target), {})
    with pytest.raises(InputError, match="mu"):
        replay_insertion(log, {"shaft_friction": {"mu": -1.0}})
