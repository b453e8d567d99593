"""Stepping a Drake Simulator the way every goflow env does: failures become SimulationError."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Context, InputPort

from assembly.envs.base import SimulationError


def advance(simulator: Simulator, t: float, owner: str) -> None:
    """simulator.AdvanceTo(t); a Drake failure is raised as SimulationError naming `owner`."""
    try:
        simulator.AdvanceTo(t)
    except RuntimeError as exc:
        raise SimulationError(f"{owner}: Drake failed advancing to t = {t:.4f} s: {exc}") from exc


def rollout_fixed_inputs(simulator: Simulator, port: InputPort, port_context: Context,
                         inputs: NDArray[np.float64], dt: float,
                         read_state: Callable[[], NDArray[np.float64]], owner: str
                         ) -> NDArray[np.float64]:
    """Hold each row of `inputs` on `port` for `dt` in turn, from the simulator's current time;
    return read_state() after every step, stacked."""
    t0 = simulator.get_context().get_time()
    out = []
    for k, u in enumerate(inputs):
        port.FixValue(port_context, u)
        advance(simulator, t0 + (k + 1) * dt, owner)
        out.append(read_state())
    return np.array(out)
