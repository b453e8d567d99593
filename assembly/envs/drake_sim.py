"""Stepping a Drake Simulator the way every goflow env does: failures become SimulationError, and
inputs are held in place rather than re-fixed every step; `SceneRendering`, the render() of the
Drake envs; `PlantEnv`, the base of the envs that drive one MultibodyPlant through one held input
(Cartpole, Quadrotor)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any
from contextlib import contextmanager

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, InputPort

from assembly.envs.base import ParamEnv, SimulationError


@contextmanager
def quiet_drake() -> Iterator[None]:
    """Drake's log at ERROR inside the block (its parser lists what it drops, and every diagram with
    a half space warns that deformable contact ignores it), restored after."""
    log = logging.getLogger("drake")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def point_contact_properties(stiffness: float, dissipation: float, friction: float):
    """ProximityProperties of a point-contact geometry: stiffness [N/m], Hunt-Crossley dissipation
    [s/m], Coulomb friction (static = dynamic)."""
    from pydrake.geometry import AddContactMaterial, ProximityProperties
    from pydrake.multibody.plant import CoulombFriction

    props = ProximityProperties()
    AddContactMaterial(
        dissipation=dissipation,
        point_stiffness=stiffness,
        friction=CoulombFriction(friction, friction),
        properties=props,
    )
    return props


class HeldInput:
    """A vector input port fixed once in its Context and then rewritten in place.

    `InputPort.FixValue` allocates a new value on every call (~6 us); rewriting the fixed value
    through `GetMutableData()` (which tells the Context it changed) costs ~1 us. Fix the port
    through this object only: a later `FixValue` on the same port would orphan it.
    """

    def __init__(self, port: InputPort, context: Context, value: ArrayLike) -> None:
        self._fixed = port.FixValue(context, np.asarray(value, dtype=np.float64))

    def set(self, value: ArrayLike | float) -> None:
        """Hold `value` (shape of the port; a float on a size-1 port, the cheapest path) from now on."""
        if isinstance(value, float):
            self._fixed.GetMutableData().get_mutable_value().SetAtIndex(0, value)
        else:
            self._fixed.GetMutableData().set_value(np.asarray(value, dtype=np.float64))


def advance(simulator: Simulator, t: float, owner: str) -> None:
    """simulator.AdvanceTo(t); a Drake failure is raised as SimulationError naming `owner`."""
    try:
        simulator.AdvanceTo(t)
    except RuntimeError as exc:
        raise SimulationError(f"{owner}: Drake failed advancing to t = {t:.4f} s: {exc}") from exc


def rollout_fixed_inputs(
    simulator: Simulator,
    held: HeldInput,
    inputs: NDArray[np.float64],
    dt: float,
    read_state: Callable[[], NDArray[np.float64]],
    owner: str,
) -> NDArray[np.float64]:
    """Hold each row of `inputs` for `dt` in turn, from the simulator's current time; return
    read_state() after every step, stacked."""
    t0 = simulator.get_context().get_time()
    out = []
    for k, u in enumerate(inputs):
        held.set(u)
        advance(simulator, t0 + (k + 1) * dt, owner)
        out.append(read_state())
    return np.array(out)


def filter_between_copies(scene_graph, copies: Sequence[Sequence[Any]]) -> None:
    """Exclude contact between the geometries of different copies (GeometryIds, one sequence per
    copy) in SceneGraph's model; contact within a copy and with shared geometry is kept."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

    manager = scene_graph.collision_filter_manager()
    later = [gid for copy in copies for gid in copy]
    for copy in copies[:-1]:
        later = later[len(copy) :]
        manager.Apply(CollisionFilterDeclaration().ExcludeBetween(GeometrySet(list(copy)), GeometrySet(later)))


class PlantAccess:
    """`plant` and `state()` of an env that keeps `_plant` and `_plant_context` (Ant, Anymal)."""

    @property
    def plant(self):
        """The Drake MultibodyPlant (read-only use)."""
        return self._plant

    def state(self) -> NDArray[np.float64]:
        """The plant's full state [q; v] (floating base quaternion wxyz, position, joints; velocities)."""
        return np.array(self._plant.GetPositionsAndVelocities(self._plant_context))


class SceneRendering:
    """render_mode "rgb_array" for a Drake ParamEnv: a SceneRenderer (assembly.envs.rendering)
    built on the first render() by the env's `_make_renderer()`, its view's target following
    `_render_track()` (a world point, or None for a fixed view). Nothing is built, and nothing in
    the Context changes, until an env made with a render mode renders."""

    metadata = {"render_modes": ["rgb_array"]}
    _renderer = None

    def _make_renderer(self):
        """The env's SceneRenderer (its camera, and the shapes drawn only in the image)."""
        raise NotImplementedError

    def _render_track(self) -> NDArray[np.float64] | None:
        """The world point the camera follows (x, y), or None for a fixed view."""
        return None

    def _scene_renderer(self):
        if self._renderer is None:
            self._renderer = self._make_renderer()
        return self._renderer

    def _render_frame(self) -> NDArray[np.uint8]:
        return self._scene_renderer().render(self._render_track())


class PlantEnv(SceneRendering, ParamEnv):
    """A ParamEnv over one MultibodyPlant, simulated by one Simulator and Context reused for every
    episode and driven through one HeldInput.

    Subclasses set, when they build their diagram: `_simulator`, `_context`, `_plant`,
    `_plant_context`, `_input` (the HeldInput), `_input_zero` (its value at rest) and
    `_initial_state = None`; and implement `_apply_xi(xi)` (write xi into the Context),
    `_default_state(xi)` (bare_rollout's start when no episode has started) and
    `_inputs(actions)` (a (T, m) array of port values for normalized actions).
    """

    _owner = "PlantEnv"  # names the env in SimulationError messages

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        raise NotImplementedError

    def _default_state(self, xi: NDArray[np.float64]) -> NDArray[np.float64]:
        raise NotImplementedError

    def _inputs(self, actions: NDArray[np.float64]) -> NDArray[np.float64]:
        raise NotImplementedError

    def _start(self, xi: NDArray[np.float64], state: NDArray[np.float64]) -> None:
        """Parameters xi, plant state `state`, input at rest, time 0."""
        self._apply_xi(xi)
        self._context.SetTime(0.0)
        self._plant.SetPositionsAndVelocities(self._plant_context, state)
        self._input.set(self._input_zero)
        self._simulator.Initialize()
        self._k = 0  # control steps since the start (simulated time = k * control_dt)

    def _advance(self, value: ArrayLike | float) -> list[float]:
        """Hold `value` on the input for one control period; return the plant state (q, v) after
        it as Python floats. The per-step path avoids numpy calls, which cost several times their
        isolated time between AdvanceTo calls (docs/envs.md, "Speed")."""
        self._input.set(value)
        self._k += 1
        advance(self._simulator, self._k * self.control_dt, self._owner)
        state = self._plant.GetPositionsAndVelocities(self._plant_context).tolist()
        if not math.isfinite(sum(state)):  # NaN or inf anywhere
            raise SimulationError(f"{self._owner}: non-finite state at t = {self._k * self.control_dt:.4f} s: {state}")
        return state

    @property
    def plant_state(self) -> NDArray[np.float64]:
        """The plant state (q, v), a copy."""
        return self._plant.GetPositionsAndVelocities(self._plant_context).copy()

    @property
    def initial_state(self) -> NDArray[np.float64] | None:
        """The plant state the last reset started from (None before the first reset)."""
        return None if self._initial_state is None else self._initial_state.copy()

    def bare_rollout(
        self, xi: ArrayLike, actions: ArrayLike, initial_state: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Advance the bare Drake simulator through `actions` (T, action dim) with no gym wrapper.

        Starts from `initial_state` (default: the state the last reset started from, else
        `_default_state(xi)`) with parameters xi, and returns the plant state after every step,
        shape (T, nq + nv), equal to `plant_state` after each env.step of the same actions. It ends
        the current episode: call reset() before stepping the env again.
        """
        xi = self.validate_xi(xi, what="bare_rollout xi")
        inputs = self._inputs(np.asarray(actions, dtype=np.float64).reshape(-1, self.action_space.shape[0]))
        if initial_state is None:
            initial_state = self._initial_state if self._initial_state is not None else self._default_state(xi)
        self._done = True
        self._start(xi, np.asarray(initial_state, dtype=np.float64))
        return rollout_fixed_inputs(
            self._simulator,
            self._input,
            inputs,
            self.control_dt,
            lambda: self._plant.GetPositionsAndVelocities(self._plant_context),
            f"{self._owner}.bare_rollout",
        )
