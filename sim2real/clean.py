"""Load-and-clean, the diagnosis's first stage: stale repeats dropped, the log put on a uniform grid.

A real robot's logger polls the controller's state: some polls read the same state twice (a stale
repeat: every joint's velocity or torque equal, bit for bit, to the previous row), the polling
period jitters and a few polls are missed (gaps of several periods). `clean` drops the repeats,
puts the fresh samples on a uniform grid at their median period (linear interpolation, which is
exact for the band the diagnosis analyses) and marks the grid points that lie inside a gap as not
fresh: they are interpolated for the filters' sake but never fitted or scored, so no sample is
invented. What it did is stated in `Cleaned.report` and in the diagnosis report.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from goflow_common.checks import check_number
from goflow_common.errors import InputError
from sim2real.log import MIN_SAMPLES, RobotLog

__all__ = ["CleanConfig", "Cleaned", "clean", "stale_rows", "resample", "interpolate"]

Array = NDArray[np.float64]

#: The fields whose full row, repeated exactly, marks a stale sample (noise makes a fresh row unique).
_NOISY = ("dq", "tau", "tau_cmd")
#: A position row repeated exactly is stale only while the arm moves (at rest a quantised q repeats).
_MOVING = 1e-2  # [rad/s] the largest joint speed below which a repeated q is taken as rest


@dataclasses.dataclass(frozen=True)
class CleanConfig:
    """drop_repeats: drop stale repeated samples (False: keep every row, as the log has it);
    gap: a grid point farther than `gap` median periods from the nearest fresh sample lies in a gap
    (interpolated for the filters, never fitted); warn_repeats: the share of repeats above which
    the report warns that the logger misses many polls."""

    drop_repeats: bool = True
    gap: float = 2.5
    warn_repeats: float = 0.2

    def __post_init__(self) -> None:
        if not isinstance(self.drop_repeats, bool):
            raise InputError(f"CleanConfig.drop_repeats = {self.drop_repeats!r}; expected True or False")
        check_number(self.gap, "CleanConfig.gap", 1.0, 100.0, low_open=True)
        check_number(self.warn_repeats, "CleanConfig.warn_repeats", 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class Cleaned:
    """A cleaned log: `log` on a uniform grid, `fresh` (T,) the grid points near a fresh sample
    (False inside gaps), `report` what was done (plain JSON data), `notes` one line each for the
    diagnosis report."""

    log: RobotLog
    fresh: NDArray[np.bool_]
    report: dict[str, Any]
    notes: list[str]


def stale_rows(log: RobotLog) -> NDArray[np.bool_]:
    """(T,) True where a sample repeats the previous one: any of dq, tau, tau_cmd equal to the
    previous row in every joint, or q equal while some joint moves faster than 0.01 rad/s. The
    first sample is never stale."""
    stale = np.zeros(log.n_samples, dtype=bool)
    for name in _NOISY:
        x = getattr(log, name)
        if x is not None:
            stale[1:] |= np.all(x[1:] == x[:-1], axis=1)
    moving = np.max(np.abs(log.dq[1:]), axis=1) > _MOVING
    stale[1:] |= np.all(log.q[1:] == log.q[:-1], axis=1) & moving
    return stale


def _take(log: RobotLog, keep: NDArray[np.bool_]) -> RobotLog:
    fields = {
        f.name: (v[keep] if isinstance(v := getattr(log, f.name), np.ndarray) else v)
        for f in dataclasses.fields(RobotLog)
    }
    return RobotLog(**fields)


def interpolate(at: Array, t: Array, values: Array) -> Array:
    """Each column of `values` (T, k), sampled at the increasing times `t` (T,), linearly
    interpolated at `at` (N,): (N, k)."""
    return np.stack([np.interp(at, t, values[:, j]) for j in range(values.shape[1])], axis=1)


def resample(log: RobotLog, dt: float) -> RobotLog:
    """The log on the grid t0 + k dt [s] (linear interpolation; phase labels held from the sample
    before), its meta as it was."""
    t = log.time
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
    fields: dict[str, Any] = {"time": grid, "meta": dict(log.meta)}
    for f in dataclasses.fields(RobotLog):
        v = getattr(log, f.name)
        if f.name in ("time", "meta") or v is None:
            continue
        if f.name == "phase":
            idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
            fields[f.name] = v[idx]
            continue
        flat = v.reshape(len(t), -1)
        fields[f.name] = interpolate(grid, t, flat).reshape((len(grid),) + v.shape[1:])
    return RobotLog(**fields)


def clean(log: RobotLog, config: CleanConfig | None = None) -> Cleaned:
    """Drop the stale repeats of `log` and put it on a uniform grid.

    Arguments:
        log: a validated robot log (any sample spacing).
        config: CleanConfig (None: the defaults).

    Returns:
        Cleaned: the uniform log at the fresh samples' median period, the mask of grid points
        outside gaps, and a report (samples in and out, repeats dropped, period, jitter
        percentiles, gaps and their longest).

    Raises:
        InputError: every sample repeats the one before it (the logger recorded no new state), or
            fewer than MIN_SAMPLES fresh samples remain.
    """
    c = config or CleanConfig()
    stale = stale_rows(log) if c.drop_repeats else np.zeros(log.n_samples, dtype=bool)
    n = log.n_samples
    if stale[1:].all():
        raise InputError(
            f"every sample of the log repeats the one before it ({n - 1} of {n - 1}): the logger "
            "recorded no new state; expected fresh samples of a moving arm"
        )
    fresh_log = _take(log, ~stale)
    if fresh_log.n_samples < MIN_SAMPLES:
        raise InputError(
            f"the log has {fresh_log.n_samples} fresh samples after dropping {int(stale.sum())} "
            f"stale repeats; expected at least {MIN_SAMPLES}"
        )
    steps = np.diff(fresh_log.time)
    dt = float(np.median(steps))
    notes = []
    if stale.any():
        share = stale.mean()
        notes.append(
            f"dropped {int(stale.sum())} stale repeated samples ({100 * share:.1f} %: the logger read "
            "the same state twice)"
        )
        if share > c.warn_repeats:
            notes.append(
                f"warning: {100 * share:.0f} % of the samples are stale repeats; the logger misses many "
                "polls (the fits use the fresh ones)"
            )
    uniform = np.allclose(steps, dt, rtol=1e-6, atol=1e-9)
    if uniform:
        out = fresh_log
        fresh = np.ones(out.n_samples, dtype=bool)
        gaps = np.zeros(0)
    else:
        out = resample(fresh_log, dt)
        # distance from each grid point to the nearest fresh sample
        t = fresh_log.time
        i = np.clip(np.searchsorted(t, out.time), 1, len(t) - 1)
        near = np.minimum(np.abs(out.time - t[i - 1]), np.abs(t[i] - out.time))
        fresh = near <= 0.5 * c.gap * dt + 1e-12
        gaps = steps[steps > c.gap * dt]
        notes.append(
            f"resampled {fresh_log.n_samples} fresh samples onto a uniform {1e3 * dt:.3f} ms grid "
            f"(steps {1e3 * np.percentile(steps, 1):.2f}-{1e3 * np.percentile(steps, 99):.2f} ms, 1-99 %)"
        )
        if gaps.size:
            notes.append(
                f"{gaps.size} gaps longer than {c.gap:g} periods (longest {1e3 * gaps.max():.1f} ms): "
                f"their {int((~fresh).sum())} grid points are interpolated, not fitted"
            )
    meta = dict(out.meta)
    report = {
        "samples_in": n,
        "stale_dropped": int(stale.sum()),
        "stale_share": float(stale.mean()),
        "period": dt,
        "uniform": bool(uniform),
        "step_percentiles_ms": {str(p): float(1e3 * np.percentile(steps, p)) for p in (1, 50, 99)},
        "gaps": int(gaps.size),
        "longest_gap_ms": float(1e3 * gaps.max()) if gaps.size else 0.0,
        "grid_samples": out.n_samples,
        "not_fresh": int((~fresh).sum()),
    }
    meta["cleaned"] = report
    return Cleaned(log=dataclasses.replace(out, meta=meta), fresh=fresh, report=report, notes=notes)
