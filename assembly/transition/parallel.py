"""`ParallelTransitionSim`: a transition simulator whose batches are split over worker processes.

Drake simulations scale across processes, not threads: Python-side callbacks hold the GIL
(docs/envs.md#speed measures process scaling).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.transition.base import TransitionSim, check_step_args, xi_groups
from goflow_common.pool import ProcessPool

__all__ = ["ParallelTransitionSim"]

_WORKER_SIM: TransitionSim | None = None


def _worker_init(env_id: str, kwargs: dict[str, Any]) -> None:
    from assembly.transition.registry import make_transition_sim

    global _WORKER_SIM
    _WORKER_SIM = make_transition_sim(env_id, **kwargs)


def _worker_step(states: NDArray, actions: NDArray, xi: NDArray) -> NDArray[np.float64]:
    assert _WORKER_SIM is not None
    return _WORKER_SIM.step(states, actions, xi)


class ParallelTransitionSim:
    """A TransitionSim whose `step` splits the batch over `workers` processes.

    Each worker builds its own simulator from the registry (`make_transition_sim`) in a fresh
    ("spawn") process, so `env_id` must be registered when `assembly.transition` is imported. Rows
    are ordered by xi first (`xi_groups`), so each chunk rewrites its model few times. A batch
    smaller than 2 x `workers` rows is stepped in-process. The result equals the serial one. The
    workers are a goflow_common.pool.ProcessPool: a worker that dies is a WorkerError, not a hang.

    Arguments:
        env_id: the registry id of the simulator.
        workers: the number of processes (1: everything in-process, no pool).
        kwargs: keyword arguments of the simulator.
    """

    def __init__(self, env_id: str, workers: int = 1, **kwargs: Any) -> None:
        from assembly.transition.registry import make_transition_sim

        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"ParallelTransitionSim: workers must be an integer >= 1, got {workers!r}")
        self._local = make_transition_sim(env_id, **kwargs)
        self.env_id, self.space = env_id, self._local.space
        self.state_dim, self.action_dim = self._local.state_dim, self._local.action_dim
        self.control_dt = self._local.control_dt
        self.workers = workers
        self._pool = ProcessPool(workers, _worker_init, (env_id, kwargs)) if workers > 1 else None

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """Step the rows in `workers` contiguous chunks of the xi-grouped order, in parallel.

        Arguments:
            states: states, shape (n, ds).
            actions: normalized actions, shape (n, da).
            xi: parameters, shape (n, d).

        Returns:
            The next states, shape (n, ds) (see `TransitionSim.step`).
        """
        s, a, x = check_step_args(self, states, actions, xi)
        if self._pool is None or len(s) < 2 * self.workers:
            return self._local.step(s, a, x)
        order = np.concatenate(xi_groups(x))
        chunks = np.array_split(order, self.workers)
        parts = self._pool.map(_worker_step, [(s[c], a[c], x[c]) for c in chunks])
        out = np.empty_like(s)
        for c, p in zip(chunks, parts):
            out[c] = p
        return out

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The in-process simulator's (see `TransitionSim.initial_state`)."""
        return self._local.initial_state(xi, rng)

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The in-process simulator's (see `TransitionSim.observe`)."""
        return self._local.observe(state)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """The in-process simulator's (see `TransitionSim.random_action`)."""
        return self._local.random_action(rng)

    def close(self) -> None:
        """Stop the worker processes (idempotent)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None
