"""The GoFlow protocol harness: every method runs, runs resume exactly, bad input is refused."""

import json

import numpy as np
import pytest

from goflow_common.errors import FileFormatError, RunFolderBusyError
from goflow_common.files import run_folder_lock
from learning.experiment import (
    ExperimentConfig,
    SamplerFitConfig,
    TrainConfig,
    fit_sampler,
    format_summary,
    load_run,
    plot_curves,
    experiment_summary,
    train,
)
from learning.ppo import PPOConfig
from learning.samplers.registry import METHODS, make_sampler

TINY = PPOConfig(num_envs=4, num_steps=16, num_minibatches=2, update_epochs=2)


def _config(method, out, rounds=2, **kwargs):
    return TrainConfig(
        env="goflow/Toy2D-v0",
        method=method,
        seed=1,
        ppo=TINY,
        eval_episodes=16,
        iterations_per_round=1,
        total_steps=rounds * 4 * 16,
        out=out,
        sampler_kwargs=kwargs,
    )


@pytest.mark.parametrize("method", METHODS)
def test_every_method_runs_the_protocol(method, tmp_path):
    kwargs = {"steps": 5, "entropy_samples": 256, "kl_samples": 256} if method == "goflow" else {}
    log = train(_config(method, tmp_path, **kwargs), progress=False)
    assert log["rounds"] == 2 and len(log["curve"]) == 2
    for step, success, mean_return in log["curve"]:
        assert 0.0 <= success <= 1.0 and np.isfinite(mean_return)
    assert 0.0 <= log["sampler_seconds"] <= log["seconds"]
    assert (tmp_path / "checkpoint.pt").exists()
    assert json.loads((tmp_path / "log.json").read_text())["rounds"] == 2


def test_interrupted_run_resumes_and_matches(tmp_path):
    kwargs = {"steps": 5, "entropy_samples": 256, "kl_samples": 256}
    full = train(_config("goflow", tmp_path / "full", rounds=3, **kwargs), progress=False)
    train(_config("goflow", tmp_path / "cut", rounds=1, **kwargs), progress=False)  # "killed"
    resumed = train(_config("goflow", tmp_path / "cut", rounds=3, **kwargs), progress=False)
    assert resumed["curve"] == full["curve"]


def test_a_later_stage_switches_goflow_to_its_own_training_episodes(tmp_path, monkeypatch):
    kwargs = {"steps": 5, "entropy_samples": 256, "kl_samples": 256}
    train(_config("goflow", tmp_path, rounds=1, **kwargs), progress=False)
    seen = []
    from learning.samplers.goflow import GoFlowSampler

    original = GoFlowSampler.update

    def spy(self, xi, returns):
        seen.append(len(returns))
        assert set(np.unique(returns)) <= {0.0, 1.0}  # sampler_signal="success"
        return original(self, xi, returns)

    monkeypatch.setattr(GoFlowSampler, "update", spy)
    stage2 = _config("goflow", tmp_path, rounds=3, **kwargs)
    stage2.sampler_batch, stage2.sampler_signal = "training", "success"
    stage2.iterations_per_round = 2  # rounds of 128 steps: one more round reaches 3 x 64 steps
    log = train(stage2, progress=False)
    # Toy2D episodes last one step: the training phase's 2 x 4 envs x 16 steps are 128 episodes
    # drawn from the flow, while the validation batch holds 16 uniform ones.
    assert seen == [128]
    assert log["rounds"] == 2 and log["stages"][0]["from_round"] == 1
    assert [c[0] for c in log["curve"]] == [64, 192] and log["steps"] == 192
    assert log["config"]["sampler_batch"] == "training"


def test_sampler_batch_is_checked_per_method():
    assert TrainConfig(method="adr").sampler_batch == "training"
    assert TrainConfig(method="goflow").sampler_batch == "validation"
    with pytest.raises(ValueError, match="sampler_batch = 'test'"):
        TrainConfig(method="goflow", sampler_batch="test")
    with pytest.raises(ValueError, match="DORAEMON"):
        TrainConfig(method="doraemon", sampler_batch="training")
    with pytest.raises(ValueError, match="ADR"):
        TrainConfig(method="adr", sampler_batch="validation")
    with pytest.raises(ValueError, match="sampler_signal = 'score'"):
        TrainConfig(method="goflow", sampler_signal="score")
    with pytest.raises(ValueError, match="doraemon compares returns"):
        TrainConfig(method="doraemon", sampler_signal="success")


def test_fit_sampler_moves_only_the_sampler_and_resumes(tmp_path):
    import torch

    kwargs = {"steps": 5, "entropy_samples": 256, "kl_samples": 256}
    for name in ("full", "cut"):
        train(_config("goflow", tmp_path / name, rounds=1, **kwargs), progress=False)
    before = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=True)
    full = fit_sampler(tmp_path / "full", SamplerFitConfig(rounds=3, episodes=16), progress=False)
    after = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=True)
    assert [row[0] for row in full["sampler_fit"]] == [1, 2, 3]
    assert all(0.0 <= row[1] <= 1.0 and np.isfinite(row[3]) for row in full["sampler_fit"])
    assert after["agent"]["config"] == before["agent"]["config"]
    for key, value in before["agent"]["actor"].items():  # the policy is frozen
        assert torch.equal(value, after["agent"]["actor"][key])
    assert after["log"]["rounds"] == 1
    # the shipped sampler is the evaluated one with the highest success (ties: highest entropy)
    rows = full["sampler_fit"]
    best = max(rows, key=lambda row: (row[1], row[3]))
    assert full["sampler_fit_best"] == {"round": best[0], "success": best[1], "entropy": best[3]}
    assert after["sampler"] == after["sampler_fit_best"]["sampler"]
    assert (after["sampler"] == before["sampler"]) == (best[0] == 1)
    fit_sampler(tmp_path / "cut", SamplerFitConfig(rounds=1, episodes=16), progress=False)  # "killed"
    resumed = fit_sampler(tmp_path / "cut", SamplerFitConfig(rounds=3, episodes=16), progress=False)
    assert resumed["sampler_fit"] == full["sampler_fit"]


def test_fit_sampler_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint.pt"):
        fit_sampler(tmp_path / "nothing", SamplerFitConfig(), progress=False)
    train(_config("fulldr", tmp_path, rounds=1), progress=False)
    with pytest.raises(ValueError, match="gradient-updated sampler"):
        fit_sampler(tmp_path, SamplerFitConfig(rounds=1), progress=False)
    with pytest.raises(ValueError, match="rounds = 0; expected an integer >= 1"):
        SamplerFitConfig(rounds=0)
    with pytest.raises(ValueError, match="signal = 'reward'"):
        SamplerFitConfig(signal="reward")


def test_experiment_sampler_signal_reaches_the_methods_that_can_use_it():
    runs = ExperimentConfig(methods=("goflow", "lsdr", "adr", "doraemon"), seeds=1, sampler_signal="success").runs()
    assert {r.method: r.sampler_signal for r in runs} == {
        "goflow": "success",
        "lsdr": "success",
        "adr": "return",
        "doraemon": "return",
    }


def test_first_seed_adds_later_seeds_to_a_grid_in_their_own_folders():
    runs = ExperimentConfig(methods=("fulldr",), seeds=2, first_seed=3, name="grid").runs()
    assert [r.seed for r in runs] == [3, 4]
    assert [r.out.name for r in runs] == ["seed3", "seed4"]
    with pytest.raises(ValueError, match="first_seed = -1"):
        ExperimentConfig(first_seed=-1)


def test_checkpoint_of_another_param_space_is_refused(tmp_path):
    train(_config("fulldr", tmp_path, rounds=1), progress=False)
    other = _config("fulldr", tmp_path, rounds=2)
    other.env_kwargs = {"half_extent": 2.0}
    with pytest.raises(ValueError, match="another ParamSpace"):
        train(other, progress=False)


def test_bad_input():
    with pytest.raises(ValueError, match="unknown sampler 'sac'"):
        TrainConfig(method="sac")
    with pytest.raises(ValueError, match="unknown sampler"):
        make_sampler("sac", None, 1.0)
    with pytest.raises(ValueError, match="total_steps"):
        TrainConfig(total_steps=0)
    with pytest.raises(ValueError, match="unknown sampler"):
        ExperimentConfig(methods=("goflow", "magic"))


def test_summary_format_and_plot(tmp_path):
    logs = [
        {"method": m, "curve": [[10, s, -100 * s], [20, s + 0.1, 100 * s]], "seconds": 10.0, "sampler_seconds": 0.2}
        for m in ("goflow", "fulldr")
        for s in (0.1, 0.3)
    ]
    summary = experiment_summary(logs, 20, "goflow/Toy2D-v0")
    assert set(summary) == {"env", "steps", "methods"}
    g = summary["methods"]["goflow"]
    assert g["seeds"] == 2 and g["final_success_mean"] == pytest.approx(0.3)
    assert g["final_success_se"] == pytest.approx(np.std([0.2, 0.4], ddof=1) / np.sqrt(2))
    assert g["curve"][0] == [10, pytest.approx(0.2), pytest.approx(np.std([0.1, 0.3], ddof=1) / np.sqrt(2))]
    assert g["sampler_time_share"] == pytest.approx(0.02)
    # the uniform-box return beside the success: informative where no method succeeds yet
    assert g["final_return_mean"] == pytest.approx(20.0)
    assert g["final_return_se"] == pytest.approx(np.std([10.0, 30.0], ddof=1) / np.sqrt(2))
    assert g["return_curve"][0][:2] == [10, pytest.approx(-20.0)]
    table = format_summary(summary).splitlines()
    goflow_row = next(line for line in table if line.startswith("goflow "))
    assert "0.300 +-" in goflow_row and "20.0 +- 10.0" in goflow_row and goflow_row.endswith("2.0%")
    plot_curves(summary, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 1000


def test_a_checkpoint_of_another_layout_is_refused(tmp_path):
    """Toy2D's layouts share one ParamSpace: the run's env options tell them apart."""
    train(_config("fulldr", tmp_path, rounds=1), progress=False)
    other = _config("fulldr", tmp_path, rounds=2)
    other.env_kwargs = {"layout": "line"}
    with pytest.raises(
        ValueError, match=r"checkpoint of another run \(env_kwargs: checkpoint \{\} vs now \{'layout': 'line'\}"
    ):
        train(other, progress=False)


def test_a_second_writer_is_refused_at_once(tmp_path):
    with run_folder_lock(tmp_path / "run"):
        with pytest.raises(RunFolderBusyError, match="in use by another run"):
            train(_config("fulldr", tmp_path / "run", rounds=1), progress=False)
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_a_crafted_checkpoint_does_not_run_code(tmp_path):
    import os

    import torch

    class Exploit:
        def __reduce__(self):
            return (os.system, (f"touch {tmp_path / 'pwned'}",))

    (tmp_path / "run").mkdir()
    torch.save({"agent": {}, "sampler": {}, "space": {}, "log": Exploit()}, tmp_path / "run" / "checkpoint.pt")
    with pytest.raises(FileFormatError, match="refused"):
        load_run(tmp_path / "run")
    with pytest.raises(FileFormatError, match="refused"):
        train(_config("fulldr", tmp_path / "run", rounds=1), progress=False)
    assert not (tmp_path / "pwned").exists()


def test_options_are_checked_before_any_work(tmp_path):
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['alpah'\]"):
        _config("goflow", tmp_path, alpah=0.1)
    with pytest.raises(ValueError, match="alpha = nan"):
        _config("goflow", tmp_path, alpha=float("nan"))
    assert not any(tmp_path.iterdir())


def test_results_do_not_go_to_the_committed_tables_by_default():
    from pathlib import Path

    assert ExperimentConfig().results == Path("runs/results")
    assert TrainConfig(total_steps=4000).steps_per_round() == 2 * 8 * 128  # 4000 steps train 2048
