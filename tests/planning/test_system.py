"""The planner as a Drake system in the station: declared ports (images and robot state in, the
scripted source's commands out: no gear pose anywhere on the decision path), a random placement
assembled 3/3 from the scene camera, and recovery from a missed pick."""

import inspect

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix

from assembly.cameras import CamerasConfig
from assembly.station import COMMAND_PORTS
from assembly.world import WorldConfig, validate_gear_pose
from learning.skill_file import load_skill
from planning.assembly import PlannedAssemblyConfig, build_planned_assembly, run_planned_assembly
from planning.domain import AssemblyDomain
from planning.system import BeliefSpacePlanner

SEED = 3
# The recovery scenarios move a gear after the scene view; with ideal cameras the planner picks
# without an inspection that would see the move (the realistic default is the notebook's test).
CAMERAS = "ideal"
GEARS = ("small", "medium", "large")


@pytest.fixture(scope="module")
def skills():
    return {g: load_skill("insert", g) for g in ("small", "medium", "large")}


def test_ports_are_sensors_in_and_commands_out():
    params = set(inspect.signature(BeliefSpacePlanner.__init__).parameters)
    assert not any("pose" in p for p in params)  # nothing about where the gears are
    domain = AssemblyDomain({g: (lambda xi: 1.0) for g in GEARS}, 0.9, lambda g, s: s)
    planner = BeliefSpacePlanner(
        {g: None for g in GEARS},
        domain,
        {g: RigidTransform() for g in GEARS},
        CamerasConfig(),
        RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.3, 0.0, 0.4]),
        0.08,
    )
    inputs = [planner.get_input_port(i).get_name() for i in range(planner.num_input_ports())]
    outputs = [planner.get_output_port(i).get_name() for i in range(planner.num_output_ports())]
    assert sorted(inputs) == sorted(
        ["scene_rgb", "scene_depth", "wrist_rgb", "wrist_depth", "X_WT", "hand_state", "external_wrench"]
    )
    assert set(COMMAND_PORTS) <= set(outputs)


# The planned assembly of a random placement is asserted by notebooks/04_assembly.ipynb
# (tests/test_notebooks.py), so that it runs once in the suite.


@pytest.mark.slow
def test_a_gear_moved_after_it_was_perceived_is_found_again(skills):
    """The small gear is moved 4 cm after the scene view: the pick closes on nothing, the planner
    sees that in the fingers' width, looks again, replans and completes."""
    built = build_planned_assembly(PlannedAssemblyConfig(seed=SEED, cameras=CAMERAS), skills=skills)
    built.simulator.AdvanceTo(0.1)  # perceived and planned
    assert built.run().plans
    st, root = built.station, built.root_context
    x, y, yaw = built.placement["small"]
    others = {g: p for g, p in built.placement.items() if g != "small"}
    for dx, dy in ((0.0, 0.04), (0.0, -0.04), (0.04, 0.0), (-0.04, 0.0)):  # a free spot 4 cm away
        try:
            validate_gear_pose("small", (x + dx, y + dy, yaw), WorldConfig().plate_pose, others)
            break
        except ValueError:
            continue
    X = st.gear_pose(root, "small")
    st.set_gear_pose(root, "small", RigidTransform(X.rotation(), X.translation() + [dx, dy, 0.0]))
    summary = run_planned_assembly(PlannedAssemblyConfig(seed=SEED, cameras=CAMERAS), built=built)
    assert summary["replans"] >= 1, summary["executed"]
    assert any(e["outcome"].startswith("missed") for e in summary["executed"])
    assert summary["status"] == "done", summary["reason"]
    assert all(g["inserted"] for g in summary["gears"].values()), summary["gears"]


def test_beliefs_are_drawn_in_meshcat():
    """The drawing is its own system: it reads the planner's beliefs port and draws each table
    gear's mean and 3-sigma disc, and removes a gear that left the table."""
    from pydrake.systems.analysis import Simulator

    from assembly.station import make_meshcat
    from planning.belief_drawing import BeliefDrawer
    from planning.domain import GearBelief

    meshcat = make_meshcat()
    domain = AssemblyDomain({g: (lambda xi: 1.0) for g in GEARS}, 0.9, lambda g, s: s)
    planner = BeliefSpacePlanner(
        {g: None for g in GEARS},
        domain,
        {g: RigidTransform() for g in GEARS},
        CamerasConfig(),
        RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.3, 0.0, 0.4]),
        0.08,
        meshcat=meshcat,
    )
    assert any(isinstance(s, BeliefDrawer) for s in planner.GetSystems())
    drawer = BeliefDrawer(meshcat, 0.04)
    simulator = Simulator(drawer)
    beliefs = {
        "small": GearBelief("table", (0.4, 0.1, 0.2), (1e-3, 1e-3, 0.01)),
        "large": GearBelief("inserted", (0.5, 0.0, 0.0), (1e-4, 1e-4, 0.01)),
    }
    drawer.GetInputPort("beliefs").FixValue(simulator.get_mutable_context(), beliefs)
    simulator.AdvanceTo(0.05)
    assert meshcat.HasPath("beliefs/small/mean") and meshcat.HasPath("beliefs/small/region")
    assert not meshcat.HasPath("beliefs/large/mean")
    beliefs = {**beliefs, "small": GearBelief("hand", (0.4, 0.1, 0.2), (1e-3, 1e-3, 0.01))}
    drawer.GetInputPort("beliefs").FixValue(simulator.get_mutable_context(), beliefs)
    simulator.AdvanceTo(0.1)
    assert not meshcat.HasPath("beliefs/small/mean")


@pytest.mark.slow
def test_an_unseated_insert_puts_the_gear_back_and_completes(skills):
    """The large gear is moved 7 mm along the pick's tool x axis (world y: the fingers close
    along world x and do not centre it) after the scene view: the pick holds it 7 mm off the
    aimed grasp error, outside the skill's success region; the insert ends unseated, the planner
    puts the gear back on the table, looks again, inspects the doubted gear before picking it
    again, and completes."""
    gear, shift = "large", -0.007
    built = build_planned_assembly(PlannedAssemblyConfig(seed=SEED, cameras=CAMERAS), skills=skills)
    built.simulator.AdvanceTo(0.1)
    assert built.run().plans
    st, root = built.station, built.root_context
    X = st.gear_pose(root, gear)
    x, y, yaw = built.placement[gear]
    others = {g: p for g, p in built.placement.items() if g != gear}
    validate_gear_pose(gear, (x, y + shift, yaw), WorldConfig().plate_pose, others)
    st.set_gear_pose(root, gear, RigidTransform(X.rotation(), X.translation() + [0.0, shift, 0.0]))
    summary = run_planned_assembly(PlannedAssemblyConfig(seed=SEED, cameras=CAMERAS), built=built)
    outcomes = [(e["skill"], e["gear"], e["outcome"]) for e in summary["executed"]]
    assert any(s == "insert" and g == gear and o.startswith("unseated") for s, g, o in outcomes), outcomes
    failed = next(i for i, (s, g, o) in enumerate(outcomes) if s == "insert" and o.startswith("unseated"))
    after = [s for s, g, _ in outcomes[failed + 1 :] if g == gear]
    assert after[:2] == ["inspect", "pick"], outcomes
    assert summary["replans"] >= 1
    assert summary["status"] == "done", (summary["reason"], outcomes)
    assert all(g["inserted"] for g in summary["gears"].values()), summary["gears"]


@pytest.mark.slow
def test_a_gear_left_unseated_on_its_shaft_is_reported_not_counted(skills, monkeypatch):
    """When the wrist camera's seat check, after the release, finds a gear unseated although the
    tool came down to its seated height, the run fails with that reason instead of going on or
    claiming the gearbox done. (Seed 40 left the small gear cocked 5 mm beside its seat with the
    stage-3 flows; with the refitted flows every gear seats, so the check's verdict is forced here,
    on the first gear the run inserts, which ends the run there.
    tests/perception/test_seat_check.py checks the verdict on rendered views of cocked and raised
    gears.)"""
    import planning.planner_perception
    from perception.seat_check import SeatCheck

    real, seen = planning.planner_perception.check_seat, []

    def first_unseated(obs, gear, X_WS, config=None):
        check = real(obs, gear, X_WS, config)
        seen.append((gear, check.verdict))
        if len(seen) > 1:
            return check
        return SeatCheck("unseated", 0.005, 0.0, check.points, "median height 5.0 mm above a seated face")

    monkeypatch.setattr(planning.planner_perception, "check_seat", first_unseated)
    summary = run_planned_assembly(PlannedAssemblyConfig(seed=SEED, cameras=CAMERAS), skills=skills)
    gear, verdict = seen[0]
    assert verdict == "seated", seen  # the real check saw the gear seated; the test overrules it
    assert len(seen) == 1, seen  # nothing is inserted after a gear left unseated
    assert summary["status"] == "failed" and gear in summary["reason"], summary["reason"]
    assert "unseated" in summary["reason"] and "shaft" in summary["reason"], summary["reason"]
    last = summary["executed"][-1]
    assert (last["skill"], last["gear"]) == ("insert", gear) and last["outcome"].startswith("unseated")


class _WrenchSeeing:
    """A shipped skill as if it sensed the wrench: it records each observation and acts on its pose part."""

    sensing = "wrench"

    def __init__(self, skill):
        self.skill, self.seen = skill, []

    def act(self, obs):
        self.seen.append(np.asarray(obs).reshape(10, 12))
        return self.skill.act(self.seen[-1][:, :8].reshape(-1))

    def __getattr__(self, name):
        return getattr(self.skill, name)


def test_a_skill_that_senses_the_wrench_reads_the_stations_estimate_tared_at_its_start(skills):
    """The insert policy's history in the planner holds the external_wrench input, tared at the
    policy's start (the held gear's weight and the estimate's bias drop out), as in its env."""
    from dataclasses import replace

    from pydrake.systems.analysis import Simulator

    from assembly.scripted_motion import start_keyframe_plan
    from planning.domain import GearBelief
    from planning.system import Phase, PlannerStateMachine, SkillRun, Then

    seeing = _WrenchSeeing(skills["medium"])
    domain = AssemblyDomain({"medium": (lambda xi: 1.0)}, 0.9, lambda g, s: s, goal=("medium",))
    X_WT = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [0.45, 0.05, 0.1])
    machine = PlannerStateMachine({"medium": seeing}, domain, {"medium": RigidTransform()}, CamerasConfig(), X_WT, 0.04)
    assert machine.laws["medium"].sensing == "wrench"
    simulator = Simulator(machine)
    context = simulator.get_mutable_context()
    state = machine.state(context)
    start = replace(
        state,
        phase=Phase.MOTION,
        then=Then.POLICY,
        current=SkillRun("insert", "medium", 0.0, 1.0),
        keyframes=start_keyframe_plan(X_WT, 0.04),
        beliefs={"medium": GearBelief("hand", (0.0, 0.0, 0.0), (1e-3, 1e-3, 0.01))},
    )
    context.get_mutable_abstract_state(0).set_value(start)
    machine.GetInputPort("X_WT").FixValue(context, X_WT)
    machine.GetInputPort("hand_state").FixValue(context, np.zeros(4))
    weight_and_bias = np.array([0.3, -0.2, -1.5, 0.01])
    machine.GetInputPort("external_wrench").FixValue(context, weight_and_bias)
    simulator.AdvanceTo(0.05)  # the policy starts: the history is tared on this reading
    machine.GetInputPort("external_wrench").FixValue(context, weight_and_bias + [0.0, 0.0, 6.0, 0.0])
    simulator.AdvanceTo(0.09)  # one policy step: it pushes the new reading
    first, second = seeing.seen[0], seeing.seen[-1]
    np.testing.assert_allclose(first[:, 8:], 0.0)
    np.testing.assert_allclose(second[0, 8:], [0.0, 0.0, 0.6, 0.0], atol=1e-6)  # 6 N / 10 N
    np.testing.assert_allclose(second[1, 8:], 0.0)
