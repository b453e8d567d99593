"""The proposal of GoFlow's entropy and constrained updates: a fixed-count mixture of uniform draws
on the box, the flow's own draws and Gaussians around the evidence's successes, with its exact
mixture density (the "balance heuristic"), so that importance weights target / mixture stay below
3 x target / uniform whatever the flow does (docs/learning.md#goflow-modes).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from learning.samplers.signal_memory import SignalMemory
from learning.samplers.spline_flow import BOX_BOUND, box_to_unit, uniform_box, unit_to_box

__all__ = ["kernel_width", "proposal", "success_centres"]


def proposal(
    n: int,
    dim: int,
    gen: torch.Generator,
    evidence: SignalMemory,
    draw_flow: Callable[[int], torch.Tensor],
    log_q: Callable[[torch.Tensor], torch.Tensor],
    log_box: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Draws of the proposal in box coordinates with their log densities.

    `n` draws per component: uniform on the box, the flow (`draw_flow(n)`, its normalized log
    density `log_q`), and Gaussians around the evidence's rows whose scaled signal is >= 1/2 (when
    there are any; draws outside the box dropped). Returns (y, the mixture's log density at y, the
    flow's log q at y, n: the flow draws are rows n to 2n, after the uniform ones)."""
    d = dim
    y_u = uniform_box(n, d, gen)
    y_q = draw_flow(n)
    parts, n_total = [y_u, y_q], 2 * n
    centres = success_centres(evidence, gen)
    if len(centres):
        h = kernel_width(evidence, centres)
        pick = torch.randint(len(centres), (n,), generator=gen)
        y_k = centres[pick] + h * torch.randn((n, d), generator=gen)
        y_k = y_k[(y_k.abs() <= BOX_BOUND).all(dim=1)]  # outside the box the target is 0 anyway
        parts.append(y_k)
        n_total += n
    y = torch.cat(parts)
    lq = log_q(y)  # the pre-update flow's density in box coordinates
    terms = [torch.full((len(y),), math.log(n / n_total) - log_box), math.log(n / n_total) + lq]
    if len(centres):
        sq = torch.cdist(y.double(), centres.double()).pow(2)
        log_k = (
            torch.logsumexp(-0.5 * sq / h**2, dim=1) - math.log(len(centres)) - d * math.log(h * math.sqrt(2 * math.pi))
        )
        terms.append(math.log(n / n_total) + log_k.float())
    log_m = torch.logsumexp(torch.stack(terms), dim=0)
    return y, log_m, lq, n


def success_centres(evidence: SignalMemory, gen: torch.Generator, limit: int = 256) -> torch.Tensor:
    """Up to `limit` rows of the evidence with scaled signal >= 1/2 (a random subset of them, in
    their order, when there are more), in box coordinates."""
    good = np.flatnonzero(evidence.scaled_signal() >= 0.5)
    if len(good) > limit:
        good = np.sort(good[torch.randperm(len(good), generator=gen)[:limit].numpy()])
    return torch.as_tensor(unit_to_box(evidence.xi[good]), dtype=torch.float32)


def kernel_width(evidence: SignalMemory, centres: torch.Tensor) -> float:
    """Gaussian width (box coordinates) around the success rows `centres`: twice their median
    distance to the nearest other row of the evidence, at least 1 % of the box."""
    gap = evidence.nearest_distance(box_to_unit(centres))
    gap = gap[np.isfinite(gap)]
    width = 2.0 * float(np.median(gap)) * 2.0 * BOX_BOUND if len(gap) else 2.0 * BOX_BOUND
    return max(width, 0.01 * 2.0 * BOX_BOUND)
