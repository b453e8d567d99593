"""What a learned sampler has seen: the latest evaluated parameters with their signals, and the
signal estimated anywhere in the box from them.

A sampler update receives one batch (xi, signal) at a time, drawn by whoever evaluated it (the
uniform validation box, the sampler itself, a mixture). `Evidence` keeps the newest `capacity`
rows of every batch and estimates the signal at any point as the mean over its k nearest rows
(Euclidean distance in the unit box). A nearest-neighbour mean is a regression of the signal on
xi, so it does not depend on where the rows came from: the estimate is the same whichever batch
protocol produced them, and it only sharpens as rows accumulate. Signals are scaled to [0, 1] by
a fixed range or, by default, by the range seen so far.

The rows are plain float64 arrays; `state_dict` is JSON-serializable so a resumed run continues
from exactly the same evidence.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from common.errors import InputError

__all__ = ["Evidence"]


class Evidence:
    """The newest `capacity` rows (unit-box xi, signal) and a k-nearest-neighbour signal estimate.

    Arguments:
        dim: the parameter dimension.
        capacity: rows kept (the oldest are dropped first).
        neighbours: k of the nearest-neighbour mean.
        signal_range: (lo, hi) mapping the signal onto [0, 1], or None for the range seen so far.
    """

    def __init__(self, dim: int, capacity: int, neighbours: int,
                 signal_range: tuple[float, float] | None = None) -> None:
        self.dim, self.capacity, self.neighbours = dim, capacity, neighbours
        self.signal_range = signal_range
        self.xi = np.zeros((0, dim))
        self.signal = np.zeros(0)
        self._tree: cKDTree | None = None

    def __len__(self) -> int:
        return len(self.signal)

    def add(self, xi_unit: NDArray[np.float64], signal: NDArray[np.float64]) -> None:
        """Append a batch (xi in the unit box, shape (n, dim); signal (n,)) and drop the oldest rows."""
        self.xi = np.concatenate([self.xi, np.asarray(xi_unit, dtype=np.float64)])[-self.capacity:]
        self.signal = np.concatenate([self.signal, np.asarray(signal, dtype=np.float64)])[-self.capacity:]
        self._tree = None

    def scale(self) -> tuple[float, float]:
        """(lo, hi) of the signal's scaling onto [0, 1]: the fixed range, else the rows' min and max."""
        if self.signal_range is not None:
            return float(self.signal_range[0]), float(self.signal_range[1])
        if not len(self):
            return 0.0, 0.0
        return float(self.signal.min()), float(self.signal.max())

    def scaled_signal(self) -> NDArray[np.float64]:
        """The rows' signals mapped onto [0, 1] (all zeros while the range is empty: no evidence yet)."""
        lo, hi = self.scale()
        if hi <= lo:
            return np.zeros(len(self))
        return np.clip((self.signal - lo) / (hi - lo), 0.0, 1.0)

    def _kd_tree(self) -> cKDTree:
        """The rows' k-d tree, built on first use after the rows change."""
        if self._tree is None:
            self._tree = cKDTree(self.xi)
        return self._tree

    def estimate(self, points_unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """The scaled signal at `points_unit` (m, dim): the mean over the k nearest rows (zeros with
        no rows)."""
        points_unit = np.asarray(points_unit, dtype=np.float64)
        if not len(self):
            return np.zeros(len(points_unit))
        k = min(self.neighbours, len(self))
        _, idx = self._kd_tree().query(points_unit, k=k)
        return self.scaled_signal()[np.asarray(idx).reshape(len(points_unit), k)].mean(axis=1)

    def nearest_distance(self, points_unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distance from each point to its nearest other row (rows given as points exclude themselves)."""
        if len(self) < 2:
            return np.full(len(points_unit), np.inf)
        dist, _ = self._kd_tree().query(np.asarray(points_unit, dtype=np.float64), k=2)
        return dist[:, 1]

    def design_weights(self, clip: float = 30.0) -> NDArray[np.float64]:
        """Weights that make the rows stand for a uniform design over the box: each row's k-nearest-
        neighbour ball volume (r_k^dim, an inverse density), relative to the median and clipped to
        [1 / clip, clip]; shape (n,). Rows from a sampler's own draws crowd where it samples, and
        these weights let the few rows elsewhere count as much as a uniform batch's would."""
        if len(self) <= self.neighbours:
            return np.ones(len(self))
        dist, _ = self._kd_tree().query(self.xi, k=self.neighbours + 1)
        volume = np.maximum(dist[:, -1], 1e-12) ** self.dim
        return np.clip(volume / np.median(volume), 1.0 / clip, clip)

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable rows."""
        return {"xi": self.xi.tolist(), "signal": self.signal.tolist()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the rows saved by `state_dict` (InputError if their shapes do not fit)."""
        xi = np.asarray(state.get("xi", []), dtype=np.float64).reshape(-1, self.dim)
        signal = np.asarray(state.get("signal", []), dtype=np.float64)
        if len(xi) != len(signal) or not (np.isfinite(xi).all() and np.isfinite(signal).all()):
            raise InputError(f"evidence state: {len(xi)} rows of xi and {len(signal)} signals, or non-finite values; "
                             "expected as many finite rows as signals")
        self.xi, self.signal = xi[-self.capacity:], signal[-self.capacity:]
        self._tree = None
