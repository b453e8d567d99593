"""The analysis band and the noise floor in it: where the excitation and the effects live.

A robot's torque residual holds, besides the model's error, sensor noise, the arm's structural
vibration (20-60 Hz on the Panda) and the noise of the acceleration differentiated from the
measured velocity; the trajectory and every catalogue effect live below ~10 Hz. Judging the gap
against the whole band's noise hides the slow errors a user cares about (on the real Panda log
joints 1-4 have 0.8-1.2 N m of broadband noise but 0.1 N m below 10 Hz). So the diagnosis looks at
the residual through one zero-phase low-pass filter (the band), applied alike to the residual and to
every effect's prediction (linear, so the fits are unchanged in kind), and samples it at four
times the band's edge.

- `choose_band`: the band's edge from the data: a multiple of the frequency below which 99 % of the
  joint velocities' power lies (the excitation), within [min_cutoff, max_cutoff].
- `noise_floor`: without a band (`DiagnosisConfig.band` None), the broadband floor: the fast
  part's spread or the variogram's nugget, for every sample (and for the station's channels).
- `band_floor`: the noise's standard deviation in the band, per column, from the residual's own
  spectrum just above the band (where the model's error is small): a fitted noise spectrum
  a |K(f)|^2 + b |D(f)|^2, white sensor noise seen through the torque filter K plus the blue noise of
  a position differentiated twice (D) into the acceleration, integrated under the band's response. docs/sim2real.md gives the
  check of it on noise-only logs.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, savgol_coeffs, sosfiltfilt, sosfreqz, welch

from goflow_common.checks import check_int, check_number
from goflow_common.errors import InputError
from sim2real.effects import Candidate, Family

__all__ = ["BandConfig", "Band", "choose_band", "band_floor", "band_candidate", "band_pool", "noise_floor"]

Array = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class BandConfig:
    """cutoff: the band's edge [Hz] (None: from the data, `excitation_factor` times the frequency
    below which 99 % of the joint velocities' power lies, within [min_cutoff, max_cutoff]);
    order: the Butterworth low-pass's order (applied forward and backward: zero phase);
    reference: the noise is read in [cutoff, reference x cutoff] (below the Panda's 20-60 Hz
    vibration band for cutoffs up to 10 Hz); samples_per_cycle: the band-limited residual is
    kept every dt x stride with stride = 1 / (samples_per_cycle x cutoff x dt)."""

    cutoff: float | None = None
    excitation_factor: float = 16.0
    min_cutoff: float = 4.0
    max_cutoff: float = 8.0
    order: int = 4
    reference: float = 1.5
    samples_per_cycle: float = 4.0

    def __post_init__(self) -> None:
        n = "BandConfig."
        if self.cutoff is not None:
            check_number(self.cutoff, n + "cutoff", 0.1, 200.0)
        check_number(self.excitation_factor, n + "excitation_factor", 1.0, 1000.0)
        check_number(self.min_cutoff, n + "min_cutoff", 0.1, 200.0)
        check_number(self.max_cutoff, n + "max_cutoff", self.min_cutoff, 200.0)
        check_int(self.order, n + "order", 1)
        check_number(self.reference, n + "reference", 1.2, 10.0)
        check_number(self.samples_per_cycle, n + "samples_per_cycle", 2.0, 100.0)


@dataclasses.dataclass(frozen=True)
class Band:
    """The analysis band: low-pass at `cutoff` [Hz] on samples `dt` [s] apart, kept every
    `stride` samples; `excitation` [Hz] the joint velocities' 99 % power frequency; `reason`
    how the edge was chosen."""

    cutoff: float
    dt: float
    stride: int
    order: int
    reference: float
    excitation: float
    reason: str

    @property
    def sos(self) -> Array:
        return butter(self.order, self.cutoff, btype="low", fs=1.0 / self.dt, output="sos")

    def filter(self, x: Array) -> Array:
        """x (T, ...) through the band's zero-phase low-pass along time, at every sample."""
        if x.shape[0] <= 3 * (2 * len(self.sos) + 1):
            raise InputError(f"a signal of {x.shape[0]} samples is too short for the {self.cutoff:g} Hz band filter")
        return sosfiltfilt(self.sos, x, axis=0)

    def apply(self, x: Array) -> Array:
        """x (T, ...) filtered and kept every `stride` samples."""
        return self.filter(np.asarray(x, dtype=np.float64))[:: self.stride]

    def rows(self, x: NDArray[Any]) -> NDArray[Any]:
        """A per-sample array (masks, labels, states) kept every `stride` samples, unfiltered."""
        return np.asarray(x)[:: self.stride]

    @property
    def settle(self) -> int:
        """Samples at each end of a log that the filter's start-up and ringing reach (two cycles of
        the edge: the derivative filters' ends are far noisier than their interior)."""
        return int(np.ceil(2.0 / (self.cutoff * self.dt)))

    def inner(self, valid: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """A copy of the per-sample mask `valid` with the `settle` samples at each end set False."""
        out = np.array(valid, dtype=bool)
        out[: self.settle] = False
        out[-self.settle :] = False
        return out

    def power_response(self, f: Array) -> Array:
        """|H(f)|^2 of the forward-backward filter (its magnitude response squared twice)."""
        _, h = sosfreqz(self.sos, worN=f, fs=1.0 / self.dt)
        return np.abs(h) ** 4

    def summary(self) -> dict[str, Any]:
        return {
            "cutoff_hz": self.cutoff,
            "excitation_hz": self.excitation,
            "stride": self.stride,
            "rate_hz": 1.0 / (self.dt * self.stride),
            "reference_hz": [self.cutoff, self.reference * self.cutoff],
            "reason": self.reason,
        }


def _power_edge(x: Array, dt: float, share: float = 0.99) -> float:
    """The frequency [Hz] below which `share` of the power of x (T, k) (each column demeaned,
    summed over columns) lies."""
    x = x - x.mean(axis=0)
    spec = np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1)
    f = np.fft.rfftfreq(x.shape[0], dt)
    cum = np.cumsum(spec[1:])
    if cum[-1] <= 0:
        return 0.0
    return float(f[1:][np.searchsorted(cum, share * cum[-1])])


def choose_band(dq: Array, dt: float, config: BandConfig | None = None) -> Band:
    """The analysis band for a log with joint velocities dq (T, 7) on a uniform grid dt [s] apart.

    Raises:
        InputError: the joints do not move (no joint's velocity varies by more than 1e-3 rad/s
            below the band's edge): nothing excites the effects.
    """
    c = config or BandConfig()
    fs = 1.0 / dt
    excitation = _power_edge(dq, dt)
    if c.cutoff is not None:
        cutoff, reason = float(c.cutoff), "given"
    else:
        cutoff = float(np.clip(c.excitation_factor * excitation, c.min_cutoff, c.max_cutoff))
        reason = (
            f"{c.excitation_factor:g} x the excitation's {excitation:.3g} Hz (99 % of the joint velocities' "
            f"power), within [{c.min_cutoff:g}, {c.max_cutoff:g}] Hz"
        )
    if c.reference * cutoff >= 0.45 * fs:
        raise InputError(
            f"band edge {cutoff:g} Hz is too high for a log sampled at {fs:g} Hz; expected at most "
            f"{0.45 * fs / c.reference:g} Hz"
        )
    stride = max(1, int(np.floor(fs / (c.samples_per_cycle * cutoff))))
    band = Band(
        cutoff=cutoff, dt=dt, stride=stride, order=c.order, reference=c.reference, excitation=excitation, reason=reason
    )
    moving = np.std(band.filter(dq - dq.mean(axis=0)), axis=0)
    if float(np.max(moving)) < 1e-3:
        raise InputError(
            f"the log's joints do not move below {cutoff:g} Hz (largest velocity spread "
            f"{float(np.max(moving)):.2g} rad/s); expected a trajectory that excites the joints"
        )
    return band


def band_floor(
    residual: Array,
    valid: NDArray[np.bool_],
    band: Band,
    kernel: Array | None = None,
    derivative: int | None = None,
    window: int = 41,
    measured: Array | None = None,
    mass: Array | None = None,
) -> tuple[Array, dict[str, Any]]:
    """The noise's standard deviation in the band for each column of `residual` (T, k).

    The residual's noise spectrum is modelled as a |K(f)|^2 + b |D(f)|^2: the sensor's noise, flat
    near the band, seen through the torque filter K (`kernel`; 1 without one), plus the noise of
    the measurement the acceleration is differentiated from, which rises with frequency: D is the
    cubic Savitzky-Golay derivative of order `derivative` over `window` samples (1: from the
    measured velocity, 2: from the position; None: no such part). a, b >= 0 are fitted to the
    residual's power spectral density (Welch, valid samples) in the reference band
    [cutoff, reference x cutoff]. b comes from the `measured` signal (T, k) the acceleration is
    differentiated from and the mass matrix `mass` (T, k, k) it enters through: what that signal
    holds there, b_j = sum_k <M_jk^2> S_k (S_k its mean density in the reference band), at most
    what the residual's density allows, and a is the rest (at least 0); over one octave a flat part
    and an f^2 part are nearly collinear, so a joint fit would trade one for the other. The noise
    variance the band-limited residual holds when the model has no gap is the spectrum's integral
    under the band's power response.

    Returns:
        (floor (k,), detail): detail holds per column a, b, the reference band's mean density and
        the broadband standard deviation for comparison.

    Raises:
        InputError: too few valid samples to read a spectrum, or `derivative` without `measured`
            and `mass`.
    """
    if derivative is not None and (measured is None or mass is None):
        raise InputError(
            f"band_floor: derivative = {derivative} needs the measured signal and the mass matrix; expected both"
        )
    r = residual[valid]
    fs = 1.0 / band.dt
    nper = int(min(len(r) // 4, 2 ** int(np.ceil(np.log2(4.0 * fs)))))
    if nper < 64:
        raise InputError(
            f"the log has {len(r)} valid samples; too few to read its noise spectrum (expected at least {4 * 64})"
        )
    f, P = welch(r - r.mean(axis=0), fs=fs, nperseg=nper, axis=0)

    def response(taps: Array) -> Array:
        lags = np.arange(len(taps)) - len(taps) // 2
        return np.abs(np.exp(-2j * np.pi * np.outer(f, lags) * band.dt) @ taps) ** 2

    K2 = np.ones_like(f) if kernel is None else response(kernel)
    D2 = (
        np.zeros_like(f)
        if derivative is None
        else response(savgol_coeffs(window, 3, deriv=derivative, delta=band.dt, use="dot"))
    )
    ref = (f >= band.cutoff) & (f <= band.reference * band.cutoff)
    fine = np.linspace(0.0, fs / 2, 8192)
    H = band.power_response(fine)
    white = np.trapezoid(np.interp(fine, f, K2) * H, fine)
    blue = np.trapezoid(np.interp(fine, f, D2) * H, fine)
    k = r.shape[1]
    a, b = np.zeros(k), np.zeros(k)
    b_max = np.zeros(k)
    if derivative is not None:
        m = measured[valid]
        fm, Pm = welch(m - m.mean(axis=0), fs=fs, nperseg=nper, axis=0)
        S = np.mean(Pm[(fm >= band.cutoff) & (fm <= band.reference * band.cutoff)], axis=0)
        D_ref = np.mean(D2[ref]) / max(float(np.mean((2 * np.pi * f[ref]) ** (2 * derivative))), 1e-300)
        b_max = np.mean(mass[valid] ** 2, axis=0) @ S / max(D_ref, 1e-300)
    for j in range(k):
        p = P[ref, j]
        if derivative is not None:
            # the measured signal's noise first, as much of the reference density as it can explain
            b[j] = min(b_max[j], float(np.mean(p / np.maximum(D2[ref], 1e-300))))
        a[j] = max(float(np.mean((p - b[j] * D2[ref]) / K2[ref])), 0.0)
    floors = np.sqrt(np.maximum(a * white + b * blue, 0.0))
    detail = {
        "a": a.tolist(),
        "b": b.tolist(),
        "b_max": b_max.tolist(),
        "reference_density": np.mean(P[ref], axis=0).tolist(),
        "broadband_std": np.std(r, axis=0).tolist(),
    }
    return np.maximum(floors, 1e-9), detail


def band_candidate(cand: Candidate, band: Band, cache: dict[Any, Any]) -> Candidate:
    """The candidate as the band sees it: its features and offsets filtered and kept every stride
    samples; a family member's refinements are banded too (`cache` keeps one banded copy per
    candidate and family, keyed by the original's id, as the fits' caches need)."""
    key = id(cand)
    if key in cache:
        return cache[key]
    family = cand.family
    if family is not None:
        family = _band_family(family, band, cache)
    out = dataclasses.replace(
        cand,
        features={c: band.apply(v) for c, v in cand.features.items()},
        offset={c: band.apply(v) for c, v in cand.offset.items()},
        family=family,
    )
    cache[key] = out
    return out


def _band_family(family: Family, band: Band, cache: dict[Any, Any]) -> Family:
    key = ("family", id(family))
    if key not in cache:
        cache[key] = Family(
            family.key,
            family.grid,
            family.low,
            family.high,
            lambda value: band_candidate(family.at(value), band, cache),
        )
    return cache[key]


def band_pool(pool: dict[str, list[Candidate]], band: Band) -> dict[str, list[Candidate]]:
    """Every candidate of an effect pool seen through the band."""
    cache: dict[Any, Any] = {}
    return {name: [band_candidate(c, band, cache) for c in options] for name, options in pool.items()}


# ---------------------------------------------------------------------------------------------- broadband


def noise_floor(
    residual: Array, valid: NDArray[np.bool_], window: int = 101, kernel: Array | None = None, reach: int | None = None
) -> Array:
    """Per column of a (T, k) residual: the standard deviation of its noise, i.e. of what varies
    faster than any effect of the state can (vibration, sensor noise, derivative noise).

    The fast-part estimate: the residual minus its cubic Savitzky-Golay smoothing over `window`
    samples, robustly (1.4826 MAD), corrected for the part of the noise the smoothing keeps
    (divided by sqrt(1 - h0), h0 the filter's centre weight, for white noise; with a `kernel`, for
    white noise smoothed by it, a replay's torque filter). Slow model error gives ~0, but noise
    bluer than assumed (derivative noise) reads too high. With `reach`, the noise's correlation
    length in samples, the nugget of the residual's semivariogram is a second estimate: beyond
    that lag the noise's share of the semivariogram is its whole variance, so a + b lag^2 fitted
    at lags reach .. 3 reach gives it at a = lag 0 whatever the noise's spectrum; slow model error
    makes it read high. The floor is the smaller of the two, and no lower than the fast part's
    spread over the smoothing's largest high-pass gain (no noise spectrum keeps more)."""
    from scipy.signal import savgol_coeffs, savgol_filter

    r = residual[valid]
    window = min(window, (len(r) // 2) * 2 - 1)
    if window < 7:  # too few samples to tell fast from slow: the whole spread, conservatively
        return np.maximum(np.std(r, axis=0), 1e-9)
    fast = r - savgol_filter(r, window, 3, axis=0)
    if kernel is None:
        kept = 1.0 - savgol_coeffs(window, 3)[window // 2]
    else:  # the fast part of kernel-smoothed white noise: (I - SG) * kernel
        impulse = np.zeros(window + 2 * len(kernel))
        impulse[len(impulse) // 2] = 1.0
        seen = np.convolve(impulse, kernel[::-1], mode="same")
        kept = float(np.sum((seen - savgol_filter(seen, window, 3)) ** 2) / np.sum(kernel**2))
    spread = 1.4826 * np.median(np.abs(fast - np.median(fast, axis=0)), axis=0)
    floor = spread / np.sqrt(kept)
    if reach is not None and len(r) >= 12 * reach:
        # the fast part keeps at most the smoothing's largest high-pass gain of any noise
        highpass = -savgol_coeffs(window, 3)
        highpass[window // 2] += 1.0
        gain = float(np.max(np.abs(np.fft.rfft(highpass, 8 * window))))
        floor = np.clip(_nugget(r, reach), spread / gain, floor)
    scale = np.sqrt(np.mean(r**2, axis=0))
    return np.maximum(floor, 1e-6 * np.maximum(scale, 1e-12) + 1e-9)


def _nugget(r: Array, reach: int) -> Array:
    """The standard deviation at lag 0 of the semivariogram gamma(lag) = E (r[t + lag] - r[t])^2 / 2
    of each column of r (T, k), extrapolated from lags reach .. 3 reach by a + b lag^2 (0 where
    the fit's a is not positive)."""
    lags = np.unique(np.linspace(reach, 3 * reach, 12).astype(int))
    gamma = np.array([0.5 * np.mean((r[k:] - r[:-k]) ** 2, axis=0) for k in lags])
    x = (lags / reach) ** 2.0
    design = np.stack([np.ones_like(x), x], axis=1)
    a = np.linalg.lstsq(design, gamma, rcond=None)[0][0]
    return np.sqrt(np.maximum(a, 0.0))
