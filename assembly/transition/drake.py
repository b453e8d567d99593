"""`DrakeTransitionSim`: the state and stepping hooks every transition simulator over one Drake
MultibodyPlant shares (state = the plant's (q, v))."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from assembly.envs.drake_sim import advance
from assembly.transition.base import BatchTransitionSim

__all__ = ["DrakeTransitionSim"]


class DrakeTransitionSim(BatchTransitionSim):
    """A BatchTransitionSim over one MultibodyPlant simulated by one Simulator.

    The state is the plant's [q; v]. Subclasses set, when they build their model, `_simulator`,
    `_context` (its root Context), `_plant` and `_plant_context`, and implement `_apply_xi`,
    `_apply_action` and `initial_state`. The hooks here: `_set_state` writes (q, v) at time 0,
    `_advance` initializes the Simulator and advances it one control period, `_read_state`
    reads (q, v).
    """

    def _set_state(self, state: NDArray[np.float64]) -> None:
        """Time 0, plant state `state` (q, v)."""
        self._context.SetTime(0.0)
        self._plant.SetPositionsAndVelocities(self._plant_context, state)

    def _advance(self) -> None:
        """Initialize the Simulator, advance it to `control_dt`; SimulationError if Drake fails."""
        self._simulator.Initialize()
        advance(self._simulator, self.control_dt, type(self).__name__)

    def _read_state(self) -> NDArray[np.float64]:
        """The plant's (q, v)."""
        return self._plant.GetPositionsAndVelocities(self._plant_context)
