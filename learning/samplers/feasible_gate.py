"""GoFlow's constrained mode on its estimated feasible set F-hat: the sampler truncated to F-hat
(mass 1 - delta in F-hat, a `floor` share of it uniform there; delta uniform on the rest of the
box), its exact density, draws by rejection, and the dual ascent of F-hat's level
(docs/learning.md#goflow-modes).

Everything is in box coordinates [-5, 5]^d; F-hat is given as `contains(y) -> bool tensor`. The
truncation's shares are a `Gate`, estimated from fixed-seed draws by `estimate_gate`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch
from numpy.typing import NDArray

from learning.samplers.spline_flow import uniform_box

__all__ = [
    "GATE_DRAWS",
    "GATE_SEED",
    "Gate",
    "draw_where",
    "estimate_gate",
    "follow_constraint",
    "sample_truncated",
    "truncated_log_density",
]

GATE_DRAWS = 16384  # fixed-seed draws behind the truncation's two shares (flow mass in F-hat, box share outside)
GATE_SEED = 15_485_863  # added to config.seed for those draws
_GATE_MIN_ACCEPT = 0.01  # below this flow mass in F-hat the flow is not truncated (rejection would stall)
_FLOOR_MIN_RATE = 1e-6  # the floor's uniform draws in F-hat: rounds sized for F-hat's own share down to this
_MIX_ITERATIONS = 50  # EM iterations for a batch's share of the sampler's own draws
_LEVEL_MAX_STEP = 0.25  # the most one update moves F-hat's level, in logits
_LEVEL_LOGIT = (-6.0, 8.0)  # the range of F-hat's level under dual ascent, in logits (0.0025 to 0.9997)

Contains = Callable[[torch.Tensor], torch.Tensor]


class Gate(NamedTuple):
    """The truncation's shares, as logs: the flow's mass in F-hat, the box's share outside F-hat,
    and F-hat's share of the box (for the floor's uniform density on it)."""

    log_accept: float
    log_outside: float
    log_share_in: float


def estimate_gate(
    y_flow: torch.Tensor,
    y_uniform: torch.Tensor,
    contains: Contains,
    log_q: Callable[[torch.Tensor], torch.Tensor],
    floor: float,
    log_box: float,
) -> Gate | None:
    """The Gate from draws of the flow (`y_flow`) and of the uniform box (`y_uniform`), `log_q` the
    flow's normalized log density; None (no truncation) while the flow puts under 1 % of its mass
    in F-hat or F-hat is empty or the whole box.

    F-hat's share of the box (with a floor > 0; else 0.0, unused) weights both sets of draws as
    draws of their half-half mixture (uniform density / mixture density), so a small F-hat that
    the flow fills is measured by the flow's draws, not by the few uniform ones that land in it."""
    in_flow, in_uniform = contains(y_flow), contains(y_uniform)
    accept = float(in_flow.double().mean())
    outside = 1.0 - float(in_uniform.double().mean())
    if not (accept >= _GATE_MIN_ACCEPT and 0.0 < outside < 1.0):
        return None
    share_in = 0.0
    if floor != 0.0:
        y = torch.cat([y_flow, y_uniform])
        inside = torch.cat([in_flow, in_uniform]).numpy()
        log_u = -log_box
        log_mix = np.logaddexp(log_q(y).double().numpy(), log_u) - math.log(2.0)
        share_in = float(np.log(np.mean(np.where(inside, np.exp(log_u - log_mix), 0.0))))
    return Gate(math.log(accept), math.log(outside), share_in)


def truncated_log_density(
    lq: torch.Tensor, inside: torch.Tensor, gate: Gate, delta: float, floor: float, log_box: float
) -> torch.Tensor:
    """The truncated sampler's log density (float64) at points where the flow's normalized log
    density is `lq` (float64) and `inside` says whether they lie in F-hat: (1 - delta) x the flow
    in F-hat / its mass there (mixed with `floor` x uniform on F-hat), delta x uniform outside."""
    outside = math.log(delta) - gate.log_outside - log_box
    in_hat = lq - gate.log_accept
    if floor > 0.0:  # (1 - floor) x the flow in F-hat + floor x uniform on F-hat
        uniform_in = torch.full_like(lq, math.log(floor) - gate.log_share_in - log_box)
        in_hat = torch.logaddexp(math.log1p(-floor) + in_hat, uniform_in)
    return torch.where(inside, math.log1p(-delta) + in_hat, torch.full_like(lq, outside))


def draw_where(
    draw: Callable[[int], torch.Tensor],
    contains: Contains,
    in_hat: bool,
    n: int,
    rate: float,
    dim: int,
    max_redraws: int,
    min_rate: float = _GATE_MIN_ACCEPT,
) -> torch.Tensor:
    """n of `draw`'s points that are (in_hat) or are not in F-hat, by rejection at about `rate`
    (each round sized for at least `min_rate`); RuntimeError after max_redraws + 1 rounds."""
    if n <= 0:
        return torch.zeros((0, dim))
    out: list[torch.Tensor] = []
    need = n
    for _ in range(max_redraws + 1):
        y = draw(min(int(math.ceil(need / max(rate, min_rate) * 1.2)) + 16, 1 << 22))
        out.append(y[contains(y) == in_hat])
        need -= len(out[-1])
        if need <= 0:
            return torch.cat(out)[:n]
    where = "in" if in_hat else "outside"
    raise RuntimeError(
        f"GoFlowSampler: {need} of {n} draws {where} the estimated feasible set still missing after "
        f"{max_redraws + 1} rounds of rejection (expected rate {rate:.3g})"
    )


def sample_truncated(
    n: int,
    gen: torch.Generator,
    gate: Gate,
    delta: float,
    floor: float,
    draw_flow: Callable[[int], torch.Tensor],
    contains: Contains,
    dim: int,
    max_redraws: int,
) -> torch.Tensor:
    """n draws of the truncated sampler: a delta share of uniform draws outside F-hat, a floor share
    of the rest uniform in F-hat, the others flow draws (`draw_flow`) in F-hat, shuffled."""
    n_out = int((torch.rand(n, generator=gen, dtype=torch.float64) < delta).sum())
    n_floor = 0
    if floor > 0.0:
        n_floor = int((torch.rand(n - n_out, generator=gen, dtype=torch.float64) < floor).sum())
    inside = draw_where(draw_flow, contains, True, n - n_out - n_floor, math.exp(gate.log_accept), dim, max_redraws)
    spread = draw_where(
        lambda m: uniform_box(m, dim, gen),
        contains,
        True,
        n_floor,
        math.exp(gate.log_share_in),
        dim,
        max_redraws,
        min_rate=_FLOOR_MIN_RATE,
    )
    rest = draw_where(
        lambda m: uniform_box(m, dim, gen), contains, False, n_out, math.exp(gate.log_outside), dim, max_redraws
    )
    return torch.cat([inside, spread, rest])[torch.randperm(n, generator=gen)]


def follow_constraint(
    level: float,
    inside: NDArray[np.bool_],
    log_ratio: NDArray[np.float64],
    signal: NDArray[np.float64],
    level_step: float,
    leak_target: float,
) -> tuple[float, dict[str, float]]:
    """One dual-ascent step of F-hat's level on a held-out batch: (the new level, what it saw).

    `inside`: the batch rows in F-hat (at least one); `log_ratio`: the sampler's log density over
    the uniform box's at each row; `signal`: the rows' 0/1 successes. The batch may be the
    sampler's own draws, uniform ones, or a mix: its density is estimated as pi x the sampler +
    (1 - pi) x uniform (pi by maximum likelihood, EM), and each row in F-hat is weighted by the
    sampler's density over that estimate, so `leak` estimates the share of the sampler's mass in
    F-hat that fails. The level's logit moves by level_step x n_eff x (leak - leak_target), n_eff
    the weights' effective count, at most 0.25 per step, within logits [-6, 8]."""
    ratio = np.exp(np.minimum(log_ratio, 700.0))
    pi = 0.5
    for _ in range(_MIX_ITERATIONS):  # EM for the batch's share of sampler draws
        pi = float(np.mean(pi * ratio / (pi * ratio + 1.0 - pi)))
    w = (ratio / (pi * ratio + 1.0 - pi))[inside]
    failed = (signal[inside] < 0.5).astype(np.float64)
    leak = float(np.sum(w * failed) / np.sum(w))
    n_eff = float(np.sum(w) ** 2 / np.sum(w**2))
    logit = math.log(level) - math.log1p(-level) if level < 1.0 else _LEVEL_LOGIT[1]
    step = level_step * n_eff * (leak - leak_target)
    logit += min(max(step, -_LEVEL_MAX_STEP), _LEVEL_MAX_STEP)
    logit = min(max(logit, _LEVEL_LOGIT[0]), _LEVEL_LOGIT[1])
    return 1.0 / (1.0 + math.exp(-logit)), {
        "heldout_in_feasible": float(inside.sum()),
        "heldout_failed": float(failed.sum()),
        "heldout_leak": leak,
        "heldout_own_share": pi,
    }
