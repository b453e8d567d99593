"""GoFlow's density model: zuko's neural spline flow on the box [-5, 5]^d ("box coordinates"),
started as the identity on a N(0, s^2) base, drawn from exactly truncated to the box, and its
tensors as JSON.

The box is invariant under the flow (the splines map [-5, 5] onto itself), so the base's mass in
the box, Z, normalizes the truncated flow exactly (docs/learning.md#goflow).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import partial
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
import zuko
from numpy.typing import NDArray
from zuko.distributions import DiagNormal
from zuko.lazy import UnconditionalDistribution
from zuko.transforms import MonotonicRQSTransform

__all__ = [
    "BOX_BOUND",
    "box_to_unit",
    "build_spline_flow",
    "draw_in_box",
    "flow_log_q",
    "identity_flow",
    "log_box_mass",
    "params_finite",
    "tensor_from_json",
    "tensor_to_json",
    "uniform_box",
    "unit_to_box",
]

BOX_BOUND = 5.0  # zuko's spline domain is [-5, 5] (the GoFlow authors' code maps the box onto it)
_BOX_TOL = 1e-4  # float32 rounding slack (box coordinates) before a draw counts as outside
_CHUNK = 65536  # rows per flow evaluation outside training


class _SplineTransform(MonotonicRQSTransform):
    """zuko's monotonic rational-quadratic spline with the bin softmax written as exp / sum.

    The same function as `MonotonicRQSTransform` (tests compare the two flows' densities): zuko first
    squashes every unconstrained width and height into (-l/2, l/2), l = -log(slope) = 6.9, so exp
    cannot overflow and the max-shift of a general softmax is not needed. torch's CPU softmax over
    8 bins costs 3.5x the plain exp / sum, and with it a d = 3 update takes a third longer.
    """

    def __init__(
        self,
        widths: torch.Tensor,
        heights: torch.Tensor,
        derivatives: torch.Tensor,
        bound: float = 5.0,
        slope: float = 1e-3,
        **kwargs: Any,
    ) -> None:
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
    return zuko.flows.MAF(
        features=features,
        transforms=transforms,
        hidden_features=hidden_features,
        univariate=partial(_SplineTransform, slope=1e-3),
        shapes=[(bins,), (bins,), (bins - 1,)],
    )


def identity_flow(
    features: int, transforms: int, hidden_features: tuple[int, ...], bins: int, base_scale: float, seed: int
) -> zuko.flows.Flow:
    """`build_spline_flow` with identity splines and a N(0, base_scale^2) base: its density is the
    base's; deterministic in `seed` (the global torch RNG is left as it was)."""
    d = features
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        flow = build_spline_flow(d, transforms, hidden_features, bins)
    flow.base = UnconditionalDistribution(DiagNormal, torch.zeros(d), torch.full((d,), float(base_scale)), buffer=True)
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


def log_box_mass(features: int, base_scale: float) -> float:
    """log Z, the N(0, base_scale^2 I) base's mass inside [-5, 5]^features."""
    return features * math.log(math.erf(BOX_BOUND / (base_scale * math.sqrt(2.0))))


def flow_log_q(flow: zuko.flows.Flow, y: torch.Tensor) -> torch.Tensor:
    """The flow's unnormalized log density at box-coordinate points y (n, d), without gradients, in
    chunks of 65536 rows."""
    with torch.no_grad():
        dist = flow()
        return torch.cat([dist.log_prob(y[i : i + _CHUNK]) for i in range(0, len(y), _CHUNK)]) if len(y) else y[:, 0]


def _base_in_box(n: int, d: int, base_scale: float, gen: torch.Generator) -> torch.Tensor:
    """n draws of the base N(0, s^2 I) truncated to [-5, 5]^d (inverse CDF, float64 -> float32)."""
    s = float(base_scale)
    p_lo = 0.5 * math.erfc(BOX_BOUND / (s * math.sqrt(2.0)))  # Phi(-5 / s)
    u = p_lo + (1.0 - 2.0 * p_lo) * torch.rand((n, d), generator=gen, dtype=torch.float64)
    z = s * torch.special.ndtri(u)
    return z.clamp(-BOX_BOUND, BOX_BOUND).to(torch.float32)


def draw_in_box(
    flow: zuko.flows.Flow, n: int, d: int, base_scale: float, max_redraws: int, gen: torch.Generator
) -> torch.Tensor:
    """n draws of the flow truncated to the box, in box coordinates (float32, shape (n, d)): base
    draws in the box mapped through the inverse transform, those that leave it (or are not finite)
    drawn again. RuntimeError after `max_redraws` rounds that leave draws missing."""
    out: list[torch.Tensor] = []
    need = n
    rounds = 0
    while need > 0:
        if rounds > max_redraws:
            raise RuntimeError(
                f"GoFlowSampler: the flow put no usable mass in the box: {need} of {n} draws still outside after "
                f"{rounds} rounds (finite parameters: {params_finite(flow)}); the flow has left the box"
            )
        rounds += 1
        z = _base_in_box(need, d, base_scale, gen)
        with torch.no_grad():
            transform = flow().transform
            y = torch.cat([transform.inv(z[i : i + _CHUNK]) for i in range(0, len(z), _CHUNK)])
        ok = torch.isfinite(y).all(dim=1) & (y.abs() <= BOX_BOUND + _BOX_TOL).all(dim=1)
        y = y[ok].clamp(-BOX_BOUND, BOX_BOUND)
        out.append(y)
        need -= len(y)
    return torch.cat(out) if out else torch.zeros((0, d))


def params_finite(flow: zuko.flows.Flow) -> bool:
    """Whether every parameter of the flow is finite."""
    return all(bool(torch.isfinite(p).all()) for p in flow.parameters())


def uniform_box(n: int, d: int, gen: torch.Generator) -> torch.Tensor:
    """n uniform draws on the box [-5, 5]^d (float32)."""
    return (torch.rand((n, d), generator=gen) * 2.0 - 1.0) * BOX_BOUND


def box_to_unit(y: torch.Tensor) -> NDArray[np.float64]:
    """Box coordinates [-5, 5]^d -> the unit box [0, 1]^d (float64)."""
    return (y.double().numpy() / BOX_BOUND + 1.0) / 2.0


def unit_to_box(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit box [0, 1]^d -> box coordinates."""
    return (u * 2.0 - 1.0) * BOX_BOUND


def tensor_to_json(t: torch.Tensor) -> dict[str, Any]:
    """A tensor as plain JSON data: dtype name, shape and the flat values."""
    return {"dtype": str(t.dtype).removeprefix("torch."), "shape": list(t.shape), "data": t.flatten().tolist()}


def tensor_from_json(d: Mapping[str, Any]) -> torch.Tensor:
    """Inverse of `tensor_to_json`."""
    dtype = getattr(torch, d["dtype"])
    return torch.tensor(d["data"], dtype=dtype).reshape(d["shape"])
