"""Every notebook under notebooks/ runs top to bottom, headless, from notebooks/ (where Jupyter
starts its kernels), and is stored executed, with its outputs, small enough to read on GitHub.

Two notebooks are also the suite's one run of what they show, so that nothing is simulated twice:
01_station is the test of the scripted assembly (every gear seated, the summary's keys) and
04_assembly of the planned assembly of a random placement (done; three inserts, each passing its
seat check). After a notebook's last cell the test reads its variables (a probe cell appended in
memory, never stored) and checks them here.

Refresh a notebook's stored outputs after editing it (outputs only: no timing metadata), from the
repository root:

    OMP_NUM_THREADS=1 .venv/bin/python tests/test_notebooks.py notebooks/01_station.ipynb

or from notebooks/ with Jupyter's nbconvert, where it is installed:
`jupyter nbconvert --to notebook --execute --inplace 01_station.ipynb`.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
from nbclient.exceptions import CellExecutionError, CellTimeoutError  # noqa: E402

from assembly.gearset import GEAR_NAMES, SEATED_HEIGHT_TOL, SEATED_LATERAL_TOL  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
CELL_TIMEOUT_S = 600
KERNEL = "python3"
MAX_STORED_BYTES = 1_000_000  # a stored notebook, outputs included
MAX_HTML_OUTPUT_CHARS = 20_000  # an HTML output (a table, not a Meshcat scene)
ANSI = re.compile(r"\x1b\[[0-9;]*m")  # colour codes in the kernel's tracebacks


def execute(nb, probe: str | None = None) -> str | None:
    """Run notebook `nb` in place in a fresh "python3" kernel started in notebooks/, as Jupyter
    starts it, without timing metadata. `probe`: code run after the last cell in the same kernel
    (the cell is removed afterwards). Returns the probe's printed text (None without a probe).
    Raises nbclient's CellExecutionError for a failing cell, CellTimeoutError for a cell running
    longer than CELL_TIMEOUT_S."""
    if probe is not None:
        nb.cells.append(nbformat.v4.new_code_cell(probe))
    try:
        nbclient.NotebookClient(
            nb,
            timeout=CELL_TIMEOUT_S,
            kernel_name=KERNEL,
            record_timing=False,
            resources={"metadata": {"path": str(NOTEBOOK_DIR)}},
        ).execute()
    finally:
        cell = nb.cells.pop() if probe is not None else None
    if cell is None:
        return None
    return "".join(out.get("text", "") for out in cell.outputs if out.get("name") == "stdout")


def _check_scripted_assembly(out: dict) -> None:
    """01_station's `summary` (assembly.demo's, as `goflow demo --scripted --json` writes it):
    every gear of the gearbox seated within the seated tolerances; its printed table (what
    `goflow demo --scripted` prints) names every gear."""
    summary = out["summary"]
    assert all(name in out["table"] for name in GEAR_NAMES), out["table"]
    assert set(summary) == {"gears", "sim_time_s", "wall_time_s"}, summary
    assert set(summary["gears"]) == set(GEAR_NAMES)
    for name, gear in summary["gears"].items():
        assert set(gear) == {"inserted", "lateral_error_m", "height_error_m", "time_s"}
        assert gear["inserted"] is True, (name, gear)
        assert gear["lateral_error_m"] < SEATED_LATERAL_TOL and gear["height_error_m"] < SEATED_HEIGHT_TOL, (name, gear)
        assert gear["time_s"] > 0
    assert summary["sim_time_s"] > sum(g["time_s"] for g in summary["gears"].values())
    assert summary["wall_time_s"] > 0


def _check_planned_assembly(out: dict) -> None:
    """04_assembly's `summary` (planning.assembly's) and the planner's log: the default, realistic
    cameras; done, three inserts in the plan, every gear seated, each insert looked at by the wrist
    camera and passed; at least one gear inspected before its pick (the far view is honestly
    uncertain under a real camera's calibration error)."""
    summary, log = out["summary"], out["log"]
    assert summary["cameras"] == "realsense"
    assert summary["status"] == "done", summary["reason"]
    assert any(e["skill"] == "inspect" for e in summary["executed"]), summary["executed"]
    checks = [line for line in log if "seat check" in line]
    assert len(checks) == 3 and all(line.endswith(": seated") for line in checks), checks
    assert all(g["inserted"] for g in summary["gears"].values()), summary["gears"]
    assert [s for s, _ in summary["plan"]].count("insert") == 3
    for e in summary["executed"]:
        assert set(e) == {"skill", "gear", "t_start", "t_end", "outcome", "precondition_prob"}
        assert e["t_end"] >= e["t_start"]


#: notebook -> (probe printing its results as JSON, the check of them)
RESULTS: dict[str, tuple[str, Callable[[dict], None]]] = {
    "01_station.ipynb": (
        'import json; print(json.dumps({"summary": summary, "table": format_summary(summary)}))',
        _check_scripted_assembly,
    ),
    "04_assembly.ipynb": (
        'import json; print(json.dumps({"summary": summary, "log": built.run().log}))',
        _check_planned_assembly,
    ),
}


def test_kernel_runs_this_interpreter_in_the_notebooks_folder():
    """The "python3" kernel runs in this interpreter's environment (jupyter_client starts a
    kernelspec whose argv[0] is "python" with sys.executable), so notebooks see the same packages
    as the tests, and in notebooks/, as Jupyter starts it. (sys.prefix, not the executable: a
    venv's python is a symlink to the base one.)"""
    nb = nbformat.v4.new_notebook()
    prefix, cwd = execute(nb, "import os, sys\nprint(sys.prefix)\nprint(os.getcwd())").splitlines()
    assert Path(prefix).resolve() == Path(sys.prefix).resolve(), (
        f"the {KERNEL!r} kernel runs in {prefix}; expected this interpreter's {sys.prefix}"
    )
    assert Path(cwd).resolve() == NOTEBOOK_DIR


def test_there_are_notebooks():
    assert NOTEBOOKS, f"no notebooks found under {NOTEBOOK_DIR}"
    assert set(RESULTS) <= {p.name for p in NOTEBOOKS}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_executed_and_small(path: Path):
    """Stored as run top to bottom in one kernel, with its outputs and without errors, timing
    metadata or large HTML (a Meshcat scene), under MAX_STORED_BYTES."""
    refresh = f"refresh it: python tests/test_notebooks.py notebooks/{path.name}"
    size = path.stat().st_size
    assert size < MAX_STORED_BYTES, f"{path.name}: {size} bytes stored; expected < {MAX_STORED_BYTES}"
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1)), (
        f"{path.name}: not stored as executed top to bottom; {refresh}"
    )
    for i, cell in enumerate(code):
        assert "execution" not in cell.metadata, f"{path.name}: code cell {i} stores timing metadata; {refresh}"
        for out in cell.outputs:
            assert out.output_type != "error", f"{path.name}: code cell {i} is stored with an error; {refresh}"
            html = out.get("data", {}).get("text/html", "")
            assert len(html) < MAX_HTML_OUTPUT_CHARS, f"{path.name}: code cell {i} stores {len(html)} chars of HTML"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path: Path):
    """Runs from notebooks/, writes nothing there, and (01, 04) gives the results checked above."""
    nb = nbformat.read(path, as_version=4)
    probe, check = RESULTS.get(path.name, (None, None))
    before = sorted(NOTEBOOK_DIR.iterdir())
    try:
        printed = execute(nb, probe)
    except CellTimeoutError as exc:
        pytest.fail(f"{path.name}: a cell ran longer than {CELL_TIMEOUT_S} s\n{exc}", pytrace=False)
    except CellExecutionError as exc:
        # str(exc) holds the failing cell's source and the kernel's traceback.
        pytest.fail(f"{path.name}: a cell failed\n{ANSI.sub('', str(exc))}", pytrace=False)
    assert sorted(NOTEBOOK_DIR.iterdir()) == before, f"{path.name} wrote into {NOTEBOOK_DIR}"
    if check is not None:
        check(json.loads(printed))


def store(path: Path) -> None:
    """Execute notebook `path` from notebooks/, check its results where RESULTS names it, and
    write it back with its outputs. Raises as `execute` does, AssertionError for a failed check."""
    nb = nbformat.read(path, as_version=4)
    probe, check = RESULTS.get(path.name, (None, None))
    printed = execute(nb, probe)
    if check is not None:
        check(json.loads(printed))
    nbformat.write(nb, path)
    print(f"{path}: {path.stat().st_size} bytes")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(
            "usage: python tests/test_notebooks.py NOTEBOOK.ipynb [...]; executes each from notebooks/ "
            "and stores it with its outputs"
        )
    for arg in sys.argv[1:]:
        store(Path(arg).resolve())
