"""GoFlow: flow-based maximum-entropy domain randomization (Curtis et al., ICML 2025).

The sampler is a neural spline flow (zuko NSF: 3 autoregressive transforms, hidden (64, 64), 8
bins) over the parameter box, mapped affinely to zuko's spline domain [-5, 5]^d ("box coordinates"
below). `update(xi, signal)` takes K guarded Adam steps (lr 1e-3, K = 100) towards the optimum of
the objective that `config.mode` names:

- "entropy": max E_p[r] + alpha H(p) over the box, r the signal scaled onto [0, 1]
  (`signal_range`, default the range seen so far). Optimum p*(xi) ~ exp(r(xi) / alpha).
- "constrained": max H(p) subject to E_p[success] >= 1 - delta, for 0/1 success signals. Optimum
  (1 - delta) x uniform on the feasible set + delta x uniform on the rest of the box.
- "paper": the authors' update, loss -(1/B) sum_i log q(y_i) R_i - alpha H_hat + beta KL_hat on the
  batch alone, R_i the batch-standardized returns (`standardize_returns`), H_hat the entropy from
  fresh uniform samples. It weights log q by returns whatever distribution drew the batch, pushes
  failures' density down without bound, and forgets earlier batches: it does not reach the optimum
  of its own objective (docs/learning.md#goflow-modes).

The entropy and constrained modes keep the newest `memory` evaluated rows (`Evidence`) and estimate
the signal anywhere as a k-nearest-neighbour mean, which does not depend on which protocol drew the
rows. The constrained mode estimates its feasible set F-hat = {P(success) >= level} with a success
classifier fitted to the rows, each weighted as a uniform design would count it
(`learning.samplers.feasibility`; or the k-NN vote, `feasible_model="knn"`), and by default
samples the flow truncated to F-hat with mass 1 - delta plus delta uniform on the rest of the box
(`truncate`): the sampler's edge is then F-hat's, not the flow's rounded one; `floor` (0.2) draws
that share of the mass in F-hat uniformly on F-hat, a floor under the flow's density there. The level starts at
`feasible_level` and follows the constraint by dual ascent: each batch, before it joins the
evidence, is a held-out test of F-hat, and the level rises while more than `leak_target` of the
sampler's mass in F-hat fails and falls while less does.

Each update draws a proposal (uniform on the box, the current flow, and Gaussians around the rows
that succeeded) with its exact mixture density, weights the draws by target / proposal
(self-normalized), and fits the flow by maximum likelihood on draws resampled by those weights:
a forward KL(p* || q) fit, which covers every component of the target instead of collapsing onto
one. `beta` > 0 adds KL(q_old || q) on the old flow's draws as a trust region (default 0).

Steps with a non-finite loss or gradient are skipped, gradients are clipped at norm 1, and the flow
reverts to its pre-update parameters if any parameter ends non-finite (all reported in the
returned diagnostics).

Conventions: `sample` draws exactly from the flow truncated to the box (with `truncate`, from the
mixture above: flow draws in F-hat by rejection, uniform ones outside); `log_prob` is that
density in parameter units, normalized over the box (-inf outside; with `truncate` the flow's
mass in F-hat is a fixed-seed Monte Carlo estimate from 16384 draws, refreshed at each update and
load); `entropy()` is -E_p[log p] in parameter units from a fixed-seed set of the sampler's draws
(deterministic). The flow
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
from collections.abc import Callable, Mapping
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
from goflow_common.checks import check_choice, check_int, check_number
from goflow_common.errors import InputError
from goflow_common.config import config_to_dict, config_with_overrides
from learning.samplers.evidence import Evidence
from learning.samplers.feasibility import SuccessClassifier

__all__ = ["FEASIBLE_MODELS", "MODES", "GoFlowConfig", "GoFlowSampler", "classifier_width", "standardize_returns",
           "update_diagnostics"]

#: What an update optimizes (GoFlowConfig.mode).
MODES: tuple[str, ...] = ("entropy", "constrained", "paper")
#: How the constrained mode estimates the feasible set (GoFlowConfig.feasible_model).
FEASIBLE_MODELS: tuple[str, ...] = ("classifier", "knn")

BOX_BOUND = 5.0  # zuko's spline domain is [-5, 5] (the GoFlow authors' code maps the box onto it)
_BOX_TOL = 1e-4  # float32 rounding slack (box coordinates) before a draw counts as outside
_LOG_Q_FLOOR = -1e4  # clamp for log q in the entropy term: exp underflows to 0 well before this
_CHUNK = 65536  # rows per flow evaluation outside training
_GATE_DRAWS = 16384  # fixed-seed draws behind the truncation's two shares (flow mass in F-hat, box share outside)
_GATE_MIN_ACCEPT = 0.01  # below this flow mass in F-hat the flow is not truncated (rejection would stall)
_GATE_SEED = 15_485_863
_FLOOR_MIN_RATE = 1e-6  # the floor's uniform draws in F-hat: rounds sized for F-hat's own share down to this
_MIX_ITERATIONS = 50  # EM iterations for a batch's share of the sampler's own draws
_LEVEL_MAX_STEP = 0.25  # the most one update moves F-hat's level, in logits
_LEVEL_LOGIT = (-6.0, 8.0)  # the range of F-hat's level under dual ascent, in logits (0.0025 to 0.9997)


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
    # configs use 0.0 for Cartpole/Anymal and 1.0 for Ant; the entropy and constrained modes fit a
    # target that changes only as evidence accumulates, and need none)
    beta: float = 0.0
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
    # What an update optimizes (docs/learning.md#goflow-modes):
    #   "entropy": E_p[r] + alpha H(p) over the box, r the signal scaled to [0, 1]; optimum p* ~ exp(r / alpha);
    #   "constrained": max H(p) subject to E_p[success] >= 1 - delta (0/1 signals); optimum (1 - delta) x
    #       uniform on the feasible set + delta x uniform on the rest of the box;
    #   "paper": the GoFlow paper's update (batch-standardized returns as weights of log p on the batch).
    mode: str = "entropy"
    delta: float = 0.002  # constrained mode: the mass allowed outside the feasible set, in (0, 1)
    signal_range: tuple[float, float] | None = None  # (lo, hi) scaled onto [0, 1]; None: the range seen so far
    memory: int = 16384  # evaluated rows kept as evidence (entropy and constrained modes)
    # rows kept beyond `memory` because they lay on the edge between the classes (scaled signal >= 0.5
    # or not) when they left the window: a row of the other class among their `neighbours` nearest
    # (Evidence; docs/learning.md, "Boundary rows"); 0: none
    boundary_memory: int = 0
    neighbours: int = 5  # k of the nearest-neighbour signal estimate
    outside_weight: float = 1.0  # constrained mode: weight of the flow's excess density outside the feasible set
    # constrained mode: estimated success probability from which a point counts as feasible (the
    # classifier's even-odds contour; the k-NN vote of 5 rows erodes less at 0.8, its old default)
    feasible_level: float = 0.5
    # constrained mode: the level follows the constraint by dual ascent (docs/learning.md#goflow-modes).
    # Each update first scores the current F-hat on the new batch, rows it has not been fitted to: every
    # held-out row in F-hat moves the level's logit by level_step x (failed - leak_target), so the level
    # settles where the share of F-hat's rows that fail is leak_target; level_step 0 keeps feasible_level.
    leak_target: float = 0.004
    level_step: float = 0.2
    # constrained mode: how the feasible set F-hat is estimated from the evidence, "knn" (the
    # k-nearest-neighbour vote) or "classifier" (an MLP fitted to the rows, learning.samplers.feasibility)
    feasible_model: str = "classifier"
    classifier_steps: int = 100  # Adam steps of the classifier per update (it continues from the last fit)
    # the classifier's layer sizes; None: `classifier_width(d)`, (64, 64) up to 4 parameters and
    # (128, 128) from 5 (measured on the 6-D ellipsoid, docs/learning.md#goflow-modes)
    classifier_hidden: tuple[int, ...] | None = None
    # constrained mode: the sampler is the flow truncated to F-hat with mass 1 - delta, plus delta
    # uniform on the rest of the box (docs/learning.md#goflow-modes); False: the flow alone
    truncate: bool = True
    # constrained mode, truncated: the share of the mass in F-hat drawn uniformly on F-hat, a floor
    # under the flow's density there (0: the flow alone shapes it; docs/learning.md#goflow-modes)
    floor: float = 0.2
    proposal_samples: int = 2048  # per proposal component (uniform, the flow, around successes) per update
    fit_batch: int = 512  # points resampled from the weighted proposal at each of the K steps

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_features", _layer_sizes(self.hidden_features, "GoFlowConfig.hidden_features"))
        for name in ("alpha", "beta"):
            object.__setattr__(self, name, check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0))
        for name in ("transforms", "bins", "steps", "entropy_samples", "kl_samples", "kl_pool", "report_samples",
                     "max_redraws"):
            check_int(getattr(self, name), f"GoFlowConfig.{name}", 1)
        check_int(self.bins, "GoFlowConfig.bins", 2)
        for name in ("base_scale", "lr", "grad_clip"):
            check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0, low_open=True)
        check_int(self.seed, "GoFlowConfig.seed", 0)
        check_choice(self.mode, MODES, "GoFlowConfig.mode")
        check_number(self.delta, "GoFlowConfig.delta", 0.0, 1.0, low_open=True, high_open=True)
        check_number(self.outside_weight, "GoFlowConfig.outside_weight", 0.0)
        check_number(self.feasible_level, "GoFlowConfig.feasible_level", 0.0, 1.0, low_open=True)
        check_number(self.leak_target, "GoFlowConfig.leak_target", 0.0, 1.0, low_open=True, high_open=True)
        check_number(self.level_step, "GoFlowConfig.level_step", 0.0)
        check_choice(self.feasible_model, FEASIBLE_MODELS, "GoFlowConfig.feasible_model")
        check_int(self.classifier_steps, "GoFlowConfig.classifier_steps", 1)
        if self.classifier_hidden is not None:
            object.__setattr__(self, "classifier_hidden",
                               _layer_sizes(self.classifier_hidden, "GoFlowConfig.classifier_hidden"))
        if not isinstance(self.truncate, bool):
            raise InputError(f"GoFlowConfig.truncate = {self.truncate!r}; expected true or false")
        check_number(self.floor, "GoFlowConfig.floor", 0.0, 1.0, high_open=True)
        for name in ("memory", "neighbours", "proposal_samples", "fit_batch"):
            check_int(getattr(self, name), f"GoFlowConfig.{name}", 1)
        check_int(self.boundary_memory, "GoFlowConfig.boundary_memory", 0)
        if self.signal_range is not None:
            pair = tuple(self.signal_range)
            if len(pair) != 2:
                raise InputError(f"GoFlowConfig.signal_range = {self.signal_range!r}; expected (lo, hi) or None")
            lo = check_number(pair[0], "GoFlowConfig.signal_range[0]")
            hi = check_number(pair[1], "GoFlowConfig.signal_range[1]")
            if not hi > lo:
                raise InputError(f"GoFlowConfig.signal_range = {self.signal_range!r}; expected lo < hi")
            object.__setattr__(self, "signal_range", (lo, hi))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable fields."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GoFlowConfig:
        """Inverse of `to_dict` (unknown keys raise UnknownOptionError, a ValueError)."""
        return config_with_overrides(cls, d)

    def classifier_layers(self, dim: int) -> tuple[int, ...]:
        """The success classifier's layer sizes on `dim` parameters: `classifier_hidden`, or
        `classifier_width(dim)` where it is None."""
        return self.classifier_hidden or classifier_width(dim)

    # fields that define the flow's parameter shapes and density (must match to load a state)
    ARCHITECTURE = ("transforms", "hidden_features", "bins", "base_scale")


def _layer_sizes(value: Any, name: str) -> tuple[int, ...]:
    """`value` as a tuple of layer sizes (integers >= 1, at least one), or InputError naming `name`."""
    sizes = tuple(value) if isinstance(value, (list, tuple)) else ()
    if not sizes:
        raise InputError(f"{name} = {value!r}; expected a non-empty list of layer sizes")
    for h in sizes:
        check_int(h, f"{name} entry", 1)
    return sizes


def classifier_width(dim: int) -> tuple[int, int]:
    """The constrained mode's default success-classifier layers for `dim` parameters: (64, 64) up
    to 4, (128, 128) from 5 (the 6-D ellipsoid's recall needs the wider one; docs/learning.md)."""
    return (64, 64) if dim <= 4 else (128, 128)


def _uniform_box(n: int, d: int, gen: torch.Generator) -> torch.Tensor:
    """n uniform draws on the box [-5, 5]^d (float32)."""
    return (torch.rand((n, d), generator=gen) * 2.0 - 1.0) * BOX_BOUND


def _box_to_unit(y: torch.Tensor) -> NDArray[np.float64]:
    """Box coordinates [-5, 5]^d -> the unit box [0, 1]^d of the evidence (float64)."""
    return (y.double().numpy() / BOX_BOUND + 1.0) / 2.0


def _unit_to_box(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit box of the evidence -> box coordinates."""
    return (u * 2.0 - 1.0) * BOX_BOUND


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
    if state.get("type") != "GoFlowSampler":
        return config
    if "mode" not in config:
        config["mode"] = "paper"  # saved before the modes existed: the paper's update made it
    if "feasible_model" not in config:
        # saved before the classifier and the truncation existed: the k-NN vote and the flow alone made it
        config["feasible_model"], config["truncate"] = "knn", False
        config.setdefault("feasible_level", 0.8)  # the k-NN vote's level of that time
    if "level_step" not in config:
        config["level_step"] = 0.0  # saved before the level followed the constraint: a fixed level made it
    if "floor" not in config:
        config["floor"] = 0.0  # saved before the floor existed: the flow alone shaped the mass in F-hat
    if "classifier_hidden" not in config:
        config["classifier_hidden"] = (64, 64)  # saved before the width followed the dimension
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
        self._log_box = d * math.log(2.0 * BOX_BOUND)  # log volume of the box [-5, 5]^d
        self._flow = self._build_flow()
        self._entropy_cache: float | None = None
        self._evidence = Evidence(d, self.config.memory, self.config.neighbours, self.config.signal_range,
                                  self.config.boundary_memory)
        self._classifier = self._make_classifier(self.config)
        # the truncation to F-hat (constrained mode): (log flow mass in F-hat, log box share outside
        # it, log box share inside it for the floor), or None while the sampler is the flow alone
        self._gate: tuple[float, float, float] | None = None
        self._level = self.config.feasible_level  # F-hat's level now (constrained mode; see GoFlowConfig)

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

    def _make_classifier(self, config: GoFlowConfig) -> SuccessClassifier | None:
        """The success classifier behind F-hat (constrained mode with feasible_model "classifier")."""
        if config.mode != "constrained" or config.feasible_model != "classifier":
            return None
        return SuccessClassifier(self.space.dim, config.classifier_layers(self.space.dim), config.seed)

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

    def _feasible_hat(self, y: torch.Tensor) -> torch.Tensor:
        """Whether box-coordinate points lie in the estimated feasible set F-hat (bool, shape (n,))."""
        u = _box_to_unit(y)
        p = self._classifier.probability(u) if self._classifier is not None else self._evidence.estimate(u)
        return torch.as_tensor(p >= self._level)

    def _follow_constraint(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, float]:
        """One dual-ascent step of F-hat's level on a batch F-hat has not been fitted to (constrained
        mode, while the sampler is truncated).

        The batch may be the sampler's own draws, uniform ones, or a mix: its density is estimated
        as pi x the sampler + (1 - pi) x uniform (pi by maximum likelihood), and each row in F-hat
        is weighted by the sampler's density over that estimate, so `leak` estimates the share of
        the sampler's mass in F-hat that fails. The level's logit moves by level_step x n_eff x
        (leak - leak_target), n_eff the weights' effective count. Returns what the step saw."""
        cfg = self.config
        if cfg.level_step == 0 or self._gate is None:  # the gate exists in the constrained mode alone
            return {}
        y = torch.as_tensor(self._to_box(xi_arr), dtype=torch.float32).clamp(-BOX_BOUND, BOX_BOUND)
        inside = self._feasible_hat(y).numpy()
        if not inside.any():
            return {"heldout_in_feasible": 0.0}
        log_ratio = self._log_p_box(y).numpy() + self._log_box  # sampler / uniform
        ratio = np.exp(np.minimum(log_ratio, 700.0))
        pi = 0.5
        for _ in range(_MIX_ITERATIONS):  # EM for the batch's share of sampler draws
            pi = float(np.mean(pi * ratio / (pi * ratio + 1.0 - pi)))
        w = (ratio / (pi * ratio + 1.0 - pi))[inside]
        failed = (ret[inside] < 0.5).astype(np.float64)
        leak = float(np.sum(w * failed) / np.sum(w))
        n_eff = float(np.sum(w) ** 2 / np.sum(w**2))
        logit = math.log(self._level) - math.log1p(-self._level) if self._level < 1.0 else _LEVEL_LOGIT[1]
        step = cfg.level_step * n_eff * (leak - cfg.leak_target)
        logit += min(max(step, -_LEVEL_MAX_STEP), _LEVEL_MAX_STEP)
        logit = min(max(logit, _LEVEL_LOGIT[0]), _LEVEL_LOGIT[1])
        self._level = 1.0 / (1.0 + math.exp(-logit))
        return {"heldout_in_feasible": float(inside.sum()), "heldout_failed": float(failed.sum()),
                "heldout_leak": leak, "heldout_own_share": pi}

    def _refresh_gate(self) -> None:
        """Re-estimate the truncation's shares from fixed-seed draws (deterministic in the flow and
        F-hat); no truncation outside the constrained mode, while F-hat is empty or the whole box,
        or while the flow puts under 1 % of its mass in F-hat."""
        self._gate = None
        if self.config.mode != "constrained" or not self.config.truncate or not len(self._evidence):
            return
        if not np.ptp(self._evidence.signal) > 0:
            return
        gen = torch.Generator().manual_seed(int(self.config.seed) + _GATE_SEED)
        y_flow, y_uniform = self._draw_box(_GATE_DRAWS, gen), _uniform_box(_GATE_DRAWS, self.space.dim, gen)
        in_flow, in_uniform = self._feasible_hat(y_flow), self._feasible_hat(y_uniform)
        accept = float(in_flow.double().mean())
        outside = 1.0 - float(in_uniform.double().mean())
        if accept >= _GATE_MIN_ACCEPT and 0.0 < outside < 1.0:
            share_in = self._log_share_in(y_flow, y_uniform, in_flow, in_uniform)
            self._gate = (math.log(accept), math.log(outside), share_in)

    def _log_share_in(self, y_flow: torch.Tensor, y_uniform: torch.Tensor, in_flow: torch.Tensor,
                      in_uniform: torch.Tensor) -> float:
        """log of F-hat's share of the box, for the floor's uniform density on F-hat: both sets of the
        gate's draws weighted as draws of their half-half mixture (uniform density / mixture density),
        so a small F-hat that the flow fills is measured by the flow's draws, not by the few uniform
        ones that land in it. Without a floor, log(1 - outside share), unused."""
        if self.config.floor == 0.0:
            return 0.0
        y = torch.cat([y_flow, y_uniform])
        inside = torch.cat([in_flow, in_uniform]).numpy()
        log_u = -self._log_box
        log_mix = np.logaddexp((self._log_q(y) - self._log_z).double().numpy(), log_u) - math.log(2.0)
        return float(np.log(np.mean(np.where(inside, np.exp(log_u - log_mix), 0.0))))

    def _log_p_box(self, y: torch.Tensor) -> torch.Tensor:
        """The sampler's log density in box coordinates, normalized over the box (float64): the
        truncated flow, or with the truncation (1 - delta) x the flow in F-hat / its mass there, and
        delta x uniform on the rest of the box."""
        lq = (self._log_q(y) - self._log_z).double()
        if self._gate is None:
            return lq
        log_accept, log_outside, log_share_in = self._gate
        delta, floor, log_box = self.config.delta, self.config.floor, self._log_box
        outside = math.log(delta) - log_outside - log_box
        inside = lq - log_accept
        if floor > 0.0:  # (1 - floor) x the flow in F-hat + floor x uniform on F-hat
            uniform_in = torch.full_like(lq, math.log(floor) - log_share_in - log_box)
            inside = torch.logaddexp(math.log1p(-floor) + inside, uniform_in)
        return torch.where(self._feasible_hat(y), math.log1p(-delta) + inside, torch.full_like(lq, outside))

    def _sample_box(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """n draws of the sampler in box coordinates: the flow truncated to the box, or with the
        truncation a delta share of uniform draws outside F-hat and the rest flow draws in F-hat
        (by rejection), shuffled."""
        if self._gate is None:
            return self._draw_box(n, gen)
        n_out = int((torch.rand(n, generator=gen, dtype=torch.float64) < self.config.delta).sum())
        log_accept, log_outside, log_share_in = self._gate
        n_floor = 0
        if self.config.floor > 0.0:
            n_floor = int((torch.rand(n - n_out, generator=gen, dtype=torch.float64) < self.config.floor).sum())
        inside = self._draw_where(lambda m: self._draw_box(m, gen), True, n - n_out - n_floor, math.exp(log_accept))
        spread = self._draw_where(lambda m: _uniform_box(m, self.space.dim, gen), True, n_floor,
                                  math.exp(log_share_in), min_rate=_FLOOR_MIN_RATE)
        rest = self._draw_where(lambda m: _uniform_box(m, self.space.dim, gen), False, n_out, math.exp(log_outside))
        return torch.cat([inside, spread, rest])[torch.randperm(n, generator=gen)]

    def _draw_where(self, draw: Callable[[int], torch.Tensor], in_hat: bool, n: int, rate: float,
                    min_rate: float = _GATE_MIN_ACCEPT) -> torch.Tensor:
        """n of `draw`'s points that are (in_hat) or are not in F-hat, by rejection at about `rate`
        (each round sized for at least `min_rate`)."""
        if n <= 0:
            return torch.zeros((0, self.space.dim))
        out: list[torch.Tensor] = []
        need = n
        for _ in range(self.config.max_redraws + 1):
            y = draw(min(int(math.ceil(need / max(rate, min_rate) * 1.2)) + 16, 1 << 22))
            out.append(y[self._feasible_hat(y) == in_hat])
            need -= len(out[-1])
            if need <= 0:
                return torch.cat(out)[:n]
        where = "in" if in_hat else "outside"
        raise RuntimeError(f"GoFlowSampler: {need} of {n} draws {where} the estimated feasible set still missing after "
                           f"{self.config.max_redraws + 1} rounds of rejection (expected rate {rate:.3g})")

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
        y = self._sample_box(n, gen).to(torch.float64).numpy()
        xi = self._from_box(y)
        return np.clip(xi, self._low, self._low + self._width)

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density (parameter units) of the flow truncated to the box and normalized exactly; -inf outside."""
        batch = self.space.as_batch(xi)
        out = np.full(len(batch), -math.inf)
        inside = np.asarray(self.space.contains(batch), dtype=bool)
        if inside.any():
            y = torch.as_tensor(self._to_box(batch[inside]), dtype=torch.float32)
            out[inside] = self._log_p_box(y).numpy() + self._log_jac
        return out

    def entropy(self) -> float:
        """Differential entropy estimate (nats, parameter units) of the truncated flow: -E_p[log p].

        Monte Carlo over a fixed-seed set of `report_samples` flow draws (deterministic in the
        parameters; cached until the next update or load).
        """
        if self._entropy_cache is None:
            gen = torch.Generator().manual_seed(int(self.config.seed) + 7_919)
            y = self._sample_box(self.config.report_samples, gen)
            h_box = -float(self._log_p_box(y).mean())
            self._entropy_cache = h_box - self._log_jac
        return self._entropy_cache

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """K Adam steps towards the mode's optimum given this batch (xi, signal); returns diagnostics.

        Raises ValueError for a batch outside the box or a non-finite signal, and InputError for a
        signal outside {0, 1} in constrained mode.
        """
        xi_arr, ret = check_update_inputs(self.space, xi, returns)
        if self.config.mode == "constrained":
            bad = ~np.isin(ret, (0.0, 1.0))
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise InputError(f"update: signal[{i}] = {float(ret[i])!r}; the constrained mode learns from 0/1 successes "
                                 "(give sampler_signal='success')")
        if self.config.mode == "paper":
            return self._paper_update(xi_arr, ret)
        return self._fit_update(xi_arr, ret)

    def _update_generator(self) -> torch.Generator:
        """The update's Monte Carlo generator: a function of (config.seed, update count) only."""
        seed = int(np.random.SeedSequence([int(self.config.seed), self.n_updates]).generate_state(1, np.uint64)[0]) >> 1
        return torch.Generator().manual_seed(seed)

    def _proposal(self, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
        """Draws of the update's proposal in box coordinates with their log densities.

        A fixed-count mixture of three components, `proposal_samples` each: uniform on the box, the
        flow before the update, and Gaussians around the rows whose scaled signal is >= 1/2 (when
        there are any). The log density is the mixture's (the "balance heuristic"), so weights
        target / mixture stay below 3 x target / uniform whatever the flow does. Returns (y, log m,
        the flow's pre-update log q at y, the number of rows that are flow draws, first after the
        uniform ones).
        """
        cfg, d = self.config, self.space.dim
        n = cfg.proposal_samples
        y_u = _uniform_box(n, d, gen)
        y_q = self._draw_box(n, gen)
        parts, n_total = [y_u, y_q], 2 * n
        centres = self._success_centres(gen)
        if len(centres):
            h = self._kernel_width(centres)
            pick = torch.randint(len(centres), (n,), generator=gen)
            y_k = centres[pick] + h * torch.randn((n, d), generator=gen)
            y_k = y_k[(y_k.abs() <= BOX_BOUND).all(dim=1)]  # outside the box the target is 0 anyway
            parts.append(y_k)
            n_total += n
        y = torch.cat(parts)
        lq = self._log_q(y) - self._log_z  # the pre-update flow's density in box coordinates
        terms = [torch.full((len(y),), math.log(n / n_total) - self._log_box), math.log(n / n_total) + lq]
        if len(centres):
            sq = torch.cdist(y.double(), centres.double()).pow(2)
            log_k = torch.logsumexp(-0.5 * sq / h**2, dim=1) - math.log(len(centres)) - d * math.log(h * math.sqrt(2 * math.pi))
            terms.append(math.log(n / n_total) + log_k.float())
        log_m = torch.logsumexp(torch.stack(terms), dim=0)
        return y, log_m, lq, n

    def _success_centres(self, gen: torch.Generator, limit: int = 256) -> torch.Tensor:
        """Up to `limit` rows of the evidence with scaled signal >= 1/2, in box coordinates."""
        ev = self._evidence
        good = np.flatnonzero(ev.scaled_signal() >= 0.5)
        if len(good) > limit:
            good = np.sort(good[torch.randperm(len(good), generator=gen)[:limit].numpy()])
        return torch.as_tensor(_unit_to_box(ev.xi[good]), dtype=torch.float32)

    def _kernel_width(self, centres: torch.Tensor) -> float:
        """Gaussian width (box coordinates) around the success rows: twice their median distance to
        the nearest other row of the evidence, at least 1 % of the box."""
        gap = self._evidence.nearest_distance(_box_to_unit(centres))
        gap = gap[np.isfinite(gap)]
        width = 2.0 * float(np.median(gap)) * 2.0 * BOX_BOUND if len(gap) else 2.0 * BOX_BOUND
        return max(width, 0.01 * 2.0 * BOX_BOUND)

    def _target_weights(self, y: torch.Tensor, log_m: torch.Tensor
                        ) -> tuple[torch.Tensor, dict[str, float], torch.Tensor]:
        """Self-normalized importance weights of the proposal draws `y` for the mode's optimum given
        the evidence; what they say (the estimated feasible share, the effective sample size, and in
        constrained mode the optimum's log density outside the feasible set, "log_ceiling"); and the
        draws outside the estimated feasible set where that ceiling applies (none otherwise)."""
        cfg = self.config
        log_w = -log_m.double()
        info: dict[str, float] = {}
        outside = y[:0]
        if cfg.mode == "entropy":
            r_hat = torch.as_tensor(self._evidence.estimate(_box_to_unit(y)))
            log_w = log_w + r_hat / cfg.alpha if cfg.alpha > 0 else torch.where(
                r_hat >= r_hat.max(), log_w, torch.full_like(log_w, -math.inf))
            w = torch.softmax(log_w, dim=0)
        else:
            inside = self._feasible_hat(y)
            base = torch.softmax(log_w, dim=0)
            share = float(base[inside].sum())  # the box share of the estimated feasible set
            info["feasible_share"] = share
            if 0.0 < share < 1.0 - cfg.delta:
                w = torch.where(inside, base * (1.0 - cfg.delta) / share, base * cfg.delta / (1.0 - share))
                # the optimum's density outside F-hat (box coordinates), a ceiling for the flow there
                info["log_ceiling"] = math.log(cfg.delta / ((1.0 - share) * (2.0 * BOX_BOUND) ** self.space.dim))
                outside = y[~inside]
            else:  # no feasible set seen yet, or the uniform box already meets the constraint
                w = base
        info["ess"] = float(1.0 / (w**2).sum())
        return w.float(), info, outside

    def _descend(self, step_loss: Callable[[], tuple[torch.Tensor, dict[str, torch.Tensor]]],
                 y_old: torch.Tensor, lq_old: torch.Tensor) -> dict[str, Any]:
        """K guarded Adam steps (fresh Adam, gradients clipped) on `step_loss()` -> (loss, terms):
        non-finite steps are skipped, and the flow reverts if a parameter ends non-finite. Counts
        the update and returns the step record with KL(q_old || q_new) on the pre-update flow's
        draws `y_old` (their unnormalized log densities `lq_old`), after any revert."""
        cfg = self.config
        backup = copy.deepcopy(self._flow.state_dict())
        params = list(self._flow.parameters())
        optimizer = torch.optim.Adam(params, lr=cfg.lr, foreach=True)  # fresh each update (no state across rounds)
        skipped = 0
        first: dict[str, float] | None = None
        last: dict[str, float] = {}
        for _ in range(cfg.steps):
            loss, terms = step_loss()
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
            last = {"loss": float(loss.detach()), **{k: float(v.detach()) for k, v in terms.items()}}
            if first is None:
                first = dict(last)
        reverted = not self._params_finite()
        if reverted:
            self._flow.load_state_dict(backup)
        self.n_updates += 1
        self._entropy_cache = None
        kl = float((lq_old - self._log_q(y_old)).mean()) if len(y_old) else 0.0
        return {"first": first, "last": last, "skipped": skipped, "reverted": reverted, "kl": kl}

    def _fit_update(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, Any]:
        """Entropy and constrained modes: remember the batch, then K Adam steps of maximum likelihood
        on draws resampled from the mode's optimum given the evidence (docs/learning.md#goflow-modes)."""
        t0 = time.perf_counter()
        cfg = self.config
        info_level = self._follow_constraint(xi_arr, ret)  # before the batch joins the evidence: held out
        self._evidence.add((xi_arr - self._low) / self._width, ret)
        gen = self._update_generator()
        if self._classifier is not None:
            loss = self._classifier.fit_evidence(self._evidence, steps=cfg.classifier_steps, batch=cfg.fit_batch,
                                                 gen=gen)
            info_classifier = {"classifier_loss": math.nan if loss is None else loss}
        else:
            info_classifier = {}
        y, log_m, lq_prop, n = self._proposal(gen)
        w, info, outside = self._target_weights(y, log_m)
        y_old, lq_old = y[n : 2 * n], lq_prop[n : 2 * n] + self._log_z  # the pre-update flow's own draws

        if cfg.outside_weight == 0:
            outside = outside[:0]
        ceiling = info.get("log_ceiling", 0.0) + self._log_z  # in the flow's unnormalized log density
        n_fit, n_out = cfg.fit_batch, min(len(outside), cfg.fit_batch // 2)

        def step_loss() -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
            parts = [y[torch.multinomial(w, n_fit, replacement=True, generator=gen)]]
            if n_out:
                parts.append(outside[torch.randperm(len(outside), generator=gen)[:n_out]])
            if self.beta > 0:
                old = torch.randperm(len(y_old), generator=gen)[: cfg.kl_samples]
                parts.append(y_old[old])
            lq = self._flow().log_prob(torch.cat(parts))
            fit = -lq[:n_fit].mean()
            terms = {"fit": fit}
            loss = fit
            if n_out:  # constrained: the flow's density above the optimum's outside F-hat, in nats
                excess = torch.relu(lq[n_fit : n_fit + n_out] - ceiling).mean()
                loss, terms["excess_outside"] = loss + cfg.outside_weight * excess, excess
            if self.beta > 0:
                kl_hat = (lq_old[old] - lq[n_fit + n_out :]).mean()
                loss, terms["kl_objective"] = loss + self.beta * kl_hat, kl_hat
            return loss, terms

        run = self._descend(step_loss, y_old, lq_old)
        self._refresh_gate()
        if self._gate is not None:
            info["flow_mass_in_feasible"] = math.exp(self._gate[0])
        if cfg.mode == "constrained":
            info["feasible_level"] = self._level
        return update_diagnostics(
            ret, self.entropy(), first=run["first"], last=run["last"], steps=cfg.steps, skipped=run["skipped"],
            reverted=run["reverted"], has_signal=bool(np.ptp(self._evidence.signal) > 0), update_index=self.n_updates,
            t0=t0, fit=run["last"].get("fit", math.nan), evidence_rows=len(self._evidence), kl=run["kl"], **info,
            **info_classifier, **info_level)

    def _paper_update(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, Any]:
        """The GoFlow paper's update: K Adam steps on the loss of the module docstring."""
        t0 = time.perf_counter()
        cfg = self.config
        d = self.space.dim
        weights_np, has_signal = standardize_returns(ret)
        weights = torch.as_tensor(weights_np, dtype=torch.float32)
        y_batch = torch.as_tensor(self._to_box(xi_arr), dtype=torch.float32).clamp(-BOX_BOUND, BOX_BOUND)
        gen = self._update_generator()
        y_old = self._draw_box(max(cfg.kl_pool, cfg.kl_samples), gen)  # draws of the frozen pre-update flow
        lq_old = self._log_q(y_old)
        n_b, n_u = len(y_batch), cfg.entropy_samples
        vol = (2.0 * BOX_BOUND) ** d

        def step_loss() -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
            u = _uniform_box(n_u, d, gen)
            pick = torch.randperm(len(y_old), generator=gen)[: cfg.kl_samples]
            lq = self._flow().log_prob(torch.cat([y_batch, u, y_old[pick]]))
            lq_b, lq_u, lq_o = lq[:n_b], lq[n_b : n_b + n_u], lq[n_b + n_u :]
            reward_term = -(lq_b * weights).mean()
            lq_u = lq_u.clamp(min=_LOG_Q_FLOOR)
            h_hat = -vol * (lq_u.exp() * lq_u).mean()
            kl_hat = (lq_old[pick] - lq_o).mean()
            loss = reward_term - self.alpha * h_hat + self.beta * kl_hat
            return loss, {"reward_term": reward_term, "entropy_objective": h_hat, "kl_objective": kl_hat}

        run = self._descend(step_loss, y_old, lq_old)
        return update_diagnostics(
            ret, self.entropy(), first=run["first"], last=run["last"], steps=cfg.steps, skipped=run["skipped"],
            reverted=run["reverted"], has_signal=has_signal, update_index=self.n_updates, t0=t0,
            reward_term=run["last"].get("reward_term", math.nan),
            entropy_objective=run["last"].get("entropy_objective", math.nan),
            kl=run["kl"])  # KL(q_old || q_new) on the old flow's samples, after any revert

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
            "evidence": self._evidence.state_dict(),
            **({"classifier": self._classifier.state_dict()} if self._classifier is not None else {}),
            "feasible_level": self._level,
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
        evidence = Evidence(self.space.dim, config.memory, config.neighbours, config.signal_range,
                            config.boundary_memory)
        evidence.load_state_dict(state.get("evidence", {}))
        classifier = self._make_classifier(config)
        if classifier is not None and "classifier" in state:
            classifier.load_state_dict(state["classifier"])
        level = check_number(state.get("feasible_level", config.feasible_level), "state feasible_level", 0.0, 1.0,
                             low_open=True)
        self.config, self.n_updates, self._evidence, self._classifier = config, n_updates, evidence, classifier
        self._level = level
        self._entropy_cache = None
        self._refresh_gate()

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
