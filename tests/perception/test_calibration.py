"""Calibration on held-out scenes (seeds never used for tuning), through the station's pipeline:
scene camera -> global detection -> far posterior -> inspect view -> close posterior. A calibrated
posterior's truth levels are uniform on (0, 1); a handful of scenes cannot pin the coverage curve
(that is `goflow bench calibration`), but it catches a posterior that is far off."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goflow_common.errors import InputError
from perception.calibration import (
    HELD_OUT_SEED,
    CalibrationConfig,
    calibrated_pass_chance,
    confidently_wrong,
    coverage_se,
    group_rows,
    markdown_table,
    pool_results,
    resampled_set_count,
    row_brightness,
    sets_text,
    coverage_summary,
)
from perception.likelihood import LikelihoodConfig
from perception.search import SearchConfig


@pytest.fixture(scope="module")
def rows():
    # scenes HELD_OUT_SEED + 777: neither the tuning seeds nor the benchmark's
    return group_rows("clean", CalibrationConfig(scenes=4, seed=HELD_OUT_SEED + 777))


def test_every_gear_found_and_every_posterior_informative(rows):
    assert len(rows) == 4 * 3 * 2
    assert all(r["seen"] and r["informative"] for r in rows), [r.get("reason") for r in rows]


def test_truth_levels_look_uniform_and_nothing_is_confidently_wrong(rows):
    levels = np.array([r["level"] for r in rows])
    # uniform on (0, 1): mean 0.5 +- 0.06 for 24 posteriors; allow 3.5 standard errors
    assert 0.29 < levels.mean() < 0.71, levels
    assert np.mean(levels < 0.9) >= 0.75, levels
    assert not any(confidently_wrong(r) for r in rows)


def test_close_view_is_sharper_on_average_and_within_a_millimetre(rows):
    std = {v: np.median([np.hypot(*r["std"][:2]) for r in rows if r["view"] == v]) for v in ("scene", "inspect")}
    assert std["inspect"] < std["scene"]
    assert all(r["xy_error_m"] < 0.001 for r in rows if r["view"] == "inspect")


def test_summary_reports_each_level(rows):
    (scene, inspect) = coverage_summary(rows)
    assert scene["view"] == "scene" and inspect["view"] == "inspect"
    assert set(scene["coverage"]) == {"0.5", "0.68", "0.8", "0.9", "0.95"}
    assert scene["posteriors"] == 12 and scene["not_seen"] == 0
    assert isinstance(scene["within_band"], bool)
    assert "cells (a perfectly calibrated pipeline" in markdown_table([scene, inspect])


def test_the_band_allows_what_sampling_noise_allows():
    # how often a perfectly calibrated pipeline reads within +-5 points at all five levels
    chances = [calibrated_pass_chance(n) for n in (0, 100, 300, 1000)]
    assert chances[0] == 0.0 and chances == sorted(chances)
    assert 0.4 < chances[1] < 0.65 and 0.8 < chances[2] < 0.95 and chances[3] > 0.99
    assert calibrated_pass_chance(300) == calibrated_pass_chance(300)  # a fixed seed


def test_the_scene_bootstrap_sees_gears_that_err_together():
    """Three gears a scene: independent truth levels give the binomial standard error; levels
    shared by a scene's gears give sqrt(3) times it (the scene, not the gear, is the sample)."""
    rng = np.random.default_rng(3)
    u = rng.random(600)
    alone = [{"scene": i // 3, "level": float(v)} for i, v in enumerate(u)]
    together = [{"scene": i // 3, "level": float(u[i // 3])} for i in range(600)]
    binomial = np.sqrt(0.5 * 0.5 / 600)
    assert abs(coverage_se(alone)[0.5] / binomial - 1) < 0.15
    assert abs(coverage_se(together)[0.5] / binomial - np.sqrt(3)) < 0.3
    assert coverage_se(alone) == coverage_se(alone)  # a fixed seed
    assert np.isnan(coverage_se([])[0.5])


def test_tuning_levels_predict_the_pipelines_own():
    """The tuning rows record levels before the reshaping; at the shipped reshaping they are the
    row's own level (the reshaping moves no cell), so a reshaping fit predicts the pipeline. At
    exponent 1 the shaped levels are the tempered ones."""
    shipped = LikelihoodConfig(close_reshaping={})  # the reshaping shared by every gear and light
    f_close, g_close = shipped.posterior_factor[1], shipped.shape_exponent[1]
    config = CalibrationConfig(
        scenes=1,
        seed=HELD_OUT_SEED + 778,
        tempering_factors=(f_close, 1.0),
        shape_exponents=(1.0, g_close),
        search=SearchConfig(likelihood=shipped),
    )
    close = [r for r in group_rows("clean", config) if r["view"] == "inspect" and r["informative"]]
    assert close
    for r in close:
        assert (r["posterior_factor"], r["shape"]) == (f_close, g_close)  # resolved teeth
        assert abs(r["brightness"] - 1.0) < 0.01  # the headlight's gain, recorded for the close-view fit
        assert r["shaped_levels"][0] == r["scaled_levels"]
        assert abs(r["shaped_levels"][1][0] - r["level"]) < 1e-6


def test_a_rows_brightness_is_recorded_or_its_groups_headlight():
    """Rows made before `brightness` was recorded read their group's headlight intensity; a light
    from elsewhere (oblique) or an unknown group gives None."""
    assert row_brightness({"group": "oblique", "brightness": 0.705}) == 0.705
    assert row_brightness({"group": "dim"}) == 0.5
    assert row_brightness({"group": "bright"}) == 1.6
    assert row_brightness({"group": "dropout_3"}) == 1.0
    assert row_brightness({"group": "oblique"}) is None
    assert row_brightness({"group": "sunset"}) is None
    assert row_brightness({"group": "oblique"}, 1.0) == 1.0  # the nominal light where it is not known


def test_pooled_sets_keep_their_scenes_apart_and_sum_their_posteriors(rows, tmp_path):
    """Two sets judged together: every cell counts both sets' posteriors, the scene bootstrap sees
    2 x 4 scenes (a set's scene 0 is not the other's), and the command writes what it printed."""
    first = {
        "config": {"scenes": 4, "seed": 1, "groups": ["clean"], "levels": [0.5, 0.68, 0.8, 0.9, 0.95]},
        "rows": rows,
    }
    second = {**first, "config": {**first["config"], "seed": 2}}
    pooled = pool_results([first, second])
    scene, inspect = pooled["summary"]
    assert scene["posteriors"] == 24 and inspect["posteriors"] == 24
    assert pooled["config"]["seeds"] == [1, 2] and pooled["config"]["scenes"] == 8
    assert len({r["scene"] for r in pooled["rows"]}) == 8
    assert scene["coverage"] == coverage_summary(rows)[0]["coverage"]  # the same rows twice: the same coverage
    with pytest.raises(InputError, match="result 1: levels"):
        pool_results([first, {**second, "config": {**second["config"], "levels": [0.5]}}])
    with pytest.raises(InputError, match="result 0: not a calibration result"):
        pool_results([{"rows": []}])
    paths = []
    for k, result in enumerate((first, second)):
        paths.append(tmp_path / f"set{k}.json")
        paths[-1].write_text(json.dumps(result))
    goflow = str(Path(sys.executable).parent / "goflow")
    out = tmp_path / "pooled.json"
    proc = subprocess.run(
        [goflow, "bench", "calibration", "--pool", *map(str, paths), "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "| clean | scene | 24 |" in proc.stdout
    written = json.loads(out.read_text())
    assert written["results"] == [str(p) for p in paths] and "rows" not in written
    assert written["summary"][0]["posteriors"] == 24
    assert [s["seed"] for s in written["sets"]["each"]] == [1, 2] and written["sets"]["scenes"] == 4
    assert "Each set alone" in proc.stdout and "resampled from the pooled scenes" in proc.stdout
    proc = subprocess.run(
        [goflow, "bench", "calibration", "--pool", str(paths[0]), "--seed", "3"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2 and proc.stderr.strip().endswith("expected only --json and --plot")
    assert len(proc.stderr.strip().splitlines()) == 1


def _synthetic_rows(scenes: int, offsets: dict[str, float], seed: int = 0) -> list[dict]:
    """Two groups x two views x three gears a scene, truth levels uniform but for a cell's offset
    (its levels shifted and clipped): a pipeline whose truth is known."""
    rng = np.random.default_rng(seed)
    rows = []
    for scene in range(scenes):
        for group in ("clean", "dim"):
            for view in ("scene", "inspect"):
                for gear in ("small", "medium", "large"):
                    level = float(np.clip(rng.random() + offsets.get(f"{group}/{view}", 0.0), 0, 1))
                    rows.append(
                        {
                            "group": group,
                            "view": view,
                            "scene": scene,
                            "gear": gear,
                            "seen": True,
                            "informative": True,
                            "level": level,
                            "xy_error_m": 1e-4,
                            "yaw_error_rad": 1e-3,
                            "map_error": [1e-4, 0.0, 1e-3],
                            "std": [1e-4, 1e-4, 1e-3],
                            "seconds": 0.1,
                        }
                    )
    return rows


def test_resampled_sets_read_what_a_calibrated_pipeline_reads_and_less_with_an_offset_cell():
    """Sets resampled from many calibrated scenes pass about as often as `calibrated_pass_chance`
    says; a cell 6 points sharp costs about that cell; sets of more scenes pass more often."""
    calibrated = _synthetic_rows(3000, {})
    expected = 4 * calibrated_pass_chance(450)
    assert abs(resampled_set_count(calibrated, 150, draws=400) - expected) < 0.15
    sharp = _synthetic_rows(3000, {"clean/scene": 0.06})
    fewer = resampled_set_count(sharp, 150, draws=400)
    assert expected - 1.0 < fewer < expected - 0.3
    # with more scenes a set reads the calibrated cells in band and the sharp one out of it
    assert 3.7 < resampled_set_count(calibrated, 600, draws=200) <= 4.0
    assert 2.6 < resampled_set_count(sharp, 600, draws=200) < 3.5
    assert resampled_set_count(calibrated, 150, draws=100) == resampled_set_count(calibrated, 150, draws=100)
    assert np.isnan(resampled_set_count([], 150))


def test_pooled_sets_report_each_set_and_the_resampled_mean():
    first = {
        "config": {"scenes": 50, "seed": 7, "groups": ["clean", "dim"], "levels": [0.5, 0.68, 0.8, 0.9, 0.95]},
        "rows": _synthetic_rows(50, {}, seed=1),
    }
    second = {"config": {**first["config"], "seed": 8}, "rows": _synthetic_rows(50, {}, seed=2)}
    sets = pool_results([first, second])["sets"]
    assert [s["seed"] for s in sets["each"]] == [7, 8] and sets["scenes"] == 50
    assert all(s["cells"] == 4 and 0 <= s["within_band"] <= 4 for s in sets["each"])
    assert 0 <= sets["resampled_within_band"] <= 4
    assert sets_text(sets).startswith("Each set alone, within +-5") and "7: " in sets_text(sets)


def test_a_row_is_confidently_wrong_against_the_belief_the_planner_bets_on():
    # 1.5 mm off: 30 posterior std, but 1 std of a belief widened by a 1.5 mm mounting uncertainty
    row = {
        "informative": True,
        "level": 0.95,
        "map_error": [0.0015, 0.0, 0.0],
        "xy_error_m": 0.0015,
        "std": [5e-5, 5e-5, 1e-3],
    }
    assert confidently_wrong(row)
    assert not confidently_wrong({**row, "belief_std": [1.5e-3, 1.5e-3, 1e-3]})
    assert confidently_wrong({**row, "belief_std": [1.5e-3, 1.5e-3, 1e-3], "xy_error_m": 0.0025})
