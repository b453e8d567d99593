"""The Cartesian impedance controller on the full Panda station (no gears: nothing else moves)."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from assembly.impedance import ImpedanceGains, rotation_error
from assembly.panda_model import HAND_TCP_OFFSET, Q_HOME
from assembly.scripted_motion import KeyframePlayer, down_pose, start_keyframe_plan
from assembly.station import StationConfig, build_station, drive_station
from assembly.world import WorldConfig

# Fingertips reach 10 mm beyond the tool frame (pad centre): see assembly/models/panda/panda_hand.urdf.
FINGERTIP_BELOW_TCP = 0.010


@pytest.fixture(scope="module")
def station():
    return build_station(StationConfig(world=WorldConfig(gears=())))


def _simulate(station, X_WT_desired, width, duration):
    context = station.diagram.CreateDefaultContext()
    station.diagram.GetInputPort("X_WT_desired").FixValue(context, X_WT_desired)
    station.diagram.GetInputPort("gripper_width").FixValue(context, [width])
    simulator = Simulator(station.diagram, context)
    simulator.AdvanceTo(duration)
    return context


def _angle_between(R_a, R_b) -> float:
    return float(np.linalg.norm(rotation_error(R_a.matrix(), R_b.matrix())))


def test_rotation_error_is_axis_angle():
    R_a = RollPitchYaw(0.1, -0.2, 0.3).ToRotationMatrix()
    for angle in (1e-8, 0.3, np.pi - 1e-3):
        R_b = RollPitchYaw(0.0, 0.0, angle).ToRotationMatrix() @ R_a
        e = rotation_error(R_b.matrix(), R_a.matrix())
        np.testing.assert_allclose(e, [0, 0, angle], atol=1e-6)


def test_free_space_step_settles(station):
    X0 = station.controller.tool_pose(Q_HOME)
    target = RigidTransform(
        X0.rotation() @ RollPitchYaw(0.0, 0.0, 0.2).ToRotationMatrix(), X0.translation() + [0.10, -0.10, -0.10]
    )
    context = _simulate(station, target, 0.08, 3.0)
    X = station.tool_pose(context)
    assert np.linalg.norm(X.translation() - target.translation()) < 0.002
    assert np.degrees(_angle_between(X.rotation(), target.rotation())) < 2.0


def _press(offset: float, gains: ImpedanceGains | None = None, hold: float = 5.0):
    """On a new station, close the fingers, move above the table, then command the tool `offset`
    below the height at which the fingertips touch; return the station and the root context
    after holding there."""
    station = build_station(StationConfig(world=WorldConfig(gears=()), gains=gains or ImpedanceGains()))
    X0 = station.controller.tool_pose(Q_HOME)
    plan = start_keyframe_plan(X0, 0.0)
    above = down_pose(np.array([0.45, 0.0, FINGERTIP_BELOW_TCP + 0.03]), np.pi / 2)
    plan.append(2.0, above, 0.0, "above table")
    plan.append(1.0, down_pose(np.array([0.45, 0.0, FINGERTIP_BELOW_TCP - offset]), np.pi / 2), 0.0, "press")
    plan.append(hold, plan.keyframes[-1].X_WT, 0.0, "hold")
    diagram = drive_station(station, KeyframePlayer(plan))
    simulator = Simulator(diagram)
    simulator.AdvanceTo(plan.end_time)
    return station, simulator.get_context()


def _robot_table_force(station, context) -> np.ndarray:
    """Total contact force the table exerts on the robot, world frame."""
    plant, inspector = station.plant, station.scene_graph.model_inspector()
    table_body = plant.GetBodyByName("table")
    results = station.diagram.GetOutputPort("contact_results").Eval(station.diagram.GetMyContextFromRoot(context))
    total = np.zeros(3)
    for i in range(results.num_hydroelastic_contacts()):
        info = results.hydroelastic_contact_info(i)
        surface = info.contact_surface()
        bodies = [plant.GetBodyFromFrameId(inspector.GetFrameId(g)) for g in (surface.id_M(), surface.id_N())]
        if table_body in bodies:
            f = info.F_Ac_W().translational()  # on M's body
            total += f if bodies[0] is not table_body else -f
    for i in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(i)
        a, b = plant.get_body(info.bodyA_index()), plant.get_body(info.bodyB_index())
        if table_body in (a, b):
            total += info.contact_force() * (1 if b is not table_body else -1)
    return total


@pytest.mark.parametrize("offset,stiffness", [(0.01, 300.0), (0.02, 300.0), (0.01, 600.0)])
def test_pressing_into_table_gives_stiffness_times_offset(offset, stiffness):
    # Fingers closed, hand pointing down; the fingertips touch the table when the tool frame is
    # FINGERTIP_BELOW_TCP above it. Command the tool `offset` below that.
    gains = ImpedanceGains(
        stiffness=np.array([50, 50, 50, stiffness, stiffness, stiffness]),
        damping=np.array([5, 5, 5, 100, 100, 100]) * np.sqrt(stiffness / 300),
    )
    station, context = _press(offset, gains)
    force = _robot_table_force(station, context)
    expected = stiffness * offset
    assert force[2] == pytest.approx(expected, rel=0.15), (force, expected)
    # Steady: the table's push balances the controller's commanded force (friction may hold a
    # small lateral error from the approach, which is physical).
    commanded = station.diagram.GetOutputPort("wrench").Eval(station.diagram.GetMyContextFromRoot(context))[3:]
    np.testing.assert_allclose(force, -commanded, atol=0.1 * expected)
    # The hand really is at the table, not somewhere else balancing the spring.
    assert abs(station.tool_pose(context).translation()[2] - FINGERTIP_BELOW_TCP) < 0.002


def test_bad_gains_are_rejected():
    with pytest.raises(ValueError, match="stiffness"):
        ImpedanceGains(stiffness=np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="damping"):
        ImpedanceGains(damping=np.array([1, 1, 1, 1, 1, -1.0]))


def test_tcp_offset_constant_matches_model(station):
    # The tool frame sits HAND_TCP_OFFSET along the hand's z axis from the flange.
    context = station.plant.CreateDefaultContext()
    plant = station.plant
    X_WF = plant.GetFrameByName("panda_link8").CalcPoseInWorld(context)
    X_WT = plant.GetFrameByName("panda_hand_tcp").CalcPoseInWorld(context)
    p_FT = X_WF.inverse() @ X_WT.translation()
    np.testing.assert_allclose(p_FT, [0, 0, HAND_TCP_OFFSET], atol=1e-9)
