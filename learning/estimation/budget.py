"""The simulator budget every estimator spends: its bookkeeping (calls, wall time, a trace of
snapshots for OT-vs-time plots, a progress bar) and the check that a budget buys one iteration."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from goflow_common.checks import check_int
from goflow_common.errors import InputError
from learning.estimation.dataset import TransitionDataset
from learning.estimation.distributions import UnitBoxDistribution

__all__ = ["Budget", "BudgetExhausted", "check_sim_budget"]


class BudgetExhausted(RuntimeError):
    """The next simulator batch would exceed the budget."""


@dataclass
class Budget:
    """Steps the simulator for an estimator while counting calls (one call = one row stepped) and
    wall time; `snapshot` records samples of the current estimate (outside the timed region).
    With `progress`, a tqdm bar shows the calls used against `max_calls`; `close()` ends it."""

    data: TransitionDataset
    sim: Any  # a TransitionSim
    max_calls: int
    snapshot_samples: int = 500
    calls: int = 0
    trace: list[dict[str, Any]] = field(default_factory=list)
    progress: bool = False
    desc: str = "estimate"  # the progress bar's label

    def __post_init__(self) -> None:
        self.max_calls = check_int(self.max_calls, "sim_budget", 1)
        self.scale = self.data.delta_scale()
        self._bar = tqdm(
            total=self.max_calls,
            initial=self.calls,
            disable=not self.progress,
            desc=self.desc,
            unit="call",
            unit_scale=True,
        )
        self._t0 = time.perf_counter()
        self._paused = 0.0

    @property
    def seconds(self) -> float:
        """Wall time since the start, excluding snapshots."""
        return time.perf_counter() - self._t0 - self._paused

    def remaining(self) -> int:
        """Simulator calls left."""
        return self.max_calls - self.calls

    def can_afford(self, calls: int) -> bool:
        """Whether `calls` more simulator calls fit in the budget."""
        return self.calls + calls <= self.max_calls

    def predict(self, rows: NDArray[np.int64], u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Next states (M, R, ds) of the logged rows under each of M unit-box parameters u (M, d)."""
        m, r = len(u), len(rows)
        if not self.can_afford(m * r):
            raise BudgetExhausted(f"{m * r} calls requested, {self.remaining()} left")
        xi = self.data.space.denormalize(np.clip(u, 0.0, 1.0))
        s = np.tile(self.data.states[rows], (m, 1))
        a = np.tile(self.data.actions[rows], (m, 1))
        x = np.repeat(xi, r, axis=0)
        out = self.sim.step(s, a, x)
        self._count(m * r)
        return out.reshape(m, r, -1)

    def step_rows(self, rows: NDArray[np.int64], u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Next states (R, ds) of the logged rows, row r under its own unit-box parameters u[r]."""
        if not self.can_afford(len(rows)):
            raise BudgetExhausted(f"{len(rows)} calls requested, {self.remaining()} left")
        xi = self.data.space.denormalize(np.clip(u, 0.0, 1.0))
        out = self.sim.step(self.data.states[rows], self.data.actions[rows], xi)
        self._count(len(rows))
        return out

    def _count(self, calls: int) -> None:
        self.calls += calls
        self._bar.update(calls)

    def close(self) -> None:
        """End the progress bar (the counts stay readable)."""
        self._bar.close()

    def snapshot(self, dist: UnitBoxDistribution, **extra: Any) -> None:
        """Record (calls, seconds, samples of dist) without counting the sampling time."""
        t = time.perf_counter()
        seconds = self.seconds
        u = dist.sample_u(self.snapshot_samples, np.random.default_rng(12345))
        self.trace.append({"calls": self.calls, "seconds": seconds, "u": u, **extra})
        self._paused += time.perf_counter() - t


def check_sim_budget(sim_budget: int, method: str, need: tuple[int, str]) -> None:
    """InputError unless `sim_budget` buys one iteration of `method`; `need` is (calls, how they
    add up), as the methods' `min_sim_calls(config, data)` return it."""
    calls, why = need
    if sim_budget < calls:
        raise InputError(
            f"sim_budget = {sim_budget}; {method} needs at least {calls} simulator calls for one "
            f"iteration on this dataset ({why})"
        )
