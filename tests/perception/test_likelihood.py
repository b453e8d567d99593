"""The per-pixel likelihood: Laplace inliers mixed with a uniform outlier floor."""

import numpy as np
import pytest

from perception.likelihood import LikelihoodConfig, table_albedo


def test_laplace_near_and_outlier_floor_far():
    cfg = LikelihoodConfig(p_out=0.1, b_rgb=0.1, b_d=0.005)
    rgb, d = np.array([[0.5, 0.4, 0.3]]), np.array([0.3])
    exact = cfg.pixel_loglik(rgb, d, rgb, d)[0]
    off = cfg.pixel_loglik(rgb, d, rgb, d + 0.005)[0]
    assert exact - off == pytest.approx(1.0, abs=1e-3)          # one b_d away: exp(-1)
    far = cfg.pixel_loglik(rgb, d, rgb + 0.5, d + 1.0)[0]
    assert far == pytest.approx(np.log(0.1 / cfg.depth_range), abs=1e-6)  # only the outlier term
    assert cfg.is_inlier(rgb, d, rgb, d)[0] and not cfg.is_inlier(rgb, d, rgb + 0.5, d)[0]
    assert not cfg.is_inlier(rgb, d, rgb, d + 0.02)[0]


def test_bad_configs_are_named():
    with pytest.raises(ValueError, match="p_out"):
        LikelihoodConfig(p_out=1.0)
    with pytest.raises(ValueError, match="b_d"):
        LikelihoodConfig(b_d=0.0)
    with pytest.raises(ValueError, match="tempering"):
        LikelihoodConfig(tempering=float("nan"))


def test_table_colour_comes_from_its_model():
    np.testing.assert_allclose(table_albedo(), [0.62, 0.45, 0.28], atol=1e-6)
