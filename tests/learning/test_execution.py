"""learning.execution: grids on this process, a process pool and a local Ray (2 CPUs) give the same
results; a job whose worker dies is run again and resumes; a failed job does not lose the others;
--ray is checked, and a cluster that is not there fails in one line before anything is written."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch

from goflow_common.errors import ClusterError, GridError, InputError
from learning.execution import (
    InlineBackend,
    Job,
    PoolBackend,
    RayBackend,
    make_backend,
    parse_ray_address,
    run_grid,
    run_jobs,
)
from learning.experiment import ExperimentConfig, TrainConfig, run_experiment, train
from learning.ppo import PPOConfig

GOFLOW = Path(sys.executable).parent / "goflow"
# Toy2D runs of 6 rounds x 512 steps (~3 s each): long enough to learn something (success > 0)
PPO = PPOConfig(num_envs=4, num_steps=64, num_minibatches=2, update_epochs=2, learning_rate=0.003, init_log_std=-1.0)
GRID = dict(
    env="goflow/Toy2D-v0",
    methods=("fulldr", "lsdr"),
    seeds=1,
    total_steps=6 * 512,
    iterations_per_round=2,
    eval_episodes=64,
    ppo=PPO,
)
TIMING = ("sampler_time_share",)  # wall-time shares: the only fields that differ between two runs


def _same_results(a: dict, b: dict) -> dict:
    """The experiment file without what differs by nature (timing shares, command, figure paths)."""

    def strip(summary):
        out = {k: v for k, v in summary.items() if k not in ("command", "figures")}
        out["methods"] = {m: {k: v for k, v in r.items() if k not in TIMING} for m, r in summary["methods"].items()}
        return out

    assert strip(a) == strip(b)
    return strip(a)


def _weights(run: Path) -> dict:
    return torch.load(run / "checkpoint.pt", weights_only=True)["agent"]["actor"]


def _same_weights(a: Path, b: Path) -> None:
    wa, wb = _weights(a), _weights(b)
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


# ---------------------------------------------------------------------------------------------
# --ray values, backends, failures (no Ray needed)
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "value", ["local", "auto", "10.0.0.5:6379", "head-node.cluster:6379", "[::1]:6379", "localhost:1"]
)
def test_good_ray_addresses(value):
    assert parse_ray_address(value) == value


@pytest.mark.parametrize(
    "value",
    [
        "",
        "Local",
        "head",
        "head:",
        ":6379",
        "head:port",
        "head:0",
        "head:65536",
        "head:-1",
        "ray://head:10001",
        "http://head:6379",
        "a b:6379",
        "head:6379 ",
        "[::1:6379",
        "[nope]:6379",
        "-head:6379",
        "head:６３７９",
        "head\n:6379",
        None,
        6379,
    ],
)
def test_malformed_ray_addresses_are_refused(value):
    with pytest.raises(InputError, match=r"--ray = .*expected 'local'|--ray = .*a URL"):
        parse_ray_address(value)
    with pytest.raises(InputError):
        make_backend(value if value is not None else 1, 2)


def test_make_backend():
    assert isinstance(make_backend(None, 2), PoolBackend) and make_backend(None, 2).workers == 2
    assert isinstance(make_backend(None, 1, inline=True), InlineBackend)
    assert isinstance(make_backend(None, 1), PoolBackend)
    local = make_backend("local", 3)
    assert isinstance(local, RayBackend) and local.workers == 3
    assert make_backend("10.0.0.5:6379", 3).workers is None  # a cluster's own CPUs decide
    with pytest.raises(InputError, match="--workers = 0"):
        make_backend(None, 0)
    with pytest.raises(InputError, match="ExperimentConfig.ray = 'nowhere'"):
        ExperimentConfig(ray="nowhere")


def test_ray_is_imported_only_when_asked_for(monkeypatch):
    """The pool backend and every command work without the `ray` package: nothing imports it until
    a RayBackend starts, and then its absence is a one-line ClusterError saying how to install it."""
    code = (
        "import sys, goflow_cli, learning.execution, learning.experiment, learning.sweep, learning.skill_training; "
        "goflow_cli.make_parser(); assert 'ray' not in sys.modules, 'ray was imported'"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails as if it were not installed
    with pytest.raises(ClusterError, match=r"--ray needs the ray package.*pip install -e \"\.\[ray\]\""):
        with RayBackend("local"):
            pass


@pytest.mark.parametrize("backend", [InlineBackend(), PoolBackend(2, retries=1)], ids=["inline", "pool"])
def test_a_failed_job_does_not_lose_the_others(backend):
    jobs = [Job("ok-1", int, ("1",)), Job("bad", int, ("x",)), Job("ok-2", int, ("2",))]
    seen = []
    with pytest.raises(GridError, match=r"1 of 3 jobs failed.*bad: ValueError: invalid literal") as err:
        run_grid(jobs, backend, progress=False, on_result=lambda i, value: seen.append((i, value)))
    assert err.value.results == [1, None, 2] and list(err.value.failures) == ["bad"]
    assert sorted(seen) == [(0, 1), (2, 2)]


def test_the_pool_runs_again_a_job_whose_worker_died():
    """os._exit kills the pool worker in the middle of the job: it is run again (retries=1), then
    reported failed, and the other job's result is kept."""
    outcomes = run_jobs(
        [Job("dies", os._exit, (3,)), Job("ok", int, ("5",))], PoolBackend(2, retries=1), progress=False
    )
    assert [o.status for o in outcomes] == ["failed", "done"] and outcomes[1].value == 5
    assert outcomes[0].attempts == 2 and "worker process" in outcomes[0].error


# ---------------------------------------------------------------------------------------------
# Ray: a local cluster with 2 CPUs, shared by the tests below
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_backend():
    ray = pytest.importorskip("ray")
    # the test's own job functions travel by value (the workers cannot import this test module)
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with RayBackend("local", workers=2) as backend:
        yield backend


@pytest.mark.slow
def test_an_experiment_gives_the_same_json_on_the_pool_and_on_ray(ray_backend, tmp_path):
    pool = run_experiment(
        ExperimentConfig(**GRID, workers=2, out=tmp_path / "pool", results=tmp_path / "pool-results"), progress=False
    )
    on_ray = run_experiment(
        ExperimentConfig(**GRID, out=tmp_path / "ray", results=tmp_path / "ray-results"),
        progress=False,
        backend=ray_backend,
    )
    results = _same_results(pool, on_ray)
    assert max(r["final_success_mean"] for r in results["methods"].values()) > 0  # something was learned
    assert _same_results(
        json.loads((tmp_path / "pool-results" / "toy2d.json").read_text()),
        json.loads((tmp_path / "ray-results" / "toy2d.json").read_text()),
    )
    for method in GRID["methods"]:
        _same_weights(tmp_path / "pool" / "toy2d" / method / "seed0", tmp_path / "ray" / "toy2d" / method / "seed0")


def _train_killed_once(config: TrainConfig, marker: str) -> dict:
    """Train `config`; on the first attempt (no `marker` yet) this worker process kills itself with
    SIGKILL as soon as the first round is checkpointed, mid-run."""
    if not os.path.exists(marker):

        def watch() -> None:
            log = Path(config.out) / "log.json"
            while True:
                try:
                    if json.loads(log.read_text())["rounds"] >= 1:
                        break
                except (OSError, ValueError, KeyError):
                    pass
                time.sleep(0.002)
            Path(marker).touch()
            os.kill(os.getpid(), signal.SIGKILL)

        threading.Thread(target=watch, daemon=True).start()
    return train(config, progress=False)


def test_a_killed_worker_is_retried_from_its_checkpoint_and_matches(ray_backend, tmp_path):
    run = dict(
        env="goflow/Toy2D-v0",
        method="lsdr",
        seed=3,
        ppo=PPO,
        eval_episodes=64,
        iterations_per_round=2,
        total_steps=6 * 512,
    )
    marker = tmp_path / "killed-once"
    outcomes = run_jobs(
        [
            Job("killed", _train_killed_once, (TrainConfig(**run, out=tmp_path / "killed"), str(marker))),
            Job("other", train, (TrainConfig(**{**run, "seed": 4}, out=tmp_path / "other"),), {"progress": False}),
        ],
        ray_backend,
        progress=False,
    )
    assert marker.exists() and [o.status for o in outcomes] == ["done", "done"], outcomes
    assert outcomes[0].attempts == 2 and outcomes[1].attempts == 1
    whole = train(TrainConfig(**run, out=tmp_path / "whole"), progress=False)  # uninterrupted, in this process
    assert outcomes[0].value["rounds"] == 6 and outcomes[0].value["curve"] == whole["curve"]
    assert outcomes[0].value["train_curve"] == whole["train_curve"]
    _same_weights(tmp_path / "killed", tmp_path / "whole")


def _die_after(seconds: float) -> None:
    time.sleep(seconds)
    os._exit(3)


def test_ray_reports_a_failed_job_and_a_worker_that_keeps_dying(ray_backend):
    retry_once = RayBackend("local", retries=1)  # the connection of `ray_backend` is used and kept
    outcomes = run_jobs(
        [Job("bad", int, ("x",)), Job("dies", _die_after, (0.5,)), Job("ok", int, ("7",))], retry_once, progress=False
    )
    assert [o.status for o in outcomes] == ["failed", "failed", "done"] and outcomes[2].value == 7
    assert outcomes[0].error.startswith("ValueError: invalid literal") and outcomes[0].attempts == 1
    assert outcomes[1].attempts == 2 and "(after 2 attempts)" in outcomes[1].error
    with pytest.raises(ClusterError, match="job gpu needs 1 GPUs; the Ray cluster has 0"):  # not left waiting
        run_jobs([Job("gpu", int, ("1",), num_gpus=1)], retry_once, progress=False)


# ---------------------------------------------------------------------------------------------
# Skills: gears as jobs, evaluation episodes split into jobs
# ---------------------------------------------------------------------------------------------


def _tiny_recipe():
    from learning.skill_training import SkillRecipe

    return SkillRecipe(
        total_steps=20,
        eval_episodes=2,
        iterations_per_round=1,
        refine_steps=0,
        fit_rounds=0,
        refit=None,
        sampler_kwargs={"steps": 3, "entropy_samples": 64, "kl_samples": 64, "kl_pool": 128, "report_samples": 256},
        ppo=PPOConfig(num_envs=2, num_steps=10, num_minibatches=2, update_epochs=1),
    )


@pytest.fixture(scope="module")
def small_skill(tmp_path_factory):
    """The small gear's tiny skill, trained in this process (`train_skills` of one gear)."""
    from learning.skill_training import train_skills

    runs = tmp_path_factory.mktemp("skills")
    (skill,) = train_skills("insert", ["small"], _tiny_recipe(), runs=runs, progress=False)
    return skill, runs / "insert-small.pt"


def test_skill_gears_train_as_jobs_and_match_a_single_run(small_skill, ray_backend, tmp_path):
    from learning.skill_training import train_skills

    skills = train_skills(
        "insert", ["medium", "small"], _tiny_recipe(), runs=tmp_path, backend=ray_backend, progress=False
    )
    assert [(s.name, s.gear) for s in skills] == [("insert", "medium"), ("insert", "small")]
    assert (tmp_path / "insert-medium.pt").is_file() and (tmp_path / "insert-small.pt").is_file()
    for key, value in small_skill[0].agent.state_dict()["actor"].items():  # the same as trained here
        assert torch.equal(value, skills[1].agent.state_dict()["actor"][key])
    with pytest.raises(ValueError, match="distinct gears"):
        train_skills("insert", ["small", "small"], runs=tmp_path)
    with pytest.raises(ValueError, match="names one skill file"):
        train_skills("insert", ["small", "medium"], runs=tmp_path, out=tmp_path / "x.pt")


def test_evaluation_split_into_jobs_is_the_same_on_every_backend(small_skill, ray_backend):
    from learning.skill_evaluation import evaluate_skill, evaluate_skill_jobs

    skill, path = small_skill
    args = dict(variant="fast", xi="uniform", episodes=5, seed=2)

    def result(evaluation):
        return {k: v for k, v in evaluation.to_json().items() if k != "seconds"}

    whole = result(evaluate_skill(skill, **args))
    assert result(evaluate_skill_jobs(path, **args)) == whole  # one job: the same episodes as evaluate_skill
    split = [
        result(evaluate_skill_jobs(path, **args, jobs=3, backend=backend))
        for backend in (InlineBackend(), PoolBackend(2), ray_backend)
    ]
    assert split[0] == split[1] == split[2] and split[0]["jobs"] == 3 and split[0]["episodes"] == 5
    with pytest.raises(ValueError, match="jobs = 6; expected at most episodes = 5"):
        evaluate_skill_jobs(path, **args, jobs=6)


# ---------------------------------------------------------------------------------------------
# The command line
# ---------------------------------------------------------------------------------------------

TINY_CLI = [
    "--env",
    "goflow/Toy2D-v0",
    "--methods",
    "fulldr",
    "--seeds",
    "1",
    "--steps",
    "16",
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


def _run(*args):
    return subprocess.run([str(GOFLOW), *args], capture_output=True, text=True, timeout=300)


def _one_line_error(proc, command):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"goflow {command}: ") and "Traceback" not in proc.stderr, (
        proc.stderr
    )
    return lines[0]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_cluster_at_the_address_is_one_line_and_writes_nothing(tmp_path, run_goflow):
    address = f"127.0.0.1:{_free_port()}"
    out, results = tmp_path / "runs", tmp_path / "results"
    line = _one_line_error(
        run_goflow("experiment", *TINY_CLI, "--ray", address, "--runs", str(out), "--results", str(results)),
        "experiment",
    )
    assert f"--ray {address}: no Ray cluster answers there" in line and "ray start --head" in line
    line = _one_line_error(
        run_goflow(
            "sweep",
            "--method",
            "lsdr",
            "--param",
            "alpha",
            "--values",
            "0.5",
            *TINY_CLI[:2],
            *TINY_CLI[4:],
            "--ray",
            address,
            "--runs",
            str(out),
            "--results",
            str(results),
        ),
        "sweep",
    )
    assert "no Ray cluster answers there" in line
    line = _one_line_error(
        run_goflow(
            "evaluate", "--gear", "medium", "--episodes", "2", "--ray", address, "--json", str(results / "eval.json")
        ),
        "evaluate",
    )
    assert "no Ray cluster answers there" in line
    assert not out.exists() and not results.exists()


def test_malformed_ray_values_are_one_line_errors(tmp_path, run_goflow):
    out = tmp_path / "runs"
    line = _one_line_error(run_goflow("experiment", *TINY_CLI, "--ray", "head-node", "--runs", str(out)), "experiment")
    assert "ray = 'head-node'; expected 'local'" in line
    line = _one_line_error(
        run_goflow("skill", "train", "--gear", "small", "--ray", "ray://head:10001", "--runs", str(out)), "skill train"
    )
    assert "a URL is not accepted" in line
    line = _one_line_error(run_goflow("evaluate", "--gear", "small", "--ray", "head:99999"), "evaluate")
    assert "--ray = 'head:99999'" in line
    proc = run_goflow("skill", "show", "--gear", "small", "medium")  # several gears are for train alone
    assert proc.returncode == 2 and "unrecognized arguments: medium" in proc.stderr
    assert not out.exists()


def test_experiment_on_a_local_ray_from_the_command_line(tmp_path):
    """`--ray local` end to end: a local Ray with --workers CPUs, the grid's bar with per-run
    states, the results file (the same results as the pool's: test_an_experiment_gives_...)."""
    pytest.importorskip("ray")
    proc = _run(
        "experiment",
        *TINY_CLI,
        "--methods",
        "fulldr",
        "lsdr",
        "--name",
        "tiny",
        "--workers",
        "2",
        "--ray",
        "local",
        "--runs",
        str(tmp_path / "runs"),
        "--results",
        str(tmp_path / "results"),
    )
    assert proc.returncode == 0, proc.stderr
    assert "running 0, done 2, retried 0, failed 0" in proc.stderr and "Traceback" not in proc.stderr
    summary = json.loads((tmp_path / "results" / "tiny.json").read_text())
    assert set(summary["methods"]) == {"fulldr", "lsdr"} and "--ray local" in summary["command"]
