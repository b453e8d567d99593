"""Bad input: a clear error, or a posterior flagged uninformative; never a confident wrong answer."""

import numpy as np
import pytest

from assembly.cameras import CameraConfig, look_at
from perception.observation import Observation
from perception.search import Prior, SearchConfig, estimate_pose


@pytest.fixture(scope="module")
def obs(plain_scene, close_view):
    return close_view(plain_scene, "medium")


def test_wrong_image_shapes_are_named(obs):
    with pytest.raises(ValueError, match=r"rgb image has shape \(480, 320, 3\)"):
        Observation(obs.rgb[:, :320], obs.depth, obs.intrinsics, obs.X_WC)
    with pytest.raises(ValueError, match=r"depth image has shape \(240, 640\)"):
        Observation(obs.rgb, obs.depth[:240], obs.intrinsics, obs.X_WC)
    with pytest.raises(ValueError, match="rgb image has shape"):
        Observation(obs.rgb[:, :, 0], obs.depth, obs.intrinsics, obs.X_WC)
    with pytest.raises(ValueError, match="RigidTransform"):
        Observation(obs.rgb, obs.depth, obs.intrinsics, np.eye(4))
    with pytest.raises(ValueError, match=r"rgb values"):
        Observation(obs.rgb * 300.0, obs.depth, obs.intrinsics, obs.X_WC)


def test_missing_depth_is_an_error(obs):
    with pytest.raises(ValueError, match="no depth image"):
        Observation(obs.rgb, None, obs.intrinsics, obs.X_WC)
    with pytest.raises(ValueError, match="no valid pixel"):
        Observation(obs.rgb, np.full_like(obs.depth, np.nan), obs.intrinsics, obs.X_WC)


def test_camera_that_does_not_see_the_region_is_an_error(plain_scene, poses):
    x, y, _ = poses["medium"]
    # looks down at the table 30 cm beyond the gear, with a narrow field of view
    away = CameraConfig("away", look_at([x + 0.3, y, 0.3], [x + 0.35, y + 0.05, 0.0]), fov_y=0.3)
    seen = plain_scene.render(away, away.X_PC)
    with pytest.raises(ValueError, match="does not see the medium gear's search region"):
        estimate_pose(seen, "medium", Prior(x, y, 0.03))


def test_gear_not_where_the_prior_says_is_uninformative(plain_scene, close_view, poses):
    """The camera sees the prior's region, but the gear is elsewhere (bare table there)."""
    x, y, _ = poses["medium"]
    view = close_view(plain_scene, "medium")
    post = estimate_pose(view, "medium", Prior(x + 0.06, y + 0.0, 0.015))
    assert not post.informative and post.reason
    # the posterior is the prior: no 5 mm box holds much mass
    assert post.probability(x=(x + 0.055, x + 0.065), y=(y - 0.005, y + 0.005)) < 0.2
    assert post.std()[0] > 0.005


def test_depth_holes_do_not_make_a_confident_wrong_answer(obs, poses):
    """Half the depth image missing (e.g. a sensor dropout): either the right answer or a flag."""
    depth = obs.depth.copy()
    depth[:, : depth.shape[1] // 2] = np.nan
    holed = Observation(obs.rgb, depth, obs.intrinsics, obs.X_WC)
    x, y, _ = poses["medium"]
    post = estimate_pose(holed, "medium", Prior(x + 0.005, y, 0.03))
    if post.informative:
        assert np.hypot(*(post.map_pose[:2] - [x, y])) < 0.002
    assert post.contains(np.array(poses["medium"]), 0.9) or not post.informative


def test_wrong_gear_colour_is_not_confident(plain_scene, close_view, poses):
    """Asking for the small gear where the medium one lies: colour and shape disagree."""
    x, y, _ = poses["medium"]
    post = estimate_pose(close_view(plain_scene, "medium"), "small", Prior(x, y, 0.02))
    assert not post.informative


def test_bad_configs_are_named():
    with pytest.raises(ValueError, match="half_width"):
        Prior(0.4, 0.0, 0.0)
    with pytest.raises(ValueError, match="not finite"):
        Prior(float("nan"), 0.0)
    with pytest.raises(ValueError, match="grid"):
        SearchConfig(grid=4)
    with pytest.raises(ValueError, match="upsample"):
        SearchConfig(upsample=0)


def test_nan_intrinsics_and_zero_width_prior_are_named(obs):
    from perception.observation import Intrinsics

    k = obs.intrinsics
    with pytest.raises(ValueError, match="intrinsics fx = nan"):
        Intrinsics(k.width, k.height, float("nan"), k.fy, k.cx, k.cy)
    with pytest.raises(ValueError, match="intrinsics width = 0"):
        Intrinsics(0, k.height, k.fx, k.fy, k.cx, k.cy)
    with pytest.raises(ValueError, match="half_width = 0"):
        Prior(0.4, 0.0, 0.0)
    with pytest.raises(ValueError, match="not finite"):
        Prior(float("nan"), 0.0, 0.01)


def test_prior_box_is_a_hard_support(obs, poses):
    """Told the gear is within +-1 cm of a point 8 mm from it, the posterior keeps all of its mass
    inside that box (it may be uninformative, never outside)."""
    x, y, _ = poses["medium"]
    prior = Prior(x + 0.008, y - 0.004, 0.01)
    post = estimate_pose(obs, "medium", prior)
    x0, x1, y0, y1 = prior.box
    assert post.probability(x=(x0, x1), y=(y0, y1)) == pytest.approx(1.0, abs=1e-9)
    assert np.all(post.std()[:2] <= 2 * prior.half_width / np.sqrt(12) + 1e-9)
