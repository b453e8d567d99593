"""`goflow estimate`: one entry point over the four estimators, with the same data, the same
simulator and the same simulator budget for each."""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from assembly.transition import ParallelTransitionSim
from goflow_common.config import config_with_overrides
from learning.estimation import ESTIMATORS
from learning.estimation.budget import Budget
from learning.estimation.dataset import TransitionDataset, load_dataset
from learning.estimation.estimate_file import save_estimate
from learning.samplers.estimated import EstimatedSampler

__all__ = ["ESTIMATORS", "EstimateConfig", "estimate", "estimate_file", "min_sim_calls"]


@dataclass
class EstimateConfig:
    """One estimation run. Every `goflow estimate` flag maps to a field."""

    method: str = "nfpde-softmax"
    seed: int = 0
    sim_budget: int = 100_000  # simulator calls (one call = one logged transition stepped once)
    workers: int = 1  # simulator processes
    options: dict[str, Any] = field(default_factory=dict)  # fields of the method's config dataclass

    def __post_init__(self) -> None:
        from goflow_common.checks import check_int
        from goflow_common.errors import InputError

        if self.method not in ESTIMATORS:
            raise InputError(f"unknown estimation method {self.method!r}; expected one of {list(ESTIMATORS)}")
        self.seed = check_int(self.seed, "seed", 0)
        self.sim_budget = check_int(self.sim_budget, "sim_budget", 1)
        self.workers = check_int(self.workers, "workers", 1)

    def method_config(self) -> Any:
        """The method's config dataclass with `options` applied (UnknownOptionError naming unknown
        keys); NFPDE's likelihood comes from the method's name."""
        _, config_type, _ = _implementation(self.method)
        opts = dict(self.options)
        if self.method.startswith("nfpde-"):
            opts["likelihood"] = self.method.split("-", 1)[1]
        return config_with_overrides(config_type, opts, owner=self.method)


#: module of learning.estimation -> (its config dataclass, its fit function); "nfpde-softmax" and
#: "nfpde-cai" are both the module nfpde.
_IMPLEMENTATIONS = {
    "nfpde": ("NFPDEConfig", "fit_nfpde"),
    "dropo": ("DROPOConfig", "fit_dropo"),
    "bayessim": ("BayesSimConfig", "fit_bayessim"),
}


def _implementation(method: str) -> tuple[Any, type, Any]:
    """(module, config dataclass, fit function) of estimation method `method` (imported now)."""
    name = method.split("-", 1)[0]
    module = importlib.import_module(f"learning.estimation.{name}")
    config_name, fit_name = _IMPLEMENTATIONS[name]
    return module, getattr(module, config_name), getattr(module, fit_name)


def min_sim_calls(config: EstimateConfig, data: TransitionDataset) -> tuple[int, str]:
    """The simulator calls one iteration of `config.method` needs on `data`, and how they add up
    (each method's own `min_sim_calls`)."""
    module, _, _ = _implementation(config.method)
    return module.min_sim_calls(config.method_config(), data)


def estimate(
    data: TransitionDataset, config: EstimateConfig, sim: Any = None, progress: bool = False
) -> tuple[EstimatedSampler, dict[str, Any], Budget]:
    """Fit `config.method` to `data` (the simulator: `sim`, else the dataset's env id); return the
    estimate as a Sampler, a JSON-able info dict and the Budget (its trace holds the snapshots).

    Raises InputError before any simulation when `config.sim_budget` is below one iteration of the
    method (`min_sim_calls`). `progress` shows a bar of the simulator calls used against the budget."""
    from learning.estimation.budget import check_sim_budget

    _, _, fit = _implementation(config.method)
    method_config = config.method_config()
    check_sim_budget(config.sim_budget, config.method, min_sim_calls(config, data))
    own = sim is None
    if own:
        sim = ParallelTransitionSim(data.env_id, workers=config.workers)
    if sim.space != data.space:
        raise ValueError(
            f"the dataset's parameters differ from the simulator's ({data.env_id}): "
            + "; ".join(data.space.diff(sim.space))
        )
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small networks: threads only contend with the simulator processes
    budget = None
    try:
        budget = Budget(data, sim, config.sim_budget, progress=progress, desc=f"estimate {config.method}")
        dist, details = fit(budget, method_config, config.seed)
    finally:
        if budget is not None:
            budget.close()
        torch.set_num_threads(threads)
        if own and hasattr(sim, "close"):
            sim.close()
    info = {
        "method": config.method,
        "seed": config.seed,
        "sim_budget": int(config.sim_budget),
        "sim_calls": budget.calls,
        "seconds": budget.seconds,
        "details": details,
        "config": dataclasses.asdict(method_config),
        "env_id": data.env_id,
        "transitions": data.num_transitions,
        "episodes": data.num_episodes,
    }
    return EstimatedSampler.of(data.space, dist), info, budget


def estimate_file(
    data_path: str | Path, out: str | Path, config: EstimateConfig, command: str = "", progress: bool = False
) -> dict[str, Any]:
    """Read a dataset (without its truth), estimate, save the estimate file; return its info
    (`command` is recorded as provenance; `progress`: a bar of simulator calls). Nothing is written
    when the estimation fails (a budget below one iteration fails before any simulation)."""
    data = load_dataset(data_path)
    sampler, info, _ = estimate(data, config, progress=progress)
    info["data"] = str(data_path)
    info["command"] = command
    save_estimate(out, sampler, config.method, data.env_id, info)
    return info
