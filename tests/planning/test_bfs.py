"""Algorithm 2 on a small skill set with a known answer: beliefs too wide for the insert skill
are inspected first, a sharp one is not; an unreachable goal is "no plan" with the reason."""

import numpy as np
import pytest

from planning.bfs import plan_bfs
from planning.domain import AssemblyDomain, BeliefState, GearBelief

SHARP, WIDE = (1e-4, 1e-4, 0.01), (4e-3, 4e-3, 0.05)


def capture(radius):
    """A stand-in insert skill that seats the gear whenever the grasp error is within `radius`."""
    return lambda xi: float(np.mean(np.hypot(xi[:, 0], xi[:, 1]) < radius))


def domain(**kw):
    kw.setdefault("preconditions", {g: capture(2e-3) for g in ("small", "medium", "large")})
    kw.setdefault("eta", 0.9)
    kw.setdefault("inspect_std", lambda gear, std: SHARP)
    return AssemblyDomain(**kw)


def start(stds):
    return BeliefState.of({g: GearBelief("table", (0.4, 0.1 * i, 0.0), s) for i, (g, s) in enumerate(stds.items())})


def test_the_two_wide_beliefs_are_inspected_and_the_sharp_one_is_not():
    plan = plan_bfs(start({"small": SHARP, "medium": WIDE, "large": WIDE}), domain())
    assert plan.found, plan.reason
    steps = plan.pairs()
    assert sorted(g for s, g in steps if s == "inspect") == ["large", "medium"]
    assert len(steps) == 8  # 2 inspections, then a pick and an insert per gear
    for gear in ("small", "medium", "large"):
        i_pick, i_insert = steps.index(["pick", gear]), steps.index(["insert", gear])
        assert i_insert == i_pick + 1
        if gear != "small":
            assert steps.index(["inspect", gear]) < i_pick
    assert all(s.probability > 0.9 for s in plan.steps if s.skill == "insert")


def test_order_is_respected():
    plan = plan_bfs(
        start({"small": SHARP, "medium": SHARP, "large": SHARP}), domain(order=("large", "medium", "small"))
    )
    assert [g for s, g in plan.pairs() if s == "insert"] == ["large", "medium", "small"]


def test_no_plan_names_the_gear_and_why():
    never = domain(preconditions={"small": capture(2e-3), "medium": capture(0.0), "large": capture(2e-3)})
    plan = plan_bfs(start({"small": SHARP, "medium": SHARP, "large": WIDE}), never)
    assert not plan.found and plan.steps == []
    assert "medium" in plan.reason and "large" not in plan.reason


def test_inspection_that_does_not_help_gives_no_plan():
    useless = domain(inspect_std=lambda gear, std: std)
    plan = plan_bfs(start({"small": SHARP, "medium": WIDE, "large": SHARP}), useless)
    assert not plan.found and "medium" in plan.reason


def test_a_doubted_gear_is_inspected_before_it_is_picked_again():
    """A gear whose pick or insert failed is inspected first even where its belief passes the
    precondition; the blind baseline (no inspections allowed) still picks it."""
    gears = start({"small": SHARP, "medium": SHARP, "large": SHARP})
    doubted = gears.with_gear("large", GearBelief("table", (0.4, 0.2, 0.0), SHARP, doubted=True))
    steps = plan_bfs(doubted, domain()).pairs()
    assert [g for s, g in steps if s == "inspect"] == ["large"]
    assert steps.index(["inspect", "large"]) < steps.index(["pick", "large"])
    assert plan_bfs(gears, domain()).pairs().count(["inspect", "large"]) == 0
    blind = plan_bfs(doubted, domain(max_inspections=0))
    assert blind.found and ["pick", "large"] in blind.pairs()


def test_bad_goal_and_missing_skill_are_named():
    with pytest.raises(ValueError, match="unknown gear"):
        domain(goal=("small", "huge"))
    with pytest.raises(ValueError, match="missing skill"):
        domain(preconditions={"small": capture(2e-3)})
    with pytest.raises(ValueError, match="location"):
        GearBelief("floor", (0, 0, 0), SHARP)


@pytest.fixture(scope="module")
def shipped():
    from planning.domain import gearbox_domain

    return gearbox_domain()


def test_shipped_skills_insert_perceived_gears_and_inspect_a_wide_one(shipped):
    """With the shipped skills and the inspect model: beliefs as sharp as the calibrated scene
    view's (0.06 mm) are picked and inserted at once, a medium gear known only to 2 mm is
    inspected first, and with no inspection allowed there is no plan, naming the medium gear."""
    from planning.domain import table_belief

    sharp = (6e-5, 6e-5, 0.003)
    beliefs = {
        "small": table_belief((0.4, 0.1, 0.2), sharp),
        "medium": table_belief((0.45, 0.0, 1.0), (2e-3, 2e-3, 0.02)),
        "large": table_belief((0.5, -0.1, -0.5), sharp),
    }
    plan = plan_bfs(BeliefState.of(beliefs), shipped)
    assert plan.found, plan.reason
    assert [g for s, g in plan.pairs() if s == "inspect"] == ["medium"]
    assert all(s.probability > 0.9 for s in plan.steps if s.skill == "insert")
    no_inspection = AssemblyDomain(**{**shipped.__dict__, "max_inspections": 0, "_cache": {}})
    plan = plan_bfs(BeliefState.of(beliefs), no_inspection)
    assert not plan.found and "medium" in plan.reason
