"""The far view's reshaping fit (benchmarks/perception_far_view.py) on rows whose miscalibration
against the sampled pixel count is known."""

import json

import numpy as np
from scipy.stats import chi2


def _rows(mod, gear: str, a: float, b: float, n: int, rng: np.random.Generator) -> list[dict]:
    """Scene rows whose posteriors are too wide by the inverse of the far factor (a, b): the truth's
    squared Mahalanobis distance is chi2_3 / factor, so the fit's factor makes them uniform."""
    gsd = rng.uniform(0.85e-3, 1.5e-3, n)
    pixels = rng.integers(300, 900, n)
    factor = mod.far_factors(gsd, pixels, a, b)
    d2 = rng.chisquare(3, n) / factor
    return [
        {
            "view": "scene",
            "informative": True,
            "gear": gear,
            "group": ("clean", "dim")[i % 2],
            "gsd": float(g),
            "pixels": int(p),
            "shape": 1.0,
            "level": float(chi2.cdf(d, 3)),
        }
        for i, (g, p, d) in enumerate(zip(gsd, pixels, d2))
    ]


def test_the_fit_finds_each_gears_slope_and_amplitude(tmp_path, benchmark_script):
    mod = benchmark_script("perception_far_view")
    rng = np.random.default_rng(3)
    rows = _rows(mod, "small", 0.9, 1.0, 4000, rng) + _rows(mod, "large", 1.0, 0.0, 4000, rng)
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"config": {}, "rows": rows}))
    loaded = mod.scene_rows([path])
    small = mod.fit_gear([r for r in loaded if r["gear"] == "small"])
    large = mod.fit_gear([r for r in loaded if r["gear"] == "large"])
    assert abs(small[0] - 0.9) < 0.06 and abs(small[1] - 1.0) < 0.3, small
    assert abs(large[0] - 1.0) < 0.06 and abs(large[1]) < 0.3, large
    # the moved levels of the fitted factor are uniform again in the fifths of fewest and most pixels
    gsd = np.array([r["gsd"] for r in rows[:4000]])
    pixels = np.array([r["pixels"] for r in rows[:4000]])
    levels = np.array([r["level"] for r in rows[:4000]])
    moved = mod.moved_levels(levels, np.ones(4000), mod.far_factors(gsd, pixels, *small))
    for m in (pixels < np.quantile(pixels, 0.2), pixels > np.quantile(pixels, 0.8)):
        assert abs(np.mean(levels[m] < 0.5) - 0.5) > 0.07  # miscalibrated before
        assert abs(np.mean(moved[m] < 0.5) - 0.5) < 0.06


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, benchmark_script):
    mod = benchmark_script("perception_far_view")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"rows": [{"view": "inspect", "informative": True}]}))
    assert mod.main(["--results", str(bad)]) == 2
    assert "no informative scene-view rows" in capsys.readouterr().err
    assert mod.main(["--results", str(tmp_path / "missing.json")]) == 2
    assert "no calibration result at" in capsys.readouterr().err
    (tmp_path / "folder.json").mkdir()
    assert mod.main(["--results", str(bad), "--json", str(tmp_path / "folder.json")]) == 2
    assert "is a folder" in capsys.readouterr().err
