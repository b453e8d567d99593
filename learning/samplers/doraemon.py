"""DORAEMON: Domain Randomization via Entropy Maximization (Tiboni et al., ICLR 2024).

The distribution p_phi is a product of independent Beta distributions, one per parameter, each
affinely mapped from [0, 1] onto the parameter's interval [low_i, high_i], starting at
a = b = 100 (a narrow bump at the box centre) as in the official code. Each `update(xi, returns)`
solves, with scipy's trust-constr and analytic gradients,

    max_phi'  H(p_phi')   (equivalently min KL(p_phi' || Uniform(box)) = -H_unit(p_phi'))
    s.t.      KL(p_phi || p_phi') <= eps                                 (trust region)
              J(phi') = (1/N) sum_i w_i * s_i >= alpha                    (success rate)

where s_i = 1[return_i >= J_T] and w_i = p_phi'(xi_i) / q(xi_i) are importance weights with q the
distribution the batch was actually drawn from. By default q is the current p_phi (the batch came
from this sampler, as in the paper); pass `proposal_log_prob` (log q(xi_i) in parameter units) when
it came from elsewhere, or set config proposal="uniform" when every batch comes from the uniform
box (the GoFlow protocol's validation phase). When the estimated success rate is below alpha, the
inverted problem (max J within the same trust region) is solved first. The trust region is never
exceeded (a final backtracking step enforces it exactly). Defaults: eps = 0.05, alpha = 0.5.

Density conventions (assembly/samplers.py): log_prob(xi) = sum_i [log Beta(u_i; a_i, b_i) -
log(high_i - low_i)] with u = normalize(xi), -inf outside the box; entropy = sum_i [H(Beta(a_i, b_i))
+ log(high_i - low_i)] in nats.

Details (the sigmoid parametrization, the inverted problem, the safeguard, the defects of the port
this replaces, the swept settings): docs/learning.md#doraemon.

References: Tiboni et al., "Domain Randomization via Entropy Maximization", ICLR 2024, and the
official code github.com/gabrieletiboni/doraemon (doraemon/doraemon.py); Curtis et al.,
"Flow-based Domain Randomization for Learning and Sequencing Robotic Skills", ICML 2025,
appendix A.2 (swept eps and alpha).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import NonlinearConstraint, minimize
from scipy.special import betaln, digamma, polygamma, xlog1py, xlogy

from assembly.params import ParamSpace
from assembly.samplers import (
    check_sample_args,
    check_sampler_args,
    check_state_dict,
    check_update_inputs,
)
from goflow_common.checks import check_choice, check_int, check_number
from goflow_common.config import config_to_dict, config_with_overrides

__all__ = ["DORAEMONConfig", "DORAEMONSampler", "beta_entropy", "beta_kl"]

# The success-rate constraint is imposed as J >= alpha - _J_SLACK, as in the official code
# ("scipy would still complain if x0 is very close to the boundary").
_J_SLACK = 1e-4
# Samples are clipped this far inside (0, 1) when computing importance weights, so that a sample
# on the box's edge cannot produce log 0 for a Beta with a or b below 1 (a measure-zero event).
_U_EPS = 1e-12


def beta_entropy(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Differential entropy (nats) of Beta(a, b) on [0, 1], elementwise."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return betaln(a, b) - (a - 1) * digamma(a) - (b - 1) * digamma(b) + (a + b - 2) * digamma(a + b)


def beta_kl(a1: ArrayLike, b1: ArrayLike, a2: ArrayLike, b2: ArrayLike) -> NDArray[np.float64]:
    """KL(Beta(a1, b1) || Beta(a2, b2)), elementwise."""
    a1, b1, a2, b2 = (np.asarray(v, dtype=np.float64) for v in (a1, b1, a2, b2))
    return (
        betaln(a2, b2)
        - betaln(a1, b1)
        + (a1 - a2) * digamma(a1)
        + (b1 - b2) * digamma(b1)
        + (a2 - a1 + b2 - b1) * digamma(a1 + b1)
    )


@dataclass(frozen=True)
class DORAEMONConfig:
    """Hyperparameters of DORAEMON (defaults: official code and GoFlow paper appendix A.2)."""

    eps: float = 0.05  # KL trust region, swept over {0.005, 0.01, 0.05, 0.1, 0.5}
    alpha: float = 0.5  # required success rate alpha_D, swept over {0.1, 0.25, 0.5, 0.75, 0.9}
    init_beta: float = 100.0  # a = b at start (official code)
    param_min: float = 0.8  # sigmoid range of a and b (official: 0.8 ...
    param_max: float | None = None  # ... init_beta + 10 when None)
    gtol: float = 1e-4  # trust-constr tolerances (official code)
    xtol: float = 1e-6
    maxiter: int = 300  # trust-constr iterations per problem
    # Where update batches come from when `update` gets no proposal_log_prob: "sampler" (drawn from
    # the current distribution, as in the paper) or "uniform" (uniform on the box, as the GoFlow
    # protocol's validation phase). Using the wrong one biases the success-rate constraint.
    proposal: str = "sampler"

    def __post_init__(self) -> None:
        def num(name: str, lo: float, hi: float | None) -> None:
            object.__setattr__(
                self, name, check_number(getattr(self, name), f"DORAEMONConfig.{name}", lo, hi, low_open=True)
            )

        num("eps", 0.0, math.inf)
        num("alpha", 0.0, 1.0)
        num("init_beta", 0.0, math.inf)
        num("param_min", 0.0, math.inf)
        num("gtol", 0.0, math.inf)
        num("xtol", 0.0, math.inf)
        if self.param_max is None:
            object.__setattr__(self, "param_max", self.init_beta + 10.0)
        num("param_max", 0.0, math.inf)
        if not self.param_min < self.init_beta < self.param_max:
            raise ValueError(
                f"DORAEMON config: need param_min < init_beta < param_max, got "
                f"{self.param_min:g}, {self.init_beta:g}, {self.param_max:g}"
            )
        object.__setattr__(self, "maxiter", check_int(self.maxiter, "DORAEMONConfig.maxiter", 1))
        check_choice(self.proposal, ("sampler", "uniform"), "DORAEMONConfig.proposal")


class _Problem:
    """The functions of one DORAEMON update in the unconstrained variables theta (shape (2d,)).

    theta = [theta_a (d,), theta_b (d,)]; a = lo + (hi - lo) sigmoid(theta_a), same for b.
    Values and gradients are cached on the last theta (trust-constr asks for them separately).
    """

    def __init__(self, lo: float, hi: float, a0: NDArray, b0: NDArray, u: NDArray, log_q_unit: NDArray, succ: NDArray):
        self.lo, self.hi = lo, hi
        self.d = a0.shape[0]
        self.n = u.shape[0]
        assert a0.shape == (self.d,) and b0.shape == (self.d,)
        assert u.shape == (self.n, self.d)
        assert log_q_unit.shape == (self.n,) and succ.shape == (self.n,)
        self.a0, self.b0 = a0, b0
        self.log_u = np.log(u)  # (n, d)
        self.log_1mu = np.log1p(-u)  # (n, d)
        self.log_q = log_q_unit  # log density of the proposal on the unit box, (n,)
        self.succ = succ  # (n,) in {0, 1}
        self._key: bytes | None = None

    def params(self, theta: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """a, b and their derivatives with respect to theta_a, theta_b."""
        theta = np.asarray(theta, dtype=np.float64)
        assert theta.shape == (2 * self.d,)
        s = 0.5 * (1.0 + np.tanh(0.5 * theta))  # numerically safe sigmoid
        p = self.lo + (self.hi - self.lo) * s
        dp = (self.hi - self.lo) * s * (1.0 - s)
        return p[: self.d], p[self.d :], dp[: self.d], dp[self.d :]

    def theta_of(self, a: NDArray, b: NDArray) -> NDArray:
        """Inverse of `params`."""
        p = np.concatenate([a, b])
        s = np.clip((p - self.lo) / (self.hi - self.lo), 1e-12, 1 - 1e-12)
        return np.log(s) - np.log1p(-s)

    def _eval(self, theta: NDArray) -> None:
        key = np.asarray(theta, dtype=np.float64).tobytes()
        if key == self._key:
            return
        a, b, da, db = self.params(theta)
        d, n = self.d, self.n
        # Objective: negative entropy on the unit box, f = -sum_j H(a_j, b_j).
        ent = beta_entropy(a, b)
        dH_da = -(a - 1) * polygamma(1, a) + (a + b - 2) * polygamma(1, a + b)
        dH_db = -(b - 1) * polygamma(1, b) + (a + b - 2) * polygamma(1, a + b)
        self.f = -float(ent.sum())
        self.df = -np.concatenate([dH_da * da, dH_db * db])
        # Trust region: KL(p_old || p_new), analytic; gradient in the new parameters.
        kl = beta_kl(self.a0, self.b0, a, b)
        dkl_da = digamma(a) - digamma(a + b) - digamma(self.a0) + digamma(self.a0 + self.b0)
        dkl_db = digamma(b) - digamma(a + b) - digamma(self.b0) + digamma(self.a0 + self.b0)
        self.kl = float(kl.sum())
        self.dkl = np.concatenate([dkl_da * da, dkl_db * db])
        # Success rate J = mean(w * s), w = p_new(u) / q(u), p_new a product of Betas.
        log_p = (a - 1) * self.log_u + (b - 1) * self.log_1mu - betaln(a, b)  # (n, d)
        assert log_p.shape == (n, d)
        log_w = log_p.sum(axis=1) - self.log_q
        assert log_w.shape == (n,)
        ws = np.exp(log_w) * self.succ
        assert ws.shape == (n,)
        self.J = float(ws.mean())
        # d log p / d a_j = log u_j - psi(a_j) + psi(a_j + b_j): (n, d); weights broadcast on rows.
        glp_a = self.log_u - (digamma(a) - digamma(a + b))[None, :]
        glp_b = self.log_1mu - (digamma(b) - digamma(a + b))[None, :]
        assert glp_a.shape == (n, d) and glp_b.shape == (n, d)
        dJ_da = (ws[:, None] * glp_a).mean(axis=0)
        dJ_db = (ws[:, None] * glp_b).mean(axis=0)
        assert dJ_da.shape == (d,)
        self.dJ = np.concatenate([dJ_da * da, dJ_db * db])
        self.ess = float(ws.sum() ** 2 / max((ws**2).sum(), 1e-300)) if ws.any() else 0.0
        self._key = key

    def fun(self, theta):  # -> (value, grad) of the objective
        self._eval(theta)
        return self.f, self.df

    def kl_fun(self, theta):
        self._eval(theta)
        return self.kl

    def kl_jac(self, theta):
        self._eval(theta)
        return self.dkl[None, :]

    def j_fun(self, theta):
        self._eval(theta)
        return self.J

    def j_jac(self, theta):
        self._eval(theta)
        return self.dJ[None, :]

    def neg_j(self, theta):
        self._eval(theta)
        return -self.J, -self.dJ

    def values(self, theta) -> tuple[float, float, float]:
        """(entropy on the unit box, KL(p_old || p_theta), J(theta))."""
        self._eval(theta)
        return -self.f, self.kl, self.J


class DORAEMONSampler:
    """DORAEMON on a ParamSpace: independent Betas whose entropy grows under a success-rate constraint.

    Args:
        space: the parameter box.
        success_threshold: J_T; an episode succeeds when its undiscounted return >= J_T.
        config: a DORAEMONConfig or a mapping of its fields (None: defaults).
        **overrides: DORAEMONConfig fields as keywords; they take precedence over `config`.

    Attributes: `a`, `b` (Beta parameters, shape (d,)), `config`, `n_updates`.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float,
        config: DORAEMONConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "DORAEMONSampler", required=True)
        self.space = space
        self.config = config_with_overrides(DORAEMONConfig, config, overrides, "DORAEMON")
        d = space.dim
        self.a: NDArray[np.float64] = np.full(d, self.config.init_beta)
        self.b: NDArray[np.float64] = np.full(d, self.config.init_beta)
        self.n_updates = 0

    # -- sampling and density ------------------------------------------------------------------

    @property
    def _width(self) -> NDArray[np.float64]:
        return self.space.high - self.space.low

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n independent draws, shape (n, d), inside the box."""
        n = check_sample_args(n, rng)
        d = self.space.dim
        u = rng.beta(self.a, self.b, size=(n, d))
        xi = np.clip(self.space.low + u * self._width, self.space.low, self.space.high)
        assert xi.shape == (n, d)
        return xi

    def _log_prob_unit(self, u: NDArray) -> NDArray:
        """Sum over dimensions of log Beta(u_j; a_j, b_j) on the unit box, shape (n,)."""
        lp = xlogy(self.a - 1, u) + xlog1py(self.b - 1, -u) - betaln(self.a, self.b)
        assert lp.shape == u.shape
        return lp.sum(axis=1)

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density in parameter units, shape (n,); -inf outside the closed box."""
        batch = self.space.as_batch(xi)
        inside = np.asarray(self.space.contains(batch), dtype=bool)
        u = np.clip(self.space.normalize(batch), 0.0, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lp = self._log_prob_unit(u) - float(np.sum(np.log(self._width)))
        out = np.where(inside, lp, -math.inf)
        assert out.shape == (batch.shape[0],)
        return out

    def entropy(self) -> float:
        """sum_j [H(Beta(a_j, b_j)) + log(high_j - low_j)] in nats."""
        return float(np.sum(beta_entropy(self.a, self.b)) + np.sum(np.log(self._width)))

    def success_rate_estimate(
        self, xi: ArrayLike, returns: ArrayLike, proposal_log_prob: ArrayLike | None = None
    ) -> float:
        """Importance-sampled success rate of *this* distribution from a batch drawn from q.

        mean_i(p(xi_i) / q(xi_i) * 1[return_i >= J_T]); q = this distribution when proposal_log_prob
        is None and config.proposal == "sampler" (the estimate is then the plain success fraction),
        the uniform box when None and config.proposal == "uniform".
        """
        x, ret = check_update_inputs(self.space, xi, returns)
        u, log_q_unit, succ = self._batch(x, ret, proposal_log_prob)
        w = np.exp(self._log_prob_unit(u) - log_q_unit)
        assert w.shape == succ.shape == (x.shape[0],)
        return float(np.mean(w * succ))

    def _batch(self, x: NDArray, ret: NDArray, proposal_log_prob: ArrayLike | None) -> tuple[NDArray, NDArray, NDArray]:
        """Unit-box samples (clipped inside (0,1)), proposal log density on the unit box, successes."""
        n, d = x.shape
        u = np.clip(self.space.normalize(x), _U_EPS, 1.0 - _U_EPS)
        assert u.shape == (n, d)
        log_vol = float(np.sum(np.log(self._width)))
        if proposal_log_prob is None and self.config.proposal == "uniform":
            log_q_unit = np.zeros(n)  # the uniform density on the unit box
        elif proposal_log_prob is None:
            log_q_unit = self._log_prob_unit(u)
        else:
            lq = np.asarray(proposal_log_prob, dtype=np.float64)
            if lq.shape != (n,):
                raise ValueError(
                    f"update: proposal_log_prob has shape {lq.shape}, expected ({n},): one log density per row of xi"
                )
            log_q_unit = lq + log_vol  # parameter units -> unit box
        if not np.all(np.isfinite(log_q_unit)):
            bad = int(np.flatnonzero(~np.isfinite(log_q_unit))[0])
            raise ValueError(
                f"update: the proposal's log density is not finite at row {bad} ({log_q_unit[bad] - log_vol}); "
                "samples must come from a distribution with positive, finite density there"
            )
        succ = (ret >= self.success_threshold).astype(np.float64)
        assert log_q_unit.shape == (n,) and succ.shape == (n,)
        return u, log_q_unit, succ

    # -- learning ------------------------------------------------------------------------------

    def update(
        self, xi: ArrayLike, returns: ArrayLike, *, proposal_log_prob: ArrayLike | None = None
    ) -> dict[str, Any]:
        """One DORAEMON step from episodes at xi (n, d) with returns (n,).

        proposal_log_prob: log density (parameter units) of the distribution xi was drawn from,
        shape (n,); None means config.proposal: this sampler's current distribution ("sampler",
        the default) or the uniform box ("uniform").

        Returns diagnostics: n, mean_return, entropy, success_rate (IS estimate under the old
        distribution), est_success_rate (IS estimate under the new one), kl_step, status
        ("feasible", "inverted+feasible", "inverted_only", "no_success", "kept_old"), ess (effective
        sample size of the weighted successes under the new distribution), a, b.
        """
        x, ret = check_update_inputs(self.space, xi, returns)
        n = x.shape[0]
        u, log_q_unit, succ = self._batch(x, ret, proposal_log_prob)
        c = self.config
        prob = _Problem(c.param_min, c.param_max, self.a.copy(), self.b.copy(), u, log_q_unit, succ)
        theta0 = prob.theta_of(self.a, self.b)
        _, _, j_old = prob.values(theta0)
        opts = {"gtol": c.gtol, "xtol": c.xtol, "maxiter": c.maxiter}
        status = "feasible"
        theta_start = theta0
        if not succ.any():
            # J(p') = 0 for every p': nothing to learn from this batch.
            status = "no_success"
            theta_new = theta0
        else:
            if j_old < c.alpha:
                # Inverted problem: max J s.t. KL(p || p') <= eps (slightly inside, as the official code).
                kl_con = NonlinearConstraint(prob.kl_fun, -np.inf, c.eps - 1e-5, jac=prob.kl_jac, keep_feasible=True)
                res = self._minimize(prob.neg_j, theta0, [kl_con], opts)
                theta_inv = self._safeguard(prob, theta0, res.x, j_floor=None)
                _, _, j_inv = prob.values(theta_inv)
                if j_inv >= c.alpha:
                    status = "inverted+feasible"
                    theta_start = theta_inv
                else:
                    status = "inverted_only"
                    theta_new = theta_inv if j_inv > j_old else theta0
            if status in ("feasible", "inverted+feasible"):
                cons = [
                    NonlinearConstraint(prob.kl_fun, -np.inf, c.eps, jac=prob.kl_jac),
                    NonlinearConstraint(prob.j_fun, c.alpha - _J_SLACK, np.inf, jac=prob.j_jac),
                ]
                res = self._minimize(prob.fun, theta_start, cons, opts)
                f_start = prob.fun(theta_start)[0]
                f_new, kl_new, j_new = prob.fun(res.x)[0], prob.kl_fun(res.x), prob.j_fun(res.x)
                ok = kl_new <= c.eps * (1 + 1e-3) and j_new >= c.alpha - 2 * _J_SLACK and f_new <= f_start
                if res.success or ok:
                    theta_new = self._safeguard(prob, theta_start, res.x, j_floor=c.alpha - _J_SLACK)
                else:
                    status = "kept_old" if status == "feasible" else "inverted+feasible"
                    theta_new = theta_start
        _, kl_step, j_new = prob.values(theta_new)
        if np.array_equal(theta_new, theta0):  # unchanged: avoid the sigmoid round trip's rounding
            a_new, b_new, kl_step, j_new = self.a.copy(), self.b.copy(), 0.0, j_old
        else:
            a_new, b_new, _, _ = prob.params(theta_new)
        ess = prob.ess
        assert a_new.shape == b_new.shape == self.a.shape
        if not (np.all(np.isfinite(a_new)) and np.all(np.isfinite(b_new))):  # pragma: no cover - defensive
            a_new, b_new, kl_step, j_new, status = self.a.copy(), self.b.copy(), 0.0, j_old, "kept_old"
        self.a, self.b = np.asarray(a_new, dtype=np.float64), np.asarray(b_new, dtype=np.float64)
        self.n_updates += 1
        return {
            "n": int(n),
            "mean_return": float(ret.mean()),
            "entropy": self.entropy(),
            "success_rate": float(j_old),
            "est_success_rate": float(j_new),
            "kl_step": float(kl_step),
            "status": status,
            "ess": float(ess),
            "a": self.a.tolist(),
            "b": self.b.tolist(),
        }

    @staticmethod
    def _minimize(fun, theta0, constraints, opts):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # trust-constr warns about delta_grad == 0 with BFGS
            return minimize(fun, theta0, method="trust-constr", jac=True, constraints=constraints, options=opts)

    def _safeguard(self, prob: _Problem, theta_from: NDArray, theta_to: NDArray, j_floor: float | None) -> NDArray:
        """Backtrack from theta_to towards theta_from until KL(p_old || p) <= eps (and J >= j_floor)."""
        eps = self.config.eps
        theta_to = np.asarray(theta_to, dtype=np.float64)
        if not np.all(np.isfinite(theta_to)):
            return theta_from
        for k in range(60):
            t = 0.5**k if k else 1.0
            theta = theta_from + t * (theta_to - theta_from)
            _, kl, j = prob.values(theta)
            if kl <= eps and (j_floor is None or j >= j_floor):
                return theta
        return theta_from

    # -- checkpoints ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable state: type, space, threshold, config, Beta parameters, update count."""
        return {
            "type": type(self).__name__,
            "space": self.space.to_dict(),
            "success_threshold": self.success_threshold,
            "config": config_to_dict(self.config),
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "n_updates": self.n_updates,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from `state_dict`; ValueError on another type, another ParamSpace or bad contents."""
        check_state_dict(self.space, state, type(self).__name__)
        try:
            restored = DORAEMONSampler(self.space, state["success_threshold"], state["config"])
            a = np.asarray(state["a"], dtype=np.float64)
            b = np.asarray(state["b"], dtype=np.float64)
            n_updates = int(state["n_updates"])
        except (KeyError, TypeError) as exc:
            raise ValueError(f"load_state_dict: malformed DORAEMONSampler state_dict ({exc!r})") from exc
        d = self.space.dim
        if a.shape != (d,) or b.shape != (d,):
            raise ValueError(f"load_state_dict: Beta parameters have shapes {a.shape}, {b.shape}, expected ({d},)")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(a > 0) and np.all(b > 0)):
            raise ValueError(
                f"load_state_dict: Beta parameters must be finite and positive, got a={a.tolist()}, b={b.tolist()}"
            )
        restored.a, restored.b, restored.n_updates = a, b, n_updates
        self.__dict__.update(restored.__dict__)

    def __repr__(self) -> str:
        """Class, Beta parameters and hyperparameters."""
        ab = ", ".join(f"{n}~Beta({a:.3g}, {b:.3g})" for n, a, b in zip(self.space.names, self.a, self.b))
        return f"DORAEMONSampler({ab}; eps={self.config.eps:g}, alpha={self.config.alpha:g})"
