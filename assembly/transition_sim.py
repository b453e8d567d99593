"""Simulators for offline parameter estimation: reset to a logged state, apply the logged action for
given parameters xi, return the next state.

Every simulator here keeps one contract (`TransitionSim`):
- `space` is the ParamSpace of the parameters it can set (names, bounds, units);
- `step(states (n, ds), actions (n, da), xi (n, d))` returns the next states (n, ds): row i is one
  control step from states[i] under actions[i] with parameters xi[i]. Rows whose physics step
  fails (SimulationError) come back as NaN: one bad parameter never aborts a batch;
- `initial_state(xi, rng)` and `observe(state)` let `collect` run episodes (the policy sees
  `observe(state)`, the log holds the full simulator state);
- `random_action(rng)` draws a uniformly random normalized action.

Batching across processes is `ParallelTransitionSim`: the rows are split into chunks stepped by
worker processes that each build their own simulator (Drake simulations scale across processes,
not threads: REFERENCES.md).

The simulators: `goflow/PointMass-v0` (an analytic damped point mass, cheap: for tests),
`goflow/Cartpole-v0` (the env's own Drake model through CartpoleEnv.bare_rollout),
`goflow/Ant-v0` (the env's Drake model, xi = torso mass and leg joint damping) and
`goflow/PandaArm-v0` (assembly/envs/panda_arm.py: our Panda arm, link masses, joint damping and
friction).
"""

from __future__ import annotations

import math
import multiprocessing as mp
from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import SimulationError
from assembly.params import Param, ParamSpace

__all__ = ["TransitionSim", "PointMassSim", "CartpoleTransitionSim", "AntTransitionSim",
           "ParallelTransitionSim", "TRANSITION_SIMS", "make_transition_sim", "check_step_args"]


@runtime_checkable
class TransitionSim(Protocol):
    """A simulator that steps arbitrary states under arbitrary parameters (see the module docstring)."""

    env_id: str
    space: ParamSpace
    state_dim: int
    action_dim: int
    control_dt: float

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row; NaN rows where the physics failed."""
        ...

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """An episode's first state for parameters xi."""
        ...

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The policy's observation of a state."""
        ...

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """A uniformly random normalized action in [-1, 1]^da."""
        ...


def check_step_args(sim: Any, states: ArrayLike, actions: ArrayLike, xi: ArrayLike
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Validate a batch for `sim.step`: shapes (n, ds), (n, da), (n, d), finite; xi inside the box."""
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
        raise ValueError(f"{name}.step: xi has shape {x.shape}, expected ({n}, {sim.space.dim}) for "
                         f"parameters {sim.space.names}")
    for what, arr in (("states", s), ("actions", a)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}.step: {what} must be finite")
    return s, a, sim.space.validate(x, what=f"{name}.step xi")


def _grouped_rows(xi: NDArray[np.float64]) -> NDArray[np.int64]:
    """Row order that visits equal parameter vectors consecutively (fewer model rewrites)."""
    return np.lexsort(xi.T[::-1])


# -- a cheap analytic simulator -----------------------------------------------------------------

POINT_MASS_SPACE = ParamSpace((
    Param("mass", 0.5, 5.0, "kg"),
    Param("damping", 0.1, 5.0, "N s/m"),
))


@dataclass(frozen=True)
class PointMassConfig:
    """A point mass on a line pushed by a force, with viscous damping (exact discretization)."""

    control_dt: float = 0.05  # [s]
    max_force: float = 10.0  # [N] force at action 1
    initial_speed: float = 1.0  # [m/s] initial speed drawn uniformly in +-this


class PointMassSim:
    """m dv/dt = F - c v, x' = x + integral of v: exact zero-order-hold steps, vectorized (no Drake)."""

    env_id = "goflow/PointMass-v0"
    state_dim = 2
    action_dim = 1

    def __init__(self, config: PointMassConfig | None = None) -> None:
        self.config = config or PointMassConfig()
        self.space = POINT_MASS_SPACE
        self.control_dt = self.config.control_dt

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """Exact step of (x, v) under a held force; vectorized over rows."""
        s, a, x = check_step_args(self, states, actions, xi)
        m, c = x[:, 0], x[:, 1]
        force = self.config.max_force * np.clip(a[:, 0], -1.0, 1.0)
        dt = self.control_dt
        v_inf = force / c  # terminal speed under the held force
        decay = np.exp(-c / m * dt)
        v = s[:, 1]
        v_next = v_inf + (v - v_inf) * decay
        x_next = s[:, 0] + v_inf * dt + (v - v_inf) * (m / c) * (1.0 - decay)
        return np.stack([x_next, v_next], axis=1)

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """At the origin with a random speed."""
        self.space.validate(np.asarray(xi, dtype=np.float64))
        return np.array([0.0, rng.uniform(-self.config.initial_speed, self.config.initial_speed)])

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The state itself."""
        return np.asarray(state, dtype=np.float32)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Uniform in [-1, 1]."""
        return rng.uniform(-1.0, 1.0, size=1)


# -- Cartpole -----------------------------------------------------------------------------------


class CartpoleTransitionSim:
    """goflow/Cartpole-v0's Drake model; state = plant state (x, z, theta, xdot, zdot, thetadot)."""

    env_id = "goflow/Cartpole-v0"
    state_dim = 6
    action_dim = 1

    def __init__(self, **env_kwargs: Any) -> None:
        from assembly.envs.cartpole import CartpoleEnv

        self._env = CartpoleEnv(**env_kwargs)
        self.space = self._env.space
        self.control_dt = self._env.control_dt

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row through CartpoleEnv.bare_rollout (rows grouped by xi)."""
        s, a, x = check_step_args(self, states, actions, xi)
        out = np.full_like(s, np.nan)
        for i in _grouped_rows(x):
            try:
                out[i] = self._env.bare_rollout(x[i], a[i:i + 1], initial_state=s[i])[0]
            except SimulationError:
                pass  # NaN row: this parameter cannot reproduce the step
        return out

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's own reset state for xi (pole angle drawn by the env from a seed taken from rng)."""
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": np.asarray(xi, dtype=np.float64)})
        return self._env.initial_state

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """The env's observation (x, xdot, cos theta, sin theta, thetadot)."""
        s = np.asarray(state, dtype=np.float64)
        obs = np.array([s[0], s[3], math.cos(s[2]), math.sin(s[2]), s[5]])
        high = self._env.observation_space.high.astype(np.float64)
        return np.clip(obs, -high, high).astype(np.float32)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Uniform in [-1, 1]."""
        return rng.uniform(-1.0, 1.0, size=1)


# -- Ant ----------------------------------------------------------------------------------------

ANT_SPACE = ParamSpace((
    Param("torso_mass", 0.01, 20.0, "kg"),  # the env's box (paper appendix A.1)
    Param("leg_damping", 0.0, 2.0, "N m s/rad", nominal=0.1),  # all 8 joints (nv_ant: 0.1)
))


class AntTransitionSim:
    """goflow/Ant-v0's Drake model (same builder and config), stepped from arbitrary states.

    State = the plant's [q; v] (29,). Parameters: the torso mass (the env's randomized parameter;
    inertia scales with it) and the damping of all eight leg joints (fixed at 0.1 in the env).
    """

    env_id = "goflow/Ant-v0"
    action_dim = 8

    def __init__(self, **env_kwargs: Any) -> None:
        import logging

        from pydrake.multibody.tree import SpatialInertia  # noqa: F401  (fail early without drake)
        from pydrake.systems.analysis import Simulator

        from assembly.envs import ant

        self._env = ant.AntEnv(**env_kwargs)  # initial states and observations
        self.config = self._env.config
        drake_log = logging.getLogger("drake")
        level = drake_log.level
        drake_log.setLevel(logging.ERROR)
        try:
            self._diagram, self._plant, self._torso, self._joints, _, m_torso = ant._build(self.config)
            self._simulator = Simulator(self._diagram)
        finally:
            drake_log.setLevel(level)
        self._com0 = np.asarray(m_torso.get_com())
        self._unit_inertia0 = m_torso.get_unit_inertia()
        self._context = self._simulator.get_mutable_context()
        self._plant_context = self._plant.GetMyMutableContextFromRoot(self._context)
        self._port = self._plant.get_actuation_input_port()
        self._u_index = np.array([j.velocity_start() for j in self._joints])  # actuator order = joint order
        self.space = ANT_SPACE
        self.state_dim = self._plant.num_positions() + self._plant.num_velocities()
        self.control_dt = self.config.control_dt
        self._set: tuple[float, float] | None = None
        probe = self._env.observation_space.shape[0]
        self._obs_dim = int(probe)

    def _apply_xi(self, mass: float, damping: float) -> None:
        from pydrake.multibody.tree import SpatialInertia

        if self._set == (mass, damping):
            return
        self._torso.SetSpatialInertiaInBodyFrame(
            self._plant_context, SpatialInertia(mass, self._com0, self._unit_inertia0))
        for j in self._joints:
            j.SetDampingVector(self._plant_context, [damping])
        self._set = (mass, damping)

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """One control step per row (rows grouped by xi)."""
        from assembly.envs.drake_sim import advance

        s, a, x = check_step_args(self, states, actions, xi)
        out = np.full_like(s, np.nan)
        u = np.zeros(self._plant.num_actuated_dofs())
        for i in _grouped_rows(x):
            self._apply_xi(float(x[i, 0]), float(x[i, 1]))
            self._context.SetTime(0.0)
            self._plant.SetPositionsAndVelocities(self._plant_context, s[i])
            u[:] = np.clip(a[i], -1.0, 1.0) * self.config.effort_limit
            self._port.FixValue(self._plant_context, u)
            try:
                self._simulator.Initialize()
                advance(self._simulator, self.control_dt, "AntTransitionSim")
            except (SimulationError, RuntimeError):
                continue
            nxt = self._plant.GetPositionsAndVelocities(self._plant_context)
            if np.all(np.isfinite(nxt)):
                out[i] = nxt
        return out

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """The env's reset pose (with its reset noise) for the torso mass xi[0]."""
        xi = self.space.validate(np.asarray(xi, dtype=np.float64))
        self._env.reset(seed=int(rng.integers(2**31)), options={"xi": xi[:1]})
        return self._env.state()

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """goflow/Ant-v0's observation of a state (height, quaternion, joints, velocities)."""
        s = np.asarray(state, dtype=np.float64)
        nq = self._plant.num_positions()
        fb_q, fb_v = self._torso.floating_positions_start(), self._torso.floating_velocities_start_in_v()
        qj = np.array([j.position_start() for j in self._joints])
        vj = np.array([j.velocity_start() for j in self._joints])
        quat = s[fb_q:fb_q + 4] / max(float(np.linalg.norm(s[fb_q:fb_q + 4])), 1e-12)
        obs = np.concatenate([[s[fb_q + 6]], quat, s[qj], s[nq + fb_v + 3:nq + fb_v + 6],
                              s[nq + fb_v:nq + fb_v + 3], s[nq + vj]])
        return obs.astype(np.float32)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Uniform in [-1, 1]^8."""
        return rng.uniform(-1.0, 1.0, size=8)


# -- registry and process pool ------------------------------------------------------------------


def _panda_arm(**kwargs: Any) -> TransitionSim:
    from assembly.envs.panda_arm import PandaArmSim
    return PandaArmSim(**kwargs)


TRANSITION_SIMS: dict[str, Callable[..., TransitionSim]] = {
    "goflow/PointMass-v0": lambda **kw: PointMassSim(PointMassConfig(**kw)),
    "goflow/Cartpole-v0": CartpoleTransitionSim,
    "goflow/Ant-v0": AntTransitionSim,
    "goflow/PandaArm-v0": _panda_arm,
}


def make_transition_sim(env_id: str, **kwargs: Any) -> TransitionSim:
    """The step-from-state simulator of `env_id`; ValueError naming the known ids otherwise."""
    if env_id not in TRANSITION_SIMS:
        raise ValueError(f"no step-from-state simulator for env {env_id!r}; known: {sorted(TRANSITION_SIMS)}")
    return TRANSITION_SIMS[env_id](**kwargs)


_WORKER_SIM: TransitionSim | None = None


def _worker_init(env_id: str, kwargs: dict[str, Any]) -> None:
    global _WORKER_SIM
    _WORKER_SIM = make_transition_sim(env_id, **kwargs)


def _worker_step(args: tuple[NDArray, NDArray, NDArray]) -> NDArray[np.float64]:
    assert _WORKER_SIM is not None
    return _WORKER_SIM.step(*args)


class ParallelTransitionSim:
    """A TransitionSim whose `step` splits the batch over `workers` processes (1: in-process)."""

    def __init__(self, env_id: str, workers: int = 1, **kwargs: Any) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"ParallelTransitionSim: workers must be an integer >= 1, got {workers!r}")
        self._local = make_transition_sim(env_id, **kwargs)
        self.env_id, self.space = env_id, self._local.space
        self.state_dim, self.action_dim = self._local.state_dim, self._local.action_dim
        self.control_dt = self._local.control_dt
        self.workers = workers
        self._pool = (mp.get_context("spawn").Pool(workers, _worker_init, (env_id, kwargs))
                      if workers > 1 else None)

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """Step the rows in `workers` contiguous chunks (grouped by xi first), in parallel."""
        s, a, x = check_step_args(self, states, actions, xi)
        if self._pool is None or len(s) < 2 * self.workers:
            return self._local.step(s, a, x)
        order = _grouped_rows(x)
        chunks = np.array_split(order, self.workers)
        parts = self._pool.map(_worker_step, [(s[c], a[c], x[c]) for c in chunks])
        out = np.empty_like(s)
        for c, p in zip(chunks, parts):
            out[c] = p
        return out

    def initial_state(self, xi: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        """Delegates to the in-process simulator."""
        return self._local.initial_state(xi, rng)

    def observe(self, state: ArrayLike) -> NDArray[np.float32]:
        """Delegates to the in-process simulator."""
        return self._local.observe(state)

    def random_action(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Delegates to the in-process simulator."""
        return self._local.random_action(rng)

    def close(self) -> None:
        """Stop the worker processes."""
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None
