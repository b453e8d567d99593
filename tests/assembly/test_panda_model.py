"""Tests of our generated Franka Panda arm + hand model (assembly/panda_model.py)."""

from __future__ import annotations

import math
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from pydrake.geometry import Box, HydroelasticContactRepresentation, Role
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import JointActuatorIndex
from pydrake.systems.framework import DiagramBuilder

from assembly.generate_models import MODELS_DIR, model_differences
from assembly.world import model_parser
from assembly import panda_model as pm

ARM_URDF, HAND_URDF = pm.panda_model_paths()
REPO_ROOT = pathlib.Path(pm.__file__).resolve().parents[1]

# Independent copies of the published numbers (Franka FCI docs; Gaz et al., RA-L 2019).
DH = [  # (a_{i-1}, d_i, alpha_{i-1})
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
    (0.0, 0.107, 0.0),
]
LINK_MASSES = [0.629769, 4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522]


def dh_flange_pose(q: np.ndarray) -> np.ndarray:
    """4x4 pose of the flange in the base frame from Craig's modified DH table."""
    pose = np.eye(4)
    for i, (a, d, alpha) in enumerate(DH):
        theta = q[i] if i < 7 else 0.0
        ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
        step = np.array(
            [
                [ct, -st, 0.0, a],
                [st * ca, ct * ca, -sa, -sa * d],
                [st * sa, ct * sa, ca, ca * d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        pose = pose @ step
    return pose


def offline_parser(plant) -> Parser:
    """The project's parser (assembly.world.model_parser): it cannot fetch remote packages."""
    parser = model_parser(plant)
    assert not parser.package_map().Contains("drake_models")
    return parser


@pytest.fixture(scope="module")
def station():
    """Arm welded to the world, hand welded to the flange; returns (diagram, plant, sg, arm, hand)."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.001)
    parser = offline_parser(plant)
    arm = parser.AddModels(str(ARM_URDF))[0]
    hand = parser.AddModels(str(HAND_URDF))[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0", arm))
    plant.WeldFrames(
        plant.GetFrameByName("panda_link8", arm),
        plant.GetFrameByName("panda_hand", hand),
        RigidTransform(RotationMatrix.MakeZRotation(pm.HAND_FLANGE_YAW)),
    )
    plant.Finalize()
    diagram = builder.Build()
    return diagram, plant, scene_graph, arm, hand


def test_files_are_self_contained() -> None:
    for path in (ARM_URDF, HAND_URDF):
        text = path.read_text()
        assert "package://" not in text and "drake_models" not in text
        for line in text.splitlines():
            if "filename=" in line:
                rel = line.split('filename="')[1].split('"')[0]
                assert rel.startswith("meshes/"), rel
                assert (path.parent / rel).is_file(), rel


def test_each_urdf_parses_alone() -> None:
    for path, bodies in ((ARM_URDF, 9), (HAND_URDF, 4)):
        plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.001)
        model = offline_parser(plant).AddModels(str(path))[0]
        plant.Finalize()
        assert len(plant.GetBodyIndices(model)) == bodies


def test_arm_joints_and_limits(station) -> None:
    _, plant, _, arm, _ = station
    joints = [plant.get_joint(j) for j in plant.GetJointIndices(arm)]
    revolute = [j for j in joints if j.type_name() == "revolute"]
    assert [j.name() for j in revolute] == list(pm.ARM_JOINT_NAMES)
    lower = np.array([j.position_lower_limits()[0] for j in revolute])
    upper = np.array([j.position_upper_limits()[0] for j in revolute])
    vel = np.array([j.velocity_upper_limits()[0] for j in revolute])
    np.testing.assert_allclose(lower, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    np.testing.assert_allclose(upper, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    np.testing.assert_allclose(vel, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_allclose(lower, pm.Q_MIN)
    np.testing.assert_allclose(upper, pm.Q_MAX)
    assert all(j.default_damping() > 0 for j in revolute)
    assert np.all((pm.Q_MIN < pm.Q_HOME) & (pm.Q_HOME < pm.Q_MAX))


def test_actuators(station) -> None:
    _, plant, _, arm, hand = station
    actuators = [plant.get_joint_actuator(JointActuatorIndex(i)) for i in range(plant.num_actuators())]
    arm_acts = [a for a in actuators if a.model_instance() == arm]
    hand_acts = [a for a in actuators if a.model_instance() == hand]
    assert [a.joint().name() for a in arm_acts] == list(pm.ARM_JOINT_NAMES)
    np.testing.assert_allclose([a.effort_limit() for a in arm_acts], [87] * 4 + [12] * 3)
    np.testing.assert_allclose([a.default_reflected_inertia() for a in arm_acts], pm.REFLECTED_INERTIA)
    assert [a.joint().name() for a in hand_acts] == list(pm.FINGER_JOINT_NAMES)
    assert all(a.effort_limit() == pm.FINGER_FORCE_MAX for a in hand_acts)


def test_flange_at_zero_and_home(station) -> None:
    diagram, plant, _, arm, _ = station
    context = plant.CreateDefaultContext()
    flange = plant.GetBodyByName("panda_link8", arm)
    plant.SetPositions(context, arm, np.zeros(7))
    X = plant.EvalBodyPoseInWorld(context, flange)
    np.testing.assert_allclose(X.translation(), [0.088, 0.0, 0.926], atol=1e-6)
    rng = np.random.default_rng(0)
    for q in [pm.Q_HOME, *rng.uniform(pm.Q_MIN, pm.Q_MAX, size=(5, 7))]:
        plant.SetPositions(context, arm, q)
        X = plant.EvalBodyPoseInWorld(context, flange).GetAsMatrix4()
        np.testing.assert_allclose(X, dh_flange_pose(q), atol=1e-6)


def test_tcp_frame(station) -> None:
    _, plant, _, arm, hand = station
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, arm, pm.Q_HOME)
    X_WF = plant.EvalBodyPoseInWorld(context, plant.GetBodyByName("panda_link8", arm))
    X_WT = plant.EvalBodyPoseInWorld(context, plant.GetBodyByName("panda_hand_tcp", hand))
    X_FT = X_WF.inverse() @ X_WT
    np.testing.assert_allclose(X_FT.translation(), [0.0, 0.0, 0.1034], atol=1e-9)
    np.testing.assert_allclose(X_FT.rotation().matrix(), RotationMatrix.MakeZRotation(-math.pi / 4).matrix(), atol=1e-9)
    # At the ready pose the TCP points straight down.
    np.testing.assert_allclose(X_WT.rotation().matrix()[:, 2], [0, 0, -1], atol=2e-3)


def test_masses_and_inertias(station) -> None:
    _, plant, _, arm, hand = station
    context = plant.CreateDefaultContext()
    assert plant.CalcTotalMass(context, [arm]) == pytest.approx(sum(LINK_MASSES), abs=1e-9)
    assert plant.CalcTotalMass(context, [hand]) == pytest.approx(0.73 + 2 * 0.015, abs=1e-9)
    for index in [*plant.GetBodyIndices(arm), *plant.GetBodyIndices(hand)]:
        body = plant.get_body(index)
        assert body.default_spatial_inertia().IsPhysicallyValid(), body.name()


def _pad_geometry(plant, scene_graph, finger: str):
    inspector = scene_graph.model_inspector()
    body = plant.GetBodyByName(finger)
    ids = [g for g in plant.GetCollisionGeometriesForBody(body) if inspector.GetName(g).endswith("_pad")]
    assert len(ids) == 1
    return ids[0]


@pytest.mark.parametrize("opening", [0.0, 0.02, 0.04])
def test_finger_pads(station, opening: float) -> None:
    diagram, plant, scene_graph, arm, hand = station
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    plant.SetPositions(plant_context, arm, pm.Q_HOME)
    plant.SetPositions(plant_context, hand, [opening, opening])
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    X_WH = plant.EvalBodyPoseInWorld(plant_context, plant.GetBodyByName("panda_hand"))
    inner = {}
    for finger, sign in (("panda_leftfinger", 1.0), ("panda_rightfinger", -1.0)):
        gid = _pad_geometry(plant, scene_graph, finger)
        shape = inspector.GetShape(gid)
        assert isinstance(shape, Box)
        assert (shape.width(), shape.depth(), shape.height()) == pytest.approx((0.018, 0.008, 0.020))
        X_HP = X_WH.inverse() @ query.GetPoseInWorld(gid)
        np.testing.assert_allclose(X_HP.rotation().matrix(), np.eye(3), atol=1e-9)
        p = X_HP.translation()
        assert abs(p[0]) < 1e-9
        assert pm.HAND_TCP_OFFSET - 0.01 <= p[2] <= pm.HAND_TCP_OFFSET + 0.01
        assert p[2] + shape.height() / 2 == pytest.approx(pm.HAND_TCP_OFFSET + 0.01, abs=2e-3)
        inner[finger] = p[1] - sign * shape.depth() / 2
        props = inspector.GetProximityProperties(gid)
        assert 5e6 <= props.GetProperty("hydroelastic", "hydroelastic_modulus") <= 1e7
        assert props.GetProperty("hydroelastic", "resolution_hint") == pytest.approx(0.004)
        assert props.GetProperty("material", "coulomb_friction").static_friction() == 1.0
    assert inner["panda_leftfinger"] == pytest.approx(opening, abs=1e-9)
    assert inner["panda_rightfinger"] == pytest.approx(-opening, abs=1e-9)
    assert inner["panda_leftfinger"] - inner["panda_rightfinger"] == pytest.approx(2 * opening)


def test_hydroelastic_roles(station) -> None:
    _, plant, scene_graph, arm, hand = station
    inspector = scene_graph.model_inspector()
    for body_name, expected in (
        ("panda_hand", {"panda_hand_palm": "rigid"}),
        ("panda_leftfinger", {"panda_leftfinger_body": "rigid", "panda_leftfinger_pad": "compliant"}),
    ):
        for gid in plant.GetCollisionGeometriesForBody(plant.GetBodyByName(body_name)):
            name = inspector.GetName(gid).split("::")[-1]
            props = inspector.GetProximityProperties(gid)
            assert props.HasProperty("hydroelastic", "compliance_type"), name
            # Only compliant geometries carry a modulus (the enum itself is not bound in Python).
            is_compliant = props.HasProperty("hydroelastic", "hydroelastic_modulus")
            assert is_compliant == (expected[name] == "compliant"), name
    for index in plant.GetBodyIndices(arm):
        for gid in plant.GetCollisionGeometriesForBody(plant.get_body(index)):
            props = inspector.GetProximityProperties(gid)
            assert not props.HasProperty("hydroelastic", "compliance_type")


def test_home_pose_is_collision_free(station) -> None:
    diagram, plant, scene_graph, arm, hand = station
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    plant.SetPositions(plant_context, arm, pm.Q_HOME)
    plant.SetPositions(plant_context, hand, [pm.FINGER_JOINT_MAX] * 2)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    assert query.ComputePointPairPenetration() == []


def test_visual_meshes_are_small(station) -> None:
    _, plant, scene_graph, arm, hand = station
    inspector = scene_graph.model_inspector()
    assert len(inspector.GetAllGeometryIds(Role.kIllustration)) >= 9
    for obj in sorted((ARM_URDF.parent / "meshes").glob("*.obj")):
        faces = sum(1 for line in obj.read_text().splitlines() if line.startswith("f "))
        assert 0 < faces < 2000, obj.name


def test_regeneration_is_bit_identical(tmp_path: pathlib.Path) -> None:
    """A fresh regeneration equals the committed files: the same files, the same geometry of every
    mesh (canonical vertex and face sets, whatever their order) and the same bytes. The listed
    differences say which: "geometry differs" is a real change; "bytes differ (same geometry)" a
    mesh writer that is not canonical."""
    pm.write_panda_models(tmp_path)
    assert model_differences(tmp_path / "panda", ARM_URDF.parent) == []


def test_regeneration_does_not_depend_on_numpy_simd_dispatch(tmp_path: pathlib.Path) -> None:
    """`python -m assembly.generate_models --out DIR` with numpy's SIMD kernels switched off
    (sorts, trigonometry, sums: as on a CPU without AVX-512 or AVX2) writes the committed files
    byte for byte. Before the canonical writer, trimesh's unstable sorts ordered ties by the CPU's
    SIMD dispatch, and 6 Panda meshes came out in another face order with AVX-512 switched off."""
    multiarray = pytest.importorskip("numpy._core._multiarray_umath")
    enabled = getattr(multiarray, "__cpu_features__", {})
    dispatched = [f for f in getattr(multiarray, "__cpu_dispatch__", []) if enabled.get(f)]
    if not dispatched:
        pytest.skip("numpy dispatches no SIMD kernels on this CPU: nothing to switch off")
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(dispatched)}
    subprocess.run(
        [sys.executable, "-m", "assembly.generate_models", "--out", str(tmp_path)],
        cwd=REPO_ROOT,
        env=env,
        check=True,
        capture_output=True,
        timeout=300,
    )
    assert model_differences(tmp_path, MODELS_DIR) == []


def test_closed_pads_make_a_hydroelastic_contact(station) -> None:
    """Pushed 1 mm past closed, the two compliant pads meet in a hydroelastic contact surface."""
    diagram, plant, scene_graph, arm, hand = station
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    plant.SetPositions(plant_context, arm, pm.Q_HOME)
    plant.SetPositions(plant_context, hand, [-0.001, -0.001])
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    surfaces, point_pairs = query.ComputeContactSurfacesWithFallback(HydroelasticContactRepresentation.kPolygon)
    assert point_pairs == [] and len(surfaces) == 1
    names = {query.inspector().GetName(g).split("::")[-1] for g in (surfaces[0].id_M(), surfaces[0].id_N())}
    assert names == {"panda_leftfinger_pad", "panda_rightfinger_pad"}
    # The contact patch is the pads' shared face, 18 mm x 20 mm.
    assert surfaces[0].total_area() == pytest.approx(0.018 * 0.020, rel=0.05)


def test_arm_collision_shapes_follow_the_table(station) -> None:
    """Each arm collision cylinder/capsule sits on its table segment (URDF rpy is right)."""
    _, plant, scene_graph, arm, _ = station
    inspector = scene_graph.model_inspector()
    for link_index, parts in enumerate(pm._ARM_PARTS):
        body = plant.GetBodyByName(f"panda_link{link_index}", arm)
        geometries = plant.GetCollisionGeometriesForBody(body)
        collidable = [p for p in parts if p.collide]
        assert len(geometries) == len(collidable)
        for gid, part in zip(geometries, collidable):
            X = inspector.GetPoseInFrame(gid)
            if part.kind == "box":
                np.testing.assert_allclose(X.translation(), part.a, atol=1e-9)
                continue
            a, b = np.asarray(part.a, float), np.asarray(part.b, float)
            np.testing.assert_allclose(X.translation(), (a + b) / 2, atol=1e-9)
            np.testing.assert_allclose(X.rotation().matrix()[:, 2], (b - a) / np.linalg.norm(b - a), atol=1e-9)
