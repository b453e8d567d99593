"""Distributions on the unit box [0, 1]^d that the estimators return, and their serialization.

Every one is bounded by construction (the seed's sigmoid bounds: u = sigmoid(y) with y unbounded)
or by truncation, samples from a numpy Generator (same rng state, same samples) and reports the
log density with respect to Lebesgue measure on the unit box:
- `FlowDistribution` (NFPDE): a zuko RealNVP over y = logit(u);
- `TruncNormalProduct` (DROPO): independent normals truncated to [0, 1];
- `GaussianMixtureAggregate` (BayesSim): the average of S Gaussian-mixture posteriors over y.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np
import torch
import zuko
from scipy.special import expit
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "UnitBoxDistribution",
    "FlowDistribution",
    "TruncNormalProduct",
    "GaussianMixtureAggregate",
    "distribution_from_dict",
    "logit",
    "EPS",
]

EPS = 1e-6  # u is clipped to [EPS, 1 - EPS] before logit


class UnitBoxDistribution(Protocol):
    """A density on [0, 1]^d."""

    dim: int

    def sample_u(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws, shape (n, d), inside the unit box."""
        ...

    def log_prob_u(self, u: ArrayLike) -> NDArray[np.float64]:
        """Log density on the unit box of u (n, d); -inf outside."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable; `distribution_from_dict` rebuilds it."""
        ...


def logit(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """log(u / (1 - u)) with u clipped to [EPS, 1 - EPS]."""
    u = np.clip(u, EPS, 1.0 - EPS)
    return np.log(u) - np.log1p(-u)


def _sigmoid_log_jacobian(y: torch.Tensor) -> torch.Tensor:
    """sum_j log du_j/dy_j for u = sigmoid(y): log sigmoid(y) + log sigmoid(-y), summed."""
    return (torch.nn.functional.logsigmoid(y) + torch.nn.functional.logsigmoid(-y)).sum(-1)


def _outside(u: NDArray[np.float64]) -> NDArray[np.bool_]:
    return np.any((u < 0) | (u > 1) | ~np.isfinite(u), axis=1)


class FlowDistribution:
    """p(u) for u = sigmoid(y), y = y_scale * w, w ~ a zuko RealNVP flow (y_scale widens the start)."""

    def __init__(
        self, dim: int, transforms: int = 4, hidden: tuple[int, ...] = (64, 64), y_scale: float = 1.5, seed: int = 0
    ) -> None:
        if dim < 1:
            raise ValueError(f"FlowDistribution: dim must be >= 1, got {dim}")
        self.dim, self.transforms, self.hidden, self.y_scale = int(dim), int(transforms), tuple(hidden), float(y_scale)
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            self.flow = zuko.flows.RealNVP(self.dim, transforms=self.transforms, hidden_features=self.hidden)

    # y = y_scale * w with w ~ flow: a standard-normal base then covers most of the box at start.
    def log_prob_y(self, y: torch.Tensor) -> torch.Tensor:
        """Differentiable log density of y = logit(u) (float32 tensor (n, d))."""
        return self.flow().log_prob(y / self.y_scale) - self.dim * math.log(self.y_scale)

    def log_prob_u_torch(self, y: torch.Tensor) -> torch.Tensor:
        """Differentiable log density on the unit box at u = sigmoid(y)."""
        return self.log_prob_y(y) - _sigmoid_log_jacobian(y)

    def sample_y(self, n: int, rng: np.random.Generator) -> torch.Tensor:
        """n draws of y (no gradient), from the rng's standard normals through the inverse flow."""
        z = torch.as_tensor(rng.standard_normal((n, self.dim)), dtype=torch.float32)
        with torch.no_grad():
            return self.flow().transform.inv(z) * self.y_scale

    def sample_u(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws in the open unit box."""
        y = self.sample_y(n, rng).double().numpy()
        return np.clip(expit(y), EPS, 1.0 - EPS)

    def log_prob_u(self, u: ArrayLike) -> NDArray[np.float64]:
        """Log density on the unit box; -inf outside."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        out = np.full(len(u), -np.inf)
        ok = ~_outside(u)
        if ok.any():
            y = torch.as_tensor(logit(u[ok]), dtype=torch.float32)
            with torch.no_grad():
                out[ok] = self.log_prob_u_torch(y).double().numpy()
        return out

    def to_dict(self) -> dict[str, Any]:
        """Architecture and weights (lists of floats)."""
        return {
            "kind": "flow",
            "dim": self.dim,
            "transforms": self.transforms,
            "hidden": list(self.hidden),
            "y_scale": self.y_scale,
            "weights": {k: v.detach().cpu().tolist() for k, v in self.flow.state_dict().items()},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FlowDistribution:
        """Rebuild from to_dict()."""
        out = cls(d["dim"], d["transforms"], tuple(d["hidden"]), d["y_scale"])
        out.flow.load_state_dict({k: torch.as_tensor(v, dtype=torch.float32) for k, v in d["weights"].items()})
        return out


class TruncNormalProduct:
    """Independent normals N(mu_j, sigma_j^2) truncated to [0, 1] (DROPO's family)."""

    def __init__(self, mu: ArrayLike, sigma: ArrayLike) -> None:
        self.mu = np.asarray(mu, dtype=np.float64).reshape(-1)
        self.sigma = np.asarray(sigma, dtype=np.float64).reshape(-1)
        if self.mu.shape != self.sigma.shape or np.any(self.sigma <= 0) or not np.all(np.isfinite(self.mu)):
            raise ValueError(
                f"TruncNormalProduct: need finite mu and positive sigma of one shape, got "
                f"{self.mu.tolist()}, {self.sigma.tolist()}"
            )
        self.dim = len(self.mu)
        self._a, self._b = (0.0 - self.mu) / self.sigma, (1.0 - self.mu) / self.sigma

    def quantile(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The inverse CDF applied to uniforms p (n, d) in [0, 1]: a draw per row."""
        from scipy.special import ndtr, ndtri

        lo, hi = ndtr(self._a), ndtr(self._b)
        q = lo + np.asarray(p, dtype=np.float64) * (hi - lo)
        return np.clip(self.mu + self.sigma * ndtri(np.clip(q, 1e-300, 1.0 - 1e-16)), 0.0, 1.0)

    def sample_u(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """Inverse-CDF draws (one uniform per value)."""
        return self.quantile(rng.uniform(size=(n, self.dim)))

    def log_prob_u(self, u: ArrayLike) -> NDArray[np.float64]:
        """Sum of truncated-normal log densities; -inf outside."""
        from scipy.stats import truncnorm

        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        lp = truncnorm.logpdf(u, self._a, self._b, loc=self.mu, scale=self.sigma).sum(axis=1)
        return np.where(_outside(u), -np.inf, lp)

    def to_dict(self) -> dict[str, Any]:
        """mu and sigma."""
        return {"kind": "truncnormal", "mu": self.mu.tolist(), "sigma": self.sigma.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TruncNormalProduct:
        """Rebuild from to_dict()."""
        return cls(d["mu"], d["sigma"])


class GaussianMixtureAggregate:
    """(1/S) sum_s sum_k w_sk N(y; m_sk, diag(s_sk^2)) over y = logit(u): BayesSim's posteriors,
    one per observed trajectory segment, averaged into one distribution of the parameters."""

    def __init__(self, weights: ArrayLike, means: ArrayLike, stds: ArrayLike) -> None:
        self.weights = np.asarray(weights, dtype=np.float64)
        self.means = np.asarray(means, dtype=np.float64)
        self.stds = np.asarray(stds, dtype=np.float64)
        s, k = self.weights.shape
        if self.means.shape[:2] != (s, k) or self.stds.shape != self.means.shape or np.any(self.stds <= 0):
            raise ValueError(
                f"GaussianMixtureAggregate: weights (S, K), means and stds (S, K, d) with "
                f"positive stds; got {self.weights.shape}, {self.means.shape}, {self.stds.shape}"
            )
        self.weights = self.weights / self.weights.sum(axis=1, keepdims=True)
        self.dim = int(self.means.shape[2])

    def sample_u(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """Pick a posterior, a component, then a Gaussian draw; squash with the sigmoid."""
        s = rng.integers(len(self.weights), size=n)
        cum = np.cumsum(self.weights[s], axis=1)
        k = np.minimum((rng.uniform(size=(n, 1)) > cum).sum(axis=1), self.weights.shape[1] - 1)
        y = self.means[s, k] + self.stds[s, k] * rng.standard_normal((n, self.dim))
        return np.clip(expit(y), EPS, 1.0 - EPS)

    def log_prob_u(self, u: ArrayLike) -> NDArray[np.float64]:
        """log of the averaged mixture density at u, with the sigmoid Jacobian; -inf outside."""
        from scipy.special import logsumexp

        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        y = logit(u)[:, None, None, :]  # (n, 1, 1, d)
        z = (y - self.means[None]) / self.stds[None]
        comp = (-0.5 * z**2 - np.log(self.stds[None]) - 0.5 * math.log(2 * math.pi)).sum(-1)  # (n, S, K)
        lp_y = logsumexp(comp + np.log(self.weights[None] + 1e-300), axis=(1, 2)) - math.log(len(self.weights))
        jac = (np.log(np.clip(u, EPS, 1)) + np.log(np.clip(1 - u, EPS, 1))).sum(1)
        return np.where(_outside(u), -np.inf, lp_y - jac)

    def to_dict(self) -> dict[str, Any]:
        """Weights, means and stds."""
        return {
            "kind": "gmm_aggregate",
            "weights": self.weights.tolist(),
            "means": self.means.tolist(),
            "stds": self.stds.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GaussianMixtureAggregate:
        """Rebuild from to_dict()."""
        return cls(d["weights"], d["means"], d["stds"])


_KINDS = {"flow": FlowDistribution, "truncnormal": TruncNormalProduct, "gmm_aggregate": GaussianMixtureAggregate}


def distribution_from_dict(d: dict[str, Any]) -> UnitBoxDistribution:
    """Rebuild any distribution from its to_dict(); ValueError for an unknown kind."""
    kind = d.get("kind") if isinstance(d, dict) else None
    if kind not in _KINDS:
        raise ValueError(f"unknown distribution kind {kind!r}; expected one of {sorted(_KINDS)}")
    return _KINDS[kind].from_dict(d)
