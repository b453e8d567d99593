"""PosePosterior on hand-made grids: sampling, region probabilities, marginals, entropies,
credible regions, the plot."""

import numpy as np
import pytest

from perception.posterior import PosePosterior, uniform_posterior, wrap


def _gaussian(sigma=(0.001, 0.002, 0.02), centre=(0.4, -0.1, 3.1), modes=1):
    xs = centre[0] + np.linspace(-0.006, 0.006, 25)
    ys = centre[1] + np.linspace(-0.012, 0.012, 25)
    offs = np.linspace(-0.12, 0.12, 25)
    X, Y, A = np.meshgrid(xs - centre[0], ys - centre[1], offs, indexing="ij")
    ll = -0.5 * ((X / sigma[0]) ** 2 + (Y / sigma[1]) ** 2 + (A / sigma[2]) ** 2)
    mode_yaws = wrap(centre[2] + 2 * np.pi * np.arange(modes) / modes)
    return PosePosterior("medium", xs, ys, mode_yaws, offs, np.repeat(ll[None], modes, axis=0))


def test_normalized_and_map():
    post = _gaussian()
    assert post.mass.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(post.map_pose, [0.4, -0.1, wrap(3.1)], atol=1e-12)


def test_samples_match_moments():
    post = _gaussian()
    s = post.sample(20000, seed=1)
    assert s.shape == (20000, 3)
    np.testing.assert_allclose(s[:, :2].mean(0), [0.4, -0.1], atol=1e-4)
    np.testing.assert_allclose(s[:, :2].std(0), [0.001, 0.002], rtol=0.05)
    # yaw straddles +-pi: samples stay wrapped and cluster around 3.1 rad
    assert np.all((s[:, 2] >= -np.pi) & (s[:, 2] < np.pi))
    assert np.abs(wrap(s[:, 2] - 3.1)).max() < 0.13
    np.testing.assert_allclose(post.std()[:2], [0.001, 0.002], rtol=0.05)


def test_region_probabilities():
    post = _gaussian()
    assert post.probability() == pytest.approx(1.0)
    assert post.probability(x=(0.4, 1.0)) == pytest.approx(0.5, abs=1e-9)
    # one sigma either side in x: 68 %
    assert post.probability(x=(0.399, 0.401)) == pytest.approx(0.683, abs=0.02)  # 0.5 sigma cells
    # a yaw arc across the +-pi seam, counter-clockwise from 3.0 to 3.2 (= 3.2 - 2 pi)
    both = post.probability(yaw=(3.0, 3.2 - 2 * np.pi))
    assert both == pytest.approx(post.probability(yaw=(3.0 - 2 * np.pi, 3.2)), abs=1e-12)
    assert both > 0.99
    assert post.probability(yaw=(3.2 - 2 * np.pi, 3.0)) < 0.01  # the complementary arc


def test_marginals_and_entropies():
    post = _gaussian()
    for dim, sigma in zip(("x", "y", "yaw"), (0.001, 0.002, 0.02)):
        v, p = post.marginal(dim)
        assert p.sum() == pytest.approx(1.0)
        # differential entropy of a Gaussian: 0.5 log(2 pi e sigma^2)
        assert post.marginal_entropy(dim) == pytest.approx(0.5 * np.log(2 * np.pi * np.e * sigma**2), abs=0.02)
    with pytest.raises(ValueError, match="unknown dimension"):
        post.marginal("z")


def test_modes_split_the_yaw_mass():
    post = _gaussian(modes=4)
    v, p = post.marginal("yaw")
    assert len(v) == 4 * 25 and np.all(np.diff(v) >= 0)
    for k in range(4):
        c = wrap(3.1 + k * np.pi / 2)
        assert post.probability(yaw=(c - 0.2, c + 0.2)) == pytest.approx(0.25, abs=1e-6)


def test_credible_region_contains():
    post = _gaussian()
    assert post.contains([0.4, -0.1, 3.1], 0.9)
    assert not post.contains([0.4 + 0.005, -0.1, 3.1], 0.9)  # 5 sigma off in x
    assert not post.contains([0.5, -0.1, 3.1], 0.9)  # off the grid
    assert post.credible_mask(0.9).sum() < post.credible_mask(0.99).sum()
    with pytest.raises(ValueError, match="level"):
        post.credible_mask(1.5)


def test_uniform_posterior_is_flagged_and_flat(tmp_path):
    post = uniform_posterior("small", (0.4, 0.0), 0.03, "not seen")
    assert not post.informative and post.reason == "not seen"
    assert post.probability(x=(0.4, 0.5), y=(0.0, 0.1)) == pytest.approx(0.25, abs=0.03)
    assert post.probability(yaw=(0.0, np.pi / 2)) == pytest.approx(0.25, abs=0.01)
    post.plot(tmp_path / "u.png")
    assert (tmp_path / "u.png").stat().st_size > 1000


def test_plot_writes_png(tmp_path):
    fig = _gaussian(modes=3).plot(tmp_path / "p.png", truth=np.array([0.4, -0.1, 3.1]))
    assert (tmp_path / "p.png").stat().st_size > 1000
    assert len(fig.axes) == 2


def test_support_is_hard_and_std_includes_the_cell_width():
    xs = np.linspace(0.39, 0.41, 5)
    offs = np.linspace(-0.01, 0.01, 5)
    ll = np.zeros((1, 5, 5, 5))
    post = PosePosterior("medium", xs, xs - 0.4, np.zeros(1), offs, ll, support=(0.3925, 0.41, -0.01, 0.01))
    assert post.probability(x=(0.0, 0.3925)) == pytest.approx(0.0, abs=1e-12)
    assert post.sample(2000, seed=0)[:, 0].min() >= 0.3925
    assert post.cell_of([0.39, 0.0, 0.0]) is None and post.credible_level([0.39, 0.0, 0.0]) == 1.0
    # one cell holding all the mass still has the spread of a uniform cell
    one = np.full((1, 5, 5, 5), -np.inf)
    one[0, 2, 2, 2] = 0.0
    post = PosePosterior("medium", xs, xs - 0.4, np.zeros(1), offs, one)
    np.testing.assert_allclose(post.std(), [0.005, 0.005, 0.005] / np.sqrt(12), rtol=1e-6)


def test_symmetry_class_and_credible_levels_of_own_samples_are_uniform():
    pitch = 2 * np.pi / 40
    post = _gaussian(sigma=(0.001, 0.002, 0.01), centre=(0.4, -0.1, 0.0))
    post = PosePosterior(
        "medium", post.xs, post.ys, post.mode_yaws, post.yaw_offsets * 0.5, post.log_mass, period=pitch
    )
    truth = post.sample(1, seed=3)[0]
    assert post.credible_level(truth) == post.credible_level(truth + [0, 0, 7 * pitch])
    assert post.probability(yaw=(truth[2] + 3 * pitch - pitch / 2, truth[2] + 3 * pitch + pitch / 2)) == pytest.approx(
        1.0
    )
    levels = np.array([post.credible_level(p) for p in post.sample(3000, seed=4)])
    for q in (0.5, 0.68, 0.9, 0.95):
        assert np.mean(levels < q) == pytest.approx(q, abs=0.03)
    with pytest.raises(ValueError, match="period"):
        PosePosterior("medium", post.xs, post.ys, post.mode_yaws, post.yaw_offsets, post.log_mass, period=0.3)


def test_tempered_scales_the_evidence_and_keeps_the_support():
    post = _gaussian()
    np.testing.assert_allclose(post.tempered(1.0).log_mass, post.log_mass, atol=1e-12)
    # a Gaussian's log-density times f is a Gaussian with std / sqrt(f) (cells resolve it)
    np.testing.assert_allclose(post.tempered(4.0).std()[:2], post.std()[:2] / 2, rtol=0.05)
    assert np.all(post.tempered(0.5).std() > post.std())
    xs = np.linspace(0.39, 0.41, 5)
    offs = np.linspace(-0.01, 0.01, 5)
    ll = -np.arange(5.0)[None, :, None, None] * np.ones((1, 5, 5, 5))
    cut = PosePosterior("medium", xs, xs - 0.4, np.zeros(1), offs, ll, support=(0.39, 0.41, -0.01, 0.01))
    # the half cells at the support's edges keep half their (rescaled) mass, none lies outside
    hot = cut.tempered(2.0)
    assert hot.sample(2000, seed=0)[:, 0].min() >= 0.39 and hot.support == cut.support
    raw = np.exp(-2.0 * np.arange(5.0)) * [0.5, 1, 1, 1, 0.5]
    np.testing.assert_allclose(hot.marginal("x")[1], raw / raw.sum(), rtol=1e-9)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="factor"):
            post.tempered(bad)


def test_reshaped_keeps_the_cells_and_the_order_and_is_undone_by_its_inverse():
    post = _gaussian()
    assert post.reshaped(1.0, 1.0) is post
    np.testing.assert_allclose(post.reshaped(2.0, 1.0).log_mass, post.tempered(2.0).log_mass, atol=1e-12)
    np.testing.assert_allclose(post.reshaped(1.0, 1.3).log_mass, post.shaped(1.3).log_mass, atol=1e-12)
    f, g = 0.7, 1.4
    out = post.reshaped(f, g)
    np.testing.assert_array_equal(out.map_pose, post.map_pose)
    # the densities' order is kept: the same cells rank the same
    order = np.argsort(-post.log_mass.ravel(), kind="stable")
    assert np.all(np.diff(out.log_mass.ravel()[order]) <= 1e-12)
    np.testing.assert_allclose(out.reshaped(f**-g, 1.0 / g).log_mass, post.log_mass, atol=1e-9)
    # a Gaussian's deficit D = r^2 / 2 made (f D)^g: below 1 the core widens, above 1 the tails fall faster
    assert np.all(post.reshaped(0.5, 1.0).std() > post.std())
    truth = np.array([0.4 + 0.0025, -0.1, 3.1])  # 2.5 sigma out in x
    assert post.reshaped(1.0, 1.5).credible_level(truth) > post.credible_level(truth)
    for bad in ((0.0, 1.0), (1.0, -1.0), (float("nan"), 1.0), (1.0, float("inf"))):
        with pytest.raises(ValueError, match="factor|exponent"):
            post.reshaped(*bad)


def test_upsampled_keeps_the_scored_cells_and_resolves_a_coarse_posterior():
    # a Gaussian scored on cells ~1.3 sigma wide (the close view's grid): too few cells to say
    # where within them the truth lies; the spline between them makes the credible levels of the
    # distribution's own draws uniform again
    sigma = np.array([4e-5, 4e-5, 2e-3])
    step = 1.3 * sigma
    centre = np.array([0.4, -0.1, 0.0])
    axes = [centre[d] + (np.arange(7) - 3) * step[d] for d in range(2)] + [(np.arange(7) - 3) * step[2]]
    X, Y, A = np.meshgrid(axes[0] - 0.4 - 1.7e-5, axes[1] + 0.1, axes[2] + 7e-4, indexing="ij")
    ll = -0.5 * ((X / sigma[0]) ** 2 + (Y / sigma[1]) ** 2 + (A / sigma[2]) ** 2)
    coarse = PosePosterior("medium", axes[0], axes[1], np.zeros(1), axes[2], ll[None], period=np.pi / 10)
    fine = coarse.upsampled(3)
    assert coarse.upsampled(1) is coarse
    assert fine.log_mass.shape == (1, 19, 19, 19)
    np.testing.assert_allclose(
        fine.log_mass[0, ::3, ::3, ::3] - fine.log_mass.max(), coarse.log_mass[0] - coarse.log_mass.max(), atol=1e-9
    )
    rng = np.random.default_rng(0)
    truths = np.array([0.4 + 1.7e-5, -0.1, -7e-4]) + rng.standard_normal((3000, 3)) * sigma
    q = np.array([0.5, 0.68, 0.8, 0.9, 0.95])
    coverage = {
        name: np.mean(np.array([p.credible_level(t) for t in truths])[:, None] < q, axis=0)
        for name, p in (("coarse", coarse), ("fine", fine))
    }
    assert np.abs(coverage["fine"] - q).max() < 0.04, coverage
    assert np.abs(coverage["fine"] - q).max() < np.abs(coverage["coarse"] - q).max(), coverage
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="factor"):
            coarse.upsampled(bad)
