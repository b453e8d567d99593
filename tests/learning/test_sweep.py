"""learning.sweep: a sweep's config is checked when built, its experiments are named per value,
and its output folders are checked before the first run."""

import pytest

from goflow_common.errors import InputError, OutputPathError, UnknownOptionError
from learning.experiment import ExperimentConfig
from learning.ppo import PPOConfig
from learning.sweep import SweepConfig, format_sweep, run_sweep, value_label

TINY = dict(
    env="goflow/Toy2D-v0",
    seeds=1,
    workers=1,
    total_steps=16,
    iterations_per_round=1,
    eval_episodes=4,
    ppo=PPOConfig(num_envs=2, num_steps=8, num_minibatches=2, update_epochs=1),
)


def test_each_value_is_an_experiment_of_the_one_method(tmp_path):
    config = SweepConfig(
        method="goflow",
        param="alpha",
        values=(0.5, 1.0),
        method_kwargs={"steps": 3},
        experiment=ExperimentConfig(out=tmp_path / "runs", results=tmp_path / "results", **TINY),
    )
    assert config.stem() == "sweep-toy2d-v0-goflow-alpha"
    experiments = config.experiments()
    assert [e.name for e in experiments] == ["sweep-toy2d-v0-goflow-alpha-0.5", "sweep-toy2d-v0-goflow-alpha-1.0"]
    assert [e.sampler_kwargs for e in experiments] == [
        {"goflow": {"steps": 3, "alpha": 0.5}},
        {"goflow": {"steps": 3, "alpha": 1.0}},
    ]
    assert all(e.methods == ("goflow",) and e.results == tmp_path / "results" / config.stem() for e in experiments)
    named = SweepConfig(values=(1,), experiment=ExperimentConfig(name="mine"))
    assert named.stem() == "mine" and named.experiments()[0].name == "mine-1"
    assert len(SweepConfig().experiments()) == 5  # the defaults work: GoFlow's alpha over appendix A.2's values


def test_a_bad_sweep_fails_when_built():
    with pytest.raises(InputError, match="at least one value"):
        SweepConfig(values=())
    with pytest.raises(InputError, match="each value once"):
        SweepConfig(values=(1, 1))
    with pytest.raises(InputError, match="swept option"):
        SweepConfig(param="alpha", values=(1,), method_kwargs={"alpha": 2})
    with pytest.raises(InputError, match="expected one of"):
        SweepConfig(method="sac", values=(1,))
    with pytest.raises(UnknownOptionError, match="alphaa"):  # the sampler's options, checked for every value
        SweepConfig(method="lsdr", param="alphaa", values=(1,))


def test_outputs_are_checked_before_the_first_run(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    config = SweepConfig(
        method="lsdr",
        values=(0.5,),
        experiment=ExperimentConfig(out=tmp_path / "runs", results=blocker / "results", **TINY),
    )
    with pytest.raises(OutputPathError, match="a-file"):
        run_sweep(config, progress=False)
    assert not (tmp_path / "runs").exists()


def test_labels_and_table():
    assert [value_label(v) for v in (0.1, 1.0, 2, "x", [1, 2], True)] == ["0.1", "1.0", "2", "x", "[1,2]", "true"]
    sweep = {
        "env": "goflow/Toy2D-v0",
        "method": "lsdr",
        "param": "alpha",
        "steps": 16,
        "rows": [
            {"value": 0.5, "final_success_mean": 0.25, "final_success_se": 0.1, "seeds": 2},
            {"value": 1.0, "final_success_mean": 0.5, "final_success_se": 0.0, "seeds": 2},
        ],
    }
    text = format_sweep(sweep)
    assert text.splitlines()[-1] == "best alpha = 1.0 (success 0.500)"
    assert len(text.splitlines()) == 5
