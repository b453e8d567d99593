"""What a GoFlow update minimizes, by mode (GoFlowConfig.mode; docs/learning.md#goflow-modes), and
the guarded descent that takes K Adam steps on it.

- "entropy" and "constrained": the mode's optimum given the evidence, as self-normalized
  importance weights of proposal draws (`target_weights`), fitted by maximum likelihood on draws
  resampled by those weights (`fit_loss`), a forward KL(p* || q); in constrained mode a hinge on
  the flow's density above the optimum's outside F-hat.
- "paper": the GoFlow paper's loss -(1/B) sum_i log q(y_i) R_i - alpha H_hat + beta KL_hat on the
  batch alone (`paper_loss`).

All in box coordinates; `beta` > 0 adds KL(q_old || q) on the pre-update flow's draws.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import torch
import zuko

from learning.samplers.signal_memory import SignalMemory
from learning.samplers.goflow_config import GoFlowConfig
from learning.samplers.spline_flow import BOX_BOUND, box_to_unit, params_finite, uniform_box

__all__ = ["Loss", "descend", "fit_loss", "paper_loss", "target_weights"]

_LOG_Q_FLOOR = -1e4  # clamp for log q in the entropy term: exp underflows to 0 well before this

#: One step's loss and its named terms.
Loss = Callable[[], tuple[torch.Tensor, dict[str, torch.Tensor]]]


def target_weights(
    cfg: GoFlowConfig,
    dim: int,
    y: torch.Tensor,
    log_m: torch.Tensor,
    evidence: SignalMemory,
    contains: Callable[[torch.Tensor], torch.Tensor],
) -> tuple[torch.Tensor, dict[str, float], torch.Tensor]:
    """Self-normalized importance weights of proposal draws `y` (mixture log density `log_m`) for
    the mode's optimum given the evidence (entropy: p* ~ exp(r_hat / alpha), r_hat the k-NN signal
    estimate; constrained: 1 - delta uniform on F-hat = `contains`, delta on the rest); what they
    say (the estimated feasible share, the effective sample size, and in constrained mode the
    optimum's log density outside F-hat, "log_ceiling"); and the draws outside F-hat where that
    ceiling applies (none otherwise)."""
    log_w = -log_m.double()
    info: dict[str, float] = {}
    outside = y[:0]
    if cfg.mode == "entropy":
        r_hat = torch.as_tensor(evidence.estimate(box_to_unit(y)))
        log_w = (
            log_w + r_hat / cfg.alpha
            if cfg.alpha > 0
            else torch.where(r_hat >= r_hat.max(), log_w, torch.full_like(log_w, -math.inf))
        )
        w = torch.softmax(log_w, dim=0)
    else:
        inside = contains(y)
        base = torch.softmax(log_w, dim=0)
        share = float(base[inside].sum())  # the box share of the estimated feasible set
        info["feasible_share"] = share
        if 0.0 < share < 1.0 - cfg.delta:
            w = torch.where(inside, base * (1.0 - cfg.delta) / share, base * cfg.delta / (1.0 - share))
            # the optimum's density outside F-hat (box coordinates), a ceiling for the flow there
            info["log_ceiling"] = math.log(cfg.delta / ((1.0 - share) * (2.0 * BOX_BOUND) ** dim))
            outside = y[~inside]
        else:  # no feasible set seen yet, or the uniform box already meets the constraint
            w = base
    info["ess"] = float(1.0 / (w**2).sum())
    return w.float(), info, outside


def fit_loss(
    cfg: GoFlowConfig,
    flow: zuko.flows.Flow,
    gen: torch.Generator,
    y: torch.Tensor,
    w: torch.Tensor,
    outside: torch.Tensor,
    ceiling: float,
    y_old: torch.Tensor,
    lq_old: torch.Tensor,
) -> Loss:
    """Entropy and constrained modes: the step loss -mean log q on `fit_batch` draws of `y`
    resampled by `w`; plus `outside_weight` x the mean excess of log q over `ceiling` (the flow's
    unnormalized log density) on up to fit_batch / 2 of the `outside` draws; plus beta x KL_hat on
    `kl_samples` of the pre-update draws `y_old` (their log densities `lq_old`)."""
    if cfg.outside_weight == 0:
        outside = outside[:0]
    n_fit, n_out = cfg.fit_batch, min(len(outside), cfg.fit_batch // 2)

    def step_loss() -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        parts = [y[torch.multinomial(w, n_fit, replacement=True, generator=gen)]]
        if n_out:
            parts.append(outside[torch.randperm(len(outside), generator=gen)[:n_out]])
        if cfg.beta > 0:
            old = torch.randperm(len(y_old), generator=gen)[: cfg.kl_samples]
            parts.append(y_old[old])
        lq = flow().log_prob(torch.cat(parts))
        fit = -lq[:n_fit].mean()
        terms = {"fit": fit}
        loss = fit
        if n_out:  # constrained: the flow's density above the optimum's outside F-hat, in nats
            excess = torch.relu(lq[n_fit : n_fit + n_out] - ceiling).mean()
            loss, terms["excess_outside"] = loss + cfg.outside_weight * excess, excess
        if cfg.beta > 0:
            kl_hat = (lq_old[old] - lq[n_fit + n_out :]).mean()
            loss, terms["kl_objective"] = loss + cfg.beta * kl_hat, kl_hat
        return loss, terms

    return step_loss


def paper_loss(
    cfg: GoFlowConfig,
    flow: zuko.flows.Flow,
    gen: torch.Generator,
    dim: int,
    y_batch: torch.Tensor,
    weights: torch.Tensor,
    y_old: torch.Tensor,
    lq_old: torch.Tensor,
) -> Loss:
    """The paper mode's step loss on the batch `y_batch` with standardized returns `weights`:
    -mean(log q(y_i) R_i) - alpha H_hat + beta KL_hat, H_hat from `entropy_samples` fresh uniform
    draws, KL_hat on `kl_samples` of the pre-update draws `y_old` (log densities `lq_old`)."""
    n_b, n_u = len(y_batch), cfg.entropy_samples
    vol = (2.0 * BOX_BOUND) ** dim

    def step_loss() -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        u = uniform_box(n_u, dim, gen)
        pick = torch.randperm(len(y_old), generator=gen)[: cfg.kl_samples]
        lq = flow().log_prob(torch.cat([y_batch, u, y_old[pick]]))
        lq_b, lq_u, lq_o = lq[:n_b], lq[n_b : n_b + n_u], lq[n_b + n_u :]
        reward_term = -(lq_b * weights).mean()
        lq_u = lq_u.clamp(min=_LOG_Q_FLOOR)
        h_hat = -vol * (lq_u.exp() * lq_u).mean()
        kl_hat = (lq_old[pick] - lq_o).mean()
        loss = reward_term - cfg.alpha * h_hat + cfg.beta * kl_hat
        return loss, {"reward_term": reward_term, "entropy_objective": h_hat, "kl_objective": kl_hat}

    return step_loss


def descend(cfg: GoFlowConfig, flow: zuko.flows.Flow, step_loss: Loss) -> dict[str, Any]:
    """`cfg.steps` guarded Adam steps (a fresh Adam at lr `cfg.lr`, gradients clipped at
    `cfg.grad_clip`) on `step_loss()`: a step with a non-finite loss or gradient is skipped, and
    the flow reverts to its parameters before the descent if one ends non-finite. Returns the first
    and last applied step's loss and terms ("first": None if none applied), "skipped", "reverted"."""
    backup = copy.deepcopy(flow.state_dict())
    params = list(flow.parameters())
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
    reverted = not params_finite(flow)
    if reverted:
        flow.load_state_dict(backup)
    return {"first": first, "last": last, "skipped": skipped, "reverted": reverted}
