"""LSDR: learning the sampling distribution for domain randomization (Mozifian et al., 2019).

p is a Gaussian N(mu, Sigma) over the *normalized* parameters u = (xi - low) / (high - low) (the
unit box), truncated to the unit box when sampling and when reporting densities. Each
`update(xi, returns)` takes K Adam steps on mu and the Cholesky factor L of Sigma (log-parametrized
diagonal; off-diagonal entries too unless `full_covariance=False`) minimizing

    loss = -( mean_i(R_i log N(u_i; mu, Sigma)) - alpha * KL(U || N(mu, Sigma)) )

with R_i the per-batch standardized returns and U the uniform distribution on the unit box, both
terms on the normalized contexts. After each step mu is clamped to the unit box and the Cholesky
diagonal to [min_std, max_std] (unit-box units); steps with a non-finite loss or gradient are
skipped and the update reverts if the parameters end non-finite (both reported in the diagnostics).

Initialization: mu = box centre, Sigma = diag((max - min) / 10) in parameter units, read
literally (GoFlow paper, appendix A.2); `LSDRConfig.init_variance` overrides it (parameter
units^2).

Densities are in parameter units: log_prob(xi) = log N(u; mu, Sigma) - log Z - sum_j log(high_j - low_j)
inside the box, -inf outside, with Z = P_N(u in [0, 1]^d); `entropy()` is the truncated Gaussian's
entropy plus sum_j log(high_j - low_j).

Derivation (the two loss terms, the literal initial covariance, how Z and the entropy are
computed): docs/learning.md#lsdr.

References: Mozifian et al., "Learning Domain Randomization Distributions for Training Robust
Locomotion Policies", 2019; Curtis et al., "Flow-based Domain Randomization for Learning and
Sequencing Robotic Skills", ICML 2025, appendix A.2 (baseline settings).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from scipy import stats
from scipy.linalg import solve_triangular
from scipy.special import log_ndtr, ndtri

from assembly.params import ParamSpace
from assembly.samplers import check_sample_args, check_sampler_args, check_state_dict, check_update_inputs
from goflow_common.checks import check_int, check_number
from goflow_common.config import config_to_dict, config_with_overrides
from learning.samplers.gradient_update import config_from_state, standardize_returns, update_diagnostics

__all__ = ["LSDRConfig", "LSDRSampler"]

_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class LSDRConfig:
    """LSDR update settings (defaults from the released configs: Adam lr 1e-2, 10 iterations)."""

    alpha: float = 1.0  # weight of KL(U || p) (the released configs use 0.5 for Cartpole, 2.0 for Ant)
    lr: float = 1e-2
    steps: int = 10  # K Adam steps per update
    full_covariance: bool = True  # learn the off-diagonal Cholesky entries too
    init_variance: tuple[float, ...] | None = None  # parameter units^2; None: (high - low) / 10 (A.2)
    min_std: float = 1e-3  # bounds on the Cholesky diagonal, unit-box units
    max_std: float = 10.0
    entropy_samples: int = 16_384  # quasi Monte Carlo points for the entropy of a non-diagonal Sigma
    max_draw_rounds: int = 100  # rejection rounds in `sample` before giving up
    seed: int = 0  # fixed seed of the quadrature / quasi Monte Carlo (determinism)

    def __post_init__(self) -> None:
        object.__setattr__(self, "alpha", check_number(self.alpha, "LSDRConfig.alpha", 0.0))
        for name in ("steps", "entropy_samples", "max_draw_rounds"):
            check_int(getattr(self, name), f"LSDRConfig.{name}", 1)
        for name in ("lr", "min_std", "max_std"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"LSDRConfig.{name} must be a finite positive number, got {value!r}")
        if not self.min_std < self.max_std:
            raise ValueError(f"LSDRConfig: need min_std < max_std, got {self.min_std} and {self.max_std}")
        if self.init_variance is not None:
            iv = tuple(float(v) for v in self.init_variance)
            if any(not math.isfinite(v) or v <= 0 for v in iv):
                raise ValueError(f"LSDRConfig.init_variance must be finite and positive, got {self.init_variance!r}")
            object.__setattr__(self, "init_variance", iv)
        check_int(self.seed, "LSDRConfig.seed", 0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable fields."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LSDRConfig:
        """Inverse of `to_dict` (unknown keys raise UnknownOptionError, a ValueError)."""
        return config_with_overrides(cls, d)


def kl_uniform_gaussian(mu: torch.Tensor, chol: torch.Tensor) -> torch.Tensor:
    """KL(U([0, 1]^d) || N(mu, L L^T)) in closed form (differentiable)."""
    d = mu.shape[0]
    eye = torch.eye(d, dtype=mu.dtype)
    linv = torch.linalg.solve_triangular(chol, eye, upper=False)
    prec = linv.T @ linv
    delta = 0.5 - mu
    quad = torch.trace(prec) / 12.0 + delta @ prec @ delta
    return 0.5 * d * _LOG_2PI + torch.log(torch.diagonal(chol)).sum() + 0.5 * quad


def _gauss_logpdf(u: torch.Tensor, mu: torch.Tensor, chol: torch.Tensor) -> torch.Tensor:
    """log N(u; mu, L L^T) for rows of u (differentiable)."""
    z = torch.linalg.solve_triangular(chol, (u - mu).T, upper=False)  # (d, n)
    d = mu.shape[0]
    return -0.5 * (z**2).sum(0) - torch.log(torch.diagonal(chol)).sum() - 0.5 * d * _LOG_2PI


class LSDRSampler:
    """LSDR on the Sampler protocol: a box-truncated Gaussian over the normalized parameters.

    Arguments:
        space: the parameter box.
        success_threshold: J_T (kept for reference: LSDR learns from the signal it is given).
        config: alpha and update settings: an LSDRConfig, a mapping of its fields, or None
            (defaults); keyword `overrides` are its fields, applied last.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: LSDRConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "LSDRSampler")
        self.space = space
        self.config = config_with_overrides(LSDRConfig, config, overrides, "LSDRSampler")
        self._width = space.high - space.low
        d = space.dim
        if self.config.init_variance is None:
            var_param = self._width / 10.0  # seed appendix A.2: Sigma = diag((max - min) / 10)
        else:
            if len(self.config.init_variance) != d:
                raise ValueError(
                    f"LSDRConfig.init_variance has {len(self.config.init_variance)} entries, space has {d}"
                )
            var_param = np.asarray(self.config.init_variance, dtype=np.float64)
        std_unit = np.sqrt(var_param) / self._width
        self.mu = np.full(d, 0.5)  # unit-box centre
        self.chol = np.diag(np.clip(std_unit, self.config.min_std, self.config.max_std))
        self.n_updates = 0
        self._cache: dict[str, float] = {}

    # -- distribution in unit-box coordinates ------------------------------------------------------

    @property
    def alpha(self) -> float:
        """Weight of KL(U || p) (config.alpha)."""
        return self.config.alpha

    def _is_diagonal(self) -> bool:
        return bool(np.all(np.tril(self.chol, -1) == 0.0))

    def _log_z(self) -> float:
        """log P(N(mu, Sigma) in [0, 1]^d) (cached)."""
        if "log_z" not in self._cache:
            if self._is_diagonal():
                s = np.diag(self.chol)
                a, b = -self.mu / s, (1.0 - self.mu) / s
                # log(Phi(b) - Phi(a)), stable in both tails
                log_mass = np.where(
                    a > 0,
                    log_ndtr(-a) + np.log1p(-np.exp(log_ndtr(-b) - log_ndtr(-a))),
                    log_ndtr(b) + np.log1p(-np.exp(log_ndtr(a) - log_ndtr(b))),
                )
                value = float(np.sum(log_mass))
            else:
                mass = stats.multivariate_normal.cdf(
                    np.ones(self.space.dim),
                    mean=self.mu,
                    cov=self.chol @ self.chol.T,
                    lower_limit=np.zeros(self.space.dim),
                    abseps=1e-7,
                    releps=1e-6,
                    rng=self.config.seed,
                )
                value = math.log(mass) if mass > 0 else -math.inf
            self._cache["log_z"] = value
        return self._cache["log_z"]

    def truncation_mass(self) -> float:
        """Z: the Gaussian's mass inside the box (1 - the rejection rate of `sample`)."""
        return math.exp(self._log_z())

    def mean(self) -> NDArray[np.float64]:
        """The (untruncated) Gaussian's mean in parameter units, shape (d,)."""
        return self.space.low + self.mu * self._width

    def covariance(self) -> NDArray[np.float64]:
        """The (untruncated) Gaussian's covariance in parameter units^2, shape (d, d)."""
        sigma_u = self.chol @ self.chol.T
        return sigma_u * np.outer(self._width, self._width)

    # -- protocol --------------------------------------------------------------------------------

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws of the Gaussian truncated to the box (redrawn until inside), shape (n, d), parameter units."""
        n = check_sample_args(n, rng)
        d = self.space.dim
        if n == 0:
            return np.zeros((0, d))
        z_mass = self.truncation_mass()
        if not z_mass > 1e-9:
            raise RuntimeError(
                f"LSDRSampler: the Gaussian has left the box (mass inside {z_mass:.3g}); cannot sample. "
                f"mean={self.mean().tolist()}, std={np.sqrt(np.diag(self.covariance())).tolist()}"
            )
        out: list[NDArray[np.float64]] = []
        need = n
        for _ in range(self.config.max_draw_rounds):
            m = min(int(math.ceil(1.2 * need / z_mass)) + 16, 4_000_000)
            u = self.mu + rng.standard_normal((m, d)) @ self.chol.T
            u = u[np.all((u >= 0.0) & (u <= 1.0), axis=1)][:need]
            out.append(u)
            need -= len(u)
            if need == 0:
                return self.space.low + np.concatenate(out) * self._width
        raise RuntimeError(
            f"LSDRSampler: only {n - need} of {n} draws landed in the box after {self.config.max_draw_rounds} rounds "
            f"(mass inside {z_mass:.3g})"
        )

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density of the box-truncated Gaussian (parameter units, normalized); -inf outside."""
        batch = self.space.as_batch(xi)
        out = np.full(len(batch), -math.inf)
        inside = np.asarray(self.space.contains(batch), dtype=bool)
        if inside.any():
            u = (batch[inside] - self.space.low) / self._width
            z = solve_triangular(self.chol, (u - self.mu).T, lower=True)
            log_n = -0.5 * np.sum(z**2, axis=0) - np.sum(np.log(np.diag(self.chol))) - 0.5 * self.space.dim * _LOG_2PI
            out[inside] = log_n - self._log_z() - float(np.sum(np.log(self._width)))
        return out

    def entropy(self) -> float:
        """Entropy (nats, parameter units) of the box-truncated Gaussian; see docs/learning.md#lsdr."""
        if "entropy" not in self._cache:
            d = self.space.dim
            if self._is_diagonal():
                s = np.diag(self.chol)
                h_unit = float(
                    sum(stats.truncnorm(-m / si, (1 - m) / si, loc=m, scale=si).entropy() for m, si in zip(self.mu, s))
                )
            else:
                sobol = stats.qmc.Sobol(d, scramble=True, rng=self.config.seed)
                q = sobol.random_base2(max(int(math.ceil(math.log2(self.config.entropy_samples))), 1))
                z = ndtri(np.clip(q, 1e-12, 1 - 1e-12))
                u = self.mu + z @ self.chol.T
                inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
                mahal = float(np.mean(np.sum(z[inside] ** 2, axis=1))) if inside.sum() >= 32 else float(d)
                h_unit = self._log_z() + 0.5 * d * _LOG_2PI + float(np.sum(np.log(np.diag(self.chol)))) + 0.5 * mahal
            self._cache["entropy"] = h_unit + float(np.sum(np.log(self._width)))
        return self._cache["entropy"]

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """K Adam steps on the LSDR loss for this batch; returns diagnostics."""
        xi_arr, ret = check_update_inputs(self.space, xi, returns)
        t0 = time.perf_counter()
        cfg = self.config
        u = torch.as_tensor((xi_arr - self.space.low) / self._width, dtype=torch.float64)
        w_np, has_signal = standardize_returns(ret)
        w = torch.as_tensor(w_np, dtype=torch.float64)
        backup = (self.mu.copy(), self.chol.copy())

        mu = torch.tensor(self.mu, dtype=torch.float64, requires_grad=True)
        log_diag = torch.tensor(np.log(np.diag(self.chol)), dtype=torch.float64, requires_grad=True)
        off = torch.tensor(np.tril(self.chol, -1), dtype=torch.float64, requires_grad=cfg.full_covariance)
        params = [mu, log_diag] + ([off] if cfg.full_covariance else [])
        optimizer = torch.optim.Adam(params, lr=cfg.lr)  # fresh each update
        lo, hi = math.log(cfg.min_std), math.log(cfg.max_std)

        def build() -> torch.Tensor:
            return torch.tril(off, -1) + torch.diag(torch.exp(log_diag))

        skipped = 0
        first: dict[str, float] | None = None
        last: dict[str, float] = {}
        for _ in range(cfg.steps):
            chol = build()
            loglik = (w * _gauss_logpdf(u, mu, chol)).mean()
            kl = kl_uniform_gaussian(mu, chol)
            loss = -(loglik - self.alpha * kl)
            if not bool(torch.isfinite(loss)):
                skipped += 1
                continue
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if not all(bool(torch.isfinite(p.grad).all()) for p in params if p.grad is not None):
                skipped += 1
                continue
            optimizer.step()
            with torch.no_grad():
                mu.clamp_(0.0, 1.0)
                log_diag.clamp_(lo, hi)
            last = {
                "loss": float(loss.detach()),
                "weighted_loglik": float(loglik.detach()),
                "kl_uniform": float(kl.detach()),
            }
            if first is None:
                first = dict(last)

        with torch.no_grad():
            new_mu, new_chol = mu.detach().numpy().copy(), build().detach().numpy().copy()
        reverted = not (np.all(np.isfinite(new_mu)) and np.all(np.isfinite(new_chol)))
        self.mu, self.chol = backup if reverted else (new_mu, new_chol)
        self._cache = {}
        self.n_updates += 1

        with torch.no_grad():
            kl_now = float(kl_uniform_gaussian(torch.as_tensor(self.mu), torch.as_tensor(self.chol)))
        return update_diagnostics(
            ret,
            self.entropy(),
            first=first,
            last=last,
            steps=cfg.steps,
            skipped=skipped,
            reverted=reverted,
            has_signal=has_signal,
            update_index=self.n_updates,
            t0=t0,
            weighted_loglik=last.get("weighted_loglik", math.nan),
            kl_uniform=kl_now,
            truncation_mass=self.truncation_mass(),
            mean=self.mean().tolist(),
            std=np.sqrt(np.diag(self.covariance())).tolist(),
        )

    # -- checkpoints -----------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable: type, space, config (alpha included), update count, mu and L (unit-box
        coordinates)."""
        return {
            "type": type(self).__name__,
            "space": self.space.to_dict(),
            "config": self.config.to_dict(),
            "n_updates": self.n_updates,
            "mu": self.mu.tolist(),
            "chol": self.chol.tolist(),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore mu, L, alpha, config and the update count; ValueError on another type/space or bad values."""
        check_state_dict(self.space, state, type(self).__name__)
        d = self.space.dim
        try:
            mu = np.asarray(state["mu"], dtype=np.float64)
            chol = np.asarray(state["chol"], dtype=np.float64)
            config = LSDRConfig.from_dict(config_from_state(state))
            n_updates = int(state["n_updates"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"load_state_dict: malformed LSDRSampler state_dict ({exc!r})") from exc
        if mu.shape != (d,) or chol.shape != (d, d):
            raise ValueError(f"load_state_dict: mu {mu.shape} / chol {chol.shape} do not fit a {d}-D space")
        if (
            not (np.all(np.isfinite(mu)) and np.all(np.isfinite(chol)))
            or np.any(np.triu(chol, 1) != 0)
            or np.any(np.diag(chol) <= 0)
        ):
            raise ValueError(
                "load_state_dict: chol must be finite lower-triangular with a positive diagonal, mu finite"
            )
        self.mu, self.chol, self.config, self.n_updates = mu, chol, config, n_updates
        self._cache = {}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> LSDRSampler:
        """Build a sampler from a `state_dict` alone."""
        sampler = cls(ParamSpace.from_dict(state["space"]), None, config_from_state(state))
        sampler.load_state_dict(state)
        return sampler

    def __repr__(self) -> str:
        return (
            f"LSDRSampler(alpha={self.alpha}, mean={self.mean().tolist()}, "
            f"std={np.sqrt(np.diag(self.covariance())).tolist()}, space={self.space})"
        )
