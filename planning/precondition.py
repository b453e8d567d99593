"""When is the learned insertion skill worth calling? The GoFlow seed paper's preconditions
(Section 6, appendix A.3): under a belief b over the skill's parameters xi (here the grasp error),

    Eq. 6 (value only):   P = E_b[ 1{V(s0, xi) > V_T} ]                      > eta
    Eq. 7 (value + flow): P = E_b[ 1{V(s0, xi) > V_T} * 1{p_flow(xi) > eps} ] > eta

estimated by sampling the belief. V is the skill's privileged critic at the skill's start state
s0 (the policy's first observation: the same for every xi, which the policy never sees), p_flow
the skill's flow. Our critic estimates the *discounted* return, so the paper's J_T (a threshold on
the undiscounted episode return) becomes a threshold V_T on the critic's scale, measured by
rollouts (`calibrate_value_threshold`); eps is in multiples of the uniform density over the
skill's box.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from goflow_common.checks import check_int
from goflow_common.errors import FileFormatError
from goflow_common.files import read_json
from learning.skill_evaluation import rollout_return
from learning.skill_file import load_skill, Skill

#: V_T per gear, measured by `benchmarks.preconditions --thresholds` (docs/planning.md).
THRESHOLDS = Path(__file__).parent / "data" / "insert_thresholds.json"


@dataclass(frozen=True)
class PreconditionConfig:
    """eta: probability the belief must give the skill's success region; eps: flow density
    threshold in multiples of the uniform density over the skill's box (None: Eq. 6, the value
    alone); samples: belief samples per estimate."""

    eta: float = 0.9
    eps: float | None = 1.0
    samples: int = 512

    def __post_init__(self) -> None:
        if not 0.0 <= self.eta < 1.0:
            raise ValueError(f"eta = {self.eta}; expected a probability in [0, 1)")
        if self.eps is not None and not (np.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps = {self.eps}; expected None (value only) or >= 0 x uniform density")
        check_int(self.samples, "samples", minimum=1)


class InsertPrecondition:
    """The precondition of one insertion skill: `probability(xi)` for belief samples xi (N, 3),
    `holds(xi)` against eta. `value_threshold` is V_T on the critic's scale."""

    def __init__(
        self,
        skill: Skill,
        value_threshold: float,
        config: PreconditionConfig | None = None,
        s0: ArrayLike | None = None,
    ) -> None:
        if not np.isfinite(value_threshold):
            raise ValueError(f"value_threshold = {value_threshold}; expected a finite value")
        self.skill = skill
        self.gear = skill.gear
        self.value_threshold = float(value_threshold)
        self.config = config or PreconditionConfig()
        self.s0 = np.asarray(start_observation(skill) if s0 is None else s0, np.float64)
        self.uniform_density = 1.0 / float(np.prod(skill.space.high - skill.space.low))

    def succeeds(self, xi: ArrayLike) -> NDArray[np.bool_]:
        """Per sample: the indicator inside Eq. 7 (Eq. 6 when eps is None); samples outside the
        skill's box are outside its success region."""
        x = np.atleast_2d(np.asarray(xi, np.float64))
        if x.ndim != 2 or x.shape[1] != self.skill.space.dim or not np.all(np.isfinite(x)):
            raise ValueError(f"xi has shape {np.shape(xi)}; expected finite (N, {self.skill.space.dim}) grasp errors")
        inside = np.all((x >= self.skill.space.low) & (x <= self.skill.space.high), axis=1)
        ok = np.zeros(len(x), bool)
        if inside.any():
            xin = x[inside]
            good = self.skill.value(np.repeat(self.s0[None], len(xin), 0), xin) > self.value_threshold
            if self.config.eps is not None:
                good &= self.skill.density(xin) > self.config.eps * self.uniform_density
            ok[inside] = good
        return ok

    def probability(self, xi: ArrayLike) -> float:
        """The Monte Carlo estimate of P over belief samples `xi`."""
        return float(np.mean(self.succeeds(xi)))

    def holds(self, xi: ArrayLike) -> bool:
        """Whether P > eta."""
        return self.probability(xi) > self.config.eta


def load_value_thresholds(path: str | os.PathLike[str] = THRESHOLDS) -> dict[str, float]:
    """{gear: V_T} from a thresholds file (strict JSON: {"thresholds": {gear: number}, ...})."""
    data = read_json(path, "value-threshold file (benchmarks.preconditions --thresholds)")
    table = data.get("thresholds") if isinstance(data, dict) else None
    if not isinstance(table, dict) or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in table.values()):
        raise FileFormatError(f'{path}: expected {{"thresholds": {{gear: finite number}}}}')
    return {str(k): float(v) for k, v in table.items()}


def insert_precondition(
    gear: str,
    config: PreconditionConfig | None = None,
    skill: Skill | None = None,
    thresholds: str | os.PathLike[str] = THRESHOLDS,
) -> InsertPrecondition:
    """The shipped insert skill's precondition for `gear` with its measured V_T."""
    table = load_value_thresholds(thresholds)
    if gear not in table:
        raise ValueError(f"no value threshold for gear {gear!r} in {thresholds}; it has {sorted(table)}")
    return InsertPrecondition(skill or load_skill("insert", gear), table[gear], config)


def preferred_grasp_error(skill: Skill, samples: int = 4096, seed: int = 0) -> NDArray[np.float64]:
    """Where a pick should aim the grasp error: the per-axis median of `samples` draws of the
    skill's flow (robust to the flow's thin spikes at the box's faces, where its density can be
    the highest). A blind policy's success region need not be centred at zero error: it co-adapts
    with the policy's drift (docs/skills.md)."""
    xi = skill.sampler.sample(check_int(samples, "samples", minimum=1), np.random.default_rng(seed))
    return np.median(xi, axis=0)


def best_aim(
    pre: InsertPrecondition,
    closing: float = 0.0,
    blur: tuple[float, float] = (5e-4, 0.01),
    samples: int = 64,
    seed: int = 0,
) -> NDArray[np.float64]:
    """The grasp error a real-finger pick should aim for: the fingers pin xi_y (their closing
    axis) at `closing`, so search x (every 0.25 mm over +-5 mm) and yaw (the flow's median +- 2
    std, 9 values) for the point whose neighbourhood (x, yaw blurred by N(0, `blur`)) passes
    `pre` most often; ties go to the point nearest the flow's median."""
    skill = pre.skill
    key = (_fingerprint(pre), closing, tuple(blur), samples, seed)
    if key in _AIMS:  # the search costs seconds; the same skill and precondition give the same aim
        return _AIMS[key].copy()
    rng = np.random.default_rng(seed)
    draws = skill.sampler.sample(4096, rng)
    centre, spread = np.median(draws, axis=0), np.std(draws, axis=0)
    xs = np.arange(-5e-3, 5e-3 + 1e-9, 2.5e-4)
    yaws = centre[2] + np.linspace(-2, 2, 9) * spread[2]
    noise = rng.standard_normal((samples, 2)) * np.asarray(blur)
    best, best_score = None, (-1.0, 0.0)
    for yaw in yaws:
        for x in xs:
            xi = np.column_stack([x + noise[:, 0], np.full(samples, closing), yaw + noise[:, 1]])
            score = (pre.probability(xi), -np.hypot((x - centre[0]) / spread[0], (yaw - centre[2]) / spread[2]))
            if score > best_score:
                best, best_score = np.array([x, closing, yaw]), score
    _AIMS[key] = best.copy()
    return best


_AIMS: dict[tuple, NDArray[np.float64]] = {}


def _fingerprint(pre: InsertPrecondition) -> bytes:
    """Identifies what best_aim depends on: the flow's and the critic's outputs at fixed draws,
    V_T and eps."""
    xi = pre.skill.sampler.sample(8, np.random.default_rng(12345))
    v = pre.skill.value(np.repeat(pre.s0[None], len(xi), 0), xi)
    return (
        np.concatenate([xi.ravel(), np.ravel(v), pre.skill.density(xi)]).tobytes()
        + repr((pre.value_threshold, pre.config.eps)).encode()
    )


def start_observation(skill: Skill) -> NDArray[np.float32]:
    """s0: the skill's first observation (its env reset; the same for every grasp error)."""
    env = skill.make_env()
    try:
        obs, _ = env.reset(seed=0, options={"xi": np.zeros(skill.space.dim)})
    finally:
        env.close()
    return obs


@dataclass(frozen=True)
class ValueCalibration:
    """What `calibrate_value_threshold` measured: the threshold and, per episode, xi, V(s0, xi),
    the return and success (return >= the skill's J_T)."""

    threshold: float
    balanced_accuracy: float
    xi: NDArray[np.float64]
    value: NDArray[np.float64]
    returns: NDArray[np.float64]
    success: NDArray[np.bool_]


def calibrate_value_threshold(
    skill: Skill, episodes: int = 200, spread: float = 0.003, seed: int = 0
) -> ValueCalibration:
    """V_T by measurement: `episodes` rollouts at grasp errors drawn from the skill's flow and
    moved by N(0, spread) in x and y [m] (clipped to the box), so that both successes and
    failures occur; V_T is the threshold on V(s0, xi) that best separates them (balanced
    accuracy), placed midway between neighbouring values."""
    episodes = check_int(episodes, "episodes", minimum=4)
    rng = np.random.default_rng(seed)
    xi = skill.sampler.sample(episodes, rng)
    xi[:, :2] += rng.normal(0.0, spread, (episodes, 2))
    xi = np.clip(xi, skill.space.low, skill.space.high)
    env = skill.make_env()
    try:
        returns = np.array([rollout_return(skill, x, env) for x in xi])
    finally:
        env.close()
    success = returns >= skill.success_threshold
    value = skill.value(np.repeat(start_observation(skill)[None], episodes, 0), xi)
    order = np.sort(value)
    cuts = np.concatenate([[order[0] - 1.0], (order[1:] + order[:-1]) / 2, [order[-1] + 1.0]])
    best, best_acc = cuts[0], -1.0
    for cut in cuts:
        predicted = value > cut
        tpr = np.mean(predicted[success]) if success.any() else 1.0
        tnr = np.mean(~predicted[~success]) if (~success).any() else 1.0
        acc = 0.5 * (tpr + tnr)
        if acc > best_acc:
            best, best_acc = float(cut), float(acc)
    return ValueCalibration(best, best_acc, xi, value, returns, success)


__all__ = [
    "InsertPrecondition",
    "PreconditionConfig",
    "THRESHOLDS",
    "ValueCalibration",
    "calibrate_value_threshold",
    "insert_precondition",
    "load_value_thresholds",
    "preferred_grasp_error",
    "best_aim",
    "start_observation",
]
