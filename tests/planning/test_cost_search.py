"""eta as a cost (planning.cost_search, AssemblyDomain(decision="cost")): the plan of least
expected cost, which need not be the shortest; a closer look planned exactly when the success
probability it adds is worth its time; bad costs and decisions refused."""

from dataclasses import dataclass

import numpy as np
import pytest

from planning.bfs import Step, plan_bfs
from planning.cost_search import plan_cheapest
from planning.domain import AssemblyDomain, BeliefState, GearBelief, PlannerConfig, SkillCosts

SHARP, WIDE = (1e-4, 1e-4, 0.01), (1.5e-3, 1.5e-3, 0.05)


@dataclass
class Graph:
    """A toy domain: states are nodes, each edge a skill with a cost."""

    edges: dict
    goal: str

    def successors(self, state):
        return [(Step(skill, "g"), nxt) for skill, nxt, _ in self.edges.get(state, [])]

    def is_goal(self, state):
        return state == self.goal

    def step_cost(self, step):
        return next(c for edges in self.edges.values() for s, _, c in edges if s == step.skill)


def test_cheapest_plan_is_not_the_shortest_one():
    graph = Graph(
        {"a": [("direct", "z", 10.0), ("hop1", "b", 1.0)], "b": [("hop2", "c", 1.0)], "c": [("hop3", "z", 1.0)]}, "z"
    )
    cheap = plan_cheapest("a", graph)
    assert cheap.found and [s.skill for s in cheap.steps] == ["hop1", "hop2", "hop3"]
    assert cheap.cost == pytest.approx(3.0)
    assert [s.skill for s in plan_bfs("a", graph).steps] == ["direct"]
    assert plan_cheapest("z", graph).found and plan_cheapest("z", graph).cost == 0.0


def test_negative_or_infinite_step_cost_is_refused():
    for bad in (-1.0, float("inf"), float("nan")):
        graph = Graph({"a": [("x", "z", bad)]}, "z")
        with pytest.raises(ValueError, match="expected a finite cost >= 0"):
            plan_cheapest("a", graph)


def test_unreachable_goal_is_no_plan():
    plan = plan_cheapest("a", Graph({"a": [("x", "b", 1.0)]}, "z"))
    assert not plan.found and plan.steps == [] and "reaches the goal" in plan.reason


def capture(radius):
    """A stand-in insert skill that seats the gear whenever the grasp error is within `radius`."""
    return lambda xi: float(np.mean(np.hypot(xi[:, 0], xi[:, 1]) < radius))


def domain(costs=SkillCosts(), **kw):
    return AssemblyDomain(
        preconditions={g: capture(2e-3) for g in ("small", "medium", "large")},
        eta=0.9,
        inspect_std=lambda gear, std: SHARP,
        decision="cost",
        costs=costs,
        **kw,
    )


def start(stds):
    return BeliefState.of({g: GearBelief("table", (0.4, 0.1 * i, 0.0), s) for i, (g, s) in enumerate(stds.items())})


def _insert_probability(plan, gear):
    return next(s.probability for s in plan.steps if s.skill == "insert" and s.gear == gear)


def test_a_closer_look_is_planned_exactly_when_it_is_worth_its_time():
    """With the medium gear's belief wide, inspecting raises its insert's P from p0 to p1: the
    cost planner looks exactly when (p1 - p0) x failed_insert > inspect."""
    belief = start({"small": SHARP, "medium": WIDE, "large": SHARP})
    blind = domain(SkillCosts(failed_insert=0.0)).plan(belief)
    assert blind.found and ["inspect", "medium"] not in blind.pairs()
    looked = domain(SkillCosts(failed_insert=1e4)).plan(belief)
    assert ["inspect", "medium"] in looked.pairs()
    p0, p1 = _insert_probability(blind, "medium"), _insert_probability(looked, "medium")
    assert 0.05 < p0 < 0.95 and p1 > p0  # the wide belief is honestly uncertain, the look helps
    inspect = SkillCosts().inspect
    worth = inspect / (p1 - p0)  # failure cost at which the look breaks even
    for factor, expect in ((0.9, False), (1.1, True)):
        plan = domain(SkillCosts(failed_insert=factor * worth)).plan(belief)
        assert plan.found
        assert (["inspect", "medium"] in plan.pairs()) is expect, (factor, plan.pairs())
        assert ["inspect", "small"] not in plan.pairs() and ["inspect", "large"] not in plan.pairs()
    # The expected cost is the sum over the calls: 3 picks, 3 inserts, the failure terms, the look.
    plan = domain(SkillCosts(failed_insert=2 * worth)).plan(belief)
    c = SkillCosts(failed_insert=2 * worth)
    expected = (
        3 * (c.pick + c.insert)
        + c.inspect
        + sum((1 - s.probability) * c.failed_insert for s in plan.steps if s.skill == "insert")
    )
    assert plan.cost == pytest.approx(expected)


def test_cost_decision_inserts_below_eta_where_threshold_finds_no_plan():
    """Without inspections a wide belief fails eta = 0.9 (no plan), but the cost planner still
    inserts: a chance of success is worth trying when nothing else can raise it."""
    belief = start({"small": SHARP, "medium": WIDE, "large": SHARP})
    threshold = AssemblyDomain(
        preconditions={g: capture(2e-3) for g in ("small", "medium", "large")},
        eta=0.9,
        inspect_std=lambda gear, std: SHARP,
        max_inspections=0,
    )
    assert not plan_bfs(belief, threshold).found
    plan = domain(max_inspections=0).plan(belief)
    assert plan.found and _insert_probability(plan, "medium") < 0.9


def test_no_chance_at_all_is_no_plan_naming_the_gear():
    never = AssemblyDomain(
        preconditions={"small": capture(2e-3), "medium": capture(0.0), "large": capture(2e-3)},
        eta=0.9,
        inspect_std=lambda gear, std: SHARP,
        decision="cost",
    )
    plan = never.plan(start({"small": SHARP, "medium": SHARP, "large": SHARP}))
    assert not plan.found and "medium" in plan.reason and "no chance" in plan.reason


def test_bad_decision_and_costs_are_named():
    with pytest.raises(ValueError, match="decision 'cheapest'"):
        PlannerConfig(decision="cheapest")
    with pytest.raises(ValueError, match="decision 'cheapest'"):
        AssemblyDomain(
            preconditions={g: capture(1.0) for g in ("small", "medium", "large")},
            eta=0.9,
            inspect_std=lambda gear, std: SHARP,
            decision="cheapest",
        )
    for name, bad in (("inspect", -1.0), ("failed_insert", float("nan")), ("pick", "6")):
        with pytest.raises(ValueError, match=f"SkillCosts.{name}"):
            SkillCosts(**{name: bad})
