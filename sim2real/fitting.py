"""Weighted least squares of residual channels on effect candidates, by time blocks.

The residual rows are (sample, channel, joint); each channel-joint is weighted by the inverse of
its noise-floor variance, so a mean weighted square of 1 means "at the noise floor". Everything a
fit needs is summed per contiguous time block (Gram matrices, cross terms), so fitting on any set
of blocks (cross-validation folds, bootstrap resamples) and scoring any held-out block is a small
linear solve. Diagonal (per-joint) columns are kept as (T, C, 7) arrays, dense ones as
(T, C, 7, P); a candidate's fixed offset is a dense column whose coefficient is held at 1.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from sim2real.effects import Candidate

__all__ = ["Design", "Model", "block_starts", "bootstrap_mean"]

Array = NDArray[np.float64]


def block_starts(valid: NDArray[np.bool_], n_blocks: int) -> NDArray[np.int64]:
    """Start indices of `n_blocks` contiguous blocks of equal numbers of valid samples (the first
    block starts at 0, so that block sums by np.add.reduceat cover every sample)."""
    idx = np.flatnonzero(valid)
    cuts = idx[(np.arange(n_blocks) * len(idx)) // n_blocks]
    cuts[0] = 0
    return cuts


def bootstrap_mean(diff: Array, n: int, rng: np.random.Generator) -> tuple[float, float]:
    """The 95 % interval of the mean of the per-block `diff` by the Bayesian block bootstrap
    (Rubin 1981: Dirichlet(1, ..., 1) block weights). Unlike resampling whole blocks it never
    leaves a block out entirely, so an effect acting in two or three blocks only (a saturation the
    trajectory reaches a few times) is not judged by the resamples that happen to miss them."""
    weights = rng.dirichlet(np.ones(len(diff)), size=n)
    means = weights @ diff
    return float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))


@dataclasses.dataclass(frozen=True)
class _Part:
    """A candidate's columns: diag (T, C, 7) one column per joint, or dense (T, C, 7, P)."""

    diag: Array | None
    dense: Array | None
    fixed: bool  # a dense (T, C, 7, 1) offset with coefficient 1

    @property
    def width(self) -> int:
        return 7 if self.diag is not None else self.dense.shape[-1]


class Design:
    """The residual y (T, C, 7) with weights w (C, 7) and valid mask, in `n_blocks` blocks."""

    def __init__(
        self,
        residual: dict[str, Array],
        channels: tuple[str, ...],
        floor: Array,
        valid: NDArray[np.bool_],
        n_blocks: int,
    ) -> None:
        self.channels = channels
        self.y = np.stack([residual[c] for c in channels], axis=1)
        self.w = 1.0 / floor**2  # (C, 7)
        self.mask = valid.astype(float)
        self.starts = block_starts(valid, n_blocks)
        self.n_blocks = n_blocks
        wm = self.mask[:, None, None] * self.w[None]
        self.wm = wm
        self.count = np.add.reduceat(self.mask, self.starts) * self.y.shape[1] * 7  # rows per block
        self.yy = self._reduce((wm * self.y**2).sum(axis=(1, 2)))
        self._parts: dict[int, tuple[Candidate, list[_Part]]] = {}
        self._gram: dict[tuple[int, int], Array] = {}
        self._cross: dict[int, Array] = {}

    def _reduce(self, per_sample: Array) -> Array:
        return np.add.reduceat(per_sample, self.starts, axis=0)

    def _stack(self, arrays: dict[str, Array], trailing: tuple[int, ...]) -> Array:
        T = self.y.shape[0]
        out = np.zeros((T, len(self.channels), 7) + trailing)
        for i, c in enumerate(self.channels):
            if c in arrays:
                out[:, i] = arrays[c].reshape((T, 7) + trailing)
        return out

    def parts(self, cand: Candidate) -> list[_Part]:
        key = id(cand)
        if key not in self._parts:
            parts: list[_Part] = []
            if cand.features:
                P = cand.n_coef
                dense = self._stack(cand.features, (P,))
                if P == 7 and _is_diagonal(dense):
                    parts.append(_Part(np.einsum("tcjj->tcj", dense), None, False))
                else:
                    parts.append(_Part(None, dense, False))
            if cand.offset:
                parts.append(_Part(None, self._stack(cand.offset, ())[..., None], True))
            # the candidate is held with its parts: a freed candidate's id, reused by a new one, would
            # otherwise return the old one's columns (and its parts' ids key the Gram caches)
            self._parts[key] = (cand, parts)
        return self._parts[key][1]

    def _gram_pair(self, a: _Part, b: _Part) -> Array:
        """Per-block weighted Gram (nb, Pa, Pb) of two parts."""
        wm = self.wm
        if a.diag is not None and b.diag is not None:
            s = self._reduce((wm * a.diag * b.diag).sum(axis=1))  # (nb, 7)
            out = np.zeros((self.n_blocks, 7, 7))
            out[:, np.arange(7), np.arange(7)] = s
            return out
        if a.diag is not None:
            return self._reduce(np.einsum("tcj,tcjq->tjq", wm * a.diag, b.dense))
        if b.diag is not None:
            return np.swapaxes(self._gram_pair(b, a), 1, 2)
        return self._reduce(np.einsum("tcjp,tcjq->tpq", wm[..., None] * a.dense, b.dense))

    def _cross_part(self, a: _Part) -> Array:
        if a.diag is not None:
            return self._reduce((self.wm * a.diag * self.y).sum(axis=1))
        return self._reduce(np.einsum("tcjp,tcj->tp", a.dense, self.wm * self.y))

    def stats(self, cands: list[Candidate]) -> tuple[Array, Array, NDArray[np.bool_], list[tuple[Candidate, int]]]:
        """Per-block A (nb, P, P), g (nb, P) over the candidates' columns, the fixed mask (P,)
        and, for each column block, (candidate, width)."""
        parts = [(c, p) for c in cands for p in self.parts(c)]
        sizes = [p.width for _, p in parts]
        P = sum(sizes)
        A = np.zeros((self.n_blocks, P, P))
        g = np.zeros((self.n_blocks, P))
        fixed = np.zeros(P, dtype=bool)
        offs = np.cumsum([0] + sizes)
        for i, (ci, pi) in enumerate(parts):
            ki = id(pi)
            if ki not in self._cross:
                self._cross[ki] = self._cross_part(pi)
            g[:, offs[i] : offs[i + 1]] = self._cross[ki]
            fixed[offs[i] : offs[i + 1]] = pi.fixed
            for j in range(i, len(parts)):
                pj = parts[j][1]
                key = (ki, id(pj))
                if key not in self._gram:
                    self._gram[key] = self._gram_pair(pi, pj)
                blk = self._gram[key]
                A[:, offs[i] : offs[i + 1], offs[j] : offs[j + 1]] = blk
                if j != i:
                    A[:, offs[j] : offs[j + 1], offs[i] : offs[i + 1]] = np.swapaxes(blk, 1, 2)
        return A, g, fixed, [(c, p.width) for c, p in parts]

    def predict(self, cands: list[Candidate], theta: Array) -> Array:
        """The candidates' prediction (T, C, 7) at full coefficients theta (fixed columns = 1)."""
        out = np.zeros_like(self.y)
        k = 0
        for c in cands:
            for p in self.parts(c):
                coef = theta[k : k + p.width]
                out += p.diag * coef if p.diag is not None else p.dense @ coef
                k += p.width
        return out


def _is_diagonal(dense: Array) -> bool:
    off = dense.copy()
    idx = np.arange(7)
    off[:, :, idx, idx] = 0.0
    return not np.any(off)


@dataclasses.dataclass
class Model:
    """A set of candidates fitted together on a Design."""

    design: Design
    cands: list[Candidate]

    @cached_property
    def _stats(self):
        return self.design.stats(self.cands)

    @cached_property
    def bounds(self) -> Array:
        b = [c.bounds for c in self.cands for p in self.design.parts(c) if not p.fixed]
        return np.concatenate(b) if b else np.zeros((0, 2))

    def fit(self, block_weights: Array) -> Array:
        """Full coefficient vector (fixed columns = 1) minimising the weighted squared residual
        on blocks weighted by `block_weights` (nb,), free coefficients within their bounds."""
        A_b, g_b, fixed, _ = self._stats
        P = len(fixed)
        theta = np.ones(P)
        free = np.flatnonzero(~fixed)
        if len(free) == 0:
            return theta
        A = np.tensordot(block_weights, A_b, axes=1)
        g = np.tensordot(block_weights, g_b, axes=1)
        fx = np.flatnonzero(fixed)
        rhs = g[free] - A[np.ix_(free, fx)] @ np.ones(len(fx))
        Aff = A[np.ix_(free, free)]
        lo, hi = self.bounds[:, 0], self.bounds[:, 1]
        active = np.zeros(len(free), dtype=bool)
        value = np.zeros(len(free))
        for _ in range(len(free) + 1):
            act = np.flatnonzero(~active)
            sol = value.copy()
            if len(act):
                M = Aff[np.ix_(act, act)]
                ridge = 1e-9 * (np.trace(M) / len(act) + 1e-30)
                r = rhs[act] - Aff[np.ix_(act, np.flatnonzero(active))] @ value[active]
                sol[act] = np.linalg.solve(M + ridge * np.eye(len(act)), r)
            out = (sol < lo) | (sol > hi)
            out &= ~active
            if not out.any():
                value = sol
                break
            value = np.where(out, np.clip(sol, lo, hi), value)
            active |= out
        theta[free] = value
        return theta

    def block_sse(self, theta: Array) -> Array:
        """Weighted squared residual per block (nb,) at coefficients theta."""
        A_b, g_b, _, _ = self._stats
        return self.design.yy - 2 * g_b @ theta + np.einsum("bpq,p,q->b", A_b, theta, theta)

    def cross_validate(self, folds: list[NDArray[np.int64]]) -> tuple[Array, list[Array]]:
        """Held-out SSE per block (each block scored by the fit on the other folds) and the
        per-fold coefficients."""
        nb = self.design.n_blocks
        sse = np.zeros(nb)
        thetas = []
        for fold in folds:
            w = np.ones(nb)
            w[fold] = 0.0
            theta = self.fit(w)
            thetas.append(theta)
            sse[fold] = self.block_sse(theta)[fold]
        return sse, thetas

    def free_params(self, theta: Array) -> list[tuple[Candidate, Array]]:
        """theta split per candidate into its free coefficients."""
        out = []
        k = 0
        for c in self.cands:
            free = []
            for p in self.design.parts(c):
                if not p.fixed:
                    free.append(theta[k : k + p.width])
                k += p.width
            out.append((c, np.concatenate(free) if free else np.zeros(0)))
        return out
