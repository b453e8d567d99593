"""A simulated robot logger: what the Panda's logging loop records of a noise-free 1 kHz truth.

Model (every number a field of `LoggerConfig`, calibrated on the real log as `PANDA_LOGGER`):

    poll times   t_{k+1} = t_k + s_k,  s_k = step_min + (step_median - step_min) exp(step_spread x_k),
                 x_k a unit AR(1) series with coefficient step_correlation (polling jitter, long steps
                 come in runs); with probability gap_rate * s_k a step is a gap of U[gap_min, gap_max] s
    values       q, dq, tau and the commands linearly interpolated in the truth at t_k (the truth's
                 tau is its per-tick average torque: interpolation, not a hold, so that no extra
                 repeats appear besides the configured ones); phase: the label of the latest tick
    noise        tau += (1 + speed_gain_j |dq_j|) (n_band + n_vib + n_floor): n_band white of one-sided
                 PSD tau_psd_j [N^2 m^2/Hz] low-passed (Butterworth tau_order at tau_corner Hz), n_vib
                 band-passed white (order 4, vibration_low..vibration_high Hz) of PSD vibration_psd_j
                 inside the band, n_floor white of PSD floor_psd_j band-passed (order 1,
                 floor_low..floor_high); dq += white of PSD dq_psd_j low-passed (dq_order at dq_corner
                 Hz); the noise is generated per logged row at the nominal rate 1 / step_median
    quantise     q to multiples of q_step (the encoder; 0: none), then every number (time too) to
                 `digits` significant digits (the text file's print precision; 0: none)
    repeats      with probability stale_probability a row starts a stale run (length L with
                 probability stale_run_lengths[L - 1]): the rows repeat the previous logged row
                 exactly (every field), with new timestamps; partial repeats: q and dq together
                 (state_repeat_probability), tau alone (tau_repeat_probability), dq alone
                 (dq_repeat_probability)
    clock        stamps t0 + (t - t0) (1 + drift_ppm 1e-6), then rounded as above; a row whose
                 rounded stamp does not increase is dropped

`log_statistics` measures the same quantities on any log (real or simulated) by one method;
benchmarks/sim2real_calibration.py compares them on the real log and a simulated one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from goflow_common.checks import check_int, check_number
from goflow_common.config import config_to_dict
from goflow_common.errors import InputError
from sim2real.clean import interpolate
from sim2real.log import RobotLog, validate_log

__all__ = ["LoggerConfig", "PANDA_LOGGER", "apply_logger", "log_statistics", "TAU_BANDS", "DQ_BANDS"]

Array = NDArray[np.float64]
N_JOINTS = 7

#: The frequency bands [Hz] in which log_statistics reports the torque-noise PSD.
TAU_BANDS: tuple[tuple[float, float], ...] = ((2, 5), (5, 10), (10, 20), (20, 60), (60, 100), (100, 200), (200, 500))
#: The frequency bands [Hz] in which log_statistics reports the velocity-noise PSD.
DQ_BANDS: tuple[tuple[float, float], ...] = ((2, 40), (60, 100), (200, 500))
_SMOOTH_CORNER = 1.0  # [Hz] the slow motion removed before the noise PSDs: a zero-phase low-pass at it
_EDGE = 1.0  # [s] left out at both ends of a log by the noise statistics
_NPERSEG = 1024  # Welch segment (samples of the uniform 1/median-step grid)
_STEP_CLIP = 2.0e-3  # [s] steps beyond it are gaps, left out of the step autocorrelation
_GAP = 2.5e-3  # [s] a step longer than this is a gap in log_statistics


def _per_joint(value: Any, name: str, low: float = 0.0, high: float | None = None) -> tuple[float, ...]:
    values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value] * N_JOINTS
    if len(values) != N_JOINTS:
        raise InputError(f"{name} has {len(values)} values; expected 1 or {N_JOINTS} (one per joint)")
    return tuple(check_number(v, f"{name}[{j}]", low, high) for j, v in enumerate(values))


@dataclasses.dataclass(frozen=True)
class LoggerConfig:
    """Every parameter of the simulated logger (SI units; PSDs one-sided). See the module docstring
    for where each acts; PANDA_LOGGER documents the calibrated values.

    tau_psd: (7,) broadband torque-noise PSD [N^2 m^2/Hz] below tau_corner [Hz] (Butterworth
        order tau_order beyond); vibration_low, vibration_high [Hz] and vibration_psd (7,)
        [N^2 m^2/Hz]: the structural vibration band added to it; floor_psd (7,) [N^2 m^2/Hz]: a
        second band reaching higher, band-passed floor_low..floor_high [Hz] (order 1); speed_gain (7,) [s/rad]: the
        torque noise's amplitude grows by speed_gain_j |dq_j|.
    dq_psd: (7,) velocity-noise PSD [(rad/s)^2/Hz] below dq_corner [Hz] (order dq_order beyond).
    q_step: the encoder's position step [rad] (0: none); digits: significant digits every logged
        number keeps (0: exact floats).
    step_min, step_median [s], step_spread (log-std of step - step_min), step_correlation [0, 1):
        the polling steps; gap_rate [1/s], gap_min, gap_max [s]: missing samples; drift_ppm: the
        stamps' clock rate error [ppm].
    stale_probability [0, 1): a row starts a stale run; stale_run_lengths: the probabilities of
        run lengths 1, 2, ... (summing to 1); state_repeat_probability, tau_repeat_probability,
        dq_repeat_probability [0, 1): partial repeats of (q, dq), tau, dq alone.
    """

    tau_psd: tuple[float, ...] = (1.0e-3,) * N_JOINTS
    tau_corner: float = 100.0
    tau_order: int = 2
    vibration_low: float = 20.0
    vibration_high: float = 60.0
    vibration_psd: tuple[float, ...] = (0.0,) * N_JOINTS
    floor_psd: tuple[float, ...] = (0.0,) * N_JOINTS
    floor_low: float = 50.0
    floor_high: float = 200.0
    speed_gain: tuple[float, ...] = (0.0,) * N_JOINTS
    dq_psd: tuple[float, ...] = (1.0e-6,) * N_JOINTS
    dq_corner: float = 40.0
    dq_order: int = 2
    q_step: float = 0.0
    digits: int = 6
    step_min: float = 7.0e-4
    step_median: float = 1.0e-3
    step_spread: float = 0.5
    step_correlation: float = 0.6
    gap_rate: float = 0.0
    gap_min: float = 8.0e-3
    gap_max: float = 9.0e-3
    drift_ppm: float = 0.0
    stale_probability: float = 0.0
    stale_run_lengths: tuple[float, ...] = (1.0,)
    state_repeat_probability: float = 0.0
    tau_repeat_probability: float = 0.0
    dq_repeat_probability: float = 0.0

    def __post_init__(self) -> None:
        name = "LoggerConfig."
        for field in ("tau_psd", "vibration_psd", "floor_psd", "dq_psd"):
            object.__setattr__(self, field, _per_joint(getattr(self, field), name + field, 0.0, 1.0))
        object.__setattr__(self, "speed_gain", _per_joint(self.speed_gain, name + "speed_gain", 0.0, 100.0))
        check_number(self.tau_corner, name + "tau_corner", 1.0, 499.0)
        check_number(self.dq_corner, name + "dq_corner", 1.0, 499.0)
        check_number(self.floor_low, name + "floor_low", 0.0, 499.0, low_open=True)
        check_number(self.floor_high, name + "floor_high", self.floor_low, 499.0, low_open=True)
        for field in ("tau_order", "dq_order"):
            if check_int(getattr(self, field), name + field, 1) > 8:
                raise InputError(f"{name}{field} = {getattr(self, field)!r}; expected an integer in [1, 8]")
        check_number(self.vibration_low, name + "vibration_low", 0.0, 499.0, low_open=True)
        check_number(self.vibration_high, name + "vibration_high", self.vibration_low, 499.0, low_open=True)
        check_number(self.q_step, name + "q_step", 0.0, 0.01)
        if check_int(self.digits, name + "digits", 0) > 17:
            raise InputError(f"{name}digits = {self.digits!r}; expected an integer in [0, 17] (0: exact)")
        check_number(self.step_min, name + "step_min", 0.0, 0.1)
        check_number(self.step_median, name + "step_median", self.step_min, 0.1, low_open=True)
        check_number(self.step_spread, name + "step_spread", 0.0, 3.0)
        check_number(self.step_correlation, name + "step_correlation", 0.0, 1.0, high_open=True)
        check_number(self.gap_rate, name + "gap_rate", 0.0, 100.0)
        check_number(self.gap_min, name + "gap_min", 0.0, 0.5)
        check_number(self.gap_max, name + "gap_max", self.gap_min, 0.5)
        check_number(self.drift_ppm, name + "drift_ppm", -1000.0, 1000.0)
        for field in (
            "stale_probability",
            "state_repeat_probability",
            "tau_repeat_probability",
            "dq_repeat_probability",
        ):
            check_number(getattr(self, field), name + field, 0.0, 1.0, high_open=True)
        runs = self.stale_run_lengths
        if isinstance(runs, (str, bytes)) or not isinstance(runs, Sequence) or not runs:
            raise InputError(f"{name}stale_run_lengths = {runs!r}; expected probabilities of run lengths 1, 2, ...")
        runs = tuple(check_number(p, f"{name}stale_run_lengths[{i}]", 0.0, 1.0) for i, p in enumerate(runs))
        if abs(sum(runs) - 1.0) > 1e-6:
            raise InputError(f"{name}stale_run_lengths = {list(runs)} sums to {sum(runs):.6g}; expected 1")
        object.__setattr__(self, "stale_run_lengths", runs)


#: The Panda's logger as the Gaz et al. 2019 log (data/panda-gaz2019) shows it, measured by
#: log_statistics (benchmarks/sim2real_calibration.py prints the comparison,
#: docs/results/sim2real_calibration.json). Where each number comes from:
#: - timing: the log's steps (percentiles 0.1/5/50/95/99.9 % = 0.77/0.82/1.0/1.35/1.83 ms, minimum
#:   0.70 ms, autocorrelation 0.58 at lag 1 of the steps under 2 ms, decaying like an AR(1));
#:   gaps: 4 steps of 8.4-8.8 ms in 21 s (the other steps over 2 ms are the jitter's tail).
#: - drift_ppm: not measurable from one log; 20 ppm, an assumption (a quartz crystal's tolerance).
#: - stale rows: 1027 runs in 20543 steps (lengths 1: 964, 2: 35, 3: 22, 4: 5, 11: 1); partial
#:   repeats: q and dq without tau 0.52 % of rows, tau alone 0.45 %, dq alone 0.09 %.
#: - digits: the files print 6 significant digits (C++ streams' default precision), which sets the
#:   smallest q steps (1e-6 rad below 1 rad, 1e-5 above) and time steps (0.1 ms after 10 s); the
#:   encoder's own step is below it and left at 0 (not measurable here).
#: - dq noise: its PSD after a 1 Hz zero-phase high-pass (2-40 Hz band per joint), flat to ~40 Hz,
#:   falling about as f^-2 beyond (first order at 45 Hz).
#: - tau noise: fitted (multiplicative iteration, three logger seeds on the nominal simulated truth)
#:   so that the simulated log's 5-10 Hz band gives tau_psd, its 20-60 Hz band the vibration band
#:   (joints 1-4 and 6; 14-60 Hz: the real log's joint 4 is flat to 12 Hz and rises beyond, and
#:   its 10-20 Hz band reads within 0.73-1.26 of the real one on every joint), its 100-200 Hz band floor_psd and its 10-60 Hz variance ratio between
#:   fast and slow thirds of |dq| (real: 3.9, 4.1, 2.0, 2.7, 2.9, 2.6, 1.3) speed_gain; the levels
#:   are at rest (the amplitude grows by 1 + speed_gain |dq|).
PANDA_LOGGER = LoggerConfig(
    tau_psd=(1.6e-4, 3.5e-4, 2.7e-4, 1.8e-4, 5.5e-6, 8.1e-6, 6.4e-6),
    tau_corner=50.0,
    tau_order=4,
    vibration_low=14.0,
    vibration_high=60.0,
    vibration_psd=(1.9e-4, 2.1e-4, 1.75e-4, 8.0e-4, 0.0, 1.2e-5, 0.0),
    floor_psd=(1.2e-5, 2.5e-5, 1.45e-5, 1.45e-5, 1.8e-5, 2.45e-5, 1.4e-6),
    floor_low=50.0,
    floor_high=200.0,
    speed_gain=(1.36, 1.51, 0.68, 0.86, 0.68, 0.58, 0.15),
    dq_psd=(6.2e-7, 6.35e-7, 5.3e-7, 7.3e-7, 5.7e-7, 9.4e-7, 7.8e-7),
    dq_corner=45.0,
    dq_order=1,
    q_step=0.0,
    digits=6,
    step_min=6.8e-4,
    step_median=1.0e-3,
    step_spread=0.42,
    step_correlation=0.65,
    gap_rate=4 / 21.0,
    gap_min=8.4e-3,
    gap_max=8.8e-3,
    drift_ppm=20.0,
    stale_probability=1027 / (20543 - 1131),
    stale_run_lengths=(964 / 1027, 35 / 1027, 22 / 1027, 5 / 1027, 0, 0, 0, 0, 0, 0, 1 / 1027),
    state_repeat_probability=0.0052,
    tau_repeat_probability=0.0045,
    dq_repeat_probability=0.0009,
)


# ---------------------------------------------------------------------------------------------- the logger


def _poll_times(t0: float, t1: float, cfg: LoggerConfig, rng: np.random.Generator) -> Array:
    """Polling instants in [t0, t1]: jittered AR(1) log-normal steps and gaps."""
    span = t1 - t0
    mean = cfg.step_min + (cfg.step_median - cfg.step_min) * math.exp(0.5 * cfg.step_spread**2)
    n = int(span / max(mean, 1e-5) * 1.2) + 64
    while True:
        e = rng.standard_normal(n)
        x = signal.lfilter(
            [math.sqrt(1.0 - cfg.step_correlation**2)],
            [1.0, -cfg.step_correlation],
            e,
            zi=[cfg.step_correlation * rng.standard_normal()],
        )[0]
        steps = cfg.step_min + (cfg.step_median - cfg.step_min) * np.exp(cfg.step_spread * x)
        gap = rng.random(n) < cfg.gap_rate * steps
        steps[gap] = rng.uniform(cfg.gap_min, cfg.gap_max, int(gap.sum()))
        t = t0 + np.concatenate([[0.0], np.cumsum(steps)])
        if t[-1] > t1:
            return t[t <= t1]
        n *= 2


def _coloured(n: int, psd: Array, fs: float, sos: Array, rng: np.random.Generator) -> Array:
    """(n, 7) noise of one-sided PSD psd_j inside the pass band of the filter `sos`."""
    warm = 2048
    white = rng.standard_normal((n + warm, psd.shape[0])) * np.sqrt(psd * fs / 2.0)
    return signal.sosfilt(sos, white, axis=0)[warm:]


def _round_digits(x: Array, digits: int) -> Array:
    if digits <= 0:
        return x
    mag = np.floor(np.log10(np.where(x == 0, 1.0, np.abs(x))))
    scale = 10.0 ** (digits - 1 - mag)
    return np.round(x * scale) / scale


def _repeat_rows(values: dict[str, Array | None], cfg: LoggerConfig, rng: np.random.Generator) -> None:
    """Stale runs (every field) and partial repeats, in place: a repeated row copies the row before."""
    names = [k for k, v in values.items() if v is not None and k != "time"]
    n = values["time"].shape[0]
    stale = np.zeros(n, dtype=bool)
    lengths = np.arange(1, len(cfg.stale_run_lengths) + 1)
    starts = np.flatnonzero(rng.random(n) < cfg.stale_probability)
    runs = rng.choice(lengths, size=starts.size, p=np.asarray(cfg.stale_run_lengths) / sum(cfg.stale_run_lengths))
    k_free = 0
    for start, length in zip(starts, runs):
        if start < max(1, k_free):
            continue
        stale[start : start + length] = True
        k_free = start + length + 1
    groups = {
        "state": (cfg.state_repeat_probability, ("q", "dq")),
        "tau": (cfg.tau_repeat_probability, ("tau",)),
        "dq": (cfg.dq_repeat_probability, ("dq",)),
    }
    partial = {key: (rng.random(n) < p) & ~stale for key, (p, _) in groups.items()}
    for k in range(1, n):
        if stale[k]:
            for name in names:
                values[name][k] = values[name][k - 1]
            continue
        for key, (_, fields) in groups.items():
            if partial[key][k]:
                for name in fields:
                    if values.get(name) is not None:
                        values[name][k] = values[name][k - 1]


def apply_logger(truth: RobotLog, config: LoggerConfig | None = None, seed: int = 0) -> RobotLog:
    """What the robot's logger records of `truth` (see the module docstring for the model).

    Arguments:
        truth: a noise-free, uniformly sampled log (the reality's truth at its control rate); it
            needs q, dq and tau.
        config: the logger (None: PANDA_LOGGER).
        seed: the random stream (same seed, same log).

    Returns:
        A validated RobotLog polled at jittered times (fewer or more rows than `truth`) with the
        same fields present; meta as truth's plus "logger": the config as plain JSON data and the seed.

    Raises:
        InputError: `truth` is not a valid log, lacks tau, or `config` is not a LoggerConfig.
    """
    cfg = PANDA_LOGGER if config is None else config
    if not isinstance(cfg, LoggerConfig):
        raise InputError(f"config = {cfg!r}; expected a LoggerConfig or None")
    seed = check_int(seed, "seed", 0)
    truth = validate_log(truth, n_joints=N_JOINTS)
    if truth.tau is None:
        raise InputError("truth.tau is missing; expected the true link-side joint torques")
    extra = {f: getattr(truth, f) for f in ("tool_pose", "tool_target", "wrench", "gripper_width")}
    if any(v is not None for v in extra.values()):
        raise InputError(
            f"truth has {[k for k, v in extra.items() if v is not None]}; expected only joint "
            "signals, time and phase (the logger models joint sensors)"
        )
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x10661]))
    t = _poll_times(float(truth.time[0]), float(truth.time[-1]), cfg, rng)
    n = t.shape[0]
    values: dict[str, Any] = {"time": t}
    for name in ("q", "dq", "tau", "tau_cmd", "q_cmd", "dq_cmd", "tau_ext"):
        arr = getattr(truth, name)
        values[name] = None if arr is None else interpolate(t, truth.time, arr)
    fs = 1.0 / cfg.step_median
    nyq = 0.5 * fs
    lp_tau = signal.butter(cfg.tau_order, min(cfg.tau_corner / nyq, 0.99), output="sos")
    lp_dq = signal.butter(cfg.dq_order, min(cfg.dq_corner / nyq, 0.99), output="sos")
    bp = signal.butter(4, [cfg.vibration_low / nyq, min(cfg.vibration_high / nyq, 0.99)], btype="band", output="sos")
    band = _coloured(n, np.asarray(cfg.tau_psd), fs, lp_tau, rng)
    vib = _coloured(n, np.asarray(cfg.vibration_psd), fs, bp, rng)
    lp_floor = signal.butter(1, [cfg.floor_low / nyq, min(cfg.floor_high / nyq, 0.99)], btype="band", output="sos")
    vib += _coloured(n, np.asarray(cfg.floor_psd), fs, lp_floor, rng)
    gain = 1.0 + np.asarray(cfg.speed_gain) * np.abs(values["dq"])
    values["tau"] = values["tau"] + gain * (band + vib)
    values["dq"] = values["dq"] + _coloured(n, np.asarray(cfg.dq_psd), fs, lp_dq, rng)
    if cfg.q_step > 0:
        values["q"] = np.round(values["q"] / cfg.q_step) * cfg.q_step
    for name in ("q", "dq", "tau", "tau_cmd", "q_cmd", "dq_cmd", "tau_ext"):
        if values[name] is not None:
            values[name] = _round_digits(values[name], cfg.digits)
    if truth.phase is not None:
        tick = np.clip(np.searchsorted(truth.time, t, side="right") - 1, 0, truth.n_samples - 1)
        values["phase"] = truth.phase[tick]
    stamps = _round_digits(t[0] + (t - t[0]) * (1.0 + 1e-6 * cfg.drift_ppm), cfg.digits)
    keep = np.concatenate([[True], np.diff(stamps) > 0])
    while not keep.all():  # a stamp rounded onto its predecessor: drop the row
        idx = np.flatnonzero(keep)
        stamps = stamps[idx]
        values = {k: (None if v is None else v[idx]) for k, v in values.items()}
        keep = np.concatenate([[True], np.diff(stamps) > 0])
    values["time"] = stamps
    _repeat_rows(values, cfg, rng)
    meta = dict(truth.meta)
    meta["logger"] = {**config_to_dict(cfg), "seed": seed, "model": "sim2real.logger.apply_logger"}
    return validate_log(RobotLog(**values, meta=meta), n_joints=N_JOINTS)


# ---------------------------------------------------------------------------------------------- statistics


def _uniform(log: RobotLog, arr: Array) -> tuple[Array, float]:
    """`arr` linearly interpolated on a uniform grid of the log's median step, ends cut by _EDGE."""
    h = float(np.median(np.diff(log.time)))
    grid = np.arange(log.time[0] + _EDGE, log.time[-1] - _EDGE, h)
    return interpolate(grid, log.time, arr), 1.0 / h


def _residual(x: Array, fs: float) -> Array:
    sos = signal.butter(4, _SMOOTH_CORNER / (0.5 * fs), output="sos")
    return x - signal.sosfiltfilt(sos, x, axis=0)


def _band_psd(x: Array, fs: float, bands: tuple[tuple[float, float], ...]) -> dict[str, list[float]]:
    f, p = signal.welch(x, fs=fs, nperseg=min(_NPERSEG, x.shape[0]), axis=0, average="median")
    out = {}
    for lo, hi in bands:
        sel = (f >= lo) & (f < min(hi, 0.5 * fs))
        out[f"{lo:g}-{hi:g}"] = (p[sel].mean(axis=0) if sel.any() else np.full(x.shape[1], np.nan)).tolist()
    return out


def _band_power(x: Array, fs: float, low: float) -> Array:
    """The variance of `x` above `low` [Hz], from the median-Welch PSD."""
    f, p = signal.welch(x, fs=fs, nperseg=min(_NPERSEG, x.shape[0]), axis=0, average="median")
    return p[f >= low].sum(axis=0) * (f[1] - f[0])


def _digits(x: Array) -> NDArray[np.int64]:
    """The significant digits each number needs (17 at most; 1 for zero)."""
    out = np.full(x.shape, 17, dtype=np.int64)
    for d in range(16, 0, -1):
        exact = np.abs(_round_digits(x, d) - x) <= 1e-12 * np.abs(x)
        out[exact] = d
    return out


def _last_digit(x: Array) -> Array:
    """The place value of each number's last significant digit (its print resolution)."""
    mag = np.floor(np.log10(np.where(x == 0, 1.0, np.abs(x))))
    return 10.0 ** (mag - _digits(x) + 1)


def _repeats(x: Array) -> Array:
    return np.all(x[1:] == x[:-1], axis=1)


def log_statistics(log: RobotLog) -> dict[str, Any]:
    """The statistics of a log's sensors and timing, by one method for every log (real or simulated).

    Returns plain JSON data: duration [s], samples; step_ms: percentiles 0.1/5/50/95/99.9 of the
    steps [ms]; step_autocorr: lag-1 autocorrelation of the steps under 2 ms; gaps_per_minute and
    max_gap_ms (steps over 2.5 ms); stale_fraction (rows repeating the previous row in q, dq and
    tau) and repeat_fraction per field; digits: the most significant digits a number of time, q,
    dq, tau needs (17: full floats); q_step: per joint, the median place value of q's last
    significant digit [rad] (the print or encoder resolution; it depends on |q|); dq_psd /
    tau_psd: per band (DQ_BANDS / TAU_BANDS, "lo-hi" keys) and joint, the median-Welch PSD of the signal minus its 1 Hz zero-phase low-pass, on a uniform grid of the
    median step (linear interpolation, 1 s cut at both ends); dq_noise_std: per joint, the std of
    that residual of dq above 2 Hz (from its PSD); tau_inband_std: per joint, sqrt(10 Hz x mean PSD over 2-10 Hz) [N m];
    tau_speed_ratio: per joint, the variance of the 10-60 Hz band-passed torque where |dq| is in
    its top third over where it is in its bottom third.

    Raises:
        InputError: the log is not valid or has no tau.
    """
    log = validate_log(log, n_joints=None)
    if log.tau is None:
        raise InputError("log.tau is missing; expected measured joint torques")
    dt = np.diff(log.time)
    short = dt[dt <= _STEP_CLIP]
    d = short - short.mean()
    gaps = dt[dt > _GAP]
    span = float(log.time[-1] - log.time[0])
    stale = _repeats(log.q) & _repeats(log.dq) & _repeats(log.tau)
    q_step = np.median(_last_digit(log.q), axis=0).tolist()
    dq_u, fs = _uniform(log, log.dq)
    tau_u, _ = _uniform(log, log.tau)
    dq_r, tau_r = _residual(dq_u, fs), _residual(tau_u, fs)
    tau_psd = _band_psd(tau_r, fs, TAU_BANDS)
    inband = _band_psd(tau_r, fs, ((2, 10),))["2-10"]
    sos = signal.butter(4, [10.0 / (0.5 * fs), 60.0 / (0.5 * fs)], btype="band", output="sos")
    vib = signal.sosfiltfilt(sos, tau_u, axis=0)
    speed = np.abs(dq_u - dq_r)  # the smooth joint speed
    ratio = []
    for j in range(log.n_joints):
        lo, hi = np.percentile(speed[:, j], [100 / 3, 200 / 3])
        low, high = vib[speed[:, j] <= lo, j], vib[speed[:, j] >= hi, j]
        ratio.append(float(np.var(high) / np.var(low)) if np.var(low) > 0 else float("nan"))
    return {
        "duration": span,
        "samples": log.n_samples,
        "step_ms": dict(
            zip(("p0.1", "p5", "p50", "p95", "p99.9"), (np.percentile(dt, [0.1, 5, 50, 95, 99.9]) * 1e3).tolist())
        ),
        "step_mean_ms": float(dt.mean() * 1e3),
        "step_autocorr": float(np.dot(d[:-1], d[1:]) / np.dot(d, d)) if d.size > 2 and d.any() else 0.0,
        "gaps_per_minute": float(gaps.size / span * 60.0),
        "max_gap_ms": float(dt.max() * 1e3),
        "stale_fraction": float(stale.mean()),
        "repeat_fraction": {name: float(_repeats(getattr(log, name)).mean()) for name in ("q", "dq", "tau")},
        "q_step": q_step,
        "digits": {name: int(_digits(getattr(log, name)).max()) for name in ("time", "q", "dq", "tau")},
        "dq_noise_std": np.sqrt(_band_power(dq_r, fs, 2.0)).tolist(),
        "dq_psd": _band_psd(dq_r, fs, DQ_BANDS),
        "tau_psd": tau_psd,
        "tau_inband_std": np.sqrt(10.0 * np.asarray(inband)).tolist(),
        "tau_speed_ratio": ratio,
    }
