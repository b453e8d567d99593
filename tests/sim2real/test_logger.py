"""Tests of the simulated Panda logger (sim2real/logger.py), its reality hook and write_gaz_layout."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from goflow_common.errors import InputError
from sim2real.importers import read_gaz_layout, write_gaz_layout
from sim2real.log import RobotLog, validate_log
from sim2real.logger import PANDA_LOGGER, LoggerConfig, apply_logger, log_statistics
from sim2real.reality import RealityConfig, make_arm_log


def _truth(duration: float = 4.0, moving: bool = True) -> RobotLog:
    t = np.arange(int(duration * 1000) + 1) * 1e-3
    phase = 2 * np.pi * 0.3 * t[:, None] * (1 + np.arange(7) / 7)
    amp = 0.5 if moving else 0.0
    q = 0.3 + amp * np.sin(phase)
    dq = amp * 2 * np.pi * 0.3 * (1 + np.arange(7) / 7) * np.cos(phase)
    tau = 5.0 + 2.0 * amp * np.sin(phase)
    return RobotLog(
        time=t,
        q=q,
        dq=dq,
        tau=tau,
        tau_cmd=tau.copy(),
        q_cmd=q.copy(),
        dq_cmd=dq.copy(),
        phase=np.zeros(t.shape[0], dtype=np.int64),
        meta={"truth": {"x": 1}},
    )


def test_valid_and_deterministic() -> None:
    truth = _truth()
    a, b, c = apply_logger(truth, seed=3), apply_logger(truth, seed=3), apply_logger(truth, seed=4)
    validate_log(a)
    assert np.all(np.diff(a.time) > 0)
    for name in ("time", "q", "dq", "tau", "tau_cmd", "q_cmd", "dq_cmd", "phase"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert a.n_samples != c.n_samples or not np.array_equal(a.tau, c.tau)
    assert a.meta["truth"] == {"x": 1} and a.meta["logger"]["seed"] == 3
    assert a.meta["logger"]["tau_psd"] == list(PANDA_LOGGER.tau_psd)


def test_timing_and_repeats_near_configured() -> None:
    cfg = dataclasses.replace(PANDA_LOGGER, stale_probability=0.05, gap_rate=3.0)
    s = log_statistics(apply_logger(_truth(8.0), cfg, seed=1))
    steps = s["step_ms"]
    assert 0.72 < steps["p0.1"] < 0.82 and 0.78 < steps["p5"] < 0.88 and 0.95 < steps["p50"] < 1.05
    assert 1.25 < steps["p95"] < 1.45
    assert 0.45 < s["step_autocorr"] < 0.75
    assert 8.3 <= s["max_gap_ms"] <= 8.9
    assert 10 < s["gaps_per_minute"] < 400  # 3 per second expected: 180 a minute
    mean_run = float(np.dot(np.arange(1, 12), PANDA_LOGGER.stale_run_lengths))
    want = 0.05 * mean_run / (1 + 0.05 * mean_run)
    assert abs(s["stale_fraction"] - want) < 0.015
    assert s["repeat_fraction"]["tau"] > s["stale_fraction"]


def test_inband_torque_noise_matches_config() -> None:
    level = (2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5)
    cfg = dataclasses.replace(
        PANDA_LOGGER, tau_psd=level, vibration_psd=(0.0,) * 7, floor_psd=(0.0,) * 7, speed_gain=(0.0,) * 7
    )
    s = log_statistics(apply_logger(_truth(40.0, moving=False), cfg, seed=2))
    measured = np.array(s["tau_inband_std"])
    want = np.sqrt(10.0 * np.array(level))
    assert np.all(np.abs(measured / want - 1) < 0.15), measured / want


def test_q_quantised() -> None:
    log = apply_logger(_truth(), dataclasses.replace(PANDA_LOGGER, q_step=1e-4, digits=0))
    assert np.allclose(log.q / 1e-4, np.round(log.q / 1e-4), atol=1e-6)
    printed = apply_logger(_truth())
    assert log_statistics(printed)["digits"]["q"] <= 6
    assert all(float(f"{x:.6g}") == x for x in printed.q[:200].ravel())


def test_ideal_sensors_unchanged() -> None:
    cfg = RealityConfig(duration=0.3, end_effector="none")
    a = make_arm_log({}, cfg)
    b = make_arm_log({}, dataclasses.replace(cfg, sensors="ideal"))
    for name in ("time", "q", "dq", "tau", "tau_cmd"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    panda = make_arm_log({}, dataclasses.replace(cfg, sensors="panda"))
    validate_log(panda)
    assert "logger" in panda.meta and panda.n_samples != a.n_samples or not np.array_equal(panda.q, a.q)
    with pytest.raises(InputError, match="RealityConfig.sensors"):
        RealityConfig(sensors="real")


@pytest.mark.parametrize(
    "field, value",
    [
        ("tau_psd", (-1e-3,) * 7),
        ("dq_psd", -1.0),
        ("stale_probability", 1.0),
        ("stale_probability", -0.1),
        ("step_correlation", 1.0),
        ("stale_run_lengths", (0.5, 0.4)),
        ("vibration_high", 5.0),
        ("digits", -1),
        ("speed_gain", (1.0, 2.0)),
        ("gap_max", 1e-3),
    ],
)
def test_bad_config(field: str, value: object) -> None:
    with pytest.raises(InputError, match=f"LoggerConfig.{field}"):
        LoggerConfig(**{field: value})


def test_gaz_round_trip(tmp_path) -> None:
    log = apply_logger(_truth(1.0), dataclasses.replace(PANDA_LOGGER, digits=0), seed=5)
    write_gaz_layout(log, tmp_path / "sim")
    back = read_gaz_layout(tmp_path / "sim")
    for name in ("time", "q", "dq", "tau"):
        assert np.array_equal(getattr(back, name), getattr(log, name))
    assert back.meta["logger"]["seed"] == 5
