"""The evaluation metric: the optimal-transport cost (POT's exact ot.emd2) between samples of an
estimate and the true per-trajectory parameters, both normalized by the box (as the seed paper's
evaluation does: "Normalizing Flow-based Parameter Distribution Estimation for Offline Adaptive
Domain Randomization"; docs/nfpde.md#how-the-table-was-made)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["ot_cost"]


def ot_cost(u_est: ArrayLike, u_true: ArrayLike) -> float:
    """Exact OT cost with Euclidean ground distance (W1) between two point clouds in the unit box,
    uniform weights; both (n, d) and (m, d)."""
    import ot

    a = np.asarray(u_est, dtype=np.float64)
    b = np.asarray(u_true, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or len(a) == 0 or len(b) == 0:
        raise ValueError(f"ot_cost: need non-empty (n, d) and (m, d) arrays, got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("ot_cost: samples must be finite")
    cost = ot.dist(a, b, metric="euclidean")
    return float(ot.emd2(np.full(len(a), 1.0 / len(a)), np.full(len(b), 1.0 / len(b)), cost))
