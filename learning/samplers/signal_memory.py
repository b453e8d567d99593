"""What a learned sampler has seen: the latest evaluated parameters with their signals, and the
signal estimated anywhere in the box from them.

A sampler update receives one batch (xi, signal) at a time, drawn by whoever evaluated it (the
uniform validation box, the sampler itself, a mixture). `SignalMemory` keeps the newest `capacity`
rows of every batch and estimates the signal at any point as the mean over its k nearest rows
(Euclidean distance in the unit box). Optionally it also keeps up to `boundary` older rows that
lay on the edge between the two classes when they left the window (a row of the other class among
their k nearest), so that the edge of a small set sharpens as rows accumulate without keeping
every row (measured in docs/learning.md, "Boundary rows"). A nearest-neighbour mean is a
regression of the signal on xi, so it does not depend on where the rows came from: the estimate
is the same whichever batch protocol produced them, and it only sharpens as rows accumulate.
Signals are scaled to [0, 1] by a fixed range or, by default, by the range seen so far.

The rows are plain float64 arrays; `state_dict` is JSON-serializable so a resumed run continues
from exactly the same evidence.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from goflow_common.checks import check_int
from goflow_common.errors import InputError

__all__ = ["SignalMemory"]


class SignalMemory:
    """The newest `capacity` rows (unit-box xi, signal) and a k-nearest-neighbour signal estimate.

    Arguments:
        dim: the parameter dimension.
        capacity: the window: the newest rows kept (the oldest leave first).
        neighbours: k of the nearest-neighbour mean.
        signal_range: (lo, hi) mapping the signal onto [0, 1], or None for the range seen so far.
        boundary: older rows kept beyond the window because, when they left it, a row of the
            other class (scaled signal >= 0.5 or < 0.5) was among their k nearest; the oldest of
            them go first (0: none).

    The rows (`xi`, `signal`) are the kept boundary rows, oldest first, then the window's.
    """

    def __init__(
        self,
        dim: int,
        capacity: int,
        neighbours: int,
        signal_range: tuple[float, float] | None = None,
        boundary: int = 0,
    ) -> None:
        self.dim, self.capacity, self.neighbours = dim, capacity, neighbours
        self.signal_range, self.boundary = signal_range, boundary
        self.xi = np.zeros((0, dim))
        self.signal = np.zeros(0)
        self.kept = 0  # the first `kept` rows are boundary rows kept beyond the window
        self._tree: cKDTree | None = None

    def __len__(self) -> int:
        return len(self.signal)

    def add(self, xi_unit: NDArray[np.float64], signal: NDArray[np.float64]) -> None:
        """Append a batch (xi in the unit box, shape (n, dim); signal (n,)); the window's oldest rows
        leave it, and those on the class boundary are kept (up to `boundary`)."""
        xi = np.concatenate([self.xi, np.asarray(xi_unit, dtype=np.float64)])
        signal = np.concatenate([self.signal, np.asarray(signal, dtype=np.float64)])
        leaving = len(signal) - self.kept - self.capacity
        if leaving <= 0:
            self.xi, self.signal = xi, signal
        else:
            kept = np.arange(self.kept)
            old = np.arange(self.kept, self.kept + leaving)
            if self.boundary > 0:  # else `kept` is empty: no row is ever kept beyond the window
                feasible = self._scaled(signal)[0] >= 0.5
                _, idx = cKDTree(xi).query(xi[old], k=min(self.neighbours + 1, len(signal)))
                idx = np.asarray(idx).reshape(leaving, -1)
                on_edge = (feasible[idx] != feasible[old][:, None]).any(axis=1)
                kept = np.concatenate([kept, old[on_edge]])[-self.boundary :]
            rows = np.concatenate([kept, np.arange(self.kept + leaving, len(signal))])
            self.xi, self.signal, self.kept = xi[rows], signal[rows], len(kept)
        self._tree = None

    def _scaled(self, signal: NDArray[np.float64]) -> tuple[NDArray[np.float64], tuple[float, float]]:
        """`signal` mapped onto [0, 1] by the fixed range, else by its own min and max (all zeros
        while that range is empty), and the range used."""
        if self.signal_range is not None:
            lo, hi = float(self.signal_range[0]), float(self.signal_range[1])
        elif len(signal):
            lo, hi = float(signal.min()), float(signal.max())
        else:
            lo, hi = 0.0, 0.0
        if hi <= lo:
            return np.zeros(len(signal)), (lo, hi)
        return np.clip((signal - lo) / (hi - lo), 0.0, 1.0), (lo, hi)

    def scale(self) -> tuple[float, float]:
        """(lo, hi) of the signal's scaling onto [0, 1]: the fixed range, else the rows' min and max."""
        return self._scaled(self.signal)[1]

    def scaled_signal(self) -> NDArray[np.float64]:
        """The rows' signals mapped onto [0, 1] (all zeros while the range is empty: no evidence yet)."""
        return self._scaled(self.signal)[0]

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
        return {"xi": self.xi.tolist(), "signal": self.signal.tolist(), "kept": self.kept}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the rows saved by `state_dict` (InputError if their shapes do not fit)."""
        xi = np.asarray(state.get("xi", []), dtype=np.float64).reshape(-1, self.dim)
        signal = np.asarray(state.get("signal", []), dtype=np.float64)
        kept = state.get("kept", 0)  # states saved before boundary rows existed hold the window alone
        if len(xi) != len(signal) or not (np.isfinite(xi).all() and np.isfinite(signal).all()):
            raise InputError(
                f"evidence state: {len(xi)} rows of xi and {len(signal)} signals, or non-finite values; "
                "expected as many finite rows as signals"
            )
        if check_int(kept, "evidence state: kept", 0) > len(signal):
            raise InputError(f"evidence state: kept = {kept}; expected at most the {len(signal)} rows")
        kept_rows = np.arange(kept)[-self.boundary :] if self.boundary > 0 else np.arange(0)
        rows = np.concatenate([kept_rows, np.arange(kept, len(signal))[-self.capacity :]])
        self.xi, self.signal, self.kept = xi[rows], signal[rows], len(kept_rows)
        self._tree = None
