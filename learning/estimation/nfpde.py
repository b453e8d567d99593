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

Why these weights: at r = 1 the surrogate's gradient is sum_m A_m grad log p(xi_m), a weighted
maximum-likelihood step. With the Softmax weights, iterating it is the EM fixed-point iteration of
the marginal likelihood sum_j log E_p[exp(-beta l_j(xi))]: every segment keeps a say, so a mixture
of trajectories with different parameters is recovered as a mixture. With the CAI weights the step
moves p toward p_old(xi) sum_j exp(-l_j(xi)/tau): iterated, it concentrates on the single xi that
explains the data best on average (a mode), which is why the Softmax variant should win on
mixed targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.special import expit, log_softmax

from learning.estimation.common import Budget, BudgetExhausted, prediction_loss, segment_rows
from learning.estimation.distributions import FlowDistribution

__all__ = ["NFPDEConfig", "fit_nfpde"]


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
            raise ValueError(f"NFPDE likelihood must be 'softmax' or 'cai', got {self.likelihood!r}")
        for name in ("samples", "segments", "segment_length", "epochs", "transforms"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"NFPDEConfig.{name} must be >= 1, got {getattr(self, name)!r}")
        if self.samples < 2:
            raise ValueError("NFPDEConfig.samples must be >= 2 (weights compare samples)")
        if not (self.beta > 0 and self.tau > 0 and self.lr > 0):
            raise ValueError(f"NFPDEConfig: beta, tau and lr must be > 0, got {self.beta}, {self.tau}, {self.lr}")
        if int(self.replay) < 1:
            raise ValueError(f"NFPDEConfig.replay must be >= 1, got {self.replay!r}")
        if self.clip is not None and not 0 < self.clip < 1:
            raise ValueError(f"NFPDEConfig.clip must be in (0, 1) or None, got {self.clip!r}")
        self.hidden = tuple(self.hidden)


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
    per_iter = config.samples * min(config.segments, len(segs)) * config.segment_length
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
        batches = (batches + [(y, logp_old, adv)])[-config.replay:]
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
