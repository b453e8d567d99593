"""Load-and-clean: stale repeats dropped, non-uniform stamps put on a grid without inventing samples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from goflow_common.errors import InputError
from sim2real.clean import CleanConfig, clean, stale_rows
from sim2real.log import RobotLog


def _log(n: int = 2000, dt: float = 1e-3, seed: int = 0) -> RobotLog:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    q = 0.3 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.ones(7)
    dq = 0.3 * np.pi * np.cos(2 * np.pi * 0.5 * t)[:, None] * np.ones(7) + 1e-3 * rng.standard_normal((n, 7))
    tau = np.sin(t)[:, None] + 0.05 * rng.standard_normal((n, 7))
    return RobotLog(time=t, q=q, dq=dq, tau=tau, meta={})


def _with_repeats(log: RobotLog, rows: np.ndarray) -> RobotLog:
    """The logger read the previous state again at `rows` (new stamps, old values)."""
    q, dq, tau = log.q.copy(), log.dq.copy(), log.tau.copy()
    for k in rows:
        q[k], dq[k], tau[k] = q[k - 1], dq[k - 1], tau[k - 1]
    return dataclasses.replace(log, q=q, dq=dq, tau=tau)


def test_stale_repeats_are_found_and_dropped():
    log = _log()
    rows = np.arange(5, 2000, 17)
    dirty = _with_repeats(log, rows)
    stale = stale_rows(dirty)
    assert set(np.flatnonzero(stale)) == set(rows)
    out = clean(dirty)
    assert out.report["stale_dropped"] == len(rows)
    assert out.log.n_samples == 2000  # back on the 1 ms grid
    np.testing.assert_allclose(np.diff(out.log.time), 1e-3, rtol=1e-9)
    assert out.fresh.all()  # one missing sample between two fresh ones is not a gap
    assert any("stale" in n for n in out.notes)


def test_a_resting_arm_repeating_its_quantised_position_is_not_stale():
    log = _log()
    q = log.q.copy()
    dq = 1e-4 * np.random.default_rng(1).standard_normal(q.shape)  # at rest: q repeats, dq noise differs
    q[:] = np.round(q[0], 6)
    rest = dataclasses.replace(log, q=q, dq=dq)
    assert not stale_rows(rest).any()


def test_gaps_are_interpolated_but_not_fresh():
    log = _log()
    keep = np.ones(2000, dtype=bool)
    keep[500:508] = False  # a 9 ms gap
    jitter = np.random.default_rng(2).uniform(-2e-4, 2e-4, 2000)
    t = log.time + jitter
    gapped = RobotLog(time=t[keep], q=log.q[keep], dq=log.dq[keep], tau=log.tau[keep], meta={})
    out = clean(gapped)
    assert out.report["gaps"] == 1 and 8.0 < out.report["longest_gap_ms"] < 9.5
    inside = (out.log.time > t[499] + 1.5e-3) & (out.log.time < t[508] - 1.5e-3)
    assert inside.any() and not out.fresh[inside].any()
    assert out.fresh.mean() > 0.99


def test_a_log_of_repeats_only_is_refused():
    log = _log(100)
    frozen = dataclasses.replace(
        log, q=np.repeat(log.q[:1], 100, 0), dq=np.repeat(log.dq[:1], 100, 0), tau=np.repeat(log.tau[:1], 100, 0)
    )
    with pytest.raises(InputError, match="every sample of the log repeats"):
        clean(frozen)


def test_every_sample_logged_twice_is_cleaned_back():
    log = _log(1000)
    doubled = RobotLog(
        time=np.arange(2000) * 0.5e-3,
        q=np.repeat(log.q, 2, 0),
        dq=np.repeat(log.dq, 2, 0),
        tau=np.repeat(log.tau, 2, 0),
        meta={},
    )
    out = clean(doubled)
    assert out.report["stale_dropped"] == 1000
    assert any("warning" in n for n in out.notes)
    np.testing.assert_allclose(out.log.tau[::1][:10], log.tau[:10])


def test_keeping_repeats_is_an_option():
    dirty = _with_repeats(_log(), np.arange(5, 2000, 17))
    assert clean(dirty, CleanConfig(drop_repeats=False)).report["stale_dropped"] == 0


@pytest.mark.parametrize("field, value", [("gap", 0.5), ("drop_repeats", "yes"), ("warn_repeats", 2.0)])
def test_bad_config_is_refused(field, value):
    with pytest.raises(InputError, match=f"CleanConfig.{field}"):
        CleanConfig(**{field: value})
