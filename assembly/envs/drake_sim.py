"""Stepping a Drake Simulator the way every goflow env does: failures become SimulationError, and
inputs are held in place rather than re-fixed every step."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, InputPort

from assembly.envs.base import SimulationError


class HeldInput:
    """A vector input port fixed once in its Context and then rewritten in place.

    `InputPort.FixValue` allocates a new value on every call (~6 us); rewriting the fixed value
    through `GetMutableData()` (which tells the Context it changed) costs ~1 us. Fix the port
    through this object only: a later `FixValue` on the same port would orphan it.
    """

    def __init__(self, port: InputPort, context: Context, value: ArrayLike) -> None:
        self._fixed = port.FixValue(context, np.asarray(value, dtype=np.float64))

    def set(self, value: ArrayLike) -> None:
        """Hold `value` (shape of the port) from now on."""
        self._fixed.GetMutableData().set_value(np.asarray(value, dtype=np.float64))

    def set_scalar(self, value: float) -> None:
        """Hold `value` on a size-1 port (the cheapest path)."""
        self._fixed.GetMutableData().get_mutable_value().SetAtIndex(0, value)


def advance(simulator: Simulator, t: float, owner: str) -> None:
    """simulator.AdvanceTo(t); a Drake failure is raised as SimulationError naming `owner`."""
    try:
        simulator.AdvanceTo(t)
    except RuntimeError as exc:
        raise SimulationError(f"{owner}: Drake failed advancing to t = {t:.4f} s: {exc}") from exc


def rollout_fixed_inputs(simulator: Simulator, held: HeldInput, inputs: NDArray[np.float64], dt: float,
                         read_state: Callable[[], NDArray[np.float64]], owner: str
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
