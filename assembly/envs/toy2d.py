"""goflow/Toy2D-v0: the GoFlow paper's illustrative 2-D domain, with an analytic feasible set.

The randomized parameter xi is the agent's position in a 2-D box; an energy function made of
Gaussians laid out in a circular or a linear array sets how precisely the agent observes its
position (high energy, precise observation); the agent cannot move and is rewarded for guessing
where it is. The functional forms and numbers are ours (the authors' code does not include this
domain), chosen so that the feasible set has a closed form:

    energy      E(p)     = sum_k exp(-||p - c_k||^2 / (2 w_k^2))                 (dimensionless, ~1 at a centre)
    noise scale sigma(p) = sigma_max * (sigma_min / sigma_max) ** min(E(p), 1)   [m] (log-linear in E)
    observation o        = xi + sigma(xi) * N(0, I_2)                             [m]
    action      a        = the guess of xi                                        [m]
    reward      r        = 1 if ||a - xi|| < tolerance else 0;  success: return >= J_T = 1

The episode is a single step (nothing moves, so a longer horizon adds nothing): reset gives the
observation, step scores the guess and terminates. control_dt (1 s by default) is the nominal
duration of that one decision; no dynamics are simulated. The feasible set is
{xi : P(success | xi) >= feasible_level} with P(success | xi) = 1 - exp(-tolerance^2 / (2 sigma(xi)^2));
with the defaults, 8 disks on a circle (9.2 % of the box) or 4 on a line (4.5 %).

It does not render (a single decision with nothing moving): render_mode must be None, and any other
value is refused with a ValueError.

Derivation of the feasible set: docs/env_models.md#feasible-set.

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025 (arXiv:2502.01800), the 2-D illustrative example.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from assembly.params import Param, ParamSpace
from assembly.envs.base import ParamEnv
from goflow_common.checks import check_choice, check_finite_array, check_int, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from assembly.samplers import Sampler

__all__ = ["Toy2DConfig", "Toy2DEnv"]

LAYOUTS = ("circle", "line")
_DEFAULT_N_GAUSSIANS = {"circle": 8, "line": 4}


@dataclass(frozen=True)
class Toy2DConfig:
    """Geometry, noise and success settings of the 2-D position-guessing domain (SI units)."""

    layout: str = "circle"  # "circle": centres on a circle; "line": centres along the x axis
    n_gaussians: int | None = None  # None: 8 for "circle", 4 for "line"
    radius: float = 0.6  # [m] circle radius (circle layout)
    spacing: float = 0.5  # [m] distance between neighbouring centres (line layout)
    # [m] std of each Gaussian: one value or one per Gaussian. 0.12 keeps the feasible disks of
    # neighbouring Gaussians apart (at 0.15 the 8 circle modes merge into one ring).
    width: float | tuple[float, ...] = 0.12
    sigma_min: float = 0.01  # [m] observation noise std where E >= 1
    sigma_max: float = 0.5  # [m] observation noise std where E = 0
    tolerance: float = 0.1  # [m] a guess closer than this to xi earns reward 1
    feasible_level: float = 0.9  # success probability that defines the feasible set
    half_extent: float = 1.0  # [m] the box is [-half_extent, half_extent]^2
    control_dt: float = 1.0  # [s] nominal duration of the single decision

    def __post_init__(self) -> None:
        check_choice(self.layout, LAYOUTS, "Toy2DConfig.layout")
        n = check_int(self.num_gaussians(), "Toy2DConfig.n_gaussians", 1)
        for name in ("radius", "spacing", "sigma_min", "sigma_max", "tolerance", "half_extent", "control_dt"):
            check_number(getattr(self, name), f"Toy2DConfig.{name}", 0.0, low_open=True)
        if isinstance(self.width, (int, float)) and not isinstance(self.width, bool):  # one width, as widths()
            check_number(self.width, "Toy2DConfig.width", 0.0, low_open=True)
        elif not np.all(check_finite_array(self.width, "Toy2DConfig.width", (n,)) > 0):
            raise InputError(f"Toy2DConfig.width = {self.width!r}; expected a number > 0 or {n} numbers > 0 [m]")
        if not self.sigma_min < self.sigma_max:
            raise InputError(f"Toy2D: need sigma_min < sigma_max, got {self.sigma_min} >= {self.sigma_max} m")
        check_number(self.feasible_level, "Toy2DConfig.feasible_level", 0.0, 1.0, low_open=True, high_open=True)

    def num_gaussians(self) -> int:
        """K: n_gaussians, or the layout's default when it is None (kept None so replace(layout=...) re-resolves)."""
        return _DEFAULT_N_GAUSSIANS[self.layout] if self.n_gaussians is None else self.n_gaussians

    def widths(self) -> NDArray[np.float64]:
        """Per-Gaussian std, shape (K,) [m]."""
        w = self.width
        if isinstance(w, (int, float)):
            return np.full(self.num_gaussians(), float(w))
        return np.asarray(w, dtype=np.float64)

    def centers(self) -> NDArray[np.float64]:
        """Gaussian centres, shape (K, 2) [m]."""
        n = self.num_gaussians()
        k = np.arange(n)
        if self.layout == "circle":
            angle = 2.0 * np.pi * k / n
            return self.radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        x = (k - (n - 1) / 2.0) * self.spacing
        return np.stack([x, np.zeros_like(x)], axis=1)


class Toy2DEnv(ParamEnv):
    """Guess your own 2-D position from one observation whose noise grows as the energy falls."""

    success_threshold: float = 1.0  # J_T: undiscounted return >= J_T counts as success (reward is 0 or 1)

    def __init__(
        self,
        config: Toy2DConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = config_with_overrides(Toy2DConfig, config, overrides, "Toy2DEnv")
        h = self.config.half_extent
        self.space = ParamSpace((Param("x", -h, h, "m"), Param("y", -h, h, "m")))
        self._centers = self.config.centers()
        if np.any(np.abs(self._centers) > h):
            raise ValueError(
                f"Toy2D: every Gaussian centre must lie inside the box [-{h:g}, {h:g}]^2 m; the farthest is at "
                f"{np.abs(self._centers).max():g} m (layout={self.config.layout!r}, n_gaussians={self.config.num_gaussians()})"
            )
        self._inv_two_w2 = 1.0 / (2.0 * self.config.widths() ** 2)
        super().__init__(self.space, sampler)
        self.control_dt = float(self.config.control_dt)
        self._init_render(render_mode)  # metadata["render_modes"] is []: only None passes
        # Observations are clipped to the box grown by 10 sigma_max: a finite space for the checker and
        # for normalizers, reached with probability < 1e-22 per episode; clipping toward a box that
        # contains xi never increases the guess error, so the analytic feasible set stays exact.
        self._obs_bound = h + 10.0 * self.config.sigma_max
        self.observation_space = spaces.Box(-self._obs_bound, self._obs_bound, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Box(-h, h, shape=(2,), dtype=np.float32)

    # -- analytic quantities (points: (2,) -> scalar, (n, 2) -> (n,)) ----------------------------

    @property
    def centers(self) -> NDArray[np.float64]:
        """Gaussian centres, shape (K, 2) [m]."""
        return self._centers.copy()

    def _apply(self, points: ArrayLike, fn) -> Any:
        """Evaluate fn on a (n, 2) batch; return a scalar for a single (2,) point."""
        arr = np.asarray(points, dtype=np.float64)
        out = fn(self.space.as_batch(arr, "points"))
        return out[0] if arr.ndim == 1 else out

    def _energy(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        d2 = np.sum((p[:, None, :] - self._centers[None, :, :]) ** 2, axis=-1)
        return np.exp(-d2 * self._inv_two_w2).sum(axis=1)

    def _sigma(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        c = self.config
        return c.sigma_max * (c.sigma_min / c.sigma_max) ** np.minimum(self._energy(p), 1.0)

    def _p_success(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        return -np.expm1(-(self.config.tolerance**2) / (2.0 * self._sigma(p) ** 2))

    def energy(self, points: ArrayLike) -> Any:
        """Energy E at points [dimensionless]; ~1 on a centre, -> 0 far from all."""
        return self._apply(points, self._energy)

    def noise_scale(self, points: ArrayLike) -> Any:
        """Observation noise std sigma at points [m], per axis."""
        return self._apply(points, self._sigma)

    def success_probability(self, points: ArrayLike) -> Any:
        """P(success) of the guesser that reports its observation: 1 - exp(-tol^2 / (2 sigma^2))."""
        return self._apply(points, self._p_success)

    def feasible_set(self, points: ArrayLike) -> Any:
        """Whether each point is feasible: success_probability >= config.feasible_level."""
        return self._apply(points, lambda p: self._p_success(p) >= self.config.feasible_level)

    # -- gymnasium API -------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        """Observe the position once, with noise sigma(xi)."""
        self._noise_scale = float(self._sigma(xi[None, :])[0])
        noisy = xi + self._noise_scale * self.np_random.standard_normal(2)
        return np.clip(noisy, -self._obs_bound, self._obs_bound).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start an episode at options["xi"] if given (validated), else at a draw from the sampler."""
        obs, info = super().reset(seed=seed, options=options)
        info["noise_scale"] = self._noise_scale
        return obs, info

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        """Score the guess `action` (2,) [m]; the episode always terminates after this step."""
        error = float(np.linalg.norm(action - self._xi))
        reward = 1.0 if error < self.config.tolerance else 0.0
        return self._obs, reward, True, {"error": error}
