"""Breadth-first search over belief states (the GoFlow seed paper's Algorithm 2): skills with
preconditions and predicted (sampled) effects, expanded level by level from the current belief
until the goal holds. The first plan found is a shortest one; if the frontier empties or the depth
bound is reached, the answer is "no plan" with the reason (the domain's `explain`, if it has one).
The gearbox assembly's domain is planning.domain.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Hashable, Protocol


@dataclass(frozen=True)
class Step:
    """One planned skill call and the precondition probability it was planned with (1 for skills
    without a learned precondition)."""

    skill: str
    gear: str
    probability: float = 1.0


@dataclass
class Plan:
    """`steps` if `found`, else `reason` says why there is none; `expanded`: belief states
    searched; `cost`: the plan's expected cost where the search minimised one
    (planning.cost_search), else None."""

    found: bool
    steps: list[Step] = field(default_factory=list)
    reason: str = ""
    expanded: int = 0
    cost: float | None = None

    def pairs(self) -> list[list[str]]:
        """[[skill, gear], ...] (the demo's JSON)."""
        return [[s.skill, s.gear] for s in self.steps]


class Domain(Protocol):
    """States are hashable; `successors` gives (step, next state) for every applicable skill."""

    def successors(self, state: Hashable) -> list[tuple[Step, Hashable]]: ...

    def is_goal(self, state: Hashable) -> bool: ...


def plan_bfs(start: Hashable, domain: Domain, max_depth: int = 12) -> Plan:
    """Algorithm 2: breadth-first over belief states from `start`; the first goal state reached
    gives a shortest plan."""
    if domain.is_goal(start):
        return Plan(True, [], "", 0)
    frontier: deque[tuple[Hashable, list[Step]]] = deque([(start, [])])
    seen = {start}
    expanded = 0
    while frontier:
        state, steps = frontier.popleft()
        if len(steps) >= max_depth:
            continue
        expanded += 1
        for step, nxt in domain.successors(state):
            if nxt in seen:
                continue
            if domain.is_goal(nxt):
                return Plan(True, steps + [step], "", expanded)
            seen.add(nxt)
            frontier.append((nxt, steps + [step]))
    reason = getattr(domain, "explain", lambda s: "")(start) or (
        f"no sequence of at most {max_depth} skills reaches the goal from this belief"
    )
    return Plan(False, [], reason, expanded)


__all__ = ["Domain", "Plan", "Step", "plan_bfs"]
