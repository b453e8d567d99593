"""The Sampler protocol shared by every domain-randomization method, and the two fixed ones.

A sampler is a distribution p(xi) over a `ParamSpace`. Environments call `sample` at reset;
learners call `update(xi, returns)` with the parameters and undiscounted episode returns of a batch
of episodes; planners and diagnostics call `log_prob` and `entropy`. The learned samplers (ADR, LSDR,
DORAEMON, GoFlow, estimates in `learning/samplers/`) implement the same protocol and must validate
their inputs with `check_update_inputs`, `check_sample_args` and `check_state_dict`, so that every
method fails the same way on the same bad input.

Construction has one signature for every sampler, `Cls(space, success_threshold=None, config=None,
**overrides)`: `config` is the sampler's config dataclass, a mapping of its fields or None (its
defaults), and keyword `overrides` are fields of that dataclass applied last
(`goflow_common.config.config_with_overrides`). Methods that compare returns with J_T (ADR, DORAEMON)
need a finite `success_threshold`; the others keep it for reference. `learning.samplers.registry`
builds any of them by name.

Conventions:
- `log_prob` is the log density with respect to Lebesgue measure in the parameters' own units
  (not the unit box): a density over a box of volume V that is uniform has log_prob = -log V.
  Points outside the support get -inf (never an error); non-finite or mis-shaped xi raise.
- `entropy` is the differential entropy in nats, in the same units (so it changes by log c when a
  parameter is rescaled by c); a point mass has entropy -inf.
- `state_dict` is JSON-serializable and always holds "type" (the class name) and "space"
  (`ParamSpace.to_dict()`); `load_state_dict` refuses a dict of another type or another space.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from goflow_common.checks import check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError

__all__ = [
    "Sampler",
    "NoDR",
    "FullDR",
    "check_update_inputs",
    "check_sample_args",
    "check_state_dict",
    "NoDRConfig",
    "FullDRConfig",
    "check_sampler_args",
    "base_diagnostics",
]


@runtime_checkable
class Sampler(Protocol):
    """A distribution over a ParamSpace that a domain-randomization method can adapt."""

    space: ParamSpace

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """Draw n parameter vectors, shape (n, d), inside the box."""
        ...

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density (Lebesgue, parameter units) of (n, d) or (d,) xi, shape (n,); -inf outside the support."""
        ...

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """Adapt to episodes run at xi (n, d) with undiscounted returns (n,); return diagnostics."""
        ...

    def entropy(self) -> float:
        """Differential entropy in nats (parameter units)."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to restore the sampler, including its ParamSpace."""
        ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from `state_dict`, raising ValueError if the type or ParamSpace differ."""
        ...


# -- validation shared by every sampler -----------------------------------------------------------


def check_sample_args(n: Any, rng: Any) -> int:
    """Validate `sample`'s arguments and return n as an int (n = 0 gives an empty (0, d) batch)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"sample: n must be a non-negative integer, got {n!r}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"sample: rng must be a numpy.random.Generator (e.g. np.random.default_rng(seed)), got {type(rng).__name__}"
        )
    return int(n)


def check_update_inputs(
    space: ParamSpace, xi: ArrayLike, returns: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate an update batch: xi (n, d) inside the box, returns (n,) finite, n >= 1; return float copies."""
    xi_arr = np.asarray(xi, dtype=np.float64)
    if xi_arr.ndim != 2 or xi_arr.shape[1] != space.dim:
        raise ValueError(
            f"update: xi has shape {xi_arr.shape}, expected shape (n, {space.dim}) for parameters {space.names}"
        )
    if xi_arr.shape[0] == 0:
        raise ValueError("update: the batch is empty (xi has 0 rows); need at least one episode")
    ret = np.asarray(returns, dtype=np.float64)
    if ret.shape != (xi_arr.shape[0],):
        raise ValueError(
            f"update: returns has shape {ret.shape}, expected ({xi_arr.shape[0]},): one return per row of xi"
        )
    bad = ~np.isfinite(ret)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise ValueError(
            f"update: returns must be finite; {len(idx)} of {len(ret)} are not (first: index {idx[0]} = {ret[idx[0]]})"
        )
    return space.validate(xi_arr, what="update: xi"), ret.copy()


def check_state_dict(space: ParamSpace, state: Mapping[str, Any], expected_type: str) -> None:
    """Raise ValueError unless `state` is a state_dict of `expected_type` over exactly `space`."""
    if not isinstance(state, Mapping) or "type" not in state or "space" not in state:
        raise ValueError(
            f"load_state_dict: expected a {expected_type} state_dict with 'type' and 'space' keys, got {state!r}"
        )
    if state["type"] != expected_type:
        raise ValueError(f"load_state_dict: state_dict is for {state['type']!r}, this sampler is {expected_type!r}")
    saved = ParamSpace.from_dict(state["space"])
    if saved != space:
        diffs = "; ".join(space.diff(saved))
        raise ValueError(
            f"load_state_dict: the checkpoint's ParamSpace differs from this sampler's (this vs checkpoint): {diffs}"
        )


def base_diagnostics(returns: NDArray[np.float64], entropy: float) -> dict[str, Any]:
    """The diagnostics every sampler's `update` reports: {"n": the rows' count, "mean_return":
    their mean return, "entropy": `entropy`} (`returns`: a non-empty 1-D array)."""
    return {"n": int(len(returns)), "mean_return": float(returns.mean()), "entropy": entropy}


# -- the fixed samplers ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class NoDRConfig:
    """Where NoDR puts its point mass."""

    point: tuple[float, ...] | None = None  # parameter units; None: the space's nominal point


@dataclasses.dataclass(frozen=True)
class FullDRConfig:
    """FullDR has no settings (the dataclass keeps the one constructor signature)."""


class NoDR:
    """No randomization: every episode runs at one fixed point (the space's nominal point by default).

    The distribution is a point mass. Its "density" is reported as log_prob = +inf at exactly the
    point and -inf elsewhere, and its differential entropy as -inf: the limits of a Gaussian of
    vanishing width. Code that mixes samplers must therefore handle infinite log_prob/entropy.

    Arguments:
        space: the parameter box.
        success_threshold: J_T (kept for reference; NoDR learns nothing).
        config: a NoDRConfig, a mapping of its fields, or None; `overrides` (e.g. `point=[...]`)
            are its fields, applied last.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: NoDRConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "NoDR")
        self.space = space
        self.config = config_with_overrides(NoDRConfig, config, overrides, "NoDR")
        point = self.config.point
        chosen = space.nominal() if point is None else np.asarray(point, dtype=np.float64)
        if chosen.ndim != 1:
            raise InputError(f"NoDR: point must have shape ({space.dim},), got {chosen.shape}")
        self.point: NDArray[np.float64] = space.validate(chosen, what="NoDR point")

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n copies of the point, shape (n, d) (rng is validated but not consumed)."""
        n = check_sample_args(n, rng)
        return np.tile(self.point, (n, 1))

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """+inf where xi equals the point exactly, -inf elsewhere; shape (n,)."""
        batch = self.space.as_batch(xi)
        at_point = np.all(batch == self.point, axis=1)
        return np.where(at_point, math.inf, -math.inf)

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """Validate the batch; nothing is learned."""
        _, ret = check_update_inputs(self.space, xi, returns)
        return base_diagnostics(ret, self.entropy())

    def entropy(self) -> float:
        """-inf: a point mass has no differential entropy."""
        return -math.inf

    def state_dict(self) -> dict[str, Any]:
        """Type, ParamSpace and the point."""
        return {"type": type(self).__name__, "space": self.space.to_dict(), "point": self.point.tolist()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the point after checking the type and ParamSpace."""
        check_state_dict(self.space, state, type(self).__name__)
        point = np.asarray(state.get("point"), dtype=np.float64)
        if point.shape != (self.space.dim,):
            raise ValueError(f"load_state_dict: NoDR point has shape {point.shape}, expected ({self.space.dim},)")
        self.point = self.space.validate(point, what="NoDR point")

    def __repr__(self) -> str:
        """Class, point and space."""
        return f"NoDR(point={self.point.tolist()}, space={self.space})"


class FullDR:
    """Uniform randomization over the whole box: log_prob = -log(volume) inside, entropy = log(volume).

    Arguments: as every sampler (`space`, `success_threshold`, `config`: FullDRConfig, empty)."""

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: FullDRConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "FullDR")
        self.space = space
        self.config = config_with_overrides(FullDRConfig, config, overrides, "FullDR")

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n independent uniform draws from the box, shape (n, d)."""
        n = check_sample_args(n, rng)
        return rng.uniform(self.space.low, self.space.high, size=(n, self.space.dim))

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """-log(volume) inside the closed box, -inf outside; shape (n,)."""
        batch = self.space.as_batch(xi)
        inside = self.space.contains(batch)
        return np.where(inside, -math.log(self.space.volume()), -math.inf)

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """Validate the batch; nothing is learned."""
        _, ret = check_update_inputs(self.space, xi, returns)
        return base_diagnostics(ret, self.entropy())

    def entropy(self) -> float:
        """log(volume) of the box, in nats."""
        return math.log(self.space.volume())

    def state_dict(self) -> dict[str, Any]:
        """Type and ParamSpace (there is nothing else)."""
        return {"type": type(self).__name__, "space": self.space.to_dict()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Check the type and ParamSpace; there is no state to restore."""
        check_state_dict(self.space, state, type(self).__name__)

    def __repr__(self) -> str:
        """Class and space."""
        return f"FullDR(space={self.space})"


def check_sampler_args(space: Any, success_threshold: Any, owner: str, required: bool = False) -> float | None:
    """Check a sampler's constructor arguments: `space` must be a ParamSpace and J_T a finite
    number, or None where the method does not need it (`required=False`); returns J_T."""
    if not isinstance(space, ParamSpace):
        raise InputError(f"{owner}: space must be a ParamSpace, got {type(space).__name__}")
    if success_threshold is None and not required:
        return None
    return check_number(success_threshold, f"{owner}: success_threshold")
