"""An estimated distribution as a Sampler (assembly/samplers.py) for training, and its file format.

`goflow estimate` writes a JSON file {"format": "goflow-estimate", "version": 1, "method",
"env_id", "sampler": EstimatedSampler.state_dict(), "info": {...}}; `load_estimate` returns an
EstimatedSampler that environments and `learning/experiment.py`'s PPO loop can draw xi from.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import check_sample_args, check_state_dict, check_update_inputs
from learning.estimation.distributions import UnitBoxDistribution, distribution_from_dict

__all__ = ["EstimatedSampler", "save_estimate", "load_estimate", "ESTIMATE_FORMAT"]

ESTIMATE_FORMAT = "goflow-estimate"


class EstimatedSampler:
    """A fixed distribution over a ParamSpace (an estimate from logged data); update learns nothing."""

    def __init__(self, space: ParamSpace, dist: UnitBoxDistribution) -> None:
        if dist.dim != space.dim:
            raise ValueError(f"EstimatedSampler: distribution has dim {dist.dim}, the space has {space.dim} "
                             f"parameters {space.names}")
        self.space, self.dist = space, dist
        self._log_volume = float(np.log(space.high - space.low).sum())

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
        dist = distribution_from_dict(dict(state["dist"]))
        if dist.dim != self.space.dim:
            raise ValueError(f"load_state_dict: distribution dim {dist.dim} != {self.space.dim}")
        self.dist = dist

    def __repr__(self) -> str:
        """Class, distribution kind and space."""
        return f"EstimatedSampler({self.dist.to_dict()['kind']}, space={self.space})"


def save_estimate(path: str | Path, sampler: EstimatedSampler, method: str, env_id: str,
                  info: Mapping[str, Any]) -> Path:
    """Write the estimate file (JSON) described in the module docstring; return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": ESTIMATE_FORMAT, "version": 1, "method": method, "env_id": env_id,
           "sampler": sampler.state_dict(), "info": dict(info)}
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc))
    tmp.replace(path)
    return path


def load_estimate(path: str | Path) -> tuple[EstimatedSampler, dict[str, Any]]:
    """(sampler, the whole file as a dict); ValueError naming the file when it is not an estimate."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"estimate {path}: cannot read it as JSON ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != ESTIMATE_FORMAT:
        raise ValueError(f"estimate {path}: not a {ESTIMATE_FORMAT!r} file (written by `goflow estimate`)")
    state = doc["sampler"]
    space = ParamSpace.from_dict(state["space"])
    sampler = EstimatedSampler(space, distribution_from_dict(state["dist"]))
    sampler.load_state_dict(state)
    return sampler, doc
