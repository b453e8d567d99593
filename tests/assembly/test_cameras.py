"""Camera extrinsic errors: the draw, the camera as it really is, and how far such an error moves
where a believed camera places a point on the table."""

import numpy as np
import pytest
from pydrake.math import RigidTransform

from assembly.cameras import (
    default_scene_camera,
    extrinsic_error,
    extrinsic_error_on_table,
    look_at,
    with_extrinsic_error,
)


def test_no_error_is_the_identity_and_moves_nothing():
    X = extrinsic_error(0.0, 0.0, np.random.default_rng(0))
    assert np.allclose(X.GetAsMatrix4(), np.eye(4))
    cov = extrinsic_error_on_table(default_scene_camera().X_PC, np.array([0.5, 0.0, 0.02]), 0.0, 0.0)
    assert np.all(cov == 0)


@pytest.mark.parametrize("bad", [(-1e-3, 0.0), (0.0, np.nan), (np.inf, 0.0)])
def test_bad_std_is_named(bad):
    with pytest.raises(ValueError, match="extrinsic error std"):
        extrinsic_error(*bad, np.random.default_rng(0))


def test_the_true_camera_is_the_believed_one_times_the_error():
    config = default_scene_camera()
    X_CE = extrinsic_error(1e-3, 1e-3, np.random.default_rng(1))
    true = with_extrinsic_error(config, X_CE)
    assert np.allclose(true.X_PC.GetAsMatrix4(), (config.X_PC @ X_CE).GetAsMatrix4())
    assert np.allclose(config.X_PC.GetAsMatrix4(), default_scene_camera().X_PC.GetAsMatrix4())  # untouched


def test_shift_on_table_scales_with_the_error_and_the_distance():
    point = np.array([0.5, 0.0, 0.0])
    near, far = look_at([0.5, 0.0, 0.5], point), look_at([0.5, 0.0, 1.0], point)  # straight down
    r = 1e-3
    s_near = np.sqrt(np.diag(extrinsic_error_on_table(near, point, 0.0, r)))
    s_far = np.sqrt(np.diag(extrinsic_error_on_table(far, point, 0.0, r)))
    # Looking straight down, a tilt r moves the point by distance * r (to first order) in x and y.
    assert np.allclose(s_near, 0.5 * r, rtol=0.25) and np.allclose(s_far, 1.0 * r, rtol=0.25)
    doubled = np.sqrt(np.diag(extrinsic_error_on_table(far, point, 0.0, 2 * r)))
    assert np.allclose(doubled, 2 * s_far, rtol=0.05)
    # A sideways translation t moves it by t; one along the optical axis not at all.
    s_t = np.sqrt(np.diag(extrinsic_error_on_table(far, point, 1e-3, 0.0)))
    assert np.allclose(s_t, 1e-3, rtol=0.25)


def test_bad_point_is_named():
    with pytest.raises(ValueError, match="point"):
        extrinsic_error_on_table(RigidTransform(), np.array([0.0, np.nan, 0.0]), 1e-3, 0.0)
