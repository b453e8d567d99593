"""The `goflow` command as a user runs it: train, sweep, bad flags, output paths, Ctrl-C, and
that a failed command leaves nothing behind. Commands run in this process (`run_goflow`, see
conftest.py); only the Ctrl-C tests start a process, since a terminal's signal is their point."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

GOFLOW = Path(sys.executable).parent / "goflow"


def _as_from_a_shell() -> None:
    """In the child before exec: Ctrl-C as a terminal delivers it (default disposition, not
    blocked), whatever the test runner's own signal state has become."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])


TINY = [
    "--ppo",
    "num_envs=2",
    "--ppo",
    "num_steps=8",
    "--ppo",
    "num_minibatches=2",
    "--ppo",
    "update_epochs=1",
    "--iterations-per-round",
    "1",
    "--eval-episodes",
    "4",
]


def _one_line_error(proc, command):
    """The failure was reported as one line `goflow <command>: ...` with exit status 2."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"goflow {command}: "), proc.stderr
    return lines[0]


def _under_a_file(tmp_path):
    """A folder path no one can create, root included: its parent is a file."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    return blocker / "missing"


# ---------------------------------------------------------------------------------------------
# train, sweep, experiment
# ---------------------------------------------------------------------------------------------


def test_train_writes_log_and_checkpoint_and_resumes(tmp_path, run_goflow):
    out = tmp_path / "run"
    args = [
        "train",
        "--env",
        "goflow/Toy2D-v0",
        "--method",
        "lsdr",
        "--method-kwarg",
        "alpha=0.5",
        "--steps",
        "32",
        "--out-dir",
        str(out),
        *TINY,
    ]
    first = run_goflow(*args)
    assert first.returncode == 0, first.stderr
    log = json.loads((out / "log.json").read_text())
    assert log["rounds"] == 2 and (out / "checkpoint.pt").exists()
    assert log["config"]["method"] == "lsdr" and log["config"]["sampler_kwargs"] == {"alpha": 0.5}
    assert "note" not in first.stderr  # 32 steps are two whole rounds of 16
    again = run_goflow(*args)  # already finished: resumes from the checkpoint, nothing to do
    assert again.returncode == 0 and json.loads((out / "log.json").read_text()) == log


def test_train_says_when_steps_are_not_whole_rounds(tmp_path, run_goflow):
    proc = run_goflow(
        "train",
        "--env",
        "goflow/Toy2D-v0",
        "--method",
        "nodr",
        "--steps",
        "40",
        "--out-dir",
        str(tmp_path / "run"),
        *TINY,
    )
    assert proc.returncode == 0, proc.stderr
    assert "--steps 40 is not a whole number of rounds" in proc.stderr and "trains 32 steps" in proc.stderr
    assert json.loads((tmp_path / "run" / "log.json").read_text())["steps"] == 32


def test_train_unknown_env_or_option_fails_in_one_line_and_writes_nothing(tmp_path, run_goflow):
    # no --out-dir: the default run folder would be runs/... under the working directory
    line = _one_line_error(run_goflow("train", "--env", "goflow/Nope-v0", "--method", "lsdr", cwd=tmp_path), "train")
    assert "goflow/Nope-v0" in line and "goflow/Toy2D-v0" in line  # the known ids are listed
    line = _one_line_error(
        run_goflow("train", "--env", "goflow/Toy2D-v0", "--env-kwarg", "bogus=1", "--method", "lsdr", cwd=tmp_path),
        "train",
    )
    assert "bogus" in line
    line = _one_line_error(
        run_goflow("train", "--env", "goflow/Toy2D-v0", "--method", "lsdr", "--method-kwarg", "bogus=1", cwd=tmp_path),
        "train",
    )
    assert "bogus" in line
    assert list(tmp_path.iterdir()) == []


def test_train_ctrl_c_keeps_the_checkpoint_and_says_how_to_resume(tmp_path, run_goflow):
    from learning.experiment import load_run

    out = tmp_path / "run"
    args = ["train", "--env", "goflow/Toy2D-v0", "--method", "lsdr", "--steps", "1000000", "--out-dir", str(out), *TINY]
    proc = subprocess.Popen(
        [str(GOFLOW), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_as_from_a_shell
    )
    try:
        deadline = time.monotonic() + 300
        while not (out / "checkpoint.pt").exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no checkpoint within 300 s"
            time.sleep(0.2)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr
    assert (
        f"goflow train: interrupted; {out / 'checkpoint.pt'} keeps the last finished round; "
        "run the same command to resume"
    ) in stderr
    rounds = load_run(out).state["log"]["rounds"]  # loadable, not half written
    assert rounds >= 1
    # the same run continues from it: one round more
    more = run_goflow(
        *args[: args.index("--steps")], "--steps", str(16 * (rounds + 1)), *args[args.index("--out-dir") :]
    )
    assert more.returncode == 0, more.stderr
    assert json.loads((out / "log.json").read_text())["rounds"] == rounds + 1


def test_experiment_ctrl_c_stops_every_run_cleanly(tmp_path):
    """Ctrl-C in a terminal reaches the whole process group: the workers stop their runs at the
    next step (each keeps its last checkpoint), with one message and no traceback or warning."""
    args = [
        "experiment",
        "--env",
        "goflow/Toy2D-v0",
        "--methods",
        "fulldr",
        "--seeds",
        "3",
        "--steps",
        "1000000",
        "--workers",
        "2",
        "--runs",
        str(tmp_path / "runs"),
        "--results",
        str(tmp_path / "results"),
        *TINY,
    ]
    proc = subprocess.Popen(
        [str(GOFLOW), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_as_from_a_shell,
    )
    try:
        deadline = time.monotonic() + 300
        while not list((tmp_path / "runs").glob("*/fulldr/seed*/checkpoint.pt")):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no checkpoint within 300 s"
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "leaked" not in stderr, stderr
    assert "goflow experiment: interrupted;" in stderr and "run the same command to resume" in stderr
    assert not list((tmp_path / "results").glob("*.json"))  # no summary of unfinished runs


def test_sweep_writes_one_row_per_value(tmp_path, run_goflow):
    proc = run_goflow(
        "sweep",
        "--env",
        "goflow/Toy2D-v0",
        "--method",
        "lsdr",
        "--param",
        "alpha",
        "--values",
        "0.5",
        "1.0",
        "--seeds",
        "1",
        "--workers",
        "1",
        "--steps",
        "16",
        "--runs",
        str(tmp_path / "runs"),
        "--results",
        str(tmp_path / "results"),
        *TINY,
    )
    assert proc.returncode == 0, proc.stderr
    sweep = json.loads((tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha.json").read_text())
    assert [row["value"] for row in sweep["rows"]] == [0.5, 1.0]
    assert all(row["seeds"] == 1 for row in sweep["rows"])
    assert sweep["command"].startswith("goflow sweep --env goflow/Toy2D-v0")
    assert (tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha.png").stat().st_size > 0
    # each value's own experiment lands in a folder named for the sweep, not beside the other results
    per_value = tmp_path / "results" / "sweep-toy2d-v0-lsdr-alpha"
    assert sorted(p.name for p in per_value.glob("*.json")) == [
        "sweep-toy2d-v0-lsdr-alpha-0.5.json",
        "sweep-toy2d-v0-lsdr-alpha-1.0.json",
    ]
    assert "best alpha" in proc.stdout


def test_sweep_and_experiment_refuse_bad_paths_and_options_before_any_run(tmp_path, run_goflow):
    blocked = _under_a_file(tmp_path)
    common = ["--env", "goflow/Toy2D-v0", "--seeds", "1", "--workers", "1", "--steps", "16", *TINY]
    line = _one_line_error(
        run_goflow(
            "sweep",
            "--method",
            "lsdr",
            "--param",
            "alpha",
            "--values",
            "0.5",
            *common,
            "--runs",
            str(tmp_path / "runs"),
            "--results",
            str(blocked),
        ),
        "sweep",
    )
    assert str(blocked) in line
    line = _one_line_error(
        run_goflow(
            "sweep",
            "--method",
            "lsdr",
            "--param",
            "alphaa",
            "--values",
            "0.5",
            *common,
            "--runs",
            str(tmp_path / "runs"),
            "--results",
            str(tmp_path / "results"),
        ),
        "sweep",
    )
    assert "alphaa" in line
    line = _one_line_error(
        run_goflow(
            "experiment", "--methods", "nodr", *common, "--runs", str(blocked), "--results", str(tmp_path / "results")
        ),
        "experiment",
    )
    assert str(blocked) in line
    assert not (tmp_path / "runs").exists() and not (tmp_path / "results").exists()


def test_bad_flags_are_explained(run_goflow):
    proc = run_goflow("train", "--env", "goflow/Toy2D-v0", "--method", "sac")
    assert proc.returncode == 2 and "invalid choice: 'sac'" in proc.stderr
    proc = run_goflow("train", "--env", "goflow/Toy2D-v0", "--method", "goflow", "--ppo", "learning_rat=1")
    assert proc.returncode == 2 and "learning_rat" in proc.stderr and "Traceback" not in proc.stderr
    proc = run_goflow("train", "--env", "goflow/Toy2D-v0", "--method", "goflow", "--ppo", "learning_rate=NaN")
    assert "NaN is not allowed" in _one_line_error(proc, "train")
    # the old spellings are gone: one flag name per concept
    proc = run_goflow("train", "--env", "goflow/Toy2D-v0", "--sampler", "goflow")
    assert proc.returncode == 2 and "--method" in proc.stderr


def test_experiment_passes_sampler_options_per_method(tmp_path, run_goflow):
    proc = run_goflow(
        "experiment",
        "--env",
        "goflow/Toy2D-v0",
        "--methods",
        "goflow",
        "nodr",
        "--seeds",
        "1",
        "--workers",
        "1",
        "--steps",
        "16",
        "--method-kwarg",
        "goflow.steps=3",
        "--method-kwarg",
        "goflow.entropy_samples=64",
        "--runs",
        str(tmp_path / "runs"),
        "--results",
        str(tmp_path / "results"),
        "--name",
        "tiny",
        *TINY,
    )
    assert proc.returncode == 0, proc.stderr
    log = json.loads((tmp_path / "runs" / "tiny" / "goflow" / "seed0" / "log.json").read_text())
    assert log["config"]["sampler_kwargs"] == {"steps": 3, "entropy_samples": 64}
    nodr = json.loads((tmp_path / "runs" / "tiny" / "nodr" / "seed0" / "log.json").read_text())
    assert nodr["config"]["sampler_kwargs"] == {}
    assert set(json.loads((tmp_path / "results" / "tiny.json").read_text())["methods"]) == {"goflow", "nodr"}
    assert f"figure: {tmp_path / 'results' / 'tiny-densities.png'}" in proc.stdout  # Toy2D's densities
    bad = run_goflow(
        "experiment",
        "--env",
        "goflow/Toy2D-v0",
        "--methods",
        "nodr",
        "--method-kwarg",
        "goflow.alpha=0.1",
        cwd=tmp_path,
    )
    assert "METHOD.KEY=VALUE" in _one_line_error(bad, "experiment")
    bad = run_goflow(
        "experiment", "--env", "goflow/Toy2D-v0", "--methods", "nodr", "--method-kwarg", "alpha=0.1", cwd=tmp_path
    )
    assert "alpha" in _one_line_error(bad, "experiment")  # a bare KEY is every method's: nodr has none


def test_defaults_write_under_runs_not_into_committed_files(tmp_path, run_goflow):
    from goflow_cli import make_parser

    args = make_parser(["experiment"]).parse_args(["experiment", "--env", "goflow/Toy2D-v0"])
    assert args.results == Path("runs/results") and args.out == Path("runs")  # --runs
    args = make_parser(["sweep"]).parse_args(
        ["sweep", "--env", "goflow/Toy2D-v0", "--method", "goflow", "--param", "alpha", "--values", "1"]
    )
    assert args.results == Path("runs/results")
    # skill export without --out: the file would go to runs/skills/, never to learning/skill_files/
    args = make_parser(["skill"]).parse_args(["skill", "export", "--gear", "medium", "--run", "r"])
    assert args.out is None and args.runs == Path("runs/skills")
    shipped = Path(__file__).parents[1] / "learning" / "skill_files" / "insert-medium.pt"
    before = shipped.stat().st_mtime_ns
    proc = run_goflow("skill", "export", "--gear", "medium", "--run", str(tmp_path / "no-run"), cwd=tmp_path)
    assert "no-run" in _one_line_error(proc, "skill export")
    assert list(tmp_path.iterdir()) == [] and shipped.stat().st_mtime_ns == before  # failed: nothing made


def test_skill_show_reports_the_flow_against_the_measured_feasible_set(run_goflow):
    proc = run_goflow("skill", "show", "--gear", "medium")
    assert proc.returncode == 0, proc.stderr
    shown = json.loads(proc.stdout.strip().splitlines()[-1])
    assert shown["mode"] == "constrained"
    report = shown["feasible_set"]
    assert set(report) >= {"share", "mass_on", "mass_outside", "coverage10", "coverage1", "episodes"}
    assert 0.0 < report["share"] < 0.01 and report["mass_on"] + report["mass_outside"] == pytest.approx(1.0)


def test_skill_refit_refuses_bad_settings_before_any_episode(tmp_path, run_goflow):
    line = _one_line_error(
        run_goflow(
            "skill",
            "refit",
            "--gear",
            "small",
            "--delta",
            "1.5",
            "--runs",
            str(tmp_path / "r"),
            "--out",
            str(tmp_path / "s.pt"),
        ),
        "skill refit",
    )
    assert "delta" in line and "1.5" in line
    line = _one_line_error(
        run_goflow(
            "skill",
            "refit",
            "--gear",
            "small",
            "--refit-rounds",
            "-1",
            "--runs",
            str(tmp_path / "r"),
            "--out",
            str(tmp_path / "s.pt"),
        ),
        "skill refit",
    )
    assert "rounds" in line and "-1" in line
    out = _under_a_file(tmp_path) / "s.pt"
    line = _one_line_error(
        run_goflow("skill", "refit", "--gear", "small", "--runs", str(tmp_path / "r"), "--out", str(out)), "skill refit"
    )
    assert str(out.parent) in line
    assert not (tmp_path / "r").exists()  # nothing measured


# ---------------------------------------------------------------------------------------------
# Output paths are checked before the work
# ---------------------------------------------------------------------------------------------


def test_demo_refuses_an_unwritable_record_path_at_once(tmp_path, run_goflow):
    record = _under_a_file(tmp_path) / "r.html"
    t0 = time.monotonic()
    proc = run_goflow("demo", "--scripted", "--quiet", "--record", str(record), "--json", str(tmp_path / "s.json"))
    assert f"--record {record}" in _one_line_error(proc, "demo")
    assert "Meshcat" not in proc.stdout and time.monotonic() - t0 < 30  # no simulation ran
    assert not (tmp_path / "s.json").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_demo_refuses_a_read_only_folder_at_once(tmp_path, run_goflow):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        proc = run_goflow("demo", "--scripted", "--quiet", "--json", str(locked / "missing" / "s.json"))
        assert "--json" in _one_line_error(proc, "demo")
    finally:
        locked.chmod(0o700)


def test_json_and_out_paths_are_refused_before_the_work(tmp_path, run_goflow):
    blocked = _under_a_file(tmp_path)
    for command, args in [
        ("evaluate", ["--gear", "small", "--episodes", "1", "--json", str(blocked / "e.json")]),
        ("bench", ["perception", "--json", str(blocked / "b.json")]),
        ("collect", ["--env", "goflow/PointMass-v0", "--episodes", "2", "--out", str(blocked / "d.npz")]),
    ]:
        t0 = time.monotonic()
        line = _one_line_error(run_goflow(command, *args), command)
        assert str(blocked) in line and time.monotonic() - t0 < 30, line


def test_estimate_refuses_non_finite_options_and_bad_outputs_at_once(tmp_path, run_goflow):
    data = tmp_path / "d.npz"
    proc = run_goflow("collect", "--env", "goflow/PointMass-v0", "--episodes", "2", "--steps", "4", "--out", str(data))
    assert proc.returncode == 0, proc.stderr
    line = _one_line_error(
        run_goflow(
            "estimate",
            "--data",
            str(data),
            "--method",
            "nfpde-softmax",
            "--method-kwarg",
            "beta=nan",
            "--out",
            str(tmp_path / "e.json"),
        ),
        "estimate",
    )
    assert "beta=nan" in line
    line = _one_line_error(
        run_goflow(
            "estimate", "--data", str(data), "--method", "dropo", "--out", str(_under_a_file(tmp_path) / "e.json")
        ),
        "estimate",
    )
    assert "--out" in line
    assert not (tmp_path / "e.json").exists()


def test_key_value_values_are_strict_json_or_strings():
    from goflow_common.errors import InputError
    from goflow_common.config import key_values

    assert key_values(["a=1", "b=x", "c=[1, 2.5]", "d=true", "e=null", "f=a=b"], "--x") == {
        "a": 1,
        "b": "x",
        "c": [1, 2.5],
        "d": True,
        "e": None,
        "f": "a=b",
    }
    for bad in (["nokey"], ["=1"], ["a=1", "a=2"], ["a=NaN"], ["a=-Infinity"], ["a=inf"], ["a=[1, NaN]"]):
        with pytest.raises(InputError):
            key_values(bad, "--x")


def test_demo_writes_the_summary_even_when_the_recording_cannot_be_saved(tmp_path, monkeypatch, capsys):
    import shutil

    import assembly.demo
    import assembly.station
    from goflow_cli import main

    record, summary_path = tmp_path / "rec" / "r.html", tmp_path / "out" / "s.json"
    summary = {
        "gears": {"small": {"inserted": True, "lateral_error_m": 1e-4, "height_error_m": 1e-8, "time_s": 9.0}},
        "sim_time_s": 9.0,
        "wall_time_s": 1.0,
    }

    class FakeMeshcat:
        def web_url(self):
            return "http://localhost:7000"

    def fake_run(config, meshcat=None, record=None, realtime=False, progress=True):
        Path(record).write_text("<html></html>")
        shutil.rmtree(tmp_path / "rec")  # the destination vanishes while the assembly runs
        return summary

    monkeypatch.setattr(assembly.station, "make_meshcat", FakeMeshcat)
    monkeypatch.setattr(assembly.demo, "run_assembly", fake_run)
    assert main(["demo", "--scripted", "--quiet", "--record", str(record), "--json", str(summary_path)]) == 2
    out, err = capsys.readouterr()
    assert "small" in out and json.loads(summary_path.read_text()) == summary
    assert err.startswith(f"goflow demo: --record {record}: the recording was not saved") and err.count("\n") == 1


# ---------------------------------------------------------------------------------------------
# A failed command leaves nothing behind; messages never suggest unsafe loads
# ---------------------------------------------------------------------------------------------


def test_a_refused_seed_leaves_no_run_folder_or_lock(tmp_path, run_goflow):
    for folder in ([], ["--out-dir", str(tmp_path / "a" / "run")]):  # the default under runs/, or named
        line = _one_line_error(
            run_goflow("train", "--env", "goflow/Toy2D-v0", "--method", "lsdr", "--seed", "-1", *folder, cwd=tmp_path),
            "train",
        )
        assert "seed = -1" in line
    assert list(tmp_path.iterdir()) == []


def test_diagnose_of_a_bad_log_leaves_no_report_folder(tmp_path, run_goflow):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a log")
    for model in ("arm", "perception"):
        line = _one_line_error(
            run_goflow("diagnose", "--model", model, "--log", bad, "--out-dir", tmp_path / "reports" / model),
            "diagnose",
        )
        assert str(bad) in line and "pickle" not in line.replace("pickled", "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]


def test_skill_train_with_bad_settings_leaves_no_runs_folder(tmp_path, run_goflow):
    runs = tmp_path / "skill-runs"
    line = _one_line_error(
        run_goflow("skill", "train", "--gear", "small", "--steps", "-1", "--runs", runs), "skill train"
    )
    assert "total_steps = -1" in line
    line = _one_line_error(
        run_goflow("skill", "train", "--gear", "small", "--refine-steps", "-5", "--runs", runs), "skill train"
    )
    assert "--refine-steps -5" in line
    assert not runs.exists()


def test_a_failure_after_the_output_checks_removes_the_folders_they_made(tmp_path, run_goflow):
    """The output folders are made before the work; the work failing removes them again."""
    out = tmp_path / "logs" / "deep" / "x.npz"
    line = _one_line_error(
        run_goflow("sim2real", "make-log", "--effect", "coulomb=9", "--out", out), "sim2real make-log"
    )
    assert "coulomb" in line and not (tmp_path / "logs").exists()


def test_a_garbage_dataset_gets_our_one_line_message(tmp_path, run_goflow):
    from goflow_common.errors import FileFormatError
    from learning.estimation.dataset import load_dataset

    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"\x80\x04 not an archive")
    line = _one_line_error(
        run_goflow("estimate", "--data", garbage, "--method", "dropo", "--out", tmp_path / "e" / "e.json"), "estimate"
    )
    assert str(garbage) in line and "allow_pickle" not in line and "pickle.load" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.npz"]
    with pytest.raises(FileFormatError, match="not a readable .npz archive"):
        load_dataset(garbage)


# ---------------------------------------------------------------------------------------------
# One spelling per concept, every flag honoured or refused
# ---------------------------------------------------------------------------------------------


def test_version(run_goflow):
    from importlib.metadata import version

    proc = run_goflow("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"goflow {version('goflow')}"


def test_scripted_demo_refuses_a_seed(run_goflow):
    line = _one_line_error(run_goflow("demo", "--scripted", "--seed", "3"), "demo")
    assert "--seed 3 with --scripted" in line
    line = _one_line_error(run_goflow("demo", "--scripted", "--decision", "cost"), "demo")
    assert "--decision cost with --scripted" in line


def test_default_budgets_are_whole_rounds():
    """A default `train`, `experiment` or `sweep` trains exactly its --steps: no rounding note."""
    from goflow_cli import make_parser
    from learning.experiment import ExperimentConfig, TrainConfig

    parser = make_parser(["train", "experiment", "sweep"])
    for argv in (
        ["train", "--env", "goflow/Toy2D-v0", "--method", "nodr"],
        ["experiment", "--env", "goflow/Toy2D-v0"],
        ["sweep", "--env", "goflow/Toy2D-v0", "--method", "lsdr", "--param", "alpha", "--values", "1"],
    ):
        args = parser.parse_args(argv)
        assert args.total_steps % TrainConfig(iterations_per_round=args.iterations_per_round).steps_per_round() == 0
    assert TrainConfig().total_steps % TrainConfig().steps_per_round() == 0
    assert ExperimentConfig().runs()[0].total_steps % TrainConfig().steps_per_round() == 0


def test_old_spellings_still_work_for_a_release_with_a_note(capsys):
    from goflow_cli import make_parser

    parser = make_parser()
    cases = [
        (["train", "--env", "E", "--out", "r"], "out_dir", Path("r"), "--out is now --out-dir"),
        (["experiment", "--env", "E", "--out", "r"], "out", Path("r"), "--out is now --runs"),
        (["diagnose", "--log", "l", "--out", "r"], "out_dir", Path("r"), "--out is now --out-dir"),
        (["collect", "--env", "E", "--xi", "mixture", "--out", "d.npz"], "xi", "mixture", "--xi is now --true-xi"),
        (["evaluate", "--gear", "small", "--xi", "uniform"], "xi_from", "uniform", "--xi is now --xi-from"),
        (
            ["sim2real", "make-log", "--set", "seed=1", "--set", "duration=2", "--out", "x.npz"],
            "model_kwarg",
            ["seed=1", "duration=2"],
            "--set is now --model-kwarg",
        ),
    ]
    for argv, dest, value, note in cases:
        assert getattr(parser.parse_args(argv), dest) == value, argv
        assert note in capsys.readouterr().err, argv


def test_method_kwarg_is_one_format_everywhere():
    from goflow_cli import _method_kwargs
    from goflow_common.errors import InputError

    assert _method_kwargs(["alpha=0.1"], ["goflow"]) == {"goflow": {"alpha": 0.1}}
    assert _method_kwargs(["goflow.alpha=0.1"], ["goflow"]) == {"goflow": {"alpha": 0.1}}
    assert _method_kwargs(["alpha=1", "lsdr.beta=2"], ["goflow", "lsdr"]) == {
        "goflow": {"alpha": 1},
        "lsdr": {"alpha": 1, "beta": 2},
    }
    for bad in (["adr.alpha=1"], ["alpha=1", "goflow.alpha=2"]):
        with pytest.raises(InputError):
            _method_kwargs(bad, ["goflow", "lsdr"])


def test_skill_actions_take_only_their_own_options(run_goflow):
    proc = run_goflow("skill", "show", "--gear", "small", "--steps", "3")
    assert proc.returncode == 2 and "unrecognized arguments: --steps 3" in proc.stderr
    proc = run_goflow("skill", "show", "--gear", "small", "medium")
    assert proc.returncode == 2 and "unrecognized arguments: medium" in proc.stderr
    proc = run_goflow("skill", "export", "--gear", "small")
    assert proc.returncode == 2 and "--run" in proc.stderr and "required" in proc.stderr
    proc = run_goflow("skill", "show")
    assert proc.returncode == 2 and "--gear" in proc.stderr


def test_help_is_written_for_users(run_goflow):
    internals = ("nothing imports", "DEFAULT_STEPS", "TrainConfig.", "THRESHOLD_METHODS", "appendix")
    for argv in (
        [],
        ["demo"],
        ["train"],
        ["experiment"],
        ["sweep"],
        ["skill", "train"],
        ["skill", "export"],
        ["skill", "refit"],
        ["skill", "show"],
        ["evaluate"],
        ["bench"],
        ["collect"],
        ["estimate"],
        ["diagnose"],
        ["sim2real", "make-log"],
        ["sim2real", "effects"],
    ):
        proc = run_goflow(*argv, "--help")
        assert proc.returncode == 0 and "usage: goflow" in proc.stdout, argv
        assert not [word for word in internals if word in proc.stdout], (argv, proc.stdout)


def test_train_draws_xi_from_an_estimate_file(tmp_path, run_goflow):
    from assembly.params import Param, ParamSpace
    from learning.estimation.distributions import TruncNormalProduct
    from learning.estimation.estimate_file import save_estimate
    from learning.experiment import probe_env
    from learning.samplers.estimated import EstimatedSampler

    space = probe_env("goflow/Toy2D-v0", {}).space
    dist = TruncNormalProduct(np.full(space.dim, 0.4), np.full(space.dim, 0.1))
    estimate = save_estimate(tmp_path / "e.json", EstimatedSampler.of(space, dist), "dropo", "goflow/Toy2D-v0", {})
    out = tmp_path / "run"
    proc = run_goflow(
        "train", "--env", "goflow/Toy2D-v0", "--sampler-file", estimate, "--steps", "16", "--out-dir", out, *TINY
    )
    assert proc.returncode == 0, proc.stderr
    log = json.loads((out / "log.json").read_text())
    assert log["method"] == "estimated" and log["config"]["sampler_kwargs"] == {"distribution": dist.to_dict()}
    # an estimate over another ParamSpace, or with --method too, is refused before any folder is made
    other = ParamSpace(tuple(Param(f"p{i}", 0.0, 1.0, "m") for i in range(space.dim)))  # same dim, other box
    wrong = save_estimate(tmp_path / "w.json", EstimatedSampler.of(other, dist), "dropo", "goflow/Toy2D-v0", {})
    line = _one_line_error(
        run_goflow("train", "--env", "goflow/Toy2D-v0", "--sampler-file", wrong, "--out-dir", tmp_path / "no"), "train"
    )
    assert "another ParamSpace" in line
    line = _one_line_error(
        run_goflow(
            "train",
            "--env",
            "goflow/Toy2D-v0",
            "--sampler-file",
            estimate,
            "--method",
            "nodr",
            "--out-dir",
            tmp_path / "no",
        ),
        "train",
    )
    assert "--sampler-file" in line and not (tmp_path / "no").exists()


def _bad_estimate_files(tmp_path, space):
    """Files --sampler-file refuses: garbage bytes, JSON that is no estimate, a missing file, an
    estimate over another ParamSpace of the same dimension; each with a word its message holds."""
    from assembly.params import Param, ParamSpace
    from learning.estimation.distributions import TruncNormalProduct
    from learning.estimation.estimate_file import save_estimate
    from learning.samplers.estimated import EstimatedSampler

    garbage = tmp_path / "garbage.json"
    garbage.write_bytes(b"\x80\x04\x95 not json \x00\xff")
    foreign = tmp_path / "foreign.json"
    foreign.write_text(json.dumps({"format": "something-else", "sampler": {}}))
    other = ParamSpace(tuple(Param(f"p{i}", 0.0, 1.0, "m") for i in range(space.dim)))
    dist = TruncNormalProduct(np.full(space.dim, 0.5), np.full(space.dim, 0.1))
    wrong = save_estimate(tmp_path / "wrong.json", EstimatedSampler.of(other, dist), "dropo", "x", {})
    return [
        (garbage, "invalid JSON"),
        (foreign, "not a 'goflow-estimate' file"),
        (tmp_path / "missing.json", "no goflow estimate file"),
        (wrong, "another ParamSpace"),
    ]


def test_evaluate_draws_xi_from_an_estimate_file(tmp_path, run_goflow):
    from learning.estimation.distributions import TruncNormalProduct
    from learning.estimation.estimate_file import save_estimate
    from learning.samplers.estimated import EstimatedSampler
    from learning.skill_file import load_skill

    space = load_skill("insert", "small").space
    dist = TruncNormalProduct(np.full(space.dim, 0.5), np.full(space.dim, 0.05))
    estimate = save_estimate(
        tmp_path / "e.json", EstimatedSampler.of(space, dist), "dropo", "goflow/GearInsertion-v0", {}
    )
    out = tmp_path / "res" / "e.json"
    args = ("evaluate", "--gear", "small", "--episodes", "2", "--seed", "3")
    proc = run_goflow(*args, "--sampler-file", estimate, "--json", out)
    assert proc.returncode == 0, proc.stderr
    assert f"xi from {estimate}" in proc.stdout
    result = json.loads(out.read_text())
    assert result["xi"] == "estimate" and result["xi_sampler"]["dist"] == dist.to_dict()
    assert result["sampler_file"]["file"] == str(estimate) and len(result["sampler_file"]["sha256"]) == 64
    u = space.normalize(np.array(result["xi_mean"]))  # the draws are the estimate's (near the box centre)
    assert np.all(np.abs(u - 0.5) < 0.2), u
    # refused in one line, leaving no --json file or folder: both sources, or a bad estimate
    no = tmp_path / "no" / "e.json"
    line = _one_line_error(
        run_goflow(*args, "--xi-from", "uniform", "--sampler-file", estimate, "--json", no), "evaluate"
    )
    assert "--xi-from uniform and --sampler-file" in line and "not both" in line
    for path, words in _bad_estimate_files(tmp_path, space):
        line = _one_line_error(run_goflow(*args, "--sampler-file", path, "--json", no), "evaluate")
        assert words in line and "pickle" not in line and "unsafe" not in line, line
    assert not (tmp_path / "no").exists()
