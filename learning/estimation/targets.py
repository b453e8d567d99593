"""True parameter distributions for collecting datasets: a Gaussian, or a mixture of Gaussians whose
means form an L shape (the seed paper's mixed-Gaussian target: "mixture" with 3 components, at the
L's ends and corner; "mixture5" with 5, adding the middle of each arm, as in the paper's locomotion
tables), both defined on the unit box of a ParamSpace and truncated to it (draws outside are
redrawn)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.params import ParamSpace
from goflow_common.checks import check_finite_array
from goflow_common.errors import InputError

__all__ = ["TargetConfig", "TargetSampler", "sample_target", "target_description", "TARGETS", "L_MEANS"]

TARGETS = ("gaussian", "mixture", "mixture5")

#: Component means (u_1, u_2) of the L-shaped mixtures: top of the stem, the corner, the end of the
#: foot; the 5-component L adds the middle of the stem and of the foot.
L_MEANS = {
    "mixture": ((0.25, 0.75), (0.25, 0.25), (0.75, 0.25)),
    "mixture5": ((0.2, 0.8), (0.2, 0.5), (0.2, 0.2), (0.5, 0.2), (0.8, 0.2)),
}


@dataclass(frozen=True)
class TargetConfig:
    """Where the true parameters lie, in unit-box coordinates (0 = low bound, 1 = high bound)."""

    kind: str = "gaussian"  # one of TARGETS
    mean: float = 0.5  # Gaussian mean on every dimension (and the mixture's dimensions >= 2)
    std: float = 0.1  # Gaussian std on every dimension (and the mixture's dimensions >= 2)
    # mixtures: component means on the first two dimensions; None: L_MEANS[kind]
    l_means: tuple[tuple[float, float], ...] | None = None
    l_std: float = 0.06  # per-dimension std of each component

    def __post_init__(self) -> None:
        if self.kind not in TARGETS:
            raise InputError(f"target kind {self.kind!r} is unknown; expected one of {list(TARGETS)}")
        if self.l_means is None:
            object.__setattr__(self, "l_means", L_MEANS.get(self.kind, L_MEANS["mixture"]))
        if not (0 < self.std < 1 and 0 < self.l_std < 1 and 0 < self.mean < 1):
            raise InputError(
                f"target mean/std/l_std must lie in (0, 1) (unit box), got {self.mean}, {self.std}, {self.l_std}"
            )
        if len(check_finite_array(self.l_means, "TargetConfig.l_means", (None, 2), 0.0, 1.0)) < 1:
            raise InputError("TargetConfig.l_means = (); expected at least one (u_1, u_2) mean in the unit box")


def _truncated_normal(mean: NDArray, std: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
    """One draw per row of N(mean, diag(std^2)) inside [0, 1]^d (rejection, row by row)."""
    out = rng.normal(mean, std)
    bad = np.any((out < 0) | (out > 1), axis=-1)
    while bad.any():
        out[bad] = rng.normal(mean[bad], std[bad])
        bad = np.any((out < 0) | (out > 1), axis=-1)
    return out


def _components(config: TargetConfig, d: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The target's equally weighted components in unit-box coordinates: means and stds, (k, d) each."""
    if config.kind == "gaussian":
        return np.full((1, d), config.mean), np.full((1, d), config.std)
    l_means = np.asarray(config.l_means, dtype=np.float64)
    means = np.full((len(l_means), d), config.mean)
    stds = np.full((len(l_means), d), config.std)
    if d == 1:  # a 1-D "L" degenerates to two modes along the one parameter
        means[:, 0] = l_means[:, 0] if len(set(l_means[:, 0])) > 1 else l_means[:, 1]
        stds[:, 0] = config.l_std
    else:
        means[:, :2] = l_means
        stds[:, :2] = config.l_std
    return means, stds


def sample_target(config: TargetConfig, space: ParamSpace, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """n true parameter vectors (n, d) in parameter units."""
    means, stds = _components(config, space.dim)
    k = np.zeros(n, dtype=np.int64) if config.kind == "gaussian" else rng.integers(len(means), size=n)
    return space.denormalize(_truncated_normal(means[k], stds[k], rng))


def target_description(config: TargetConfig) -> dict[str, Any]:
    """A JSON-serializable record of the target for the dataset's collection info."""
    out: dict[str, Any] = {"kind": config.kind, "coordinates": "unit box (0 = low, 1 = high)"}
    if config.kind == "gaussian":
        out.update(mean=config.mean, std=config.std)
    else:
        out.update(
            l_means=[list(m) for m in config.l_means],
            l_std=config.l_std,
            other_dims={"mean": config.mean, "std": config.std},
        )
    return out


class TargetSampler:
    """The true target distribution as a Sampler (evaluation of transfer: episodes on the truth).

    Its density is exact: each component is a diagonal Gaussian truncated to the unit box, which is
    what the row-wise rejection in `sample_target` draws from."""

    def __init__(self, space: ParamSpace, config: TargetConfig) -> None:
        self.space, self.config = space, config
        self._means, self._stds = _components(config, space.dim)

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws (n, d) in parameter units."""
        from assembly.samplers import check_sample_args

        return sample_target(self.config, self.space, check_sample_args(n, rng), rng)

    def log_prob(self, xi: Any) -> NDArray[np.float64]:
        """Exact log density (parameter units); -inf outside the box."""
        from scipy.special import logsumexp
        from scipy.stats import truncnorm

        batch = self.space.as_batch(xi)
        u = self.space.normalize(batch)
        a, b = (0 - self._means) / self._stds, (1 - self._means) / self._stds
        comp = truncnorm.logpdf(u[:, None, :], a[None], b[None], loc=self._means[None], scale=self._stds[None])
        lp = logsumexp(comp.sum(-1), axis=1) - np.log(len(self._means))
        lp = lp - float(np.log(self.space.high - self.space.low).sum())
        return np.where(self.space.contains(batch), lp, -np.inf)

    def update(self, xi: Any, returns: Any) -> dict[str, Any]:
        """Validate; the truth does not adapt."""
        from assembly.samplers import check_update_inputs

        _, ret = check_update_inputs(self.space, xi, returns)
        return {"n": int(len(ret)), "mean_return": float(ret.mean())}

    def entropy(self) -> float:
        """Monte Carlo entropy in nats (parameter units), fixed seed."""
        return float(-self.log_prob(self.sample(4096, np.random.default_rng(0))).mean())

    def state_dict(self) -> dict[str, Any]:
        """Type, space and the target's description."""
        return {"type": type(self).__name__, "space": self.space.to_dict(), "target": target_description(self.config)}

    def load_state_dict(self, state: Any) -> None:
        """Check type and space (the target is fixed at construction)."""
        from assembly.samplers import check_state_dict

        check_state_dict(self.space, state, type(self).__name__)
