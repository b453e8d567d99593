"""Uniform-cost search over belief states: the plan of least expected cost.

The seed paper's Algorithm 2 (planning.bfs) accepts a skill call when its precondition clears a
bar eta and returns a shortest plan. Its conclusion suggests the alternative built here: every
skill call has an expected cost (for the gearbox: seconds, plus a failure cost weighted by the
chance of failing, planning.domain.SkillCosts) and the planner returns the sequence whose summed
expected cost is least. A closer look is then planned exactly when what it buys in success
probability is worth more than the time it takes.
"""

from __future__ import annotations

import heapq
import itertools
import math
from typing import Hashable, Protocol

from planning.bfs import Plan, Step


class CostDomain(Protocol):
    """A planning.bfs Domain whose steps have an expected cost (finite, >= 0)."""

    def successors(self, state: Hashable) -> list[tuple[Step, Hashable]]: ...

    def is_goal(self, state: Hashable) -> bool: ...

    def step_cost(self, step: Step) -> float: ...


def plan_cheapest(start: Hashable, domain: CostDomain, max_depth: int = 12) -> Plan:
    """The plan of least summed `domain.step_cost` from `start` to a goal state, by uniform-cost
    search (Dijkstra over belief states); ties go to the plan found first. `Plan.cost` holds the
    plan's expected cost. No plan (frontier empty or every path longer than `max_depth`): the
    answer says why (the domain's `explain`, if it has one). ValueError if a step's cost is
    negative or not finite."""
    if domain.is_goal(start):
        return Plan(True, [], "", 0, 0.0)
    order = itertools.count()
    frontier: list[tuple[float, int, Hashable, list[Step]]] = [(0.0, next(order), start, [])]
    best = {start: 0.0}
    expanded = 0
    while frontier:
        cost, _, state, steps = heapq.heappop(frontier)
        if cost > best.get(state, math.inf):
            continue  # a cheaper way here was expanded already
        if domain.is_goal(state):
            return Plan(True, steps, "", expanded, cost)
        if len(steps) >= max_depth:
            continue
        expanded += 1
        for step, nxt in domain.successors(state):
            c = float(domain.step_cost(step))
            if not (math.isfinite(c) and c >= 0):
                raise ValueError(f"step_cost({step.skill}({step.gear})) = {c}; expected a finite cost >= 0")
            if cost + c < best.get(nxt, math.inf):
                best[nxt] = cost + c
                heapq.heappush(frontier, (cost + c, next(order), nxt, steps + [step]))
    reason = getattr(domain, "explain", lambda s: "")(start) or (
        f"no sequence of at most {max_depth} skills reaches the goal from this belief"
    )
    return Plan(False, [], reason, expanded)


__all__ = ["CostDomain", "plan_cheapest"]
