"""Every notebook under notebooks/ runs top to bottom, headless, in a kernel on this interpreter.

Each notebook is executed with nbclient in a fresh "python3" kernel whose working directory is the
repository root (so `import assembly` works without installing the project). A failing cell fails
the test with that cell's source and traceback.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
from nbclient.exceptions import CellExecutionError, CellTimeoutError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
CELL_TIMEOUT_S = 600
KERNEL = "python3"
ANSI = re.compile(r"\x1b\[[0-9;]*m")  # colour codes in the kernel's tracebacks


def _execute(nb) -> None:
    """Run `nb` in place in a fresh kernel started in the repository root."""
    client = nbclient.NotebookClient(
        nb, timeout=CELL_TIMEOUT_S, kernel_name=KERNEL,
        resources={"metadata": {"path": str(ROOT)}})
    client.execute()


def test_kernel_runs_this_interpreter():
    """The "python3" kernel runs in this interpreter's environment (jupyter_client starts a
    kernelspec whose argv[0] is "python" with sys.executable), so notebooks see the same packages
    as the tests. (sys.prefix, not the executable: a venv's python is a symlink to the base one.)"""
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(
        "import os, sys\nprint(sys.prefix)\nprint(os.getcwd())")])
    _execute(nb)
    prefix, cwd = nb.cells[0].outputs[0]["text"].splitlines()
    assert Path(prefix).resolve() == Path(sys.prefix).resolve(), (
        f"the {KERNEL!r} kernel runs in {prefix}; expected this interpreter's {sys.prefix}")
    assert Path(cwd).resolve() == ROOT


def test_there_are_notebooks():
    assert NOTEBOOKS, f"no notebooks found under {ROOT / 'notebooks'}"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path: Path):
    nb = nbformat.read(path, as_version=4)
    try:
        _execute(nb)
    except CellTimeoutError as exc:
        pytest.fail(f"{path.name}: a cell ran longer than {CELL_TIMEOUT_S} s\n{exc}", pytrace=False)
    except CellExecutionError as exc:
        # str(exc) holds the failing cell's source and the kernel's traceback.
        pytest.fail(f"{path.name}: a cell failed\n{ANSI.sub('', str(exc))}", pytrace=False)
