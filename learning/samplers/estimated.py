"""EstimatedSampler: a fixed distribution over a ParamSpace (an estimate from logged data, e.g.
by `goflow estimate`) on the Sampler protocol, so that environments and training can draw xi
from it. It does not adapt: `update` validates the batch and learns nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import check_sample_args, check_sampler_args, check_state_dict, check_update_inputs
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from learning.estimation.distributions import UnitBoxDistribution, distribution_from_dict

__all__ = ["EstimatedSampler", "EstimatedSamplerConfig"]


@dataclass(frozen=True)
class EstimatedSamplerConfig:
    """The estimate: a unit-box distribution as written by its `to_dict()` (plain JSON data)."""

    distribution: Mapping[str, Any] = field(default_factory=dict)


class EstimatedSampler:
    """A fixed distribution over a ParamSpace; `update` learns nothing.

    Arguments:
        space: the parameter box.
        success_threshold: J_T (kept for reference).
        config: an EstimatedSamplerConfig or a mapping with "distribution" (the `to_dict()` of a
            unit-box distribution from learning.estimation.distributions); `overrides` are its
            fields. `EstimatedSampler.of(space, dist)` wraps a distribution object directly.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: EstimatedSamplerConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "EstimatedSampler")
        self.config = config_with_overrides(EstimatedSamplerConfig, config, overrides, "EstimatedSampler")
        if not self.config.distribution:
            raise InputError(
                "EstimatedSampler: config.distribution is empty; expected the to_dict() of a "
                "unit-box distribution (learning.estimation.distributions)"
            )
        self.space = space
        self._set_dist(distribution_from_dict(dict(self.config.distribution)))
        self._log_volume = float(np.log(space.high - space.low).sum())

    @classmethod
    def of(
        cls, space: ParamSpace, dist: UnitBoxDistribution, success_threshold: float | None = None
    ) -> EstimatedSampler:
        """The sampler of distribution object `dist` over `space`."""
        return cls(space, success_threshold, {"distribution": dist.to_dict()})

    def _set_dist(self, dist: UnitBoxDistribution) -> None:
        if dist.dim != self.space.dim:
            raise InputError(
                f"EstimatedSampler: the distribution has dim {dist.dim}, the space has "
                f"{self.space.dim} parameters {self.space.names}"
            )
        self.dist = dist

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws (n, d) in parameter units, inside the box."""
        n = check_sample_args(n, rng)
        if n == 0:
            return np.zeros((0, self.space.dim))
        return np.clip(self.space.denormalize(self.dist.sample_u(n, rng)), self.space.low, self.space.high)

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density in parameter units, shape (n,); -inf outside the box."""
        batch = self.space.as_batch(xi)
        return self.dist.log_prob_u(self.space.normalize(batch)) - self._log_volume

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """Validate the batch; an estimate does not adapt to returns."""
        _, ret = check_update_inputs(self.space, xi, returns)
        return {"n": int(len(ret)), "mean_return": float(ret.mean()), "entropy": self.entropy()}

    def entropy(self, n: int = 4096) -> float:
        """Monte Carlo differential entropy -E[log p] in nats (parameter units), fixed seed."""
        xi = self.sample(n, np.random.default_rng(0))
        lp = self.log_prob(xi)
        return float(-lp[np.isfinite(lp)].mean())

    def state_dict(self) -> dict[str, Any]:
        """Type, ParamSpace and the distribution."""
        return {"type": type(self).__name__, "space": self.space.to_dict(), "dist": self.dist.to_dict()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the distribution after checking type and ParamSpace."""
        check_state_dict(self.space, state, type(self).__name__)
        self._set_dist(distribution_from_dict(dict(state["dist"])))

    def __repr__(self) -> str:
        """Class, distribution kind and space."""
        return f"EstimatedSampler({self.dist.to_dict()['kind']}, space={self.space})"
