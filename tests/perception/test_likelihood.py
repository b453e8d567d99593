"""The per-pixel likelihood: Laplace inliers mixed with a uniform outlier floor."""

import numpy as np
import pytest

from perception.likelihood import LikelihoodConfig, table_albedo


def test_laplace_near_and_outlier_floor_far():
    cfg = LikelihoodConfig(p_out=0.1, b_rgb=0.1, b_d=0.005)
    rgb, d = np.array([[0.5, 0.4, 0.3]]), np.array([0.3])
    exact = cfg.pixel_loglik(rgb, d, rgb, d)[0]
    off = cfg.pixel_loglik(rgb, d, rgb, d + 0.005)[0]
    assert exact - off == pytest.approx(1.0, abs=1e-3)  # one b_d away: exp(-1)
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


def test_gear_tempering_is_a_factor_on_the_shared_law():
    base = LikelihoodConfig(gear_tempering={})
    cfg = LikelihoodConfig(gear_tempering={"medium": (0.5, 1.0)})
    g0 = cfg.reference_gsd
    assert cfg.tempering_for("medium", g0) == pytest.approx(0.5 * base.tempering_for("medium", g0))
    assert cfg.tempering_for("medium", 3 * g0) == pytest.approx(1.5 * base.tempering_for("medium", 3 * g0))
    assert cfg.tempering_for("large", 3 * g0) == pytest.approx(base.tempering_for("large", 3 * g0))
    assert (
        LikelihoodConfig(tempering=0.01, gear_tempering={"large": (2.0, 0.0)}).tempering_for("large", g0) == 0.01
    )  # a fixed exponent overrides the law
    with pytest.raises(ValueError, match="unknown gear 'huge'"):
        LikelihoodConfig(gear_tempering={"huge": (1.0, 0.0)})
    with pytest.raises(ValueError, match=r"gear_tempering\['small'\]"):
        LikelihoodConfig(gear_tempering={"small": (0.0, 0.0)})
    with pytest.raises(ValueError, match=r"gear_tempering\['small'\]"):
        LikelihoodConfig(gear_tempering={"small": (1.0, float("inf"))})


def test_evidence_factor_follows_occlusion_where_teeth_are_resolved_and_depth_noise():
    cfg = LikelihoodConfig(occlusion_exponent=0.5, noise_exponent=1.0)
    close, coarse = np.pi * 1e-3 / 8, np.pi * 1e-3 / 2  # 8 and 2 pixels a tooth
    assert cfg.evidence_factor(close, 1.0, 0.0) == pytest.approx(1.0)
    # half the gear hidden: sqrt(2) times the weight a pixel where teeth are resolved ...
    assert cfg.evidence_factor(close, 0.5, 0.0) == pytest.approx(np.sqrt(2))
    # ... none where they are not (the error there shrinks with the pixels seen)
    assert cfg.evidence_factor(coarse, 0.5, 0.0) == pytest.approx(1.0)
    noisy = cfg.evidence_factor(close, 1.0, cfg.b_d)
    assert noisy == pytest.approx(1 / np.sqrt(2))
    assert LikelihoodConfig(occlusion_exponent=0.0, noise_exponent=0.0).evidence_factor(
        close, 0.3, 0.01
    ) == pytest.approx(1.0)
    for kwargs, name in (
        ({"gsd": 0.0}, "gsd"),
        ({"visible": 0.0}, "visible"),
        ({"visible": 1.5}, "visible"),
        ({"depth_noise": float("nan")}, "depth_noise"),
    ):
        args = {"gsd": close, "visible": 1.0, "depth_noise": 0.0, **kwargs}
        with pytest.raises(ValueError, match=name):
            cfg.evidence_factor(**args)
    with pytest.raises(ValueError, match="occlusion_exponent"):
        LikelihoodConfig(occlusion_exponent=-1.0)


def test_a_fitted_lamp_discounts_the_evidence_where_the_teeth_are_not_resolved():
    cfg = LikelihoodConfig(occlusion_exponent=0.0, noise_exponent=0.0, lamp_discount=0.64)
    close, coarse = np.pi * 1e-3 / 8, np.pi * 1e-3 / 2  # 8 and 2 pixels a tooth
    assert cfg.evidence_factor(coarse, 1.0, 0.0, fitted_light=True) == pytest.approx(0.64)
    assert cfg.evidence_factor(np.pi * 1e-3 / 4, 1.0, 0.0, fitted_light=True) == pytest.approx(0.8)
    assert cfg.evidence_factor(close, 1.0, 0.0, fitted_light=True) == pytest.approx(1.0)
    assert cfg.evidence_factor(coarse, 1.0, 0.0) == pytest.approx(1.0)  # the light assumed
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="lamp_discount"):
            LikelihoodConfig(lamp_discount=bad)


def test_the_colour_scale_follows_the_light_by_view():
    """A dimmer light narrows b_rgb by brightness^brightness_exponent in every view; a brighter one
    widens it by brightness^e, e blended from (unresolved, resolved teeth) by the view."""
    cfg = LikelihoodConfig(
        b_rgb=0.1, brightness_exponent=0.5, bright_exponent=(1.0, 0.5), colour_scale_factor=(1.0, 1.0)
    )
    close, coarse, half = np.pi * 1e-3 / 8, np.pi * 1e-3 / 2, np.pi * 1e-3 / 4  # 8, 2, 4 pixels a tooth
    assert cfg.colour_scale_for(1.0, coarse) == pytest.approx(0.1)
    assert cfg.colour_scale_for(0.25, coarse) == pytest.approx(0.05)
    assert cfg.colour_scale_for(0.25, close) == pytest.approx(0.05)
    assert cfg.colour_scale_for(4.0, coarse) == pytest.approx(0.4)
    assert cfg.colour_scale_for(4.0, close) == pytest.approx(0.2)
    assert cfg.colour_scale_for(4.0, half) == pytest.approx(0.1 * 4.0**0.75)
    assert cfg.colour_scale_for(9.0, coarse) == pytest.approx(0.4)  # the gain is clipped to [0.25, 4]
    with pytest.raises(ValueError, match="brightness"):
        cfg.colour_scale_for(float("nan"), close)
    for bad in ((1.0,), (-0.1, 0.75), (float("inf"), 0.75)):
        with pytest.raises(ValueError, match="bright_exponent"):
            LikelihoodConfig(bright_exponent=bad)
    # the factor by view: its resolved value where the teeth are resolved, geometric in between
    wide = LikelihoodConfig(b_rgb=0.1, brightness_exponent=0.5, colour_scale_factor=(1.0, 4.0))
    assert wide.colour_scale_for(1.0, coarse) == pytest.approx(0.1)
    assert wide.colour_scale_for(1.0, close) == pytest.approx(0.4)
    assert wide.colour_scale_for(1.0, half) == pytest.approx(0.2)
    assert wide.colour_scale_for(0.25, close) == pytest.approx(0.2)
    for bad in ((1.0,), (0.0, 1.0), (1.0, float("nan"))):
        with pytest.raises(ValueError, match="colour_scale_factor"):
            LikelihoodConfig(colour_scale_factor=bad)


def test_the_far_reshaping_follows_the_sampled_pixels_of_the_gears_it_names_where_teeth_are_not_resolved():
    """reshaping_for(gsd, gear, pixels) multiplies the view's factor by (a (pixels / n_far)^b)^(1 - w)
    for a gear in far_reshaping; the close view (teeth resolved), other gears and gear None keep it."""
    cfg = LikelihoodConfig(
        posterior_factor=(0.8, 1.0),
        shape_exponent=(1.1, 1.4),
        far_reshaping={"small": (0.9, 1.0)},
        far_reference_pixels=600.0,
        close_reshaping={},
    )
    close, coarse, half = np.pi * 1e-3 / 8, np.pi * 1e-3 / 2, np.pi * 1e-3 / 4  # 8, 2, 4 pixels a tooth
    assert cfg.reshaping_for(close, "small", 300) == pytest.approx((1.0, 1.4))
    assert cfg.reshaping_for(close) == pytest.approx((1.0, 1.4))
    assert cfg.reshaping_for(coarse, "medium") == pytest.approx((0.8, 1.1))
    assert cfg.reshaping_for(coarse) == pytest.approx((0.8, 1.1))
    far = 0.9 * (300 / 600) ** 1.0
    assert cfg.reshaping_for(coarse, "small", 300) == pytest.approx((0.8 * far, 1.1))
    assert cfg.reshaping_for(half, "small", 300)[0] == pytest.approx(np.sqrt(0.8) * np.sqrt(far))  # w = 0.5
    # fewer sampled pixels of the same gear at the same gsd: a smaller factor, a wider posterior
    assert cfg.reshaping_for(coarse, "small", 450)[0] < cfg.reshaping_for(coarse, "small", 700)[0]
    for bad in (None, 0, float("nan")):
        with pytest.raises(ValueError, match="sampled pixel count"):
            cfg.reshaping_for(coarse, "small", bad)
    with pytest.raises(ValueError, match="unknown gear 'huge'"):
        LikelihoodConfig(far_reshaping={"huge": (1.0, 0.0)})
    for bad in ((0.0, 1.0), (1.0, float("nan")), (1.0,), (5.0, 0.0)):
        with pytest.raises(ValueError, match=r"far_reshaping\['small'\]"):
            LikelihoodConfig(far_reshaping={"small": bad})
    with pytest.raises(ValueError, match="far_reference_pixels"):
        LikelihoodConfig(far_reference_pixels=0.0)


def test_table_colour_comes_from_its_model():
    np.testing.assert_allclose(table_albedo(), [0.62, 0.45, 0.28], atol=1e-6)


def test_pixel_loglik_is_the_mixture_density_in_float32():
    """The compiled per-pixel terms against the module docstring's density written out in float64:
    with and without depth, near and far from the rendering, broadcast over leading axes."""
    cfg = LikelihoodConfig(p_out=0.1, b_rgb=0.15, b_d=0.004)
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (4, 50, 3))
    rgb_hat = np.clip(rgb + rng.normal(0, 0.3, rgb.shape), 0, 1)
    depth = rng.uniform(0.2, 1.0, (4, 50))
    depth_hat = depth + rng.normal(0, 0.01, depth.shape)
    depth[0, :10] = np.nan  # no depth: scored on colour alone
    inlier = (1 - cfg.p_out) * np.exp(-np.abs(rgb - rgb_hat).sum(-1) / cfg.b_rgb) / (2 * cfg.b_rgb) ** 3
    has = np.isfinite(depth)
    inlier = np.where(has, inlier * np.exp(-np.abs(depth - depth_hat) / cfg.b_d) / (2 * cfg.b_d), inlier)
    outlier = np.where(has, cfg.p_out / cfg.depth_range, cfg.p_out)
    got = cfg.pixel_loglik(rgb, depth, rgb_hat, depth_hat)
    assert got.shape == (4, 50) and got.dtype == np.float64
    np.testing.assert_allclose(got, np.log(inlier + outlier), rtol=1e-5, atol=1e-5)
    # One rendering against many observed pixels (broadcast), and the inlier test's scales.
    one = cfg.pixel_loglik(rgb[0], depth[0], rgb_hat[0, 0], depth_hat[0, 0])
    assert one.shape == (50,)
    close = np.abs(rgb - rgb_hat).sum(-1) < 3 * cfg.b_rgb
    depth_ok = ~has | (np.abs(depth - depth_hat) < 3 * cfg.b_d)
    np.testing.assert_array_equal(cfg.is_inlier(rgb, depth, rgb_hat, depth_hat), close & depth_ok)


def test_a_hypothesis_scores_its_pixels_against_the_bare_table(plain_scene, close_view, poses):
    """ImageScorer.score (one compiled loop over the hits) is, per hypothesis, the tempered sum
    over the pixels its gear covers of pixel_loglik minus the pixel's bare-table term."""
    from perception.gear_model import gear_model
    from perception.scoring import ImageScorer

    obs = close_view(plain_scene, "medium")
    truth = np.array(poses["medium"])
    scorer = ImageScorer(obs, gear_model("medium"), truth[:2], 0.005)
    stride = scorer.stride_for(600)
    hyps = truth + np.array([[0, 0, 0], [4e-4, -3e-4, 0.01], [2e-3, 1e-3, 0.05]])
    scores = scorer.score(hyps, stride)
    ps = scorer.pixels(stride)
    hits = scorer.caster.render(ps.origin, ps.dirs, scorer.light, hyps)
    rgb_hat = np.minimum(hits.rgb * scorer.conditions.gain, 1.0)
    terms = (
        scorer.pixels_model.pixel_loglik(ps.rgb[hits.pix], ps.depth[hits.pix], rgb_hat, hits.depth)
        - ps.delta_bg[hits.pix]
    )
    expected = ps.weight * np.bincount(hits.hyp, weights=terms, minlength=3)
    np.testing.assert_allclose(scores.loglik, expected, rtol=1e-9)
    np.testing.assert_array_equal(scores.pixels, np.bincount(hits.hyp, minlength=3))
    assert scores.loglik[0] > scores.loglik[2]  # the truth explains its pixels better than 2 mm off


def test_the_close_reshaping_follows_the_light_for_the_gears_it_names_where_teeth_are_resolved():
    """reshaping_for(gsd, gear, pixels, brightness) multiplies the view's factor by (a g^c)^w for a
    gear in close_reshaping, c = c_dim below g = 1 and c_bright above; the far view (teeth not
    resolved), other gears and gear None keep it."""
    cfg = LikelihoodConfig(
        posterior_factor=(0.8, 1.0),
        shape_exponent=(1.1, 1.4),
        far_reshaping={},
        close_reshaping={"large": (1.1, 0.5, -1.0)},
    )
    close, coarse, half = np.pi * 1e-3 / 8, np.pi * 1e-3 / 2, np.pi * 1e-3 / 4  # 8, 2, 4 pixels a tooth
    assert cfg.reshaping_for(close, "large") == pytest.approx((1.1, 1.4))
    assert cfg.reshaping_for(close, "large", brightness=0.5) == pytest.approx((1.1 * 0.5**0.5, 1.4))
    assert cfg.reshaping_for(close, "large", brightness=1.6) == pytest.approx((1.1 / 1.6, 1.4))
    assert cfg.reshaping_for(close, "large", brightness=100.0)[0] == pytest.approx(
        1.1 / 4.0
    )  # clipped like the colour scale
    assert cfg.reshaping_for(half, "large", brightness=1.6)[0] == pytest.approx(np.sqrt(0.8) * np.sqrt(1.1 / 1.6))
    assert cfg.reshaping_for(coarse, "large", brightness=1.6) == pytest.approx((0.8, 1.1))
    assert cfg.reshaping_for(close, "medium", brightness=1.6) == pytest.approx((1.0, 1.4))
    assert cfg.reshaping_for(close, None, brightness=1.6) == pytest.approx((1.0, 1.4))
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="colour gain"):
            cfg.reshaping_for(close, "large", brightness=bad)
    with pytest.raises(ValueError, match="unknown gear 'huge'"):
        LikelihoodConfig(close_reshaping={"huge": (1.0, 0.0, 0.0)})
    for bad in ((0.0, 0.0, 0.0), (1.0, float("nan"), 0.0), (1.0, 0.0), (1.0, 0.0, 9.0)):
        with pytest.raises(ValueError, match=r"close_reshaping\['large'\]"):
            LikelihoodConfig(close_reshaping={"large": bad})
