"""GoFlow: flow-based maximum-entropy domain randomization (Curtis et al., ICML 2025).

The sampler is a neural spline flow (zuko NSF: 3 autoregressive transforms, hidden (64, 64), 8
bins) over the parameter box, mapped affinely to zuko's spline domain [-5, 5]^d ("box coordinates"
below). Each `update(xi, returns)` takes K Adam steps (lr 1e-3, K = 100) on

    loss = -(1/B) sum_i log q(y_i) R_i  -  alpha * H_hat(q)  +  beta * KL_hat(q_old || q)

where y_i are the batch's parameters in box coordinates, R_i the per-batch standardized returns
(`standardize_returns`), H_hat = -vol * E_{u ~ U(box)}[q(u) log q(u)] the entropy over the box
estimated with fresh uniform samples at every step, and KL_hat the KL from the flow as it was at
the start of the update, estimated with samples of that frozen flow. Steps with a non-finite loss
or gradient are skipped, gradients are clipped at norm 1, and the flow reverts to its pre-update
parameters if any parameter ends non-finite (all reported in the returned diagnostics).

Conventions: `sample` draws exactly from the flow truncated to the box; `log_prob` is that
truncated density in parameter units, normalized exactly over the box (-inf outside); `entropy()`
is -E_p[log p] in parameter units from a fixed-seed set of flow draws (deterministic). The flow
starts as the identity on a N(0, 2.5^2) base in box coordinates (broad, close to uniform). An
update depends only on the flow, the batch and (config.seed, update count), so a run resumed from
a `state_dict` reproduces the uninterrupted one.

Derivation (box invariance and exact normalization, the identity initialization and base scale,
the entropy estimators): docs/learning.md#goflow; sample sizes: docs/learning.md, "Departures
from the paper".

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025 (arXiv:2502.01800), and the authors' code github.com/aidan-curtis/goflow;
Durkan et al., "Neural Spline Flows", NeurIPS 2019; zuko (github.com/probabilists/zuko).
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
import zuko
from numpy.typing import ArrayLike, NDArray
from zuko.distributions import DiagNormal
from zuko.lazy import UnconditionalDistribution
from zuko.transforms import MonotonicRQSTransform

from assembly.params import ParamSpace
from assembly.samplers import (
    _diagnostics, check_sample_args, check_sampler_args, check_state_dict, check_update_inputs,
)
from common.checks import check_int, check_number
from common.errors import InputError
from common.config import config_to_dict, config_with_overrides

__all__ = ["GoFlowConfig", "GoFlowSampler", "standardize_returns", "update_diagnostics"]

BOX_BOUND = 5.0  # zuko's spline domain is [-5, 5] (the GoFlow authors' code maps the box onto it)
_BOX_TOL = 1e-4  # float32 rounding slack (box coordinates) before a draw counts as outside
_LOG_Q_FLOOR = -1e4  # clamp for log q in the entropy term: exp underflows to 0 well before this
_CHUNK = 65536  # rows per flow evaluation outside training


class _SplineTransform(MonotonicRQSTransform):
    """zuko's monotonic rational-quadratic spline with the bin softmax written as exp / sum.

    The same function as `MonotonicRQSTransform` (tests compare the two flows' densities): zuko first
    squashes every unconstrained width and height into (-l/2, l/2), l = -log(slope) = 6.9, so exp
    cannot overflow and the max-shift of a general softmax is not needed. torch's CPU softmax over
    8 bins costs 3.5x the plain exp / sum, and with it a d = 3 update takes a third longer.
    """

    def __init__(self, widths: torch.Tensor, heights: torch.Tensor, derivatives: torch.Tensor,
                 bound: float = 5.0, slope: float = 1e-3, **kwargs: Any) -> None:
        torch.distributions.Transform.__init__(self, **kwargs)
        log_slope = math.log(slope)
        widths = torch.exp(widths / (1 + abs(2 * widths / log_slope)))
        heights = torch.exp(heights / (1 + abs(2 * heights / log_slope)))
        derivatives = derivatives / (1 + abs(derivatives / log_slope))
        widths = F.pad(widths / widths.sum(dim=-1, keepdim=True), (1, 0), value=0)
        heights = F.pad(heights / heights.sum(dim=-1, keepdim=True), (1, 0), value=0)
        self.horizontal = bound * (2 * torch.cumsum(widths, dim=-1) - 1)
        self.vertical = bound * (2 * torch.cumsum(heights, dim=-1) - 1)
        self.derivatives = torch.exp(F.pad(derivatives, (1, 1), value=0))


def build_spline_flow(features: int, transforms: int, hidden_features: tuple[int, ...], bins: int) -> zuko.flows.Flow:
    """zuko's NSF (same modules and state_dict keys as `zuko.flows.NSF`) on `_SplineTransform`."""
    return zuko.flows.MAF(features=features, transforms=transforms, hidden_features=hidden_features,
                          univariate=partial(_SplineTransform, slope=1e-3), shapes=[(bins,), (bins,), (bins - 1,)])


def standardize_returns(returns: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """Per-batch standardized returns (mean 0, std 1) and whether they carry any signal.

    All-equal returns (or a single one) give zeros, never NaN. The returns are first divided by
    their largest magnitude so that huge finite values (1e300) cannot overflow the mean or variance.
    """
    r = np.asarray(returns, dtype=np.float64)
    scale = float(np.max(np.abs(r))) if r.size else 0.0
    if r.size < 2 or scale == 0.0:
        return np.zeros_like(r), False
    r = r / scale
    centred = r - r.mean()
    std = float(np.sqrt(np.mean(centred**2)))
    if not math.isfinite(std) or std <= 1e-12:
        return np.zeros_like(r), False
    return centred / std, True


def update_diagnostics(returns: NDArray[np.float64], entropy: float, *, first: dict[str, float] | None,
                       last: dict[str, float], steps: int, skipped: int, reverted: bool, has_signal: bool,
                       update_index: int, t0: float, **extra: Any) -> dict[str, Any]:
    """What a sampler updated by gradient steps reports (GoFlow, LSDR): the protocol's diagnostics,
    the first and last step's loss, the step counts, whether it reverted, and `extra`."""
    diag = _diagnostics(returns, entropy)
    diag.update({"loss": last.get("loss", math.nan), "loss_first": math.nan if first is None else first["loss"],
                 **extra, "steps": steps, "skipped_steps": skipped, "reverted": reverted,
                 "returns_have_signal": has_signal, "update_index": update_index,
                 "time_s": time.perf_counter() - t0})
    return diag


@dataclass(frozen=True)
class GoFlowConfig:
    """GoFlow flow architecture and update settings (defaults: the GoFlow paper and its code)."""

    alpha: float = 1.0  # entropy weight (the seed swept {0.1, 0.5, 1.0, 1.5, 2.0})
    # weight of KL(q_old || q), a trust region to the flow before the update (the authors' released
    # configs use 0.0 for Cartpole/Anymal and 1.0 for Ant)
    beta: float = 1.0
    transforms: int = 3
    hidden_features: tuple[int, ...] = (64, 64)
    bins: int = 8
    base_scale: float = 2.5  # std of the Gaussian base in box coordinates (docs/learning.md#goflow)
    lr: float = 1e-3
    steps: int = 100  # K gradient steps per update
    # The GoFlow authors' code uses ~10k samples for H_hat and KL_hat. On a 2-core CPU that makes
    # one update 16-34 s (d = 2..5), far above the 5 % share of training time the sampler may take.
    # The uniform samples are fresh at every step, so over K = 100 steps H_hat averages 51k points;
    # the KL draws are a fresh subset of a pool of `kl_pool` pre-update draws at every step. 512
    # per step makes an update 3.4x faster than 2048 (1.7 s vs 5.7 s, d = 3, B = 64, one thread:
    # docs/learning.md) and the sampler tests pass unchanged.
    entropy_samples: int = 512  # uniform samples per step for H_hat
    kl_samples: int = 512  # pre-update flow samples per step for KL_hat (a subset of the pool)
    kl_pool: int = 4096  # pre-update flow draws per update, for KL_hat and the reported KL
    report_samples: int = 4096  # fixed-seed flow draws behind entropy()
    grad_clip: float = 1.0
    max_redraws: int = 20  # redraw rounds for draws that left the box before giving up
    seed: int = 0  # flow initialization and the update's internal Monte Carlo draws

    def __post_init__(self) -> None:
        hidden = tuple(self.hidden_features)
        object.__setattr__(self, "hidden_features", hidden)
        for name in ("alpha", "beta"):
            object.__setattr__(self, name, check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0))
        for name in ("transforms", "bins", "steps", "entropy_samples", "kl_samples", "kl_pool", "report_samples",
                     "max_redraws"):
            check_int(getattr(self, name), f"GoFlowConfig.{name}", 1)
        check_int(self.bins, "GoFlowConfig.bins", 2)
        if not hidden:
            raise InputError("GoFlowConfig.hidden_features = (); expected at least one layer size")
        for h in hidden:
            check_int(h, "GoFlowConfig.hidden_features entry", 1)
        for name in ("base_scale", "lr", "grad_clip"):
            check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0, low_open=True)
        check_int(self.seed, "GoFlowConfig.seed", 0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable fields."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GoFlowConfig:
        """Inverse of `to_dict` (unknown keys raise UnknownOptionError, a ValueError)."""
        return config_with_overrides(cls, d)

    # fields that define the flow's parameter shapes and density (must match to load a state)
    ARCHITECTURE = ("transforms", "hidden_features", "bins", "base_scale")


def _tensor_to_json(t: torch.Tensor) -> dict[str, Any]:
    return {"dtype": str(t.dtype).removeprefix("torch."), "shape": list(t.shape), "data": t.flatten().tolist()}


def _tensor_from_json(d: Mapping[str, Any]) -> torch.Tensor:
    dtype = getattr(torch, d["dtype"])
    return torch.tensor(d["data"], dtype=dtype).reshape(d["shape"])


def _config_of(state: Mapping[str, Any]) -> dict[str, Any]:
    """The config dict of a GoFlowSampler or LSDRSampler state, with the weights that older
    states kept beside it (top-level "alpha", "beta") folded in."""
    config = dict(state["config"])
    for key in ("alpha", "beta"):
        if key in state and key not in config:
            config[key] = state[key]
    return config


class GoFlowSampler:
    """Flow-based maximum-entropy DR sampler (GoFlow) on the Sampler protocol.

    Arguments:
        space: the parameter box.
        success_threshold: J_T (kept for reference: GoFlow learns from the signal it is given).
        config: weights (alpha, beta), architecture and update settings: a GoFlowConfig, a mapping
            of its fields, or None (defaults); keyword `overrides` are its fields, applied last.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: GoFlowConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "GoFlowSampler")
        self.space = space
        self.config = config_with_overrides(GoFlowConfig, config, overrides, "GoFlowSampler")
        self.n_updates = 0
        d = space.dim
        self._low = space.low
        self._width = space.high - space.low
        self._centre = space.center()
        self._half_scale = self._width / (2.0 * BOX_BOUND)  # parameter units per box unit
        # log Z: base mass inside [-5, 5]^d, exact and constant (the box is invariant under the flow)
        self._log_z = d * math.log(math.erf(BOX_BOUND / (self.config.base_scale * math.sqrt(2.0))))
        self._log_jac = -float(np.sum(np.log(self._half_scale)))  # log|dy/dxi|
        self._flow = self._build_flow()
        self._entropy_cache: float | None = None

    @property
    def alpha(self) -> float:
        """Entropy weight (config.alpha)."""
        return self.config.alpha

    @property
    def beta(self) -> float:
        """KL trust-region weight (config.beta)."""
        return self.config.beta

    # -- construction ----------------------------------------------------------------------------

    def _build_flow(self) -> zuko.flows.Flow:
        """zuko NSF with identity splines and a N(0, base_scale^2) base, deterministic in config.seed."""
        cfg = self.config
        d = self.space.dim
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            flow = build_spline_flow(d, cfg.transforms, cfg.hidden_features, cfg.bins)
        flow.base = UnconditionalDistribution(
            DiagNormal, torch.zeros(d), torch.full((d,), float(cfg.base_scale)), buffer=True
        )
        with torch.no_grad():
            for t in flow.transform.transforms:
                hyper = getattr(t, "hyper", None)
                if hyper is not None:  # d > 1: zero the conditioner's output layer
                    last = [m for m in hyper.modules() if isinstance(m, torch.nn.Linear)][-1]
                    last.weight.zero_()
                    last.bias.zero_()
                else:  # d = 1: zuko keeps raw, randomly initialized spline parameters
                    for p in t.parameters():
                        p.zero_()
        return flow

    # -- coordinates -----------------------------------------------------------------------------

    def _to_box(self, xi: NDArray[np.float64]) -> NDArray[np.float64]:
        return (xi - self._centre) / self._half_scale

    def _from_box(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._centre + y * self._half_scale

    def _log_q(self, y: torch.Tensor) -> torch.Tensor:
        """Unnormalized flow log density in box coordinates, without gradients, chunked."""
        with torch.no_grad():
            dist = self._flow()
            return torch.cat([dist.log_prob(y[i : i + _CHUNK]) for i in range(0, len(y), _CHUNK)]) if len(y) else y[:, 0]

    def _base_in_box(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """n draws of the base N(0, s^2 I) truncated to [-5, 5]^d (inverse CDF, float64 -> float32)."""
        s = float(self.config.base_scale)
        p_lo = 0.5 * math.erfc(BOX_BOUND / (s * math.sqrt(2.0)))  # Phi(-5 / s)
        u = p_lo + (1.0 - 2.0 * p_lo) * torch.rand((n, self.space.dim), generator=gen, dtype=torch.float64)
        z = s * torch.special.ndtri(u)
        return z.clamp(-BOX_BOUND, BOX_BOUND).to(torch.float32)

    def _draw_box(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """n draws of the flow truncated to the box, in box coordinates (float32, shape (n, d))."""
        out: list[torch.Tensor] = []
        need = n
        rounds = 0
        while need > 0:
            if rounds > self.config.max_redraws:
                raise RuntimeError(
                    f"GoFlowSampler: the flow put no usable mass in the box: {need} of {n} draws still outside after "
                    f"{rounds} rounds (finite parameters: {self._params_finite()}); the flow has left the box"
                )
            rounds += 1
            z = self._base_in_box(need, gen)
            with torch.no_grad():
                transform = self._flow().transform
                y = torch.cat([transform.inv(z[i : i + _CHUNK]) for i in range(0, len(z), _CHUNK)])
            ok = torch.isfinite(y).all(dim=1) & (y.abs() <= BOX_BOUND + _BOX_TOL).all(dim=1)
            y = y[ok].clamp(-BOX_BOUND, BOX_BOUND)
            out.append(y)
            need -= len(y)
        return torch.cat(out) if out else torch.zeros((0, self.space.dim))

    def _params_finite(self) -> bool:
        return all(bool(torch.isfinite(p).all()) for p in self._flow.parameters())

    # -- protocol --------------------------------------------------------------------------------

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws from the flow truncated to the box, shape (n, d), parameter units.

        The torch generator is seeded from `rng` (one integer drawn), so the same numpy rng state
        gives the same samples.
        """
        n = check_sample_args(n, rng)
        gen = torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))
        if n == 0:
            return np.zeros((0, self.space.dim))
        y = self._draw_box(n, gen).to(torch.float64).numpy()
        xi = self._from_box(y)
        return np.clip(xi, self._low, self._low + self._width)

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density (parameter units) of the flow truncated to the box and normalized exactly; -inf outside."""
        batch = self.space.as_batch(xi)
        out = np.full(len(batch), -math.inf)
        inside = np.asarray(self.space.contains(batch), dtype=bool)
        if inside.any():
            y = torch.as_tensor(self._to_box(batch[inside]), dtype=torch.float32)
            lq = self._log_q(y).to(torch.float64).numpy()
            out[inside] = lq - self._log_z + self._log_jac
        return out

    def entropy(self) -> float:
        """Differential entropy estimate (nats, parameter units) of the truncated flow: -E_p[log p].

        Monte Carlo over a fixed-seed set of `report_samples` flow draws (deterministic in the
        parameters; cached until the next update or load).
        """
        if self._entropy_cache is None:
            gen = torch.Generator().manual_seed(int(self.config.seed) + 7_919)
            y = self._draw_box(self.config.report_samples, gen)
            lq = self._log_q(y).to(torch.float64)
            h_box = -float((lq - self._log_z).mean())
            self._entropy_cache = h_box - self._log_jac
        return self._entropy_cache

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """K Adam steps on the GoFlow loss for this batch; returns diagnostics (see module docstring)."""
        xi_arr, ret = check_update_inputs(self.space, xi, returns)
        t0 = time.perf_counter()
        cfg = self.config
        d = self.space.dim
        weights_np, has_signal = standardize_returns(ret)
        weights = torch.as_tensor(weights_np, dtype=torch.float32)
        y_batch = torch.as_tensor(self._to_box(xi_arr), dtype=torch.float32).clamp(-BOX_BOUND, BOX_BOUND)
        seed = int(np.random.SeedSequence([int(cfg.seed), self.n_updates]).generate_state(1, np.uint64)[0]) >> 1
        gen = torch.Generator().manual_seed(seed)

        backup = copy.deepcopy(self._flow.state_dict())
        y_old = self._draw_box(max(cfg.kl_pool, cfg.kl_samples), gen)  # draws of the frozen pre-update flow
        lq_old = self._log_q(y_old)
        n_b, n_u = len(y_batch), cfg.entropy_samples
        vol = (2.0 * BOX_BOUND) ** d
        params = list(self._flow.parameters())
        optimizer = torch.optim.Adam(params, lr=cfg.lr, foreach=True)  # fresh each update (no state across rounds)

        skipped = 0
        first: dict[str, float] | None = None
        last: dict[str, float] = {}
        for _ in range(cfg.steps):
            u = (torch.rand((n_u, d), generator=gen) * 2.0 - 1.0) * BOX_BOUND
            pick = torch.randperm(len(y_old), generator=gen)[: cfg.kl_samples]
            lq = self._flow().log_prob(torch.cat([y_batch, u, y_old[pick]]))
            lq_b, lq_u, lq_o = lq[:n_b], lq[n_b : n_b + n_u], lq[n_b + n_u :]
            reward_term = -(lq_b * weights).mean()
            lq_u = lq_u.clamp(min=_LOG_Q_FLOOR)
            h_hat = -vol * (lq_u.exp() * lq_u).mean()
            kl_hat = (lq_old[pick] - lq_o).mean()
            loss = reward_term - self.alpha * h_hat + self.beta * kl_hat
            if not bool(torch.isfinite(loss)):
                skipped += 1
                continue
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip)
            if not bool(torch.isfinite(grad_norm)):
                skipped += 1
                continue
            optimizer.step()
            last = {
                "loss": float(loss.detach()),
                "reward_term": float(reward_term.detach()),
                "entropy_objective": float(h_hat.detach()),
                "kl_objective": float(kl_hat.detach()),
            }
            if first is None:
                first = dict(last)

        reverted = not self._params_finite()
        if reverted:
            self._flow.load_state_dict(backup)
        self.n_updates += 1
        self._entropy_cache = None
        kl = float((lq_old - self._log_q(y_old)).mean()) if len(y_old) else 0.0

        return update_diagnostics(
            ret, self.entropy(), first=first, last=last, steps=cfg.steps, skipped=skipped, reverted=reverted,
            has_signal=has_signal, update_index=self.n_updates, t0=t0,
            reward_term=last.get("reward_term", math.nan),
            entropy_objective=last.get("entropy_objective", math.nan),
            kl=kl)  # KL(q_old || q_new) on the old flow's samples, after any revert

    # -- checkpoints -----------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable: type, space, config (alpha and beta included), update count and the
        flow's tensors."""
        return {
            "type": type(self).__name__,
            "space": self.space.to_dict(),
            "config": self.config.to_dict(),
            "n_updates": self.n_updates,
            "flow": {k: _tensor_to_json(v) for k, v in self._flow.state_dict().items()},
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the flow and update count (the config, alpha, beta and seed are restored too;
        states that hold alpha and beta beside the config, as older checkpoints do, load as well).

        Raises ValueError for another sampler type, another ParamSpace, or another flow architecture.
        """
        check_state_dict(self.space, state, type(self).__name__)
        try:
            config = GoFlowConfig.from_dict(_config_of(state))
            n_updates = int(state["n_updates"])
            tensors = {k: _tensor_from_json(v) for k, v in state["flow"].items()}
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"load_state_dict: malformed GoFlowSampler state_dict ({exc!r})") from exc
        diffs = [
            f"{name}: {getattr(self.config, name)!r} vs {getattr(config, name)!r}"
            for name in GoFlowConfig.ARCHITECTURE
            if getattr(self.config, name) != getattr(config, name)
        ]
        if diffs:
            raise ValueError("load_state_dict: flow architecture differs (this vs checkpoint): " + "; ".join(diffs))
        if not all(torch.isfinite(t).all() for t in tensors.values() if t.is_floating_point()):
            raise ValueError("load_state_dict: the checkpoint's flow has non-finite parameters")
        try:
            self._flow.load_state_dict(tensors)
        except RuntimeError as exc:
            raise ValueError(f"load_state_dict: flow tensors do not fit this architecture: {exc}") from exc
        self.config, self.n_updates = config, n_updates
        self._entropy_cache = None

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> GoFlowSampler:
        """Build a sampler from a `state_dict` alone."""
        space = ParamSpace.from_dict(state["space"])
        sampler = cls(space, None, _config_of(state))
        sampler.load_state_dict(state)
        return sampler

    def __getstate__(self) -> dict[str, Any]:
        """Pickle through the JSON state (compact and independent of zuko's module internals)."""
        return self.state_dict()

    def __setstate__(self, state: dict[str, Any]) -> None:
        other = type(self).from_state_dict(state)
        self.__dict__.update(other.__dict__)

    def __repr__(self) -> str:
        return f"GoFlowSampler(alpha={self.alpha}, beta={self.beta}, updates={self.n_updates}, space={self.space})"
