"""The scripts in benchmarks/ run as `python benchmarks/X.py`, which puts benchmarks/ first on
sys.path: a script named like one of our packages would hide that package from all the others."""

from pathlib import Path

ROOT = Path(__file__).parents[1]


def test_no_benchmark_script_hides_a_package():
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}
    assert {"assembly", "learning", "planning"} <= packages
    scripts = {p.stem for p in (ROOT / "benchmarks").glob("*.py")}
    assert not scripts & packages, f"benchmarks/ scripts named like packages: {sorted(scripts & packages)}"
