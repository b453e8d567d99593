"""The generated gear-set models: geometry, mass properties, Drake parsing, hydroelastic contact,
the canonical mesh form every mesh writer uses, and byte-for-byte regeneration
(assembly/gear_meshes.py -> assembly/models/gearset/)."""

from __future__ import annotations

import math
import pathlib
import time

import numpy as np
import pytest
import trimesh
from pydrake.geometry import Convex, Role
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import FixedOffsetFrame, PrismaticJoint
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from assembly.generate_models import model_differences
from assembly.world import model_parser
from assembly import gear_meshes as gm
from assembly import gearset
from assembly import panda_model as pm

MODEL_PATHS = gm.gearset_model_paths()
GEARSET_DIR = MODEL_PATHS["plate"].parent
PLATE_TOP = gearset.PLATE_SIZE[2]
TOL = 1e-6  # geometric tolerance [m] (OBJ files hold 0.1 um)


def _add_models_offline(plant: MultibodyPlant, paths: list[pathlib.Path], monkeypatch: pytest.MonkeyPatch) -> list:
    """Parses `paths` with no way to reach the network: the remote `drake_models` package is
    removed from the parser's package map and Drake's network governor is set to "none".

    (drake 1.51: with DRAKE_ALLOW_NETWORK=none set *before* it, the Parser constructor itself throws,
    because its default package map registers the remote drake_models package.)"""
    parser = model_parser(plant)
    monkeypatch.setenv("DRAKE_ALLOW_NETWORK", "none")
    instances = []
    for path in paths:
        instances += parser.AddModels(str(path))
    return instances


def _contact_plant(builder: DiagramBuilder) -> MultibodyPlant:
    config = MultibodyPlantConfig(
        time_step=0.002, contact_model="hydroelastic_with_fallback", discrete_contact_approximation="lagged"
    )
    plant, _ = AddMultibodyPlant(config, builder)
    return plant


def _ring(mesh: gm.TriangleMesh, z: float, r_min: float, r_max: float) -> np.ndarray:
    """The mesh vertices (x, y) at height z with r_min < radius < r_max, sorted by angle."""
    v = mesh.vertices
    r = np.hypot(v[:, 0], v[:, 1])
    xy = v[(np.abs(v[:, 2] - z) < 1e-9) & (r > r_min) & (r < r_max), :2]
    return xy[np.argsort(np.arctan2(xy[:, 1], xy[:, 0]))]


def _inscribed_radius(polygon: np.ndarray) -> float:
    """Distance from the origin to the nearest edge line of a closed, angle-sorted polygon."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    edge = b - a
    cross = edge[:, 0] * a[:, 1] - edge[:, 1] * a[:, 0]
    return float(np.min(np.abs(cross) / np.linalg.norm(edge, axis=1)))


# ---------------------------------------------------------------------------------------------- files


def test_model_paths_and_files():
    assert set(MODEL_PATHS) == {"plate", "table", *gearset.GEAR_NAMES}
    for path in MODEL_PATHS.values():
        assert path.is_file(), f"{path} missing: run `python -m assembly.gear_meshes`"
    for path in GEARSET_DIR.rglob("*"):
        if path.is_file():
            assert path.suffix in (".sdf", ".obj"), f"unexpected file {path}"
            text = path.read_text()
            assert "package://" not in text and "drake_models" not in text, path
    for sdf in GEARSET_DIR.glob("*.sdf"):
        assert '<sdf version="1.9"' in sdf.read_text()


def test_regeneration_is_byte_identical(tmp_path):
    """A fresh regeneration equals the committed files: the same files, the same geometry of every
    mesh (canonical vertex and face sets, whatever their order) and the same bytes."""
    gm.write_gearset_models(tmp_path)
    assert model_differences(tmp_path / "gearset", GEARSET_DIR) == []


# ------------------------------------------------------------------------------- canonical meshes


def _reindexed(rows: np.ndarray, faces: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The same mesh indexed otherwise: vertices and faces randomly permuted, each face's indices
    cyclically rotated (winding kept), and float noise far below the written precision added."""
    rng = np.random.default_rng(seed)
    moved_to = rng.permutation(len(rows))
    new_rows = np.empty_like(rows)
    new_rows[moved_to] = rows
    new_faces = moved_to[faces][rng.permutation(len(faces))]
    shift = rng.integers(0, 3, len(new_faces))[:, None]
    new_faces = np.take_along_axis(new_faces, (shift + np.arange(3)) % 3, axis=1)
    return new_rows + rng.uniform(-1e-12, 1e-12, rows.shape), new_faces


def _gear_visual() -> tuple[np.ndarray, np.ndarray]:
    mesh = gm.gear_visual_mesh(gearset.gear_spec("small"))
    return mesh.vertices, mesh.faces


def _capsule_with_normals() -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.capsule(height=0.05, radius=0.02, count=[12, 6])
    return np.round(np.hstack([mesh.vertices, mesh.vertex_normals]), 6), mesh.faces


def _gear_obj(rows: np.ndarray, faces: np.ndarray, path: pathlib.Path, normals: bool) -> bytes:
    return gm.write_obj(gm.TriangleMesh(rows, faces), path, normals=normals).read_bytes()


# Every mesh writer of the generated models: name -> (input mesh, (rows, faces, path) -> file bytes).
MESH_WRITERS = {
    "gear_obj": (_gear_visual, lambda rows, faces, path: _gear_obj(rows, faces, path, False)),
    "gear_obj_with_normals": (_gear_visual, lambda rows, faces, path: _gear_obj(rows, faces, path, True)),
    "panda_smooth_obj": (
        _capsule_with_normals,
        lambda rows, faces, path: pm._smooth_obj_text(rows[:, :3], rows[:, 3:], faces).encode(),
    ),
}


@pytest.mark.parametrize("writer", sorted(MESH_WRITERS))
def test_mesh_writers_ignore_vertex_and_face_order(writer, tmp_path):
    """The same geometry gives the same bytes whatever the order of vertices and faces, the rotation
    of each face's indices, or float noise below the written precision: what a library's sort or
    another CPU may change."""
    make_mesh, write = MESH_WRITERS[writer]
    rows, faces = make_mesh()
    reference = write(rows, faces, tmp_path / "reference" / "mesh.obj")
    for seed in range(3):
        assert write(*_reindexed(rows, faces, seed), tmp_path / f"reindexed{seed}" / "mesh.obj") == reference


def test_canonical_mesh_contract():
    rows, faces = _gear_visual()
    canon_rows, canon_faces = gm.canonical_mesh(rows, faces, gm.OBJ_DECIMALS)
    # Invariant under re-indexing, and its own canonical form.
    for seed in range(3):
        again = gm.canonical_mesh(*_reindexed(rows, faces, seed), gm.OBJ_DECIMALS)
        np.testing.assert_array_equal(again[0], canon_rows)
        np.testing.assert_array_equal(again[1], canon_faces)
    fixed_point = gm.canonical_mesh(canon_rows, canon_faces, gm.OBJ_DECIMALS)
    np.testing.assert_array_equal(fixed_point[0], canon_rows)
    np.testing.assert_array_equal(fixed_point[1], canon_faces)
    # Rows sorted and distinct, each face starting at its smallest index, faces sorted.
    assert np.all(np.lexsort(canon_rows.T[::-1]) == np.arange(len(canon_rows)))
    assert len(np.unique(canon_rows, axis=0)) == len(canon_rows)
    assert np.all(canon_faces[:, 0] == canon_faces.min(axis=1))
    assert np.all(np.lexsort(canon_faces.T[::-1]) == np.arange(len(canon_faces)))
    # The winding, hence the outward normals and the volume, is kept.
    before = trimesh.Trimesh(rows, faces, process=False)
    after = trimesh.Trimesh(canon_rows, canon_faces, process=False)
    assert after.is_volume and after.volume == pytest.approx(before.volume, rel=1e-9)


def test_canonical_mesh_merges_rows_that_round_alike_and_drops_unused_ones():
    rows, faces = gm.box_mesh((0.1, 0.2, 0.3)).vertices, gm.box_mesh((0.1, 0.2, 0.3)).faces
    reference = gm.canonical_mesh(rows, faces, gm.OBJ_DECIMALS)
    # A duplicate of vertex 0 (1e-10 away) used by the faces that held vertex 0, plus an unused vertex.
    duplicated = np.vstack([rows, rows[0] + 1e-10, [[5.0, 5.0, 5.0]]])
    redirected = np.where(faces == 0, len(rows), faces)
    result = gm.canonical_mesh(duplicated, redirected, gm.OBJ_DECIMALS)
    np.testing.assert_array_equal(result[0], reference[0])
    np.testing.assert_array_equal(result[1], reference[1])


def test_canonical_mesh_rejects_bad_input():
    rows = np.array([[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with pytest.raises(ValueError, match="lose a corner"):
        gm.canonical_mesh(rows, np.array([[0, 1, 2]]), gm.OBJ_DECIMALS)
    with pytest.raises(ValueError, match="finite"):
        gm.canonical_mesh(np.where(rows == 1.0, np.nan, rows), np.array([[0, 1, 2]]), gm.OBJ_DECIMALS)
    with pytest.raises(ValueError, match="indices"):
        gm.canonical_mesh(rows, np.array([[0, 1, 3]]), gm.OBJ_DECIMALS)


def test_committed_meshes_are_canonical():
    """Every committed OBJ under assembly/models lists its vertices and faces in canonical order (a
    Panda mesh's vertex is a position with its own normal, `f i//i`)."""
    for path in sorted(GEARSET_DIR.parent.rglob("*.obj")):
        lines = path.read_text().splitlines()
        positions = [[float(t) for t in line.split()[1:]] for line in lines if line.startswith("v ")]
        normals = [[float(t) for t in line.split()[1:]] for line in lines if line.startswith("vn ")]
        corners = np.array(
            [
                [int(i or 0) for i in token.split("/")[::2]]
                for line in lines
                if line.startswith("f ")
                for token in line.split()[1:]
            ]
        )
        per_vertex_normals = corners.shape[1] == 2 and np.array_equal(corners[:, 0], corners[:, 1])
        rows = np.hstack([positions, normals]) if per_vertex_normals else np.array(positions)
        faces = corners[:, 0].reshape(-1, 3) - 1
        canon_rows, canon_faces = gm.canonical_mesh(rows, faces, decimals=9)
        np.testing.assert_array_equal(canon_rows, rows, err_msg=str(path))
        np.testing.assert_array_equal(canon_faces, faces, err_msg=str(path))


# ----------------------------------------------------------------------------------------- parsing


@pytest.mark.parametrize("key", sorted(MODEL_PATHS))
def test_each_sdf_parses_offline(key, monkeypatch):
    builder = DiagramBuilder()
    plant = _contact_plant(builder)
    (instance,) = _add_models_offline(plant, [MODEL_PATHS[key]], monkeypatch)
    bodies = plant.GetBodyIndices(instance)
    assert len(bodies) == 1
    body = plant.get_body(bodies[0])
    expected = {"plate": gm.PLATE_BODY_NAME, "table": gm.TABLE_BODY_NAME}.get(key) or gm.gear_body_name(key)
    assert body.name() == expected
    assert plant.GetCollisionGeometriesForBody(body)
    plant.Finalize()


# ---------------------------------------------------------------------------------------- the gears


@pytest.mark.parametrize("name", gearset.GEAR_NAMES)
def test_gear_visual_mesh_is_a_watertight_involute_gear(name):
    spec = gearset.gear_spec(name)
    mesh = gm.read_obj(GEARSET_DIR / "meshes" / f"{gm.gear_body_name(name)}_visual.obj")
    tm = mesh.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent and tm.is_volume
    assert len(mesh.faces) < 5000
    assert mesh.vertices[:, 2].min() == pytest.approx(0.0, abs=TOL)
    assert mesh.vertices[:, 2].max() == pytest.approx(gearset.GEAR_THICKNESS, abs=TOL)
    # The outline of the bottom face: tooth count = number of times the radius rises past the pitch
    # circle going once around; the radii span root to tip circle.
    outline = _ring(mesh, 0.0, gearset.GEAR_BORE_RADIUS + gearset.GEAR_BORE_CHAMFER + 1e-3, 1.0)
    radius = np.hypot(outline[:, 0], outline[:, 1])
    above = radius > spec.pitch_radius
    assert int(np.sum(above & ~np.roll(above, 1))) == spec.teeth
    assert radius.max() == pytest.approx(spec.tip_radius, abs=TOL)
    assert radius.min() == pytest.approx(spec.root_radius, abs=TOL)
    # Chamfered bore: radius 6 mm at both faces, 5 mm from 1 mm in.
    bore = np.hypot(*_ring(mesh, 0.0, 0.0, spec.root_radius - 1e-3).T)
    np.testing.assert_allclose(bore, gearset.GEAR_BORE_RADIUS + gearset.GEAR_BORE_CHAMFER, atol=TOL)
    inner = np.hypot(*_ring(mesh, gearset.GEAR_BORE_CHAMFER, 0.0, spec.root_radius - 1e-3).T)
    np.testing.assert_allclose(inner, gearset.GEAR_BORE_RADIUS, atol=TOL)


@pytest.mark.parametrize("name", gearset.GEAR_NAMES)
def test_gear_collision_mesh_bore_and_tip(name):
    spec = gearset.gear_spec(name)
    mesh = gm.read_obj(GEARSET_DIR / "meshes" / f"{gm.gear_body_name(name)}_collision.obj")
    assert mesh.to_trimesh().is_volume
    assert len(mesh.faces) <= 600
    ch, r_bore = gearset.GEAR_BORE_CHAMFER, gearset.GEAR_BORE_RADIUS
    for z in (ch, gearset.GEAR_THICKNESS - ch):  # bore proper: inscribed radius 5 mm
        bore = _ring(mesh, z, 0.0, r_bore + 0.5 * ch)
        assert len(bore) == gm.BORE_COLLISION_SIDES
        assert _inscribed_radius(bore) == pytest.approx(r_bore, abs=5e-5)
    for z in (0.0, gearset.GEAR_THICKNESS):  # chamfer mouths: 1 mm wider
        mouth = _ring(mesh, z, 0.0, r_bore + 2 * ch)
        assert _inscribed_radius(mouth) == pytest.approx(r_bore + ch, abs=5e-5)
    outer = _ring(mesh, 0.0, spec.root_radius, 1.0)
    assert len(outer) == gm.GEAR_COLLISION_SIDES
    assert _inscribed_radius(outer) == pytest.approx(spec.tip_radius, abs=TOL)  # circumscribed


@pytest.mark.parametrize("name", gearset.GEAR_NAMES)
def test_gear_mass_properties_come_from_the_visual_mesh(name, monkeypatch):
    mesh = gm.read_obj(GEARSET_DIR / "meshes" / f"{gm.gear_body_name(name)}_visual.obj").to_trimesh()
    builder = DiagramBuilder()
    plant = _contact_plant(builder)
    _add_models_offline(plant, [MODEL_PATHS[name]], monkeypatch)
    plant.Finalize()
    body = plant.GetBodyByName(gm.gear_body_name(name))
    assert body.default_mass() == pytest.approx(mesh.volume * gearset.GEAR_DENSITY, rel=1e-6)
    np.testing.assert_allclose(body.default_com(), [0.0, 0.0, 0.5 * gearset.GEAR_THICKNESS], atol=1e-9)
    izz = mesh.moment_inertia[2, 2] * gearset.GEAR_DENSITY  # trimesh: unit density, about the COM
    assert body.default_rotational_inertia().get_moments()[2] == pytest.approx(izz, rel=1e-6)


# ---------------------------------------------------------------------------------- plate and shafts


def test_shafts_are_compliant_convex_and_sized(monkeypatch):
    builder = DiagramBuilder()
    plant = _contact_plant(builder)
    _add_models_offline(plant, [MODEL_PATHS["plate"]], monkeypatch)
    plant.Finalize()
    inspector = builder.GetSubsystemByName("scene_graph").model_inspector()
    frame_id = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(gm.PLATE_BODY_NAME).index())
    by_name = {inspector.GetName(g).split("::")[-1]: g for g in inspector.GetGeometries(frame_id, Role.kProximity)}
    for name in gearset.GEAR_NAMES:
        geometry = by_name[gm.shaft_collision_name(name)]
        shape = inspector.GetShape(geometry)
        assert isinstance(shape, Convex)
        props = inspector.GetProximityProperties(geometry)
        assert props.GetProperty("hydroelastic", "hydroelastic_modulus") == pytest.approx(1e7)
        X_PS = inspector.GetPoseInFrame(geometry)
        v_P = X_PS.multiply(gm.read_obj(pathlib.Path(shape.source().path())).vertices.T).T
        axis = gearset.shaft_position_in_plate(name)
        radius = np.hypot(v_P[:, 0] - axis[0], v_P[:, 1] - axis[1])
        below_chamfer = v_P[:, 2] < PLATE_TOP + gearset.SHAFT_HEIGHT - gearset.SHAFT_CHAMFER + TOL
        np.testing.assert_allclose(radius[below_chamfer], gearset.SHAFT_RADIUS, atol=TOL)
        assert radius.max() == pytest.approx(gearset.SHAFT_RADIUS, abs=TOL)  # vertices ON 4.5 mm
        assert v_P[:, 2].max() == pytest.approx(PLATE_TOP + gearset.SHAFT_HEIGHT, abs=TOL)
        top = radius[v_P[:, 2] > PLATE_TOP + gearset.SHAFT_HEIGHT - TOL]
        np.testing.assert_allclose(top, gearset.SHAFT_RADIUS - gearset.SHAFT_CHAMFER, atol=TOL)
        assert v_P[:, 2].min() < PLATE_TOP  # rooted in the plate: no gap at the foot


# ------------------------------------------------------------------------------ hydroelastic contact


def _drop_medium_gear(
    monkeypatch, lateral_offset: float, drop_height: float, hold_lateral: bool, duration: float = 0.5
) -> tuple[float, np.ndarray, float]:
    """Simulates the medium gear released `drop_height` above its seated pose, shifted by
    `lateral_offset` along x, with the plate welded to the world. With `hold_lateral`, the gear can
    only move along z (as if guided by the gripper); otherwise it is free. Returns (wall-clock
    seconds for the simulation, gear origin minus seated origin [m], tilt of the gear axis [rad])."""
    builder = DiagramBuilder()
    plant = _contact_plant(builder)
    _add_models_offline(plant, [MODEL_PATHS["plate"], MODEL_PATHS["medium"]], monkeypatch)
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(gm.PLATE_BODY_NAME))
    gear = plant.GetBodyByName(gm.gear_body_name("medium"))
    seat = gearset.shaft_position_in_plate("medium")
    start = seat + np.array([lateral_offset, 0.0, drop_height])
    joint = None
    if hold_lateral:
        guide = plant.AddFrame(
            FixedOffsetFrame("guide", plant.world_frame(), RigidTransform(start - [0, 0, drop_height]))
        )
        joint = plant.AddJoint(PrismaticJoint("drop", guide, gear.body_frame(), [0.0, 0.0, 1.0]))
    plant.Finalize()
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    if joint is None:
        plant.SetFreeBodyPose(context, gear, RigidTransform(start))
    else:
        joint.set_translation(context, drop_height)
    simulator.Initialize()
    t0 = time.perf_counter()
    simulator.AdvanceTo(duration)
    wall = time.perf_counter() - t0
    X_WG = plant.EvalBodyPoseInWorld(context, gear)
    tilt = math.acos(np.clip(X_WG.rotation().matrix()[2, 2], -1.0, 1.0))
    return wall, X_WG.translation() - seat, tilt


def test_aligned_gear_drops_onto_its_seat(monkeypatch, capsys):
    wall, error, tilt = _drop_medium_gear(monkeypatch, 0.0, 0.005, hold_lateral=False)
    with capsys.disabled():
        print(
            f"\n[gear models] 0.5 s hydroelastic drop of the medium gear onto its shaft and the plate "
            f"(dt 2 ms, lagged): {wall:.3f} s wall ({0.5 / wall:.2f}x real time)"
        )
    assert abs(error[2]) < 1e-3, f"height error {error[2] * 1e3:.3f} mm"
    assert np.hypot(error[0], error[1]) < 0.6e-3  # within the bore clearance
    assert tilt < math.radians(2.0)


def test_off_axis_gear_rests_on_the_shaft_top(monkeypatch):
    # 2.5 mm off the axis, lateral motion held (as by the gripper), released 2 mm above the shaft top:
    # the bore cannot pass the shaft, so the gear must come to rest on the shaft's top chamfer. With
    # the contact missing it would fall to the plate; with the gear's mesh collapsed to its convex
    # hull (point-contact fallback) it would rest on the shaft's top face, which is the same height,
    # so the aligned drop above is the test that the bore is real.
    _, error, _ = _drop_medium_gear(monkeypatch, 0.0025, gearset.SHAFT_HEIGHT + 0.002, hold_lateral=True)
    assert error[2] > 1e-3, "the off-axis gear fell to its seat: shaft contact is missing"
    assert error[2] == pytest.approx(gearset.SHAFT_HEIGHT, abs=1e-3)
