"""benchmarks/ as a package run with `python -m benchmarks.X`: no script named like one of our
packages, no sys.path patch, every script listed in its README; the pick model the planner loads
is what benchmarks.grasp_map derives from its recorded picks; docs/results stays small."""

import json
import re
from pathlib import Path

import pytest

from goflow_common.errors import FileFormatError
from planning.grasp import PICK_MODEL, PICK_MODEL_FILE, load_pick_model

ROOT = Path(__file__).parents[1]
SCRIPTS = sorted(p for p in (ROOT / "benchmarks").glob("*.py") if p.stem not in {"__init__", "provenance"})


def test_no_benchmark_script_hides_a_package():
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}
    assert {"assembly", "learning", "planning", "benchmarks"} <= packages
    scripts = {p.stem for p in SCRIPTS}
    assert not scripts & packages, f"benchmarks/ scripts named like packages: {sorted(scripts & packages)}"


def test_no_script_patches_sys_path():
    patched = {p.stem for p in SCRIPTS if re.search(r"sys\.path\.(insert|append)", p.read_text())}
    assert not patched, f"benchmarks/ scripts patching sys.path: {sorted(patched)}"


def test_every_script_is_listed_in_the_readme():
    readme = (ROOT / "benchmarks" / "README.md").read_text()
    missing = [p.stem for p in SCRIPTS if f"`{p.stem}`" not in readme]
    assert not missing, f"benchmarks/README.md does not list {missing}"


def test_the_shipped_pick_model_is_what_grasp_map_derives_from_its_picks(tmp_path):
    from benchmarks import grasp_map

    out = tmp_path / "pick_model.json"
    assert grasp_map.main(["--from", str(ROOT / "docs" / "results" / "grasp_map.json"), "--model", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["pick_model"] == json.loads(PICK_MODEL_FILE.read_text())["pick_model"]
    assert load_pick_model(out) == PICK_MODEL
    assert {"command", "date", "commit"} <= set(written)


@pytest.mark.parametrize(
    "text, named",
    [
        ('{"pick_model": {"small": {"closing": [0, 1e-6]}}}', "pick_model['small']"),
        ('{"pick_model": {"small": {"closing": [0, -1], "along": [0, 0], "yaw": [0, 0]}}}', "std >= 0"),
        ('{"thresholds": {}}', "expected"),
        ('{"pick_model": NaN}', "not a pick-model file"),
    ],
)
def test_a_bad_pick_model_file_is_refused_by_name(tmp_path, text, named):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=re.escape(named)):
        load_pick_model(path)


def test_docs_results_stays_small():
    files = [p for p in (ROOT / "docs" / "results").rglob("*") if p.is_file()]
    total = sum(p.stat().st_size for p in files)
    assert total <= 15 * 2**20, f"docs/results holds {total / 2**20:.1f} MiB; expected <= 15 MiB"
    big = [p.name for p in files if p.stat().st_size > 4 * 2**20]
    assert not big, f"docs/results files over 4 MiB: {big}"
