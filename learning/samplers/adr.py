"""Automatic Domain Randomization (ADR; OpenAI et al. 2019, "Solving Rubik's Cube with a Robot Hand").

ADR keeps one interval [lo_i, hi_i] per parameter, starting around the nominal point, and samples
uniformly from the product of the intervals. With probability `boundary_prob` a sample instead pins
one uniformly chosen dimension i to one of its two current bounds (lo_i or hi_i, each with
probability 1/2; the other dimensions stay uniform). The returns of episodes run at a bound go into
that bound's queue; when a queue holds `queue_length` returns its mean decides the bound's move:

- mean >= t+ : the bound moves outward by Delta_i (expand), clipped to the ParamSpace box;
- mean <= t- : the bound moves inward by Delta_i (contract), never past the nominal point
  (so lo_i <= nominal_i <= hi_i always holds, and a bound never crosses the other one);
- otherwise nothing moves;

and the queue is cleared in all three cases. Defaults (the GoFlow paper's ADR baseline): t+ = J_T,
t- = 0.5 x t+, Delta_i = 0.1 x (high_i - low_i), boundary probability 0.5; initial width 0.05 of
the box (`init_width_fraction`; 0 gives the paper's zero-width start).

`update(xi, returns)` counts a row toward bound (i, side) exactly when xi[row, i] equals that
bound (exact float equality), so feed it the episodes it sampled; a batch with no row on any bound
changes nothing and raises a UserWarning.

Density conventions (assembly/samplers.py): `log_prob` and `entropy` describe the uniform
distribution on the current intervals, without boundary sampling's point masses:
log_prob = -sum_i log(hi_i - lo_i) inside the closed intervals, -inf outside; entropy =
sum_i log(hi_i - lo_i). With a zero-width dimension entropy = -inf and log_prob = +inf on the
degenerate set (-inf off it), as for NoDR.

Details (boundary-row matching, t- for J_T <= 0, the defects of the port this replaces):
docs/learning.md#adr.

References: OpenAI et al., "Solving Rubik's Cube with a Robot Hand", arXiv:1910.07113, 2019;
Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic Skills",
ICML 2025, appendix A.2 (baseline settings).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import (
    check_sample_args,
    check_sampler_args,
    check_state_dict,
    check_update_inputs,
)
from goflow_common.checks import check_int, check_number
from goflow_common.config import config_to_dict, config_with_overrides

__all__ = ["ADRConfig", "ADRSampler"]

_SIDES = ("low", "high")


@dataclass(frozen=True)
class ADRConfig:
    """Hyperparameters of ADR (defaults: GoFlow paper, Curtis et al., ICML 2025, appendix A.2)."""

    # t- = t+ - (1 - ratio)|t+| (= ratio * t+ for t+ > 0); swept over {0.1, 0.25, 0.5, 0.75, 0.9}.
    t_minus_ratio: float = 0.5
    # Explicit thresholds override the defaults (t+ = success_threshold J_T, t- from the ratio).
    t_plus: float | None = None
    t_minus: float | None = None
    # Delta_i = step_fraction * (high_i - low_i) (A.2: 0.1 x range).
    step_fraction: float = 0.1
    # Probability that a sample pins one dimension to one of its bounds (A.2: 0.5).
    boundary_prob: float = 0.5
    # Returns per bound averaged before a decision (m in the ADR paper; TeachMyAgent uses 10).
    queue_length: int = 10
    # Initial interval width as a fraction of the box width, centred on the nominal point and
    # clipped to the box (0 = the ADR paper's start at the nominal point).
    init_width_fraction: float = 0.05

    def __post_init__(self) -> None:
        def num(name: str, lo: float | None, hi: float | None, lo_open: bool = False) -> None:
            object.__setattr__(
                self, name, check_number(getattr(self, name), f"ADRConfig.{name}", lo, hi, low_open=lo_open)
            )

        num("t_minus_ratio", 0.0, 1.0)
        num("step_fraction", 0.0, 1.0, lo_open=True)
        num("boundary_prob", 0.0, 1.0)
        num("init_width_fraction", 0.0, 1.0)
        for name in ("t_plus", "t_minus"):
            v = getattr(self, name)
            if v is not None:
                num(name, None, None)
        object.__setattr__(self, "queue_length", check_int(self.queue_length, "ADRConfig.queue_length", 1))


class ADRSampler:
    """ADR on a ParamSpace: per-dimension intervals grown and shrunk by boundary performance.

    Args:
        space: the parameter box.
        success_threshold: J_T, the return that counts as success; the default t+.
        config: an ADRConfig or a mapping of its fields (None: defaults).
        **overrides: ADRConfig fields as keywords; they take precedence over `config`.

    Attributes (read-only by convention): `lo`, `hi` (current bounds, shape (d,)), `delta`
    (step per dimension), `t_plus`, `t_minus`, and `queues` (dict keyed by (dim, "low"/"high")).
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float,
        config: ADRConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "ADRSampler", required=True)
        self.space = space
        self.config = config_with_overrides(ADRConfig, config, overrides, "ADR")
        c = self.config
        self.t_plus = self.success_threshold if c.t_plus is None else c.t_plus
        if c.t_minus is not None:
            self.t_minus = c.t_minus
        else:
            self.t_minus = self.t_plus - (1.0 - c.t_minus_ratio) * abs(self.t_plus)
        if not self.t_minus <= self.t_plus:
            raise ValueError(
                f"ADR config: need t_minus <= t_plus, got t_minus={self.t_minus:g}, t_plus={self.t_plus:g}"
            )

        self._box_lo = space.low
        self._box_hi = space.high
        self._nominal = space.nominal()
        width = self._box_hi - self._box_lo
        self.delta: NDArray[np.float64] = c.step_fraction * width
        half = 0.5 * c.init_width_fraction * width
        self.lo: NDArray[np.float64] = np.maximum(self._nominal - half, self._box_lo)
        self.hi: NDArray[np.float64] = np.minimum(self._nominal + half, self._box_hi)
        self.queues: dict[tuple[int, str], list[float]] = {(i, s): [] for i in range(space.dim) for s in _SIDES}
        self.n_updates = 0
        self.n_expansions = 0
        self.n_contractions = 0

    # -- sampling and density ------------------------------------------------------------------

    def bounds(self) -> NDArray[np.float64]:
        """Current bounds as a (d, 2) array [[lo_0, hi_0], ...] (a copy)."""
        return np.stack([self.lo, self.hi], axis=1)

    def widths(self) -> NDArray[np.float64]:
        """Current interval widths hi - lo, shape (d,)."""
        return self.hi - self.lo

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws, shape (n, d): uniform on the intervals, a fraction boundary_prob pinned to a bound."""
        n = check_sample_args(n, rng)
        d = self.space.dim
        xi = rng.uniform(self.lo, self.hi, size=(n, d))
        xi = np.clip(xi, self.lo, self.hi)  # uniform's half-open upper end, rounding: stay inside
        pinned = rng.random(n) < self.config.boundary_prob
        rows = np.flatnonzero(pinned)
        dims = rng.integers(0, d, size=rows.size)
        sides = rng.integers(0, 2, size=rows.size)
        values = np.where(sides == 0, self.lo[dims], self.hi[dims])
        xi[rows, dims] = values
        assert xi.shape == (n, d)
        return xi

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density of the uniform part on the current intervals (parameter units), shape (n,).

        Boundary-sampling atoms are ignored (see the module docstring). Outside the intervals:
        -inf. With a zero-width dimension: +inf on the degenerate set, -inf elsewhere.
        """
        batch = self.space.as_batch(xi)
        inside = np.all((batch >= self.lo) & (batch <= self.hi), axis=1)
        w = self.widths()
        if np.any(w <= 0.0):
            value = math.inf
        else:
            value = -float(np.sum(np.log(w)))
        out = np.where(inside, value, -math.inf)
        assert out.shape == (batch.shape[0],)
        return out

    def entropy(self) -> float:
        """sum_i log(hi_i - lo_i) in nats (parameter units); -inf if any width is zero."""
        w = self.widths()
        if np.any(w <= 0.0):
            return -math.inf
        return float(np.sum(np.log(w)))

    # -- learning ------------------------------------------------------------------------------

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """Push the returns of boundary episodes into their queues and move bounds whose queue is full.

        Returns diagnostics: n, mean_return, entropy, n_boundary (rows that sat on a bound),
        expanded / contracted (lists of [dim_name, side]), lo, hi, queue_fill.
        """
        x, ret = check_update_inputs(self.space, xi, returns)
        n, d = x.shape
        assert ret.shape == (n,)
        m = self.config.queue_length
        expanded: list[list[str]] = []
        contracted: list[list[str]] = []
        n_boundary = 0
        for r in range(n):
            row = x[r]
            on_bound = False
            for i in range(d):
                for side in _SIDES:
                    bound = self.lo[i] if side == "low" else self.hi[i]
                    if row[i] != bound:
                        continue
                    on_bound = True
                    q = self.queues[(i, side)]
                    q.append(float(ret[r]))
                    if len(q) < m:
                        continue
                    mean = float(np.mean(q))
                    q.clear()
                    if mean >= self.t_plus:
                        if self._move(i, side, outward=True):
                            expanded.append([self.space.names[i], side])
                    elif mean <= self.t_minus:
                        if self._move(i, side, outward=False):
                            contracted.append([self.space.names[i], side])
            n_boundary += on_bound
        if n_boundary == 0:
            warnings.warn(
                f"ADR update: none of the {n} episodes ran at a current bound, so no bound can move. ADR learns "
                "only from its own boundary samples: feed it episodes drawn with ADRSampler.sample "
                "(e.g. the training phase), not a batch drawn elsewhere (e.g. uniform on the box).",
                stacklevel=2,
            )
        self.n_updates += 1
        self.n_expansions += len(expanded)
        self.n_contractions += len(contracted)
        return {
            "n": int(n),
            "mean_return": float(ret.mean()),
            "entropy": self.entropy(),
            "n_boundary": int(n_boundary),
            "expanded": expanded,
            "contracted": contracted,
            "lo": self.lo.tolist(),
            "hi": self.hi.tolist(),
            "queue_fill": {f"{self.space.names[i]}:{s}": len(q) for (i, s), q in self.queues.items()},
        }

    def _move(self, i: int, side: str, outward: bool) -> bool:
        """Move bound (i, side) by delta_i; outward clips to the box, inward to the nominal point."""
        nominal = self._nominal[i]
        if side == "low":
            old = self.lo[i]
            new = max(old - self.delta[i], self._box_lo[i]) if outward else min(old + self.delta[i], nominal)
            self.lo[i] = new
        else:
            old = self.hi[i]
            new = min(old + self.delta[i], self._box_hi[i]) if outward else max(old - self.delta[i], nominal)
            self.hi[i] = new
        assert self._box_lo[i] <= self.lo[i] <= nominal <= self.hi[i] <= self._box_hi[i]
        return bool(new != old)

    # -- checkpoints ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable state: type, space, threshold, config, bounds, queues and counters."""
        return {
            "type": type(self).__name__,
            "space": self.space.to_dict(),
            "success_threshold": self.success_threshold,
            "config": config_to_dict(self.config),
            "lo": self.lo.tolist(),
            "hi": self.hi.tolist(),
            "queues": [[i, s, list(q)] for (i, s), q in self.queues.items()],
            "n_updates": self.n_updates,
            "n_expansions": self.n_expansions,
            "n_contractions": self.n_contractions,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from `state_dict`; ValueError on another type, another ParamSpace or bad contents."""
        check_state_dict(self.space, state, type(self).__name__)
        try:
            restored = ADRSampler(self.space, state["success_threshold"], state["config"])
            lo = np.asarray(state["lo"], dtype=np.float64)
            hi = np.asarray(state["hi"], dtype=np.float64)
            queues = {(int(i), str(s)): [float(v) for v in q] for i, s, q in state["queues"]}
            counters = {k: int(state[k]) for k in ("n_updates", "n_expansions", "n_contractions")}
        except (KeyError, TypeError) as exc:
            raise ValueError(f"load_state_dict: malformed ADRSampler state_dict ({exc!r})") from exc
        d = self.space.dim
        if lo.shape != (d,) or hi.shape != (d,):
            raise ValueError(f"load_state_dict: ADR bounds have shapes {lo.shape}, {hi.shape}, expected ({d},)")
        nom = self.space.nominal()
        ok = np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
        ok = (
            ok
            and np.all(self.space.low <= lo)
            and np.all(lo <= nom)
            and np.all(nom <= hi)
            and np.all(hi <= self.space.high)
        )
        if not ok:
            raise ValueError(
                f"load_state_dict: ADR bounds lo={lo.tolist()}, hi={hi.tolist()} are not low <= lo <= nominal <= hi <= high"
            )
        if set(queues) != set(restored.queues):
            raise ValueError("load_state_dict: ADR queues do not match the ParamSpace's dimensions")
        restored.lo, restored.hi, restored.queues = lo, hi, queues
        restored.n_updates = counters["n_updates"]
        restored.n_expansions = counters["n_expansions"]
        restored.n_contractions = counters["n_contractions"]
        self.__dict__.update(restored.__dict__)

    def __repr__(self) -> str:
        """Class, current intervals and thresholds."""
        iv = ", ".join(f"{name} in [{a:g}, {b:g}]" for name, a, b in zip(self.space.names, self.lo, self.hi))
        return f"ADRSampler({iv}; t+={self.t_plus:g}, t-={self.t_minus:g})"
