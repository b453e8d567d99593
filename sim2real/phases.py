"""Task phases segmented from a log's own signals, for logs that carry no phase labels.

Contact is where the external force (the wrench, or else the robot's external-torque estimate)
stands above its sensor noise; insertion is contact while the tool moves down along the world z
axis (its height smoothed over 0.1 s); approach is the second before the first contact; the rest is free motion. The labels index
sim2real.log.PHASES. A log with neither a wrench nor an external-torque estimate is all free motion.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sim2real.log import PHASES, RobotLog

__all__ = ["segment_phases", "APPROACH_TIME", "DESCENT_SPEED"]

APPROACH_TIME = 1.0  # [s] before the first contact that counts as the approach
DESCENT_SPEED = 1e-3  # [m/s] downward tool speed that makes contact an insertion
_FREE, _APPROACH, _CONTACT, _INSERTION = (PHASES.index(p) for p in ("free", "approach", "contact", "insertion"))


def _contact(vectors: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Samples whose force (T, k) stands above its sensor noise: the norm beyond 5 noise standard
    deviations of a k-vector (the noise from the robust spread of sample-to-sample differences)."""
    d = np.diff(vectors, axis=0)
    sigma = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)
    level = 5.0 * float(np.sqrt(np.sum(sigma**2))) + 1e-9
    return np.linalg.norm(vectors, axis=1) > level


def _smooth(x: NDArray[np.float64], t: NDArray[np.float64], seconds: float = 0.1) -> NDArray[np.float64]:
    """x smoothed over about `seconds` (a moving average), for a noise-robust velocity."""
    n = max(1, int(round(seconds / max(float(np.median(np.diff(t))), 1e-9))))
    kernel = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), kernel, mode="valid")


def segment_phases(log: RobotLog) -> NDArray[np.int64]:
    """Phase labels (T,) for `log`: its own labels when it has them, else segmented from its
    wrench or external-torque estimate and the tool's height (see the module docstring)."""
    if log.phase is not None:
        return np.asarray(log.phase, dtype=np.int64)
    T = log.n_samples
    phase = np.full(T, _FREE, dtype=np.int64)
    if log.wrench is not None:
        force = log.wrench[:, :3]
    elif log.tau_ext is not None:
        force = log.tau_ext
    else:
        return phase
    touching = _contact(force)
    if not touching.any():
        return phase
    phase[touching] = _CONTACT
    if log.tool_pose is not None:
        vz = np.gradient(_smooth(log.tool_pose[:, 2, 3], log.time), log.time)
        phase[touching & (vz < -DESCENT_SPEED)] = _INSERTION
    first = int(np.flatnonzero(touching)[0])
    start = int(np.searchsorted(log.time, log.time[first] - APPROACH_TIME))
    phase[start:first] = _APPROACH
    return phase
