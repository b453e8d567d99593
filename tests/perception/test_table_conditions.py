"""What the bare table says about an image: the per-pixel depth noise is read to within a tenth of
the rendered noise at both views, and a depth bias (a sensor error) or a camera off its pose does
not count as noise (the evidence factor would otherwise widen a posterior that is wrong, and hide
the gap from the sim2real diagnosis)."""

import numpy as np
import pytest

from perception.gear_model import gear_model
from perception.observation import Observation
from perception.scenes import DEPTH_NOISE_REFERENCE, SceneRenderer, apply_depth_noise, random_scenes
from perception.scoring import ImageScorer


@pytest.fixture(scope="module")
def views():
    renderer = SceneRenderer()
    scene = next(iter(random_scenes(101, 1)))  # a tuning seed (the benchmark's start at 7000)
    truth = np.array(scene.poses["large"])
    return truth, {
        v: renderer.render_view(scene, v, "large", "clean", scene.rng("t", v), believed_xy=tuple(truth[:2]))
        for v in ("scene", "inspect")
    }


def _scorer(obs: Observation, truth: np.ndarray, depth: np.ndarray | None = None, X_WC=None) -> ImageScorer:
    obs = Observation(
        obs.rgb, obs.depth if depth is None else depth, obs.intrinsics, obs.X_WC if X_WC is None else X_WC
    )
    return ImageScorer(obs, gear_model("large"), truth[:2], 0.02)


@pytest.mark.parametrize("view", ["scene", "inspect"])
def test_pixel_noise_is_read_and_a_bias_is_not_noise(views, view):
    truth, rendered = views
    obs = rendered[view].obs
    assert _scorer(obs, truth).conditions.pixel_noise == pytest.approx(0.0, abs=2e-5)
    noisy = apply_depth_noise(obs.depth, 0.001, np.random.default_rng(0))
    scorer = _scorer(obs, truth, noisy)
    u, v = scorer._u[scorer.roi], scorer._v[scorer.roi]  # the region's pixels (all have depth)
    sigma = 0.001 * np.median((obs.depth[v, u] / DEPTH_NOISE_REFERENCE) ** 2)
    assert scorer.conditions.pixel_noise == pytest.approx(sigma, rel=0.15)
    for bias in (-0.02, 0.01, 0.03):
        biased = _scorer(obs, truth, obs.depth + np.float32(bias))
        assert biased.conditions.pixel_noise == pytest.approx(0.0, abs=2e-5), bias
        both = _scorer(obs, truth, noisy + np.float32(bias))
        assert both.conditions.pixel_noise == pytest.approx(sigma, rel=0.15), bias


def test_a_camera_off_its_pose_is_not_noise(views):
    from pydrake.math import RigidTransform

    truth, rendered = views
    obs = rendered["scene"].obs
    moved = obs.X_WC @ RigidTransform([0.015, 0.0, -0.01])  # the pipeline believes the wrong pose
    scorer = _scorer(obs, truth, X_WC=moved)
    assert scorer.conditions.pixel_noise == pytest.approx(0.0, abs=2e-5)
