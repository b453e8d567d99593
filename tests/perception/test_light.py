"""The light's direction read off a gear's shading: recovered under an oblique lamp, left alone
under the headlight, and what it buys the far posterior (a scene view lit from the side used to
give confidently wrong answers)."""

import numpy as np
import pytest

from perception.detection import detect_gears
from perception.gear_model import gear_model
from perception.renderer import RayCaster
from perception.scenes import SceneRenderer, random_scenes
from perception.scoring import ImageScorer
from perception.search import SearchConfig, estimate_pose

# The catalogue's oblique lamp (perception.scenes): 45 deg elevation, azimuth 38 deg.
_EL, _AZ = np.radians(45.0), np.radians(38.0)
OBLIQUE = np.array([np.cos(_EL) * np.cos(_AZ), np.cos(_EL) * np.sin(_AZ), np.sin(_EL)])


@pytest.fixture(scope="module")
def scene():
    # seed 100: a tuning seed (the benchmark's start at 7000)
    return next(iter(random_scenes(100, 1)))


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer()


def test_surface_normals_are_unit_and_the_top_face_points_up():
    caster = RayCaster(gear_model("medium"))
    v, u = np.mgrid[-20:21, -20:21] * 5e-4
    origin = np.array([0.4, 0.0, 0.5])
    dirs = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, -0.5)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = caster.render(origin, dirs, np.array([0, 0, 1.0]), np.array([[0.4, 0.0, 0.2]]), surface=True)
    assert len(hits.pix) > 100
    np.testing.assert_allclose(np.linalg.norm(hits.normal, axis=1), 1.0, atol=1e-5)
    top = hits.depth < 0.4801  # the top face, 20 mm up, straight under the camera
    assert top.any() and np.all(hits.normal[top, 2] > 0.999)
    np.testing.assert_allclose(hits.rgb, hits.albedo * hits.normal[:, 2:3], atol=1e-5)
    assert caster.render(origin, dirs, np.array([0, 0, 1.0]), np.array([[0.4, 0.0, 0.2]])).normal is None


@pytest.mark.parametrize("gear", ["small", "large"])
def test_oblique_light_is_recovered_from_a_close_view(scene, renderer, gear):
    """Seen from above, a gear shows little wall: the large gear's walls are read on every pixel
    (the search's sparse pixels hold too few of them, and the light is then kept)."""
    truth = np.array(scene.poses[gear])
    view = renderer.render_view(
        scene, "inspect", gear, "oblique", scene.rng("inspect", gear), believed_xy=tuple(truth[:2])
    )
    scorer = ImageScorer(view.obs, gear_model(gear), truth[:2], 0.003)
    assert scorer.fit_light(truth, scorer.stride_for(600) if gear == "small" else 1)
    assert np.degrees(np.arccos(np.clip(scorer.light @ OBLIQUE, -1, 1))) < 3.0
    # the gain read off the table under the fitted light is the lamp's intensity (1): white light
    np.testing.assert_allclose(scorer.conditions.gain, 1.0, atol=0.05)


@pytest.mark.parametrize("gear", ["medium", "large"])
def test_oblique_light_is_recovered_from_the_scene_view(scene, renderer, gear):
    """The scene camera sees only the walls facing it, about half of them in their own shade: the
    fit keeps those dark walls (they say which side the lamp is on) and starts from lights all
    round. Fitted on the lit walls alone from the headlight, the lamp came out 24-39 deg off at
    the true pose (seed 100, scenes 0-3), often on the wrong side of the camera, and
    their far MAPs were biased; now 5-10 deg on every pixel."""
    truth = np.array(scene.poses[gear])
    view = renderer.render_view(scene, "scene", None, "oblique", scene.rng("scene", "oblique"))
    scorer = ImageScorer(view.obs, gear_model(gear), truth[:2], 0.003)
    assert scorer.fit_light(truth, 1)
    assert np.degrees(np.arccos(np.clip(scorer.light @ OBLIQUE, -1, 1))) < 12.0


@pytest.mark.parametrize("view_name", ["scene", "inspect"])
def test_headlight_is_kept(scene, renderer, view_name):
    truth = np.array(scene.poses["medium"])
    view = renderer.render_view(
        scene, view_name, "medium", "clean", scene.rng("h", view_name), believed_xy=tuple(truth[:2])
    )
    scorer = ImageScorer(view.obs, gear_model("medium"), truth[:2], 0.003)
    headlight = scorer.light.copy()
    assert not scorer.fit_light(truth, scorer.stride_for(600))
    np.testing.assert_array_equal(scorer.light, headlight)


def test_far_view_under_an_oblique_lamp_is_closer_to_the_truth(scene, renderer):
    """Scene 0 of seed 100 under the oblique lamp: with the headlight assumed the large and the
    small gear came out confidently wrong (MAP 0.57 and 0.75 mm off at ~0.1-0.3 mm std); with
    the fitted light the medium and large gears hold the truth (0.03 and 0.07 mm off) and the
    small gear is 0.14 mm off inside its 99 % region (fitted on the lit walls alone, the light
    left it in a wrong tooth basin, 0.58 mm off; docs/perception.md)."""
    view = renderer.render_view(scene, "scene", None, "oblique", scene.rng("scene", "oblique"))
    found = detect_gears(view.obs)
    fitted_err, headlight_err, levels = [], [], {}
    for gear in ("small", "medium", "large"):
        truth = np.array(scene.poses[gear])
        fitted = estimate_pose(view.obs, gear_model(gear), found[gear].prior)
        headlight = estimate_pose(view.obs, gear_model(gear), found[gear].prior, SearchConfig(fit_light=False))
        assert fitted.informative and "light" in fitted.info and "light" not in headlight.info
        levels[gear] = fitted.credible_level(truth)
        fitted_err.append(np.hypot(*(fitted.map_pose - truth)[:2]))
        headlight_err.append(np.hypot(*(headlight.map_pose - truth)[:2]))
    assert levels["medium"] < 0.9 and levels["large"] < 0.9 and levels["small"] < 0.99, levels
    assert fitted_err[0] < 3e-4 and fitted_err[1] < 1e-4 and fitted_err[2] < 2e-4, fitted_err
    assert sum(fitted_err) < sum(headlight_err), (fitted_err, headlight_err)


def test_light_fit_needs_walls(scene, renderer):
    """Too few wall pixels (a tiny prior region and a huge minimum): the light is kept."""
    truth = np.array(scene.poses["small"])
    view = renderer.render_view(scene, "scene", None, "oblique", scene.rng("scene", "oblique"))
    scorer = ImageScorer(view.obs, gear_model("small"), truth[:2], 0.003)
    assert not scorer.fit_light(truth, 1, min_walls=10**6)
