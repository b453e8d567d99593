"""NFPDE: a normalizing flow (zuko RealNVP) over the simulator parameters, fitted to logged
transitions through an importance-sampled surrogate (the seed paper's section IV; no public code).

Each iteration:
  1. draw M parameters xi_m from the current flow p_old (sigmoid bounds: u = sigmoid(y), so every
     draw is inside the box);
  2. for B logged segments o_j (L consecutive transitions of one trajectory), reset the simulator to
     each logged state, apply the logged action with xi_m and compare with the logged next state:
     l_mj = mean over the segment's transitions and state dims of ((s'_sim - s'_log) / sigma)^2,
     sigma = the per-dimension std of s' - s in the data;
  3. likelihood weights of the M samples:
       Softmax: w_mj = softmax_m(-beta l_mj)  (each segment distributes one vote over the samples;
                advantage A_m = M mean_j w_mj - 1)
       CAI:     w_mj = exp(-l_mj / tau)  (control-as-inference: likelihood proportional to
                exp(-l_pred); A_m = w_m / mean_m w_m - 1 with w_m = mean_j w_mj)
  4. K Adam steps on the surrogate  mean_m min(r_m A_m, clip(r_m, 1 - eps, 1 + eps) A_m),
     r_m = p(xi_m) / p_old(xi_m)  (PPO clipping optional: clip = None gives the plain
     importance-sampled surrogate).

Softmax weights keep a mixture of trajectory parameters a mixture; CAI weights concentrate on a
mode. Why: docs/nfpde.md#nfpde-why-these-weights.

References: "Normalizing Flow-based Parameter Distribution Estimation for Offline Adaptive Domain
Randomization" (the seed paper), section IV; Dinh et al., "Density estimation using Real NVP",
ICLR 2017; zuko (github.com/probabilists/zuko).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.special import expit, log_softmax

from goflow_common.checks import check_int, check_number
from goflow_common.errors import InputError
from learning.estimation.budget import Budget, BudgetExhausted, check_sim_budget
from learning.estimation.dataset import TransitionDataset, segment_rows
from learning.estimation.distributions import FlowDistribution

__all__ = ["NFPDEConfig", "fit_nfpde", "min_sim_calls", "prediction_loss"]

FAILED_LOSS = 1e6  # loss of a row whose simulation failed (NaN prediction)


@dataclass
class NFPDEConfig:
    """NFPDE hyperparameters; the defaults are the ones the results in docs/nfpde.md use."""

    likelihood: str = "softmax"  # "softmax" | "cai"
    samples: int = 64  # M parameter draws per iteration
    segments: int = 16  # B logged segments per iteration
    segment_length: int = 2  # L transitions per segment
    beta: float = 1000.0  # Softmax inverse temperature on l_pred
    tau: float = 0.05  # CAI temperature: likelihood exp(-l_pred / tau)
    epochs: int = 30  # K gradient steps per simulated batch
    lr: float = 5e-3
    clip: float | None = 0.3  # PPO ratio clipping; None: plain importance-sampled surrogate
    replay: int = 4  # also reuse the last `replay` - 1 batches (their ratios are against their own p_old)
    transforms: int = 6  # RealNVP coupling layers
    hidden: tuple[int, ...] = (64, 64)
    y_scale: float = 1.0  # start: u = sigmoid(w), w ~ N(0, I): 95 % of each parameter in [0.12, 0.88]

    def __post_init__(self) -> None:
        if self.likelihood not in ("softmax", "cai"):
            raise InputError(f"NFPDE likelihood must be 'softmax' or 'cai', got {self.likelihood!r}")
        self.samples = check_int(self.samples, "NFPDEConfig.samples", 2)  # weights compare samples
        for name in ("segments", "segment_length", "epochs", "transforms", "replay"):
            setattr(self, name, check_int(getattr(self, name), f"NFPDEConfig.{name}", 1))
        for name in ("beta", "tau", "lr", "y_scale"):
            setattr(self, name, check_number(getattr(self, name), f"NFPDEConfig.{name}", 0.0, low_open=True))
        if self.clip is not None:
            self.clip = check_number(self.clip, "NFPDEConfig.clip", 0.0, 1.0, low_open=True, high_open=True)
        if isinstance(self.hidden, (str, bytes)) or not hasattr(self.hidden, "__iter__"):
            raise InputError(f"NFPDEConfig.hidden = {self.hidden!r}; expected a list of layer widths")
        self.hidden = tuple(check_int(h, f"NFPDEConfig.hidden[{i}]", 1) for i, h in enumerate(self.hidden))


def min_sim_calls(config: NFPDEConfig, data: TransitionDataset) -> tuple[int, str]:
    """Simulator calls one NFPDE iteration needs on `data`, and how they add up: the smallest
    budget that changes the flow (InputError if no trajectory holds one segment)."""
    segments = min(config.segments, len(segment_rows(data, config.segment_length)))
    calls = config.samples * segments * config.segment_length
    return calls, (
        f"{config.samples} samples x {segments} segments x {config.segment_length} transitions, "
        "set by the options samples, segments, segment_length"
    )


def _advantages(loss: np.ndarray, config: NFPDEConfig) -> np.ndarray:
    """A_m (M,) from the losses l_mj (M, B); zero mean over the samples."""
    m = loss.shape[0]
    if config.likelihood == "softmax":
        w = np.exp(log_softmax(-config.beta * loss, axis=0))  # (M, B), columns sum to 1
        return m * w.mean(axis=1) - 1.0
    logw = -loss / config.tau
    w = np.exp(logw - logw.max()).mean(axis=1)  # common factor cancels in w / mean(w)
    return w / max(float(w.mean()), 1e-300) - 1.0


def fit_nfpde(budget: Budget, config: NFPDEConfig, seed: int) -> tuple[FlowDistribution, dict]:
    """Run NFPDE until the simulator budget is spent; return the flow and a summary."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    data = budget.data
    dist = FlowDistribution(data.space.dim, config.transforms, config.hidden, config.y_scale, seed=seed)
    opt = torch.optim.Adam(dist.flow.parameters(), lr=config.lr)
    segs = segment_rows(data, config.segment_length)
    need = min_sim_calls(config, data)
    check_sim_budget(budget.remaining(), f"nfpde-{config.likelihood}", need)
    per_iter = need[0]
    budget.snapshot(dist, iteration=0)
    it, skipped = 0, 0
    batches: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
    while budget.can_afford(per_iter):
        y = dist.sample_y(config.samples, rng)
        u = expit(y.double().numpy())
        with torch.no_grad():
            logp_old = dist.log_prob_y(y)
        chosen = segs[rng.choice(len(segs), size=min(config.segments, len(segs)), replace=False)]
        rows = chosen.reshape(-1)
        try:
            pred = budget.predict(rows, u)
        except BudgetExhausted:
            break
        loss = prediction_loss(pred, data.next_states[rows], budget.scale)  # (M, B * L)
        seg_loss = loss.reshape(config.samples, len(chosen), config.segment_length).mean(axis=2)
        adv = torch.as_tensor(_advantages(seg_loss, config), dtype=torch.float32)
        batches = (batches + [(y, logp_old, adv)])[-config.replay :]
        ys = torch.cat([b[0] for b in batches])
        logp_olds = torch.cat([b[1] for b in batches])
        advs = torch.cat([b[2] for b in batches])
        backup = {k: v.clone() for k, v in dist.flow.state_dict().items()}
        for _ in range(config.epochs):
            ratio = torch.exp(dist.log_prob_y(ys) - logp_olds)
            adv = advs
            surrogate = ratio * adv
            if config.clip is not None:
                surrogate = torch.minimum(surrogate, torch.clamp(ratio, 1 - config.clip, 1 + config.clip) * adv)
            obj = -surrogate.mean()
            if not torch.isfinite(obj):
                skipped += 1
                break
            opt.zero_grad()
            obj.backward()
            torch.nn.utils.clip_grad_norm_(dist.flow.parameters(), 1.0)
            opt.step()
        if not all(torch.isfinite(p).all() for p in dist.flow.parameters()):
            dist.flow.load_state_dict(backup)  # revert a step that broke the flow
            skipped += 1
        it += 1
        budget.snapshot(dist, iteration=it, mean_loss=float(seg_loss.mean()))
    return dist, {"iterations": it, "skipped_updates": skipped, "calls_per_iteration": per_iter}


def prediction_loss(
    pred: NDArray[np.float64], target: NDArray[np.float64], scale: NDArray[np.float64]
) -> NDArray[np.float64]:
    """l_pred per (sample, row): mean over state dims of ((s'_sim - s'_log) / scale)^2, (M, R);
    failed simulations (NaN) get FAILED_LOSS."""
    err = ((pred - target[None]) / scale) ** 2
    loss = err.mean(axis=-1)
    return np.where(np.isfinite(loss), loss, FAILED_LOSS)
