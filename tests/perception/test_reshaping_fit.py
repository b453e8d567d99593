"""The reshaping's fit from calibration results (benchmarks/perception_reshaping.py) on rows whose
calibrated reshaping is known."""

import json

import numpy as np
from scipy.special import gammainc

from perception.likelihood import LikelihoodConfig

CLOSE_GSD = 4e-4  # the inspect camera's: teeth resolved (w = 1)


def _rows(factor: float, exponent: float, n: int, rng: np.random.Generator) -> list[dict]:
    """Close rows recorded unreshaped (1, 1) whose truths follow the posterior reshaped with
    (factor, exponent): (factor D)^exponent ~ Gamma(3 / (2 exponent)), D the truth's raw deficit."""
    u = rng.gamma(1.5 / exponent, size=n)
    deficit = u ** (1 / exponent) / factor
    groups = ("clean", "dropout_3", "dim")
    return [
        {
            "view": "inspect",
            "informative": True,
            "seen": True,
            "scene": i // 3,
            "gear": "small",
            "group": groups[i % 3],
            "gsd": CLOSE_GSD,
            "pixels": 3000,
            "posterior_factor": 1.0,
            "shape": 1.0,
            "brightness": 1.0,
            "level": float(gammainc(1.5, d)),
        }
        for i, d in enumerate(deficit)
    ]


def test_the_fit_finds_the_reshaping_that_calibrates_the_rows(tmp_path, benchmark_script):
    mod = benchmark_script("perception_reshaping")
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"rows": _rows(1.1, 1.3, 9000, np.random.default_rng(3))}))
    base = LikelihoodConfig(close_reshaping={}, far_reshaping={})
    data = mod.Reading(mod.shape_rows([path]), base)
    before = mod.coverage(data.at(1, 1.0, 1.0), np.array([0.5, 0.9]))
    assert before[0] > 0.55  # unreshaped, the rows' core is too wide
    _, factor, exponent = mod.fit_pair(
        data, 1, factors=np.array([1.0, 1.1, 1.2]), exponents=np.array([1.0, 1.2, 1.3, 1.4])
    )
    assert (factor, exponent) == (1.1, 1.3)
    np.testing.assert_allclose(
        mod.coverage(data.at(1, factor, exponent), np.array([0.5, 0.8, 0.95])), [0.5, 0.8, 0.95], atol=0.02
    )
    # the unresolved pair does not reach a close view (w = 1)
    np.testing.assert_allclose(data.at(0, 0.5, 1.6), data.at(0, 2.0, 1.0))


def test_the_reading_is_the_identity_at_the_recorded_pair(benchmark_script):
    mod = benchmark_script("perception_reshaping")
    levels = np.linspace(0.01, 0.99, 50)
    np.testing.assert_allclose(mod.shape_levels(levels, 0.9, 1.25, 0.9, 1.25), levels, atol=1e-9)
    sharper = mod.shape_levels(levels, 0.9, 1.25, 1.2, 1.25)
    assert np.all(sharper >= levels)  # a larger factor puts the truths further out


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, benchmark_script):
    mod = benchmark_script("perception_reshaping")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"rows": [{"view": "inspect", "informative": True, "level": 0.5}]}))
    assert mod.main(["--results", str(bad)]) == 2
    assert "no informative rows with their reshaping" in capsys.readouterr().err
    assert mod.main(["--results", str(tmp_path / "missing.json")]) == 2
    assert "no calibration result at" in capsys.readouterr().err
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"rows": _rows(1.0, 1.25, 30, np.random.default_rng(0))}))
    plain = tmp_path / "plain.json"  # tuning rows without shaped levels
    plain.write_text(json.dumps({"config": {"tempering_factors": [1.0], "groups": ["clean"], "seed": 1}, "rows": []}))
    assert mod.main(["--results", str(good), "--tuning-rows", str(plain)]) == 2
    assert "no shaped levels" in capsys.readouterr().err
    assert mod.main(["--results", str(good), "--json", str(good / "fit.json")]) == 2  # a file in the way
    assert "is a file" in capsys.readouterr().err
    assert mod.main(["--results", str(good), "--sets", "0"]) == 2
    assert "--sets [0]: expected scene counts >= 1" in capsys.readouterr().err


def test_sets_resampled_from_the_results_are_counted(tmp_path, capsys, benchmark_script):
    """--sets: the mean cells within +-5 of sets of that many scenes drawn from the results' scenes,
    two files' scenes kept apart."""
    mod = benchmark_script("perception_reshaping")
    paths = []
    for k in range(2):
        paths.append(tmp_path / f"set{k}.json")
        paths[-1].write_text(json.dumps({"rows": _rows(1.0, 1.25, 600, np.random.default_rng(k))}))
    assert len({r["scene"] for r in mod.shape_rows(paths)}) == 400  # 200 scenes a file
    out = tmp_path / "fit.json"
    assert mod.main(["--results", *map(str, paths), "--sets", "50", "400", "--json", str(out)]) == 0
    assert "cells within +-5 of sets resampled" in capsys.readouterr().out
    counts = json.loads(out.read_text())["resampled_sets"]
    assert set(counts) == {"50", "400"} and all(0 <= c <= 3 for c in counts.values())
