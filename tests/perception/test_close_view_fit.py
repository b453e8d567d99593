"""The close view's reshaping fit (benchmarks/perception_close_view.py) on rows whose
miscalibration against the light's brightness is known."""

import json

import numpy as np
from scipy.stats import chi2

from perception.likelihood import close_factor

CLOSE_GSD = 4e-4  # the inspect camera's: teeth resolved (w = 1)


def _rows(
    gear: str, fit: tuple[float, float, float], n: int, rng: np.random.Generator, recorded: bool = True
) -> list[dict]:
    """Close rows, a third under each light, whose posteriors are too wide by the inverse of the
    close factor `fit`: the truth's squared Mahalanobis distance is chi2_3 / factor."""
    lights = (("clean", 1.0), ("dim", 0.5), ("bright", 1.6))
    rows = []
    for i in range(n):
        group, g = lights[i % 3]
        d2 = rng.chisquare(3) / close_factor(CLOSE_GSD, g, *fit)
        rows.append(
            {
                "view": "inspect",
                "informative": True,
                "gear": gear,
                "group": group,
                "gsd": CLOSE_GSD,
                "shape": 1.0,
                "level": float(chi2.cdf(d2, 3)),
                **({"brightness": g} if recorded else {}),
            }
        )
    return rows


def test_the_fit_finds_each_gears_amplitude_and_light_exponents(tmp_path, benchmark_script):
    mod = benchmark_script("perception_close_view")
    rng = np.random.default_rng(5)
    # the medium gear's rows were made before the brightness was recorded: their groups give it
    rows = _rows("large", (1.1, 0.0, 0.5), 6000, rng) + _rows("medium", (1.0, 0.4, 0.0), 6000, rng, recorded=False)
    rows.append(
        {
            "view": "inspect",
            "informative": True,
            "gear": "large",
            "group": "oblique",
            "gsd": CLOSE_GSD,
            "shape": 1.0,
            "level": 0.999,
        }
    )  # no brightness: left out
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"config": {}, "rows": rows}))
    loaded = mod.close_rows([path])
    assert len(loaded) == 12000 and all(r["group"] != "oblique" for r in loaded)
    large = mod.fit_gear([r for r in loaded if r["gear"] == "large"])
    medium = mod.fit_gear([r for r in loaded if r["gear"] == "medium"])
    assert abs(large[0] - 1.1) < 0.06 and abs(large[1]) < 0.2 and abs(large[2] - 0.5) < 0.2, large
    assert abs(medium[0] - 1.0) < 0.06 and abs(medium[1] - 0.4) < 0.2 and abs(medium[2]) < 0.2, medium
    # the table: the bright large close view was over-wide, the fit's moved levels are not
    line = next(x for x in mod.report([r for r in loaded if r["gear"] == "large"], large) if "| bright |" in x)
    before, after = (int(part.split("/")[0]) for part in line.strip("| ").split(" | ")[3:5])
    assert before >= 56 and abs(after - 50) <= 3, line


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, benchmark_script):
    mod = benchmark_script("perception_close_view")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"rows": [{"view": "scene", "informative": True}]}))
    assert mod.main(["--results", str(bad)]) == 2
    assert "no informative close-view rows" in capsys.readouterr().err
    assert mod.main(["--results", str(tmp_path / "missing.json")]) == 2
    assert "no calibration result at" in capsys.readouterr().err
    dim_only = tmp_path / "dim.json"
    dim_only.write_text(json.dumps({"rows": _rows("small", (1.0, 0.0, 0.0), 3, np.random.default_rng(0))[1:2]}))
    assert mod.main(["--results", str(dim_only)]) == 2
    assert "no close views under the nominal light" in capsys.readouterr().err
