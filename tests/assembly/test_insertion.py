"""The scripted pick-and-insert seats real gears on real shafts, through `goflow demo`.

The scripted assembly of all three gears is run once in the suite, by notebooks/01_station.ipynb
(tests/test_notebooks.py checks its summary: the keys `goflow demo --scripted --json` writes, every
gear seated); here `goflow demo --scripted` runs one gear, to check what the command adds."""

import contextlib
import functools
import io
import json

from assembly import demo
from assembly.demo import AssemblyConfig, format_summary, run_assembly
from assembly.gearset import SEATED_HEIGHT_TOL, SEATED_LATERAL_TOL


def test_grasp_error_beyond_capture_range_does_not_seat():
    # The script believes the medium gear is 4 mm further along world y than it is: the fingers
    # close along x, so the gear ends up 4 mm off-centre in the hand, beyond the chamfers'
    # capture range (0.5 mm clearance + 1 mm bore chamfer + 1 mm shaft chamfer). Nothing
    # corrects it, so the bore lands on the shaft top and the gear cannot go down.
    summary = run_assembly(AssemblyConfig(order=("medium",), belief_offsets={"medium": (0.0, 0.004)}), progress=False)
    gear = summary["gears"]["medium"]
    assert "sim_error" not in summary
    assert not gear["inserted"]
    assert gear["height_error_m"] > 0.005  # held up by the shaft, not seated


def test_gripper_centres_error_along_closing_direction(tmp_path, monkeypatch):
    # The same 4 mm error along the fingers' closing direction is removed by the grasp itself.
    # Run as `goflow demo --scripted --record HTML --json PATH` (in this process, its run cut to
    # this gear and this belief), into folders that do not exist yet: the command prints the
    # summary's table, writes it as JSON, saves the Meshcat recording and exits 0.
    from goflow_cli import main

    config = functools.partial(AssemblyConfig, order=("small",), belief_offsets={"small": (0.004, 0.0)})
    monkeypatch.setattr(demo, "AssemblyConfig", config)
    out, record = tmp_path / "json" / "missing" / "summary.json", tmp_path / "rec" / "missing" / "insert_small.html"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["demo", "--scripted", "--quiet", "--record", str(record), "--json", str(out)])
    assert code == 0, stdout.getvalue()
    summary = json.loads(out.read_text())
    assert set(summary) == {"gears", "sim_time_s", "wall_time_s"} and set(summary["gears"]) == {"small"}
    gear = summary["gears"]["small"]
    assert gear["inserted"], summary
    assert gear["lateral_error_m"] < SEATED_LATERAL_TOL and gear["height_error_m"] < SEATED_HEIGHT_TOL, gear
    assert format_summary(summary) in stdout.getvalue()  # the printed per-gear table
    assert f"recording: {record}" in stdout.getvalue()
    assert record.stat().st_size > 100_000 and "meshcat" in record.read_text()[:100_000].lower()


def test_planned_demo_refuses_bad_input_before_running(tmp_path, run_goflow):
    """`goflow demo` (the planned assembly) names a bad seed or output path at once."""
    proc = run_goflow("demo", "--seed", "-1")
    assert proc.returncode == 2 and "--seed -1" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    (tmp_path / "file").write_text("")
    proc = run_goflow("demo", "--json", tmp_path / "file" / "s.json")
    assert proc.returncode == 2 and "--json" in proc.stderr
