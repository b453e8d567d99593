"""The `goflow` command as a user runs it: train, sweep, bad flags."""

import json
import subprocess
import sys
from pathlib import Path

GOFLOW = Path(sys.executable).parent / "goflow"
TINY = ["--ppo", "num_envs=2", "--ppo", "num_steps=8", "--ppo", "num_minibatches=2",
        "--ppo", "update_epochs=1", "--iterations-per-round", "1", "--eval-episodes", "4"]


def _run(*args, cwd=None):
    return subprocess.run([str(GOFLOW), *args], capture_output=True, text=True, timeout=600, cwd=cwd)


def test_train_writes_log_and_checkpoint_and_resumes(tmp_path):
    out = tmp_path / "run"
    args = ["train", "--env", "goflow/Toy2D-v0", "--sampler", "lsdr", "--steps", "32",
            "--out", str(out), *TINY]
    first = _run(*args)
    assert first.returncode == 0, first.stderr
    log = json.loads((out / "log.json").read_text())
    assert log["rounds"] == 2 and (out / "checkpoint.pt").exists()
    again = _run(*args)  # already finished: resumes from the checkpoint, nothing to do
    assert again.returncode == 0 and json.loads((out / "log.json").read_text()) == log


def test_sweep_writes_one_row_per_value(tmp_path):
    proc = _run("sweep", "--env", "goflow/Toy2D-v0", "--method", "lsdr", "--param", "alpha",
                "--values", "0.5", "1.0", "--seeds", "1", "--workers", "1", "--steps", "16",
                "--out", str(tmp_path / "runs"), "--results", str(tmp_path / "results"), *TINY)
    assert proc.returncode == 0, proc.stderr
    sweep = json.loads((tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha.json").read_text())
    assert [row["value"] for row in sweep["rows"]] == [0.5, 1.0]
    assert all(row["seeds"] == 1 for row in sweep["rows"])
    assert (tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha.png").stat().st_size > 0
    # each value's own experiment lands in a folder named for the sweep, not beside the other results
    per_value = tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha"
    assert sorted(p.name for p in per_value.glob("*.json")) == [
        "sweep-toy2d-v0-lsdr-alpha-0.5.json", "sweep-toy2d-v0-lsdr-alpha-1.0.json"]
    assert "best alpha" in proc.stdout


def test_bad_flags_are_explained():
    proc = _run("train", "--env", "goflow/Toy2D-v0", "--sampler", "sac")
    assert proc.returncode == 2 and "invalid choice: 'sac'" in proc.stderr
    proc = _run("train", "--env", "goflow/Toy2D-v0", "--sampler", "goflow", "--ppo", "learning_rat=1")
    assert proc.returncode != 0 and "learning_rat" in proc.stderr


def test_experiment_passes_sampler_options_per_method(tmp_path):
    proc = _run("experiment", "--env", "goflow/Toy2D-v0", "--methods", "goflow", "nodr", "--seeds", "1",
                "--workers", "1", "--steps", "16", "--method-kwarg", "goflow.steps=3",
                "--method-kwarg", "goflow.entropy_samples=64", "--out", str(tmp_path / "runs"),
                "--results", str(tmp_path / "results"), "--name", "tiny", *TINY)
    assert proc.returncode == 0, proc.stderr
    log = json.loads((tmp_path / "runs" / "tiny" / "goflow" / "seed0" / "log.json").read_text())
    assert log["config"]["sampler_kwargs"] == {"steps": 3, "entropy_samples": 64}
    nodr = json.loads((tmp_path / "runs" / "tiny" / "nodr" / "seed0" / "log.json").read_text())
    assert nodr["config"]["sampler_kwargs"] == {}
    assert set(json.loads((tmp_path / "results" / "tiny.json").read_text())["methods"]) == {"goflow", "nodr"}
    bad = _run("experiment", "--env", "goflow/Toy2D-v0", "--methods", "nodr", "--method-kwarg", "alpha=0.1")
    assert bad.returncode != 0 and "METHOD.KEY=VALUE" in bad.stderr
