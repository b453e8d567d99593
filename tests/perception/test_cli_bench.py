"""`goflow bench perception --json PATH` as a user runs it."""

import json
import subprocess
import sys
from pathlib import Path

GOFLOW = Path(sys.executable).parent / "goflow"


def test_bench_perception_writes_the_three_numbers(tmp_path):
    out = tmp_path / "bench" / "perception.json"
    proc = subprocess.run([str(GOFLOW), "bench", "perception", "--json", str(out), "--posteriors", "1"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert set(result) == {"seconds_per_posterior", "hypotheses_per_second", "renderer"}
    assert isinstance(result["seconds_per_posterior"], float) and result["seconds_per_posterior"] > 0
    assert result["hypotheses_per_second"] > 100
    assert result["renderer"] == "raycast-heightmap"
    assert "s per posterior" in proc.stdout


def test_bench_rejects_unknown_target_and_bad_counts():
    proc = subprocess.run([str(GOFLOW), "bench", "vision"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "invalid choice" in proc.stderr
    proc = subprocess.run([str(GOFLOW), "bench", "perception", "--posteriors", "0"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--posteriors 0" in proc.stderr
