"""`goflow collect` and `goflow estimate` as a user runs them."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

GOFLOW = Path(sys.executable).parent / "goflow"


def _run(*args):
    return subprocess.run([str(GOFLOW), *args], capture_output=True, text=True, timeout=600)


def test_collect_then_estimate_gives_a_sampler_file(tmp_path):
    data = tmp_path / "pm.npz"
    proc = _run("collect", "--env", "goflow/PointMass-v0", "--xi", "mixture", "--episodes", "6",
                "--steps", "8", "--seed", "1", "--out", str(data))
    assert proc.returncode == 0, proc.stderr
    from learning.estimation.dataset import load_dataset
    ds = load_dataset(data)
    assert ds.num_episodes == 6 and ds.collection["command"].startswith("goflow collect")
    out = tmp_path / "est.json"
    proc = _run("estimate", "--data", str(data), "--method", "dropo", "--sim-budget", "3000",
                "--option", "samples=10", "--option", "transitions=8", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    from learning.estimation.sampler import load_estimate
    sampler, doc = load_estimate(out)
    assert doc["method"] == "dropo" and doc["info"]["sim_calls"] <= 3000
    assert np.all(ds.space.contains(sampler.sample(10, np.random.default_rng(0))))
    assert json.loads(out.read_text())["env_id"] == "goflow/PointMass-v0"


def test_bad_flags_are_explained(tmp_path):
    proc = _run("collect", "--env", "goflow/Nope-v0", "--xi", "gaussian", "--episodes", "2",
                "--out", str(tmp_path / "x.npz"))
    assert proc.returncode != 0 and "no step-from-state simulator for env 'goflow/Nope-v0'" in proc.stderr
    proc = _run("collect", "--env", "goflow/PointMass-v0", "--xi", "uniform", "--episodes", "2",
                "--out", str(tmp_path / "x.npz"))
    assert proc.returncode == 2 and "invalid choice: 'uniform'" in proc.stderr
    proc = _run("estimate", "--data", str(tmp_path / "missing.npz"), "--method", "nfpde-softmax",
                "--out", str(tmp_path / "e.json"))
    assert proc.returncode != 0 and "no such file" in proc.stderr
    proc = _run("estimate", "--data", str(tmp_path / "m.npz"), "--method", "mle", "--out", "e.json")
    assert proc.returncode == 2 and "invalid choice: 'mle'" in proc.stderr
