"""The analysis band: its edge from the excitation, and an honest noise floor in it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from goflow_common.errors import InputError
from sim2real.band import BandConfig, band_floor, choose_band


def _velocity(n: int, dt: float, f0: float = 0.1) -> np.ndarray:
    t = np.arange(n) * dt
    return np.stack([np.sin(2 * np.pi * f0 * (k + 1) * t + k) for k in range(7)], axis=1)


def test_the_edge_follows_the_excitation_and_is_reported():
    band = choose_band(_velocity(20000, 1e-3, f0=0.05), 1e-3)
    assert 0.3 < band.excitation < 0.4  # the 7th harmonic of 0.05 Hz
    assert band.cutoff == pytest.approx(16 * band.excitation)
    assert band.summary()["reason"].startswith("16 x")
    fast = choose_band(_velocity(20000, 1e-3, f0=0.5), 1e-3)
    assert fast.cutoff == BandConfig().max_cutoff  # capped: above it sits the arm's vibration band
    assert choose_band(_velocity(20000, 1e-3), 1e-3, BandConfig(cutoff=5.0)).cutoff == 5.0


def test_a_log_whose_joints_do_not_move_is_refused():
    still = 1e-5 * np.random.default_rng(0).standard_normal((5000, 7))
    with pytest.raises(InputError, match="do not move"):
        choose_band(still, 1e-3)


@pytest.mark.parametrize("colour", ["white", "vibration"])
def test_the_floor_predicts_the_band_limited_noise_within_10_percent(colour):
    """Noise only (white, or white plus a 25-60 Hz vibration band 30 times stronger): the floor
    read above the band predicts the band-limited residual's spread. 100 s, so that the observed
    spread's own sampling error (7 % on a 20 s log) does not hide a bias."""
    dt, n = 1e-3, 100000
    rng = np.random.default_rng(3)
    band = choose_band(_velocity(n, dt), dt)
    sigma = np.array([0.1, 0.2, 0.1, 0.1, 0.02, 0.02, 0.01])
    noise = sigma * rng.standard_normal((n, 7))
    if colour == "vibration":
        sos = butter(4, [25, 60], btype="band", fs=1 / dt, output="sos")
        noise += sosfiltfilt(sos, 30 * sigma * rng.standard_normal((n, 7)), axis=0)
    valid = np.ones(n, dtype=bool)
    floor, detail = band_floor(noise, valid, band)
    observed = np.std(band.apply(noise), axis=0)
    assert abs(np.mean(floor / observed) - 1.0) < 0.07
    np.testing.assert_allclose(floor / observed, 1.0, atol=0.15)
    assert np.all(np.asarray(detail["broadband_std"]) > 2 * floor)  # the broadband spread would mislead


def test_the_floor_adds_the_differentiated_velocity_noise():
    """The residual holds M times the derivative of the measured velocity's noise, rising as f^2
    into the band (the Panda's velocity estimate): fitted with its shape, bounded by what the
    velocity holds above the band, it is predicted in the band; read flat it would be overestimated."""
    from scipy.signal import savgol_filter

    dt, n = 1e-3, 100000
    rng = np.random.default_rng(4)
    band = choose_band(_velocity(n, dt), dt)
    dq_noise = 3e-3 * rng.standard_normal((n, 7))  # the real log's velocity noise is ~6e-3 rad/s
    mass = np.broadcast_to(np.eye(7) * 2.0, (n, 7, 7))
    accel = savgol_filter(dq_noise, 41, 3, deriv=1, delta=dt, axis=0)
    residual = 0.02 * rng.standard_normal((n, 7)) - accel @ (2.0 * np.eye(7))
    valid = np.ones(n, dtype=bool)
    floor, _ = band_floor(residual, valid, band, derivative=1, window=41, measured=dq_noise, mass=mass)
    flat, _ = band_floor(residual, valid, band)
    observed = np.std(band.filter(residual)[band.settle : -band.settle], axis=0)
    assert abs(np.mean(floor / observed) - 1.0) < 0.1
    np.testing.assert_allclose(floor / observed, 1.0, atol=0.2)
    assert np.all(flat > 1.3 * observed)


@pytest.mark.parametrize("field, value", [("cutoff", -1.0), ("order", 0), ("max_cutoff", 1.0), ("reference", 1.0)])
def test_bad_band_config_is_refused(field, value):
    with pytest.raises(InputError, match=f"BandConfig.{field}"):
        BandConfig(**{field: value})
