"""The tempering fit (benchmarks/perception_tempering.py) on rows whose miscalibration is known."""

from dataclasses import replace

import numpy as np
from scipy.stats import chi2

from perception.likelihood import LikelihoodConfig


def test_fit_recovers_each_gears_factor(benchmark_script):
    """Each gear's posteriors too sharp or too wide by a known factor on its tempering: the truths'
    squared Mahalanobis distances are chi2_3 times it, so multiplying the tempering by its inverse
    makes the levels uniform; the fit must find that factor per gear and leave the exponents."""
    mod = benchmark_script("perception_tempering")
    rng = np.random.default_rng(0)
    bare = LikelihoodConfig(gear_tempering={})
    truth = {"small": 1.0, "medium": 1.5, "large": 0.7}  # > 1: over-confident
    factors = np.asarray(mod.FACTORS)
    rows = []
    for gear, k in truth.items():
        for view, gsd in (("scene", 1.2e-3), ("inspect", 4.1e-4)):
            m2 = k * rng.chisquare(3, 1000)
            for i, d2 in enumerate(m2):
                rows.append(
                    {
                        "gear": gear,
                        "view": view,
                        "group": "clean",
                        "gsd": gsd,
                        "pixels": 600,
                        "tempering": bare.tempering_for(gear, gsd),
                        "inlier_fraction": 1.0,
                        "depth_noise": 0.0,
                        "level": float(chi2.cdf(d2, 3)),
                        "scaled_levels": chi2.cdf(d2 * factors, 3).tolist(),
                    }
                )
    data = mod.Rows(rows, factors)
    fitted = mod.fit(data, LikelihoodConfig(), occlusion=np.array([0.5]), noise=np.array([0.5]), lamp=np.array([1.0]))
    for gear, k in truth.items():
        a, b = fitted.gear_tempering[gear]
        assert abs(np.log(a * k)) < 0.12, (gear, a, 1 / k)  # A ~ 1 / k, within 12 %
        assert abs(b) <= 0.15, (gear, b)  # the same at both pixel sizes
    levels = data.levels(data.scale(fitted))
    cover = mod.coverage(levels, np.array([0.5, 0.9]))
    np.testing.assert_allclose(cover, [0.5, 0.9], atol=0.04)
    assert (fitted.occlusion_exponent, fitted.noise_exponent) == (0.5, 0.5)


def _radial_levels(r_truth: np.ndarray, deficit, factors, shapes) -> np.ndarray:
    """Truth levels (rows, shapes, factors) of an isotropic 3-D posterior whose log-evidence
    deficit at Mahalanobis radius r is deficit(r), tempered by f and then shaped by g: the mass
    within the truth's radius, 4 pi r^2 dr, by quadrature."""
    r = np.linspace(1e-4, 12.0, 6000)
    out = np.empty((len(r_truth), len(shapes), len(factors)))
    for i, g in enumerate(shapes):
        for j, f in enumerate(factors):
            dens = np.exp(-((f * deficit(r)) ** g)) * r**2
            cdf = np.cumsum(dens) / dens.sum()
            out[:, i, j] = np.interp(r_truth, r, cdf)
    return out


def test_fit_recovers_the_reshaping(benchmark_script):
    """Close views whose posterior deficit is (r^2 / 2)^(1 / 1.25) / 0.84 (heavier tails and a
    sharper core than the Gaussian truths'), far views Gaussian: the reshaping (factor D)^exponent
    that makes them Gaussian is (0.84, 1.25) close and (1, 1) far; the fit must pick both from
    the grids and make both views' levels uniform."""
    mod = benchmark_script("perception_tempering")
    rng = np.random.default_rng(1)
    bare = LikelihoodConfig(gear_tempering={})
    factors = np.asarray(mod.FACTORS)
    shapes = np.asarray(mod.SHAPES)
    f_true = float(factors[14])  # 2^-0.25, one of the recorded factors
    rows = []
    for view, gsd, f, g in (("scene", 2e-3, 1.0, 1.0), ("inspect", 4.1e-4, f_true, 1.25)):
        r_truth = np.sqrt(rng.chisquare(3, 2000))
        table = _radial_levels(r_truth, lambda r, f=f, g=g: (r**2 / 2) ** (1 / g) / f, factors, shapes)
        for i in range(len(r_truth)):
            rows.append(
                {
                    "gear": "medium",
                    "view": view,
                    "group": "clean",
                    "gsd": gsd,
                    "pixels": 600,
                    "tempering": bare.tempering_for("medium", gsd),
                    "inlier_fraction": 1.0,
                    "depth_noise": 0.0,
                    "level": float(table[i, 1, 16]),
                    "scaled_levels": table[i, 1].tolist(),
                    "shaped_levels": table[i].tolist(),
                }
            )
    data = mod.Rows(rows, factors, shapes)
    base = LikelihoodConfig(
        gear_tempering={}, posterior_factor=(1.0, 1.0), shape_exponent=(1.0, 1.0), far_reshaping={}, close_reshaping={}
    )
    fitted = mod.fit_reshaping(data, base, factors=factors[[12, 14, 16]], shapes=np.array([1.0, 1.25]))
    assert fitted.shape_exponent == (1.0, 1.25)
    np.testing.assert_allclose(fitted.posterior_factor, (1.0, f_true), atol=1e-4)
    levels = data.at(fitted)
    for view in ("scene", "inspect"):
        m = np.array([r["view"] == view for r in rows])
        np.testing.assert_allclose(mod.coverage(levels[m], np.array([0.5, 0.8, 0.95])), [0.5, 0.8, 0.95], atol=0.05)
    held = mod.fit_reshaping(
        data,
        replace(base, posterior_factor=(0.9, 1.0), shape_exponent=(1.1, 1.0)),
        factors=factors[[12, 14, 16]],
        shapes=np.array([1.0, 1.25]),
        sides=(1,),
    )
    assert (held.posterior_factor[0], held.shape_exponent[0]) == (0.9, 1.1)  # the far side held
    assert held.shape_exponent[1] == 1.25
    close = np.array([r["view"] == "inspect" for r in rows])
    before = mod.coverage(np.array([r["level"] for r in rows])[close], np.array([0.5, 0.95]))
    assert before[1] - 0.95 > 0.02  # the close view was miscalibrated before the fit


def test_the_likelihood_flag_refuses_an_unknown_field_or_a_bad_value(tmp_path, capsys, benchmark_script):
    """`--likelihood KEY=VALUE` names the bad key or value in one line and exits 2, before any
    scene is rendered."""
    mod = benchmark_script("perception_tempering")
    rows = tmp_path / "rows.json"
    assert mod.main(["--likelihood", "colour_scale=[1,2]", "--rows", str(rows)]) == 2
    assert "colour_scale" in capsys.readouterr().err
    assert mod.main(["--likelihood", "colour_scale_factor=[1,9]", "--rows", str(rows)]) == 2
    assert "colour_scale_factor = [1, 9]" in capsys.readouterr().err
    assert not rows.exists()
