"""`goflow bench perception --json PATH` as a user runs it."""

import json

from perception.calibration import load_result


def test_bench_perception_writes_its_numbers(tmp_path, run_goflow):
    out = tmp_path / "bench" / "perception.json"
    proc = run_goflow("bench", "perception", "--json", str(out), "--posteriors", "1")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert set(result) == {"seconds_per_posterior", "hypotheses_per_second", "renderer", "seconds_per_scene"}
    assert result["seconds_per_scene"] > 0
    assert isinstance(result["seconds_per_posterior"], float) and result["seconds_per_posterior"] > 0
    assert result["hypotheses_per_second"] > 100
    assert result["renderer"] == "raycast-heightmap"
    assert "s per close-view posterior" in proc.stdout and "s per scene image" in proc.stdout


def test_bench_rejects_unknown_target_and_bad_counts(run_goflow):
    proc = run_goflow("bench", "vision")
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    proc = run_goflow("bench", "perception", "--posteriors", "0")
    assert proc.returncode == 2 and "--posteriors 0" in proc.stderr


def test_bench_calibration_writes_summary_and_plot(tmp_path, run_goflow):
    out, plot, rows = tmp_path / "cal.json", tmp_path / "reliability.png", tmp_path / "rows.json.gz"
    proc = run_goflow(
        "bench",
        "calibration",
        "--scenes",
        "1",
        "--groups",
        "dim",
        "--seed",
        "7999",
        "--json",
        str(out),
        "--plot",
        str(plot),
        "--rows",
        str(rows),
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert [(s["group"], s["view"]) for s in result["summary"]] == [("dim", "scene"), ("dim", "inspect")]
    assert "rows" not in result  # the summary file is small; the rows go where --rows says
    assert len(load_result(rows)["rows"]) == 6 and plot.stat().st_size > 10_000
    assert "| dim | scene |" in proc.stdout
    proc = run_goflow("bench", "calibration", "--groups", "foggy")
    assert proc.returncode == 2 and "--groups foggy" in proc.stderr
