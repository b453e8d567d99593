"""Structure left in a residual: what a generic smooth model of the state still predicts.

After the selection, the held-out residual of a log whose gap the catalogue explains is noise plus
small misfits; an effect outside the catalogue that a catalogue effect only partly fits (a drag
growing with the square of the speed fitted by viscous friction, a sensor offset drifting in time
fitted by a constant one) leaves a residual that a generic function of the state predicts on held-out
blocks. Per column (channel and joint) and per named basis (docs/sim2real.md, "Structure left"):

- a basis holds, per joint, K functions of the state, e.g. piecewise-linear hats over the joint's
  velocity at its quantiles (`hat_basis`), or a linear trend in time (`trend_basis`);
- the basis plus a constant is fitted by weighted least squares on the training folds (a little
  ridge) and scored on the held-out fold, against the constant alone: the gain is what the
  basis predicts beyond a constant offset, in noise variances per row, with a block-bootstrap
  interval, as the effects' gains are.

A basis is fitted only where it can generalise from one block of a log to another: velocities
repeat on an exciting trajectory; positions do not (a function of q fitted on four fifths of the
log extrapolates wildly on the fifth), so positions are not offered.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sim2real.fitting import bootstrap_mean

__all__ = ["hat_basis", "trend_basis", "structure_gains", "HAT_KNOTS"]

Array = NDArray[np.float64]

HAT_KNOTS = 8  # hats per joint over its velocity: at its 0, 1/7, ..., 1 quantiles
_RIDGE = 1e-6  # relative to the Gram matrix's mean diagonal


def hat_basis(x: Array, knots: int = HAT_KNOTS) -> Array:
    """Piecewise-linear hats over each column of x (T, J) at `knots` quantiles of it: (T, J, knots)
    (a column with fewer distinct quantiles gets zero columns for the missing hats). The hats sum
    to 1 at every sample."""
    T, J = x.shape
    out = np.zeros((T, J, knots))
    rows = np.arange(T)
    for j in range(J):
        k = np.unique(np.quantile(x[:, j], np.linspace(0.0, 1.0, knots)))
        if len(k) < 2:
            out[:, j, 0] = 1.0
            continue
        i = np.clip(np.searchsorted(k, x[:, j]) - 1, 0, len(k) - 2)
        f = np.clip((x[:, j] - k[i]) / (k[i + 1] - k[i]), 0.0, 1.0)
        out[rows, j, i] = 1.0 - f
        out[rows, j, i + 1] += f
    return out


def trend_basis(time: Array, joints: int) -> Array:
    """A linear trend in time (T,) for each of `joints` joints: (T, joints, 1), centred and scaled."""
    t = (time - time.mean()) / max(float(np.ptp(time)), 1e-12)
    return np.repeat(t[:, None, None], joints, axis=1)


def _fold_rows(starts: NDArray[np.int64], n_samples: int, blocks: NDArray[np.int64]) -> NDArray[np.bool_]:
    rows = np.zeros(n_samples, dtype=bool)
    for b in blocks:
        rows[starts[b] : starts[b + 1] if b + 1 < len(starts) else n_samples] = True
    return rows


def structure_gains(
    residual: Array,
    weight: Array,
    valid: NDArray[np.bool_],
    starts: NDArray[np.int64],
    folds: list[NDArray[np.int64]],
    bases: dict[str, Array],
    n_boot: int,
    rng: np.random.Generator,
) -> list[dict[str, float | str]]:
    """Per basis in `bases` (name -> (T, J, K)): the held-out gain of fitting it (plus a constant)
    to each column of `residual` (T, C, J) over the constant alone, in weighted squares per row
    (`weight` (C, J): inverse noise variances), with the 95 % block-bootstrap interval. Blocks start
    at `starts`; `folds` are lists of block indices; only `valid` samples count.

    Returns [{"basis", "gain", "low", "high"}] in the order of `bases`."""
    T, C, J = residual.shape
    n_blocks = len(starts)
    block = np.zeros(T, dtype=np.int64)
    block[starts[1:]] = 1
    block = np.cumsum(block)
    held = [_fold_rows(starts, T, f) & valid for f in folds]
    rows = np.bincount(block[valid], minlength=n_blocks) * C * J
    out = []
    for name, basis in bases.items():
        plain = np.zeros(n_blocks)  # the constant's held-out weighted squares per block
        fitted = np.zeros(n_blocks)
        for j in range(J):
            X = np.concatenate([np.ones((T, 1)), basis[:, j, :]], axis=1)
            X = X[:, np.abs(X[valid]).sum(axis=0) > 0]
            for test in held:
                train = valid & ~test
                A = X[train].T @ X[train]
                A += _RIDGE * np.trace(A) / len(A) * np.eye(len(A))
                for c in range(C):
                    y = residual[:, c, j]
                    coef = np.linalg.solve(A, X[train].T @ y[train])
                    w = weight[c, j]
                    plain += np.bincount(block[test], weights=w * (y[test] - y[train].mean()) ** 2, minlength=n_blocks)
                    fitted += np.bincount(block[test], weights=w * (y[test] - X[test] @ coef) ** 2, minlength=n_blocks)
        diff = (plain - fitted) / np.maximum(rows, 1)
        low, high = bootstrap_mean(diff, n_boot, rng)
        out.append(
            {"basis": name, "gain": float((plain.sum() - fitted.sum()) / max(rows.sum(), 1)), "low": low, "high": high}
        )
    return out
