"""Hyperparameter sweeps: one experiment per value of one sampler option (the paper's appendix A.2)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from goflow_common.checks import check_choice
from goflow_common.errors import InputError
from goflow_common.files import check_output_dir, write_json
from learning.execution import Backend, run_grid
from learning.experiment import ExperimentConfig, experiment_backend, experiment_jobs, probe_env, write_experiment
from learning.samplers.registry import METHODS

__all__ = ["SweepConfig", "run_sweep", "format_sweep", "value_label"]


@dataclass
class SweepConfig:
    """One method, one of its sampler options, several values: one experiment per value.

    The sweep writes `<results>/<stem>.json` (a row per value) and `<stem>.png`; each value's own
    experiment writes `<results>/<stem>/<stem>-<value>.json` and its runs `<out>/<stem>-<value>/`.
    """

    method: str = "goflow"  # the sampler whose option is swept
    param: str = "alpha"  # the swept option, a keyword of the method's sampler
    values: tuple[Any, ...] = (0.1, 0.5, 1.0, 1.5, 2.0)  # the values tried, one experiment each
    method_kwargs: dict[str, Any] = field(default_factory=dict)  # the method's other options, fixed
    # env, budget, seeds, workers, out and results of every value's experiment; its `methods` and
    # `sampler_kwargs` are set per value, its `name` (if given) is the sweep's file stem
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)

    def __post_init__(self) -> None:
        check_choice(self.method, METHODS, "SweepConfig.method")
        self.values = tuple(self.values)
        if not self.values:
            raise InputError("SweepConfig.values = (); expected at least one value")
        labels = [value_label(v) for v in self.values]
        if len(set(labels)) < len(labels):
            raise InputError(f"SweepConfig.values = {list(self.values)}; expected each value once")
        if self.param in self.method_kwargs:
            raise InputError(
                f"SweepConfig.method_kwargs sets {self.param!r}, the swept option; expected it only in values"
            )
        for experiment in self.experiments():
            experiment.runs()  # every value's sampler options are checked now, before any run

    def stem(self) -> str:
        """The sweep's file stem: the experiment's name, else sweep-<env>-<method>-<param>."""
        env = self.experiment.env.split("/")[-1].lower()
        return self.experiment.name or f"sweep-{env}-{self.method}-{self.param}"

    def experiments(self) -> list[ExperimentConfig]:
        """The experiment of each value, in the order of `values`."""
        stem = self.stem()
        return [
            dataclasses.replace(
                self.experiment,
                methods=(self.method,),
                sampler_kwargs={self.method: {**self.method_kwargs, self.param: v}},
                name=f"{stem}-{value_label(v)}",
                results=Path(self.experiment.results) / stem,
            )
            for v in self.values
        ]


def value_label(value: Any) -> str:
    """A swept value as it appears in file names: strings as they are, the rest as compact JSON."""
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


def run_sweep(
    config: SweepConfig, progress: bool = True, command: str = "", backend: Backend | None = None
) -> dict[str, Any]:
    """Run the experiments of every value as one grid on `backend` (default: the experiment's
    process pool, or Ray at its `ray`), each run resuming from its checkpoint; write each value's
    experiment, then `<results>/<stem>.json` with `command` as provenance and `<stem>.png`; return
    the sweep: {"env", "env_kwargs", "method", "param", "steps", "rows": [{"value",
    "final_success_mean", "final_success_se", "seeds"}, ...], "command", "figures"}.

    The environment and its options are checked, then the backend is started (ClusterError if a
    Ray cluster cannot be reached), then the output folders (OutputPathError if one cannot be
    written), before the first run. A failed run does not stop the others (GridError at the end).
    """
    from learning.plots import plot_sweep

    probe_env(config.experiment.env, config.experiment.env_kwargs)
    stem, results = config.stem(), Path(config.experiment.results)
    experiments = config.experiments()
    with backend or experiment_backend(config.experiment) as grid:
        check_output_dir(results / stem, "sweep results folder")
        check_output_dir(config.experiment.out, "run folder")
        jobs = [
            [
                dataclasses.replace(job, name=f"{config.param}={value_label(value)} {job.name}")
                for job in experiment_jobs(e)
            ]
            for value, e in zip(config.values, experiments)
        ]
        logs = run_grid([job for value_jobs in jobs for job in value_jobs], grid, progress, f"sweep {stem}")
    rows, first = [], 0
    for value, experiment, value_jobs in zip(config.values, experiments, jobs):
        summary = write_experiment(experiment, logs[first : first + len(value_jobs)], command)
        first += len(value_jobs)
        res = summary["methods"][config.method]
        rows.append(
            {
                "value": value,
                "final_success_mean": res["final_success_mean"],
                "final_success_se": res["final_success_se"],
                "seeds": res["seeds"],
            }
        )
    figure = results / f"{stem}.png"
    sweep = {
        "env": config.experiment.env,
        "env_kwargs": dict(config.experiment.env_kwargs),
        "method": config.method,
        "param": config.param,
        "steps": config.experiment.total_steps,
        "rows": rows,
        "command": command,
        "figures": [str(figure)],
    }
    write_json(results / f"{stem}.json", sweep)
    plot_sweep(sweep, figure)
    return sweep


def format_sweep(sweep: dict[str, Any]) -> str:
    """A table of final success per value, and the best value."""
    lines = [
        f"{sweep['env']}  {sweep['method']} {sweep['param']} ({sweep['steps']} steps per run)",
        f"{sweep['param']:<12} {'final success':>16} {'seeds':>6}",
    ]
    for row in sweep["rows"]:
        lines.append(
            f"{value_label(row['value']):<12} {row['final_success_mean']:>7.3f} +- "
            f"{row['final_success_se']:<5.3f} {row['seeds']:>6}"
        )
    best = max(sweep["rows"], key=lambda r: r["final_success_mean"])
    lines.append(f"best {sweep['param']} = {value_label(best['value'])} (success {best['final_success_mean']:.3f})")
    return "\n".join(lines)
