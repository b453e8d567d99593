"""Symmetry: a plain gear looks the same every tooth pitch, so its yaw posterior is over the class
modulo the pitch: every repeat of the truth is the truth, ties cannot be broken arbitrarily, and
a closer look narrows x and y; a marked gear (period 2 pi) has one mode per repeat, and a close
view puts the mass on the one true repeat."""

import numpy as np
import pytest

from assembly.cameras import default_scene_camera
from assembly.gearset import gear_spec
from perception.gear_model import gear_model
from perception.posterior import PosePosterior, wrap
from perception.search import Prior, estimate_pose

GEAR = "medium"


def repeat_masses(post: PosePosterior, truth_yaw: float, teeth: int) -> np.ndarray:
    """Mass within half a tooth pitch of each repeat truth_yaw + k * pitch."""
    pitch = 2 * np.pi / teeth
    return np.array(
        [post.probability(yaw=(truth_yaw + (k - 0.5) * pitch, truth_yaw + (k + 0.5) * pitch)) for k in range(teeth)]
    )


def effective_repeats(m: np.ndarray) -> float:
    """exp(entropy) of the repeat masses: how many repeats effectively share the mass."""
    m = m[m > 0] / m.sum()
    return float(np.exp(-(m * np.log(m)).sum()))


def _posteriors(scene, marked: bool, poses, close_view):
    x, y, yaw = poses[GEAR]
    prior = Prior(x + 0.01, y - 0.008, 0.03)
    model = gear_model(GEAR, marked)
    cam = default_scene_camera()
    far = estimate_pose(scene.render(cam, cam.X_PC), model, prior)
    close = estimate_pose(close_view(scene, GEAR), model, prior)
    return far, close


@pytest.fixture(scope="module")
def plain(plain_scene, poses, close_view):
    return _posteriors(plain_scene, False, poses, close_view)


def test_plain_gear_yaw_is_a_class_modulo_the_tooth_pitch(plain, poses):
    teeth = gear_spec(GEAR).teeth
    pitch = 2 * np.pi / teeth
    x, y, yaw = poses[GEAR]
    for post in plain:
        assert post.period == pytest.approx(pitch) and len(post.mode_yaws) == 1
        # every tooth repeat of the truth is the same pose: same cell, same credible level
        levels = [post.credible_level([x, y, yaw + k * pitch]) for k in range(teeth)]
        assert max(levels) - min(levels) < 1e-12
        assert all(post.contains([x, y, yaw + k * pitch], 0.95) for k in range(teeth))
        # an arc of one pitch around any repeat holds all of the mass
        m = repeat_masses(post, yaw, teeth)
        assert np.allclose(m, 1.0, atol=1e-6)
        assert abs(wrap(post.map_pose[2] - yaw, pitch)) < np.radians(3.0)


def test_closer_look_narrows_xy(plain, poses):
    far, close = plain
    for dim in ("x", "y"):
        assert close.marginal_entropy(dim) < far.marginal_entropy(dim) - 0.2
    assert np.all(close.std()[:2] < far.std()[:2])


def test_marked_gear_close_view_concentrates_on_the_true_repeat(marked_scene, poses, close_view):
    far, close = _posteriors(marked_scene, True, poses, close_view)
    x, y, yaw = poses[GEAR]
    teeth = gear_spec(GEAR).teeth
    m = repeat_masses(close, yaw, teeth)
    assert m[0] > 0.9, m  # repeat 0 is the truth
    assert effective_repeats(m) < 1.5
    assert abs(wrap(close.map_pose[2] - yaw)) < np.radians(3.0)
    # the close view settles which repeat it is: its yaw spread over the turn is far smaller (the
    # far view's core within a repeat is about as sharp, so their entropies are close)
    assert close.std()[2] < 0.25 * far.std()[2]
