"""True parameter distributions for collecting datasets: a Gaussian, or a mixture of Gaussians whose
means form an L shape (the seed paper's mixed-Gaussian target), both defined on the unit box of a
ParamSpace and truncated to it (draws outside are redrawn)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.params import ParamSpace

__all__ = ["TargetConfig", "sample_target", "target_description", "TARGETS"]

TARGETS = ("gaussian", "mixture")


@dataclass(frozen=True)
class TargetConfig:
    """Where the true parameters lie, in unit-box coordinates (0 = low bound, 1 = high bound)."""

    kind: str = "gaussian"  # "gaussian" | "mixture"
    mean: float = 0.5  # Gaussian mean on every dimension (and the mixture's dimensions >= 2)
    std: float = 0.1  # Gaussian std on every dimension (and the mixture's dimensions >= 2)
    # mixture: component means on the first two dimensions, an L: top of the stem, the corner,
    # the end of the foot
    l_means: tuple[tuple[float, float], ...] = ((0.25, 0.75), (0.25, 0.25), (0.75, 0.25))
    l_std: float = 0.06  # per-dimension std of each component

    def __post_init__(self) -> None:
        if self.kind not in TARGETS:
            raise ValueError(f"target kind {self.kind!r} is unknown; expected one of {list(TARGETS)}")
        if not (0 < self.std < 1 and 0 < self.l_std < 1 and 0 < self.mean < 1):
            raise ValueError(f"target mean/std/l_std must lie in (0, 1) (unit box), got "
                             f"{self.mean}, {self.std}, {self.l_std}")


def _truncated_normal(mean: NDArray, std: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
    """One draw per row of N(mean, diag(std^2)) inside [0, 1]^d (rejection, row by row)."""
    out = rng.normal(mean, std)
    bad = np.any((out < 0) | (out > 1), axis=-1)
    while bad.any():
        out[bad] = rng.normal(mean[bad], std[bad])
        bad = np.any((out < 0) | (out > 1), axis=-1)
    return out


def sample_target(config: TargetConfig, space: ParamSpace, n: int, rng: np.random.Generator
                  ) -> NDArray[np.float64]:
    """n true parameter vectors (n, d) in parameter units."""
    d = space.dim
    mean = np.full((n, d), config.mean)
    std = np.full((n, d), config.std)
    if config.kind == "mixture":
        means = np.asarray(config.l_means, dtype=np.float64)
        k = rng.integers(len(means), size=n)
        if d == 1:  # a 1-D "L" degenerates to two modes along the one parameter
            mean[:, 0] = means[k, 0] if len(set(means[:, 0])) > 1 else means[k, 1]
            std[:, 0] = config.l_std
        else:
            mean[:, :2] = means[k]
            std[:, :2] = config.l_std
    return space.denormalize(_truncated_normal(mean, std, rng))


def target_description(config: TargetConfig) -> dict[str, Any]:
    """A JSON-serializable record of the target for the dataset's collection info."""
    out: dict[str, Any] = {"kind": config.kind, "coordinates": "unit box (0 = low, 1 = high)"}
    if config.kind == "gaussian":
        out.update(mean=config.mean, std=config.std)
    else:
        out.update(l_means=[list(m) for m in config.l_means], l_std=config.l_std,
                   other_dims={"mean": config.mean, "std": config.std})
    return out
