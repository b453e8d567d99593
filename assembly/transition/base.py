"""The transition-simulator contract (`TransitionSim`), its batch check, and the base class that
owns the batch loop (`BatchTransitionSim`)."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from goflow_common.errors import SimulationError

__all__ = ["TransitionSim", "BatchTransitionSim", "check_step_args", "xi_groups"]


@runtime_checkable
class TransitionSim(Protocol):
    """A simulator that steps arbitrary states under arbitrary parameters xi.

    Offline estimation replays logged transitions with it: reset to a logged state, apply the
    logged action under parameters xi, compare the next state with the logged one.

    Attributes:
        env_id: the registry id (`assembly.transition.TRANSITION_SIMS`).
        space: the ParamSpace of the parameters it can set (names, bounds, units).
        state_dim: the length ds of a state (the full simulator state, what logs hold).
        action_dim: the length da of a normalized action.
        control_dt: simulated seconds of one step [s].
    """

    env_id: str
    space: ParamSpace
    state_dim: int
    action_dim: int
    control_dt: float

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row.

        Arguments:
            states: states, shape (n, ds), finite.
            actions: normalized actions, shape (n, da), finite (clipped to [-1, 1]).
            xi: parameters, shape (n, d), inside `space`.

        Returns:
            The next states, shape (n, ds): row i is one control step from `states[i]` under
            `actions[i]` with parameters `xi[i]`, independent of the other rows and of their
            order. A row whose physics fails (SimulationError, non-finite state) is NaN: one bad
            parameter never aborts a batch.
        """
        ...

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """An episode's first state.

        Arguments:
            xi: parameters, shape (d,).
            rng: the generator any reset noise is drawn from.

        Returns:
            The state, shape (ds,).
        """
        ...

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The policy's observation of a state (what `collect` feeds a policy).

        Arguments:
            state: a state, shape (ds,).

        Returns:
            The observation, float32.
        """
        ...

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """A uniformly random normalized action.

        Arguments:
            rng: the generator it is drawn from.

        Returns:
            An action in [-1, 1]^da.
        """
        ...


def check_step_args(
    sim: Any, states: ArrayLike, actions: ArrayLike, xi: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Validate a batch for `sim.step`.

    Arguments:
        sim: the simulator (its `state_dim`, `action_dim` and `space` give the shapes and box).
        states: shape (n, ds), finite.
        actions: shape (n, da), finite.
        xi: shape (n, d), inside `sim.space`.

    Returns:
        The three as float64 arrays (xi a copy).

    Raises:
        ValueError: a shape, a non-finite entry or a parameter out of its bounds, named.
    """
    s = np.asarray(states, dtype=np.float64)
    a = np.asarray(actions, dtype=np.float64)
    x = np.asarray(xi, dtype=np.float64)
    name = type(sim).__name__
    if s.ndim != 2 or s.shape[1] != sim.state_dim:
        raise ValueError(f"{name}.step: states has shape {s.shape}, expected (n, {sim.state_dim})")
    n = s.shape[0]
    if a.shape != (n, sim.action_dim):
        raise ValueError(f"{name}.step: actions has shape {a.shape}, expected ({n}, {sim.action_dim})")
    if x.shape != (n, sim.space.dim):
        raise ValueError(
            f"{name}.step: xi has shape {x.shape}, expected ({n}, {sim.space.dim}) for parameters {sim.space.names}"
        )
    for what, arr in (("states", s), ("actions", a)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}.step: {what} must be finite")
    return s, a, sim.space.validate(x, what=f"{name}.step xi")


def xi_groups(xi: NDArray[np.float64]) -> list[NDArray[np.int64]]:
    """The rows of a batch grouped by equal parameters (each group's model is written once).

    Arguments:
        xi: parameters, shape (n, d).

    Returns:
        Row-index arrays, one per distinct parameter vector, in lexicographic order of xi; their
        concatenation is a permutation of range(n) (empty list for n = 0).
    """
    if len(xi) == 0:
        return []
    order = np.lexsort(xi.T[::-1])
    ordered = xi[order]
    starts = np.flatnonzero(np.any(ordered[1:] != ordered[:-1], axis=1)) + 1
    return np.split(order, starts)


class BatchTransitionSim:
    """Base of the transition simulators: it owns the batch loop; a model implements hooks.

    `step` validates the batch (`check_step_args`), groups the rows with equal xi (`xi_groups`),
    calls `_apply_xi` once per group, and then, per row of the group:

    1. `_set_state(state)`: put the model at the row's state, time 0;
    2. `_apply_action(state, action)`: fix the model's inputs for one control step;
    3. `_advance()`: simulate one control step;
    4. `_read_state()`: the state after the step.

    A row whose `_advance` raises SimulationError or RuntimeError (Drake's failures), or whose
    next state is not finite, is NaN; the batch goes on. A model that steps a batch at once
    (an analytic one) may override `step` instead, keeping its contract (`TransitionSim.step`).

    Subclasses set `env_id`, `space`, `state_dim`, `action_dim`, `control_dt` and implement
    the five hooks and `initial_state`; `observe` (the state as float32) and `random_action`
    (uniform in [-1, 1]^da) have defaults.

    Where an effect goes. The sim-to-real diagnosis adds unmodelled effects (joint friction, a
    sensor offset, an actuation delay) as subclasses or mixins that override one hook and call
    `super()`:

    - actuation effects (delay, deadband, torque bias, extra joint friction) change the inputs
      in `_apply_action`, which sees the row's state (a model may split it further, e.g.
      `PandaArmSim._joint_friction`);
    - sensing effects (offset, scale, noise) map the model state to the measured one in
      `_read_state` and back in `_set_state`, so that logged states keep their meaning;
    - an effect's own parameters extend `space`; its `_apply_xi` takes its slice and passes the
      model's slice to `super()._apply_xi` (rows are grouped by the whole xi, effect included);
    - an effect with memory (a delay) must carry it in the state: every row starts from a
      logged state, never from the previous row.
    """

    env_id: str
    space: ParamSpace
    state_dim: int
    action_dim: int
    control_dt: float

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row; NaN rows where the physics failed (see `TransitionSim.step`).

        Arguments:
            states: states, shape (n, ds).
            actions: normalized actions, shape (n, da).
            xi: parameters, shape (n, d).

        Returns:
            The next states, shape (n, ds).
        """
        s, a, x = check_step_args(self, states, actions, xi)
        out = np.full_like(s, np.nan)
        for rows in xi_groups(x):
            self._apply_xi(x[rows[0]])
            for i in rows:
                out[i] = self._step_row(s[i], a[i])
        return out

    def _step_row(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> NDArray[np.float64]:
        """One control step from `state` under the parameters last applied; NaN on failure."""
        self._set_state(state)
        self._apply_action(state, action)
        try:
            self._advance()
        except (SimulationError, RuntimeError):
            return np.full(self.state_dim, np.nan)
        nxt = self._read_state()
        return nxt if np.all(np.isfinite(nxt)) else np.full(self.state_dim, np.nan)

    # -- hooks ---------------------------------------------------------------------------------

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """Write the parameters into the model.

        Arguments:
            xi: one parameter vector, shape (d,), inside `space`.
        """
        raise NotImplementedError

    def _set_state(self, state: NDArray[np.float64]) -> None:
        """Put the model at `state`, at time 0.

        Arguments:
            state: shape (ds,).
        """
        raise NotImplementedError

    def _apply_action(self, state: NDArray[np.float64], action: NDArray[np.float64]) -> None:
        """Fix the model's inputs for one control step.

        Arguments:
            state: the row's state, shape (ds,) (for state-dependent inputs).
            action: the normalized action, shape (da,).
        """
        raise NotImplementedError

    def _advance(self) -> None:
        """Simulate one control step; SimulationError (or Drake's RuntimeError) if it fails."""
        raise NotImplementedError

    def _read_state(self) -> NDArray[np.float64]:
        """The model's state, shape (ds,), a copy."""
        raise NotImplementedError

    # -- defaults ------------------------------------------------------------------------------

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """An episode's first state (see `TransitionSim.initial_state`)."""
        raise NotImplementedError

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The state itself, as float32.

        Arguments:
            state: shape (ds,).

        Returns:
            The observation, shape (ds,).
        """
        return np.asarray(state, dtype=np.float32)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """A uniform draw in [-1, 1]^da.

        Arguments:
            rng: the generator it is drawn from.

        Returns:
            The action, shape (da,).
        """
        return rng.uniform(-1.0, 1.0, size=self.action_dim)
