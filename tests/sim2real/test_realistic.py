"""The default diagnosis on realistic torque-only logs (the Panda's logger, the real log's layouts)
and on the real Panda log: a small leave-one-effect-out run, noise only, bad logs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from goflow_common.errors import InputError
from sim2real.diagnosis import diagnose
from sim2real.importers import load_log
from sim2real.log import validate_log
from sim2real.realistic import RealisticCase, make_case_log, run_realistic

DURATION = 10.0
REAL_LOG = Path(__file__).resolve().parents[2] / "data" / "panda-gaz2019" / "log.npz"


def test_a_noise_only_log_reads_no_gap_and_its_floor_predicts_the_residual():
    r = run_realistic(RealisticCase("noise", (), "noise", None, 7, "gaz"), DURATION)
    assert r["verdict"] == "no gap", r
    ratio = np.asarray(r["floor_ratio"])  # predicted / observed in-band residual per joint
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio
    assert abs(np.mean(ratio) - 1.0) < 0.12, ratio


@pytest.mark.slow
@pytest.mark.parametrize(
    "effect, layout",
    [
        ("coulomb", "gaz"),
        ("link_inertia", "csv"),
        ("torque_scale", "gaz"),
        ("torque_delay", "csv"),
        ("joint_inertia", "gaz"),
    ],
)
def test_leave_one_effect_out_on_realistic_logs(effect, layout):
    """Each effect at in-band SNR 8, in the real log's folder layout or Franka's CSV, is named first
    and the joint with the largest effect torque leads the where-table."""
    r = run_realistic(RealisticCase(effect, (effect,), "single", 8.0, 3, layout), DURATION)
    assert r["selected"][:1] == [effect], r
    assert r["verdict"] == "explained", r
    assert r["where_right"], r


@pytest.mark.slow
def test_an_effect_outside_the_catalogue_reads_unexplained_on_a_realistic_log():
    r = run_realistic(RealisticCase("drag", ("drag",), "outside", 8.0, 3, "gaz"), DURATION)
    assert r["verdict"] == "unexplained", r


def test_the_case_log_has_the_real_logs_layout_and_timing():
    log, truth = make_case_log(RealisticCase("noise", (), "noise", None, 1, "csv"), 4.0)
    assert log.tau_cmd is None and log.q_cmd is None and log.tau is not None
    steps = np.diff(log.time)
    assert 0.9e-3 < np.median(steps) < 1.1e-3 and steps.max() > 3e-3  # jitter and gaps
    assert np.mean(np.all(log.dq[1:] == log.dq[:-1], axis=1)) > 0.02  # stale repeats
    assert truth["effect_torque"] == [0.0] * 7


@pytest.mark.slow
def test_the_real_log_finds_friction_on_the_shoulder_and_the_wrist():
    """The real Panda log (Gaz et al.): friction on joints 1-4 as on the wrist, its level at
    0.5 rad/s within a factor 2 of Gaz et al.'s identified friction on every joint."""
    d = diagnose(load_log(REAL_LOG))
    s = d.summary()
    assert s["verdict"]["label"] == "explained", s["verdict"]
    assert "velocity and acceleration from the measured" in " ".join(s["notes"])
    fr = s["friction"]
    at = fr["speeds"].index(0.5)
    A = np.array([0.546, 0.872, 0.641, 1.279, 0.839, 0.303, 0.565])  # Gaz et al.'s sigmoid amplitude
    alpha = np.array([5.12, 9.07, 10.14, 5.59, 8.35, 17.13, 10.34])
    phi = np.array([0.0395, 0.0259, -0.0461, 0.0362, 0.0262, -0.0210, 0.0036])
    sig = lambda v: A / (1 + np.exp(-alpha * (v + phi))) - A / (1 + np.exp(-alpha * phi))  # noqa: E731
    gaz = 0.5 * (sig(0.5) - sig(-0.5))
    ratio = np.asarray(fr["value"][at]) / gaz
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    tau = [r for r in s["where"]["channels"] if r["channel"] == "tau"]
    assert {r["joint"] for r in tau[:4]} & {1, 2, 3, 4}  # the shoulder carries N m of the gap
    floors = np.asarray(s["preprocessing"]["floor"]["tau"]["in_band"])
    assert np.all(floors[:4] < 0.2), floors  # the in-band floor, not the 0.8-1.4 N m broadband spread


def test_a_stalled_clock_is_named():
    log = load_log(REAL_LOG)
    t = log.time.copy()
    t[100:150] = t[100]
    with pytest.raises(InputError, match="time repeats at sample 101"):
        validate_log(dataclasses.replace(log, time=t))


def test_a_log_that_does_not_move_is_named():
    log = load_log(REAL_LOG)
    n = 4000
    still = dataclasses.replace(
        log,
        time=log.time[:n],
        q=np.repeat(log.q[:1], n, 0),
        dq=1e-5 * np.random.default_rng(0).standard_normal((n, 7)),
        tau=log.tau[:n],
    )
    with pytest.raises(InputError, match="do not move"):
        diagnose(still)
