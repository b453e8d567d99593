"""The scripted pick-and-insert seats real gears on real shafts, through `goflow demo`."""

import contextlib
import io
import json

import pytest

from assembly.demo import AssemblyConfig, run_assembly
from assembly.gearset import GEAR_NAMES
from assembly.gearset import SEATED_HEIGHT_TOL, SEATED_LATERAL_TOL
from assembly.station import make_meshcat


@pytest.fixture(scope="module")
def demo_summary(tmp_path_factory):
    """`goflow demo --scripted --record HTML --json PATH` (in this process), into folders that
    do not exist yet (the one demo run of the suite: the tests below read it)."""
    from goflow_cli import main

    root = tmp_path_factory.mktemp("demo")
    out, record = root / "json" / "missing" / "summary.json", root / "rec" / "missing" / "r.html"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["demo", "--scripted", "--quiet", "--record", str(record), "--json", str(out)])
    assert code == 0, stdout.getvalue()
    assert record.stat().st_size > 0 and f"recording: {record}" in stdout.getvalue()
    return json.loads(out.read_text()), stdout.getvalue()


@pytest.mark.slow
def test_demo_json_schema(demo_summary):
    summary, _ = demo_summary
    assert set(summary) == {"gears", "sim_time_s", "wall_time_s"}
    assert set(summary["gears"]) == set(GEAR_NAMES)
    for gear in summary["gears"].values():
        assert set(gear) == {"inserted", "lateral_error_m", "height_error_m", "time_s"}
        assert isinstance(gear["inserted"], bool)
        assert gear["time_s"] > 0
    assert summary["sim_time_s"] > sum(g["time_s"] for g in summary["gears"].values())
    assert summary["wall_time_s"] > 0


def test_scripted_insertion_seats_every_gear(demo_summary):
    summary, stdout = demo_summary
    for name, gear in summary["gears"].items():
        assert gear["inserted"], (name, gear)
        assert gear["lateral_error_m"] < SEATED_LATERAL_TOL
        assert gear["height_error_m"] < SEATED_HEIGHT_TOL
    for name in GEAR_NAMES:  # the printed per-gear table
        assert name in stdout


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


def test_gripper_centres_error_along_closing_direction(tmp_path):
    # The same 4 mm error along the fingers' closing direction is removed by the grasp itself.
    # (Also records the run for Meshcat, as `goflow demo --record FILE.html` does.)
    record = tmp_path / "insert_small.html"
    summary = run_assembly(
        AssemblyConfig(order=("small",), belief_offsets={"small": (0.004, 0.0)}),
        meshcat=make_meshcat(),
        record=record,
        progress=False,
    )
    assert summary["gears"]["small"]["inserted"], summary
    assert record.stat().st_size > 100_000 and "meshcat" in record.read_text()[:100_000].lower()


def test_planned_demo_refuses_bad_input_before_running(tmp_path, run_goflow):
    """`goflow demo` (the planned assembly) names a bad seed or output path at once."""
    proc = run_goflow("demo", "--seed", "-1")
    assert proc.returncode == 2 and "--seed -1" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    (tmp_path / "file").write_text("")
    proc = run_goflow("demo", "--json", tmp_path / "file" / "s.json")
    assert proc.returncode == 2 and "--json" in proc.stderr
