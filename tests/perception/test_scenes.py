"""Random calibration scenes and their perturbations (perception.scenes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from assembly.gearset import GEAR_THICKNESS
from assembly.world import PLACEMENT_X, PLACEMENT_Y, WorldConfig
from perception.scenes import (
    DEPTH_NOISE_REFERENCE,
    INSPECT_OFFSET,
    PERTURBATIONS,
    RandomScene,
    SceneRenderer,
    random_scenes,
)


@pytest.fixture(scope="module")
def renderer() -> SceneRenderer:
    return SceneRenderer()


@pytest.fixture(scope="module")
def scene() -> RandomScene:
    return next(random_scenes(21, 1))


def _render(renderer, scene, perturbation, view="scene", gear=None, tag="t"):
    return renderer.render_view(scene, view, gear, perturbation, scene.rng(tag, view, perturbation))


def test_catalogue():
    for name in (
        "clean",
        "depth_noise",
        "dropout_3",
        "dropout_10",
        "dim",
        "bright",
        "oblique",
        "occluded_hand",
        "occluded_gear",
    ):
        assert PERTURBATIONS[name].name == name
    with pytest.raises(dataclasses.FrozenInstanceError):
        PERTURBATIONS["clean"].dropout = 0.5


def test_scenes_deterministic_and_valid():
    a, b = list(random_scenes(5, 4)), list(random_scenes(5, 4))
    assert [s.poses for s in a] == [s.poses for s in b]
    assert a[0].poses != next(random_scenes(6, 1)).poses
    for s in a:
        WorldConfig(gear_start_poses=s.poses)
        for x, y, _ in s.poses.values():
            assert PLACEMENT_X[0] <= x <= PLACEMENT_X[1] and PLACEMENT_Y[0] <= y <= PLACEMENT_Y[1]


def test_renders_deterministic(renderer, scene):
    for p in ("dropout_10", "occluded_gear"):
        one, two = _render(renderer, scene, p), _render(renderer, scene, p)
        np.testing.assert_array_equal(one.obs.rgb, two.obs.rgb)
        np.testing.assert_array_equal(one.obs.depth, two.obs.depth)  # NaN at the same pixels
        assert one.hidden_fraction == two.hidden_fraction
    other = _render(renderer, scene, "dropout_10", tag="other")
    assert not np.array_equal(np.isnan(other.obs.depth), np.isnan(one.obs.depth))


def test_dropout_and_noise(renderer, scene):
    clean = _render(renderer, scene, "clean").obs.depth
    for name, fraction in (("dropout_3", 0.03), ("dropout_10", 0.10)):
        depth = _render(renderer, scene, name).obs.depth
        assert abs(np.isnan(depth).mean() - fraction) < 0.003
        kept = ~np.isnan(depth)
        np.testing.assert_array_equal(depth[kept], clean[kept])
    noisy = _render(renderer, scene, "depth_noise").obs.depth
    finite = np.isfinite(clean)
    assert np.array_equal(np.isfinite(noisy), finite)  # nothing dropped or clipped
    scaled = (noisy[finite] - clean[finite]) / (clean[finite] / DEPTH_NOISE_REFERENCE) ** 2
    assert abs(scaled.std() - 1e-3) < 0.03e-3 and abs(scaled.mean()) < 0.03e-3


def test_lighting_rendered_by_drake(renderer, scene):
    clean = _render(renderer, scene, "clean").obs
    cam = renderer.scene_camera
    labels = renderer.scene.render_labels(cam.info(), cam.near, cam.far, cam.X_PC)
    table = labels == int(renderer.scene.plant.GetBodyByName("table").index())
    for name, gain in (("dim", 0.5), ("bright", 1.6)):
        obs = _render(renderer, scene, name).obs
        np.testing.assert_array_equal(obs.depth, clean.depth)
        expected = np.minimum(clean.rgb[table] * gain, 1.0)
        assert np.abs(obs.rgb[table] - expected).mean() < 0.01
    assert _render(renderer, scene, "bright").obs.rgb.max() == 1.0  # saturates
    oblique = _render(renderer, scene, "oblique").obs
    # The light arrives at 45 deg elevation: the table's shade is sin 45 deg (the headlight's is
    # the cosine of the camera's tilt), and the gears' walls are lit on one side only.
    shade = oblique.rgb[table].sum(-1)
    assert np.mean(np.abs(shade - np.median(shade)) < 0.01) > 0.97  # all but antialiased edges
    assert abs(np.median(shade) / (0.62 + 0.45 + 0.28) - np.sin(np.pi / 4)) < 0.01
    gears = np.isin(labels, [renderer.scene.label(g) for g in scene.poses])
    assert np.abs(oblique.rgb[gears] - clean.rgb[gears]).sum(-1).mean() > 0.1


def test_occluders_hide_15_to_40_percent(renderer):
    cam = renderer.scene_camera
    for scene in random_scenes(22, 3):
        for name in ("occluded_hand", "occluded_gear"):
            view = _render(renderer, scene, name)
            assert 0.15 <= view.hidden_fraction <= 0.40
            target = renderer.scene.label(view.gear)
            # Recount on label images: with the occluder where render_view left it, and parked.
            hidden = renderer.scene.render_labels(cam.info(), cam.near, cam.far, cam.X_PC) == target
            for occ in renderer.scene.occluder_bodies:
                renderer.scene.set_occluder_pose(occ, None)
            shown = renderer.scene.render_labels(cam.info(), cam.near, cam.far, cam.X_PC) == target
            assert abs(1 - hidden.sum() / shown.sum() - view.hidden_fraction) < 1e-9
            assert view.visible[view.gear] == pytest.approx(1 - view.hidden_fraction)
            kind, X_WO = view.occluder
            assert kind == "hand" if name == "occluded_hand" else kind != view.gear
            assert X_WO.translation()[2] > GEAR_THICKNESS + 0.01


def test_inspect_view(renderer, scene):
    for gear in scene.poses:
        view = _render(renderer, scene, "clean", view="inspect", gear=gear)
        x, y, _ = scene.poses[gear]
        assert np.hypot(view.believed_xy[0] - x, view.believed_xy[1] - y) <= INSPECT_OFFSET
        p = view.obs.X_WC.translation()
        assert p[2] == pytest.approx(GEAR_THICKNESS + 0.17, abs=1e-9)
        assert np.allclose(p[:2], view.believed_xy, atol=1e-9)
        np.testing.assert_allclose(view.obs.X_WC.rotation().matrix()[:, 2], [0, 0, -1], atol=1e-9)
        assert view.obs.intrinsics.fy == pytest.approx(240 / np.tan(np.radians(30)))
    occluded = _render(renderer, scene, "occluded_gear", view="inspect", gear="medium")
    assert 0.15 <= occluded.hidden_fraction <= 0.40


def test_bad_input(renderer, scene):
    with pytest.raises(ValueError, match="unknown perturbation"):
        _render(renderer, scene, "foggy")
    with pytest.raises(ValueError, match="view"):
        renderer.render_view(scene, "top", None, "clean", np.random.default_rng(0))
    with pytest.raises(ValueError, match="needs a gear"):
        renderer.render_view(scene, "inspect", None, "clean", np.random.default_rng(0))
    with pytest.raises(ValueError, match="Generator"):
        renderer.render_view(scene, "scene", None, "clean", 0)
    with pytest.raises(ValueError, match="seed"):
        next(random_scenes(-1))
