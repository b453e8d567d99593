"""Exciting joint trajectories for the simulated reality: a finite Fourier series per joint.

The form is the usual one of dynamic identification (Swevers et al., IEEE TRA 13(5), 1997; used by
Gaz et al., IEEE RA-L 4(4), 2019 for the Panda): per joint i, with base angular frequency w and H
harmonics,

    q_i(t) = q0_i + sum_l [ a_il / (w l) sin(w l t) - b_il / (w l) cos(w l t) ]
    dq_i(t) = sum_l [ a_il cos(w l t) + b_il sin(w l t) ]
    ddq_i(t) = sum_l [ -a_il w l sin(w l t) + b_il w l cos(w l t) ].

`exciting_trajectory` draws the coefficients from a seed, projects them so that the trajectory
starts at `q_start` at rest with zero acceleration (sum_l a_il = 0, sum_l l b_il = 0) and, since
the duration holds a whole number of periods, ends there at rest too; then it scales each joint so
that it keeps `margin` from the joint limits and its peak speed and acceleration are at most
`speed_fraction` of V_MAX and DDQ_MAX (each joint's excursion may run either way round, whichever
leaves it the larger range). The coefficients are drawn with standard deviation l for harmonic l,
so that the higher harmonics carry more of the speed: more reversals for the same position range.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.panda_model import Q_HOME, Q_MAX, Q_MIN, V_MAX
from goflow_common.checks import check_int, check_number
from goflow_common.errors import InputError

__all__ = ["FourierTrajectory", "exciting_trajectory", "default_base_frequency", "DDQ_MAX"]

#: The base frequency the default rule aims at [Hz] (Gaz et al. 2019 excite at 0.1 Hz).
TARGET_BASE_FREQUENCY = 0.1
#: Joint acceleration limits [rad/s^2] (Franka Control Interface docs, "Limits for Panda").
DDQ_MAX: NDArray[np.float64] = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])


@dataclasses.dataclass(frozen=True)
class FourierTrajectory:
    """A finite Fourier series per joint (see the module docstring for the formulas).

    q0: (n,) offsets [rad]; a, b: (n, H) velocity amplitudes of the cosine and sine terms of dq
    [rad/s]; omega: the base angular frequency [rad/s]."""

    q0: NDArray[np.float64]
    a: NDArray[np.float64]
    b: NDArray[np.float64]
    omega: float

    @property
    def period(self) -> float:
        """The period of the base harmonic [s]."""
        return 2.0 * math.pi / self.omega

    def __call__(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Positions [rad], velocities [rad/s] and accelerations [rad/s^2] at times `t` (T,) [s],
        each of shape (T, n)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        wl = self.omega * np.arange(1, self.a.shape[1] + 1)  # (H,)
        phase = np.outer(t, wl)  # (T, H)
        s, c = np.sin(phase), np.cos(phase)
        q = self.q0 + s @ (self.a / wl).T - c @ (self.b / wl).T
        dq = c @ self.a.T + s @ self.b.T
        ddq = -s @ (self.a * wl).T + c @ (self.b * wl).T
        return q, dq, ddq


def default_base_frequency(duration: float) -> float:
    """The base frequency [Hz] for a trajectory of `duration` [s]: a whole number of periods, as
    close to 0.1 Hz as that allows (at least one period): 0.1 Hz for 20 s, 0.25 Hz for 4 s."""
    duration = check_number(duration, "duration", 0.0, low_open=True)
    periods = max(1, round(duration * TARGET_BASE_FREQUENCY))
    return periods / duration


def exciting_trajectory(
    duration: float,
    seed: int,
    harmonics: int = 5,
    base_frequency: float | None = None,
    speed_fraction: float = 0.65,
    margin: float = 0.2,
    q_start: ArrayLike = Q_HOME,
) -> FourierTrajectory:
    """A random exciting trajectory of the Panda's 7 joints that starts and ends at rest at `q_start`.

    Arguments:
        duration: its length [s]; it must hold a whole number of base periods.
        seed: the seed of the random coefficients (standard normal before projection and scaling).
        harmonics: H, the number of harmonics per joint.
        base_frequency: [Hz]; None: `default_base_frequency(duration)`.
        speed_fraction: each joint's peak speed is at most this fraction of V_MAX and its peak
            acceleration at most this fraction of DDQ_MAX (the speed is exactly this fraction
            unless the acceleration or the joint's position margin binds first).
        margin: the distance [rad] kept from Q_MIN and Q_MAX.
        q_start: the start (and end) configuration (7,) [rad]; it must lie `margin` inside the limits.

    Returns:
        The trajectory.

    Raises:
        InputError: a value out of range, or a duration that is not a whole number of periods.

    Example:
        >>> traj = exciting_trajectory(4.0, seed=0)
        >>> q, dq, ddq = traj([0.0, 4.0])
        >>> bool(abs(dq).max() < 1e-9)
        True
    """
    duration = check_number(duration, "duration", 0.0, low_open=True)
    seed = check_int(seed, "seed", 0)
    harmonics = check_int(harmonics, "harmonics", 2)
    speed_fraction = check_number(speed_fraction, "speed_fraction", 0.0, 1.0, low_open=True)
    margin = check_number(margin, "margin", 0.0)
    f0 = (
        default_base_frequency(duration)
        if base_frequency is None
        else check_number(base_frequency, "base_frequency", 0.0, low_open=True)
    )
    periods = duration * f0
    if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
        raise InputError(
            f"base_frequency = {f0:g} Hz; expected one that fits a whole number of periods "
            f"into duration = {duration:g} s (e.g. {default_base_frequency(duration):g} Hz)"
        )
    q_start = np.asarray(q_start, dtype=np.float64)
    lo, hi = Q_MIN + margin, Q_MAX - margin
    if q_start.shape != (7,) or np.any(q_start < lo) or np.any(q_start > hi):
        raise InputError(
            f"q_start = {q_start.tolist()}; expected 7 joint positions at least {margin:g} rad inside the joint limits"
        )

    rng = np.random.default_rng(seed)
    ell = np.arange(1, harmonics + 1, dtype=np.float64)
    a = rng.standard_normal((7, harmonics)) * ell  # weighted to the higher harmonics: more speed
    b = rng.standard_normal((7, harmonics)) * ell  # for the same position range
    a -= a.mean(axis=1, keepdims=True)  # dq(0) = sum_l a_l = 0
    b -= np.outer(b @ ell, ell) / (ell @ ell)  # ddq(0) = w sum_l l b_l = 0
    omega = 2.0 * math.pi * f0
    unit = FourierTrajectory(q0=(b / (omega * ell)).sum(axis=1), a=a, b=b, omega=omega)  # q(0) = 0

    q, dq, ddq = unit(np.linspace(0.0, 1.0 / f0, 4000, endpoint=False))
    rate_scale = np.minimum(
        speed_fraction * V_MAX / np.abs(dq).max(axis=0), speed_fraction * DDQ_MAX / np.abs(ddq).max(axis=0)
    )
    up, down = q.max(axis=0), -q.min(axis=0)  # excursions above and below q_start (both > 0)
    room_up, room_down = hi - q_start, q_start - lo
    # Each joint runs its excursion either way round; keep the sign that allows the larger scale.
    keep = np.minimum(room_up / up, room_down / down)
    flip = np.minimum(room_up / down, room_down / up)
    sign = np.where(flip > keep, -1.0, 1.0)
    scale = sign * np.minimum(rate_scale, np.maximum(keep, flip))
    return FourierTrajectory(q0=q_start + scale * unit.q0, a=scale[:, None] * a, b=scale[:, None] * b, omega=omega)
