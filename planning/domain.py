"""The gearbox assembly as a planning domain over belief states (for planning.bfs).

`AssemblyDomain` holds, per gear, where it is (table, hand, inserted) and a Gaussian
summary of the pose belief (mean, std; x, y [m], yaw [rad]). Its skills:

* inspect(g): g on the table, hand empty, fewer than `max_inspections` so far. Effect: the std the
  inspect model predicts (perception.inspect_model; cautious: the 90th-percentile close view).
* pick(g): g on the table, hand empty, and not doubted (a gear whose pick or insert failed is
  inspected first, while inspections remain). Effect: g in the hand, grasped by a tool aimed so
  that the believed pose's grasp error is the skill's preferred one (`aim_xi`).
* insert(g): g in the hand, every gear before it in `order` inserted, and the skill's precondition
  (Eq. 6 or 7) on grasp errors sampled from the belief pushed through the grasp geometry above
  eta (decision "threshold") or above 0 (decision "cost"). Effect: g inserted, hand empty.

Decisions: "threshold" is the seed's Algorithm 2, a shortest plan of calls whose preconditions
clear eta (planning.bfs); "cost" is the plan of least expected time plus failure cost
(planning.cost_search, `SkillCosts`): an insert costs its time plus (1 - P) times what a failure
costs, so a closer look is planned exactly when the probability it adds is worth its time.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from assembly.gearset import GEAR_NAMES, gear_spec
from planning.bfs import Plan, Step, plan_bfs
from planning.cost_search import plan_cheapest
from planning.grasp import aim_tool, grasp_error, picked_grasp_errors

LOCATIONS = ("table", "hand", "inserted")
DECISIONS = ("threshold", "cost")


@dataclass(frozen=True)
class SkillCosts:
    """Expected seconds of simulated (robot) time per skill call, and what a failed insert costs.

    Defaults measured on the 525 finished assemblies logged in docs/results/assembly*.json (sim
    time against the calls each made): a close look adds 1.5 s, a pick and an insert together
    13.2 s (split evenly). `failed_insert`: the retry a failure forces (the gear put back, a close
    look, a new pick and insert: ~15 s) plus the chance that the failure cannot be recovered (13 of
    the 34 logged assemblies with a failed insert did not finish) times 120 s, the value given to
    an unfinished gearbox (an assumption: an operator resetting the station)."""

    inspect: float = 1.5
    pick: float = 6.6
    insert: float = 6.6
    failed_insert: float = 60.0

    def __post_init__(self) -> None:
        for name in ("inspect", "pick", "insert", "failed_insert"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
                raise ValueError(f"SkillCosts.{name} = {value!r}; expected a finite number of seconds >= 0")


@dataclass(frozen=True)
class GearBelief:
    """One gear in a belief state: `location` (table | hand | inserted), the pose belief's mean and
    std (x, y [m], yaw [rad]; yaw a class modulo the gear's tooth pitch), how often it was
    inspected, (in the hand) the tool pose the pick aimed at, and whether it is `doubted`: a pick
    or insert of it failed since its last close view, so it is inspected before it is picked
    again (while inspections remain)."""

    location: str
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    inspections: int = 0
    tool: tuple[float, float, float] | None = None
    doubted: bool = False

    def __post_init__(self) -> None:
        if self.location not in LOCATIONS:
            raise ValueError(f"location {self.location!r}; expected one of {LOCATIONS}")
        if len(self.mean) != 3 or len(self.std) != 3 or not np.all(np.isfinite(self.mean)):
            raise ValueError(f"mean {self.mean}, std {self.std}; expected 3 finite numbers each")
        if not all(np.isfinite(s) and s >= 0 for s in self.std):
            raise ValueError(f"std {self.std}; expected 3 standard deviations >= 0")


@dataclass(frozen=True)
class BeliefState:
    """Every gear's belief (name -> GearBelief, as sorted pairs so that states hash) and which
    gear the hand holds (None: empty)."""

    gears: tuple[tuple[str, GearBelief], ...]
    holding: str | None = None

    @classmethod
    def of(cls, gears: dict[str, GearBelief], holding: str | None = None) -> BeliefState:
        return cls(tuple(sorted(gears.items())), holding)

    def gear(self, name: str) -> GearBelief:
        for n, g in self.gears:
            if n == name:
                return g
        raise KeyError(f"no gear {name!r} in the belief; it has {[n for n, _ in self.gears]}")

    def with_gear(self, name: str, belief: GearBelief, holding: str | None | object = ...) -> BeliefState:
        gears = dict(self.gears)
        gears[name] = belief
        return BeliefState.of(gears, self.holding if holding is ... else holding)


# A precondition for the planner: belief samples of the grasp error (N, 3) -> probability.
PreconditionFn = Callable[[NDArray[np.float64]], float]


@dataclass
class AssemblyDomain:
    """The gearbox assembly's skills over belief states. `preconditions[g]` estimates the insert
    skill's success probability from grasp-error samples; `eta` the bar; `inspect_std(g, std)` the
    std after inspect(g); `aim_xi[g]` the grasp error a pick aims for (e.g. the flow's mode);
    `goal` the gears to insert, in `order` if given; `real_fingers`: the pick centres the gear
    along the fingers' closing axis (planning.grasp.PICK_MODEL), else the grasp is exactly the
    aimed one; `min_inspections`: inspections a gear needs before it may be picked (1: the
    "always inspect" baseline); `decision`: "threshold" (P > eta, shortest plan) or "cost" (P > 0,
    the plan of least expected `costs`; eta unused)."""

    preconditions: dict[str, PreconditionFn]
    eta: float
    inspect_std: Callable[[str, tuple[float, float, float]], tuple[float, float, float]]
    goal: tuple[str, ...] = GEAR_NAMES
    order: tuple[str, ...] | None = None
    aim_xi: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    max_inspections: int = 2
    samples: int = 256
    seed: int = 0
    real_fingers: bool = True
    min_inspections: int = 0
    decision: str = "threshold"
    costs: SkillCosts = SkillCosts()
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.decision not in DECISIONS:
            raise ValueError(f"decision {self.decision!r}; expected one of {DECISIONS}")
        unknown = [g for g in self.goal if g not in GEAR_NAMES]
        if unknown or not self.goal:
            raise ValueError(f"goal {list(self.goal)}: unknown gear(s) {unknown}; expected some of {list(GEAR_NAMES)}")
        missing = [g for g in self.goal if g not in self.preconditions]
        if missing:
            raise ValueError(f"no insert skill precondition for {missing}: a missing skill file?")
        if self.order is not None and set(self.goal) - set(self.order):
            raise ValueError(
                f"order {list(self.order)} leaves out goal gears {sorted(set(self.goal) - set(self.order))}"
            )

    def is_goal(self, state: BeliefState) -> bool:
        return all(state.gear(g).location == "inserted" for g in self.goal)

    def step_cost(self, step: Step) -> float:
        """A call's expected cost in seconds (`costs`): an insert adds (1 - P) x failed_insert."""
        if step.skill == "insert":
            return self.costs.insert + (1.0 - step.probability) * self.costs.failed_insert
        return float(getattr(self.costs, step.skill))

    def plan(self, start: BeliefState, max_depth: int = 12) -> Plan:
        """The plan from `start` the decision asks for: threshold, planning.bfs.plan_bfs (a
        shortest plan); cost, planning.cost_search.plan_cheapest (least expected cost)."""
        if self.decision == "cost":
            return plan_cheapest(start, self, max_depth)
        return plan_bfs(start, self, max_depth)

    def _insert_bar(self) -> float:
        return self.eta if self.decision == "threshold" else 0.0

    def insert_probability(self, gear: str, belief: GearBelief) -> float:
        """Eq. 6/7 on grasp errors sampled from the belief (Gaussian in x, y, yaw), pushed
        through the grasp at the aimed tool pose."""
        key = (gear, belief.mean, belief.std, belief.tool)
        if key not in self._cache:
            rng = np.random.default_rng([self.seed, zlib.crc32(repr(key).encode())])
            poses = np.asarray(belief.mean) + rng.standard_normal((self.samples, 3)) * np.asarray(belief.std)
            aim = self.aim_xi.get(gear, (0.0, 0.0, 0.0))
            period = 2 * np.pi / gear_spec(gear).teeth
            if self.real_fingers:
                xi = picked_grasp_errors(gear, poses, belief.tool, period, rng, aim[2])
            else:
                xi = grasp_error(poses, belief.tool, period, aim[2])
            self._cache[key] = float(self.preconditions[gear](xi))
        return self._cache[key]

    def _ready(self, state: BeliefState, gear: str) -> bool:
        if self.order is None or gear not in self.order:
            return True
        before = self.order[: self.order.index(gear)]
        return all(state.gear(g).location == "inserted" for g in before if g in dict(state.gears))

    def successors(self, state: BeliefState) -> list[tuple[Step, BeliefState]]:
        out: list[tuple[Step, BeliefState]] = []
        for name, g in state.gears:
            if state.holding is None and g.location == "table":
                if g.inspections < self.max_inspections:
                    std = tuple(float(s) for s in self.inspect_std(name, g.std))
                    out.append(
                        (
                            Step("inspect", name),
                            state.with_gear(name, replace(g, std=std, inspections=g.inspections + 1, doubted=False)),
                        )
                    )
                if g.inspections < self.min_inspections or (g.doubted and g.inspections < self.max_inspections):
                    continue
                tool = tuple(float(t) for t in aim_tool(g.mean, self.aim_xi.get(name, (0.0, 0.0, 0.0))))
                out.append(
                    (Step("pick", name), state.with_gear(name, replace(g, location="hand", tool=tool), holding=name))
                )
            elif g.location == "hand" and state.holding == name and self._ready(state, name):
                p = self.insert_probability(name, g)
                if p > self._insert_bar():
                    out.append(
                        (
                            Step("insert", name, p),
                            state.with_gear(name, replace(g, location="inserted", tool=None), holding=None),
                        )
                    )
        return out

    def explain(self, start: BeliefState) -> str:
        """Why no plan: the gears whose insert precondition fails even after every inspection."""
        bad = []
        for name in self.goal:
            g = start.gear(name)
            if g.location == "inserted":
                continue
            std = g.std
            for _ in range(self.max_inspections - g.inspections if g.location == "table" else 0):
                std = tuple(float(s) for s in self.inspect_std(name, std))
            tool = g.tool if g.location == "hand" else tuple(aim_tool(g.mean, self.aim_xi.get(name, (0.0, 0.0, 0.0))))
            p = self.insert_probability(name, replace(g, std=std, tool=tool))
            if p <= self._insert_bar():
                bar = f"eta = {self.eta:.2f}" if self.decision == "threshold" else "0 (no chance at all)"
                bad.append(
                    f"{name} (P = {p:.2f} <= {bar} after "
                    f"{max(self.max_inspections - g.inspections, 0)} more inspection(s))"
                )
        return ("insert's precondition fails for " + ", ".join(bad)) if bad else ""


@dataclass(frozen=True)
class PlannerConfig:
    """eta, eps: Eq. 7's bars (eps None: Eq. 6, the value alone); samples: belief samples per
    precondition estimate; max_inspections per gear; order: gears inserted in this order (None:
    any); seed of the belief samples; min_inspections before a pick (1: always inspect); blind:
    insert whatever the belief (no precondition: the "insert at the MAP" baseline);
    real_fingers: picks centre the gear along the fingers'
    closing axis (measured, planning.grasp.PICK_MODEL) and aim for the best grasp error on that
    slice (planning.precondition.best_aim), else the grasp is the aimed one and aims for the
    flow's median. decision: "threshold" (insert when P > eta; the seed's Algorithm 2) or "cost"
    (the plan of least expected time plus failure cost, `costs`; eta unused)."""

    eta: float = 0.9
    eps: float | None = 1.0
    samples: int = 256
    max_inspections: int = 2
    order: tuple[str, ...] | None = None
    seed: int = 0
    real_fingers: bool = True
    min_inspections: int = 0
    blind: bool = False
    decision: str = "threshold"
    costs: SkillCosts = SkillCosts()

    def __post_init__(self) -> None:
        if self.decision not in DECISIONS:
            raise ValueError(f"decision {self.decision!r}; expected one of {DECISIONS}")
        if self.max_inspections < 0 or self.min_inspections < 0 or self.min_inspections > self.max_inspections:
            raise ValueError(
                f"min_inspections = {self.min_inspections}, max_inspections = "
                f"{self.max_inspections}; expected 0 <= min <= max"
            )


def gearbox_domain(
    config: PlannerConfig | None = None, goal: tuple[str, ...] = GEAR_NAMES, skills: dict | None = None
) -> AssemblyDomain:
    """The domain of the shipped skills: each goal gear's insert precondition (its skill file and
    measured V_T), picks aimed at the skill's preferred grasp error, and inspections predicted by
    the measured inspect model (its cautious 90th-percentile close view). `skills` may hold
    already-loaded Skill objects by gear. ValueError for an unknown gear; FileNotFoundError for a
    missing skill or threshold file."""
    from learning.skill_file import load_skill
    from perception.inspect_model import predict_inspection
    from planning.precondition import (
        PreconditionConfig,
        best_aim,
        insert_precondition,
        preferred_grasp_error,
    )

    config = config or PlannerConfig()
    unknown = [g for g in goal if g not in GEAR_NAMES]
    if unknown or not goal:
        raise ValueError(f"goal {list(goal)}: unknown gear(s) {unknown}; expected some of {list(GEAR_NAMES)}")
    pre_config = PreconditionConfig(eta=config.eta, eps=config.eps, samples=config.samples)
    preconditions, aims = {}, {}
    for gear in goal:
        skill = (skills or {}).get(gear) or load_skill("insert", gear)
        pre = insert_precondition(gear, pre_config, skill=skill)
        preconditions[gear] = (lambda xi: 1.0) if config.blind else pre.probability
        aim = best_aim(pre) if config.real_fingers else preferred_grasp_error(skill)
        aims[gear] = tuple(float(v) for v in aim)

    def inspect_std(gear: str, std: tuple[float, float, float]) -> tuple[float, float, float]:
        return tuple(float(v) for v in predict_inspection(gear, np.maximum(std, 1e-9)).std_after_cautious)

    return AssemblyDomain(
        preconditions,
        config.eta,
        inspect_std,
        tuple(goal),
        config.order,
        aims,
        config.max_inspections,
        config.samples,
        config.seed,
        config.real_fingers,
        config.min_inspections,
        config.decision,
        config.costs,
    )


def table_belief(
    mean: tuple[float, float, float] | NDArray[np.float64],
    std: tuple[float, float, float] | NDArray[np.float64],
    doubted: bool = False,
) -> GearBelief:
    """A gear on the table believed at `mean` with `std` (x, y [m], yaw [rad]), e.g. a pose
    posterior's mean() and std(); `doubted`: see GearBelief."""
    return GearBelief("table", tuple(float(v) for v in mean), tuple(float(v) for v in std), doubted=doubted)


__all__ = [
    "AssemblyDomain",
    "BeliefState",
    "DECISIONS",
    "SkillCosts",
    "GearBelief",
    "LOCATIONS",
    "PlannerConfig",
    "PreconditionFn",
    "gearbox_domain",
    "table_belief",
]
