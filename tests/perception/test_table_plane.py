"""A real camera's depth scale is read off the table and divided out; an ideal image is left as it
is; a realsense view is rendered from the true mounting with the calibrated pose kept."""

import numpy as np
import pytest

from perception.observation import Observation
from perception.scenes import SceneRenderer, random_scenes
from perception.table_plane import aligned_to_table, depth_scale


@pytest.fixture(scope="module")
def scene_view():
    renderer = SceneRenderer()
    scene = next(random_scenes(40000, 1))
    return renderer, scene, renderer.render_view(scene, "scene", None, "clean", scene.rng("t"))


@pytest.mark.parametrize("scale", [0.98, 1.005, 1.02])
def test_a_scaled_depth_is_read_and_divided_out(scene_view, scale) -> None:
    _, _, view = scene_view
    obs = Observation(view.obs.rgb, view.obs.depth * np.float32(scale), view.obs.intrinsics, view.obs.X_WC)
    assert depth_scale(obs) == pytest.approx(scale, abs=3e-4)
    aligned = aligned_to_table(obs)
    finite = np.isfinite(view.obs.depth)
    assert np.median(np.abs(aligned.depth[finite] - view.obs.depth[finite])) < 3e-4


def test_an_ideal_image_is_returned_as_it_is(scene_view) -> None:
    _, _, view = scene_view
    assert aligned_to_table(view.obs) is view.obs


def test_a_realsense_view_keeps_the_calibrated_pose_and_states_its_mounting_std(scene_view) -> None:
    renderer, scene, clean = scene_view
    real = renderer.render_view(scene, "scene", None, "realsense", scene.rng("t"))
    assert np.allclose(real.obs.X_WC.GetAsMatrix4(), clean.obs.X_WC.GetAsMatrix4())
    assert real.extrinsic_std == pytest.approx((0.001, np.radians(0.1)))
    assert clean.extrinsic_std == (0.0, 0.0)
    mm = real.obs.depth[np.isfinite(real.obs.depth)] * 1000
    assert np.allclose(mm, np.round(mm), atol=1e-3)  # the D415's depth unit
