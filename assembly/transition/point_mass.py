"""goflow/PointMass-v0: an analytic damped point mass (no Drake), cheap enough for tests."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import Param, ParamSpace
from assembly.transition.base import BatchTransitionSim, check_step_args
from goflow_common.config import config_with_overrides

__all__ = ["POINT_MASS_SPACE", "PointMassConfig", "PointMassSim"]

POINT_MASS_SPACE = ParamSpace(
    (
        Param("mass", 0.5, 5.0, "kg"),
        Param("damping", 0.1, 5.0, "N s/m"),
    )
)


@dataclass(frozen=True)
class PointMassConfig:
    """A point mass on a line pushed by a force, with viscous damping (exact discretization)."""

    control_dt: float = 0.05  # [s]
    max_force: float = 10.0  # [N] force at action 1
    initial_speed: float = 1.0  # [m/s] initial speed drawn uniformly in +-this


class PointMassSim(BatchTransitionSim):
    """m dv/dt = F - c v, dx/dt = v, stepped exactly under a held force; vectorized over rows.

    State (x, v); action: the force as a fraction of `max_force`; xi = (mass, damping).

    Arguments:
        config: the config (None: defaults).
        overrides: fields of PointMassConfig applied last.
    """

    env_id = "goflow/PointMass-v0"
    state_dim = 2
    action_dim = 1

    def __init__(self, config: PointMassConfig | None = None, **overrides: Any) -> None:
        self.config = config_with_overrides(PointMassConfig, config, overrides, "PointMassSim")
        self.space = POINT_MASS_SPACE
        self.control_dt = self.config.control_dt

    def step(self, states: ArrayLike, actions: ArrayLike, xi: ArrayLike) -> NDArray[np.float64]:
        """The exact step of every row at once (overrides the row loop; no row can fail).

        Arguments:
            states: (x, v) per row, shape (n, 2).
            actions: normalized forces, shape (n, 1).
            xi: (mass, damping) per row, shape (n, 2).

        Returns:
            The next states, shape (n, 2).
        """
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
        """At the origin with a uniformly random speed in +-`initial_speed`.

        Arguments:
            xi: parameters, shape (2,) (checked, unused).
            rng: the generator of the speed.

        Returns:
            The state (0, v0).
        """
        self.space.validate(np.asarray(xi, dtype=np.float64))
        return np.array([0.0, rng.uniform(-self.config.initial_speed, self.config.initial_speed)])
