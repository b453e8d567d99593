"""`goflow estimate`: one entry point over the four estimators, with the same data, the same
simulator and the same simulator budget for each."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from assembly.transition_sim import ParallelTransitionSim
from learning.estimation import ESTIMATORS
from learning.estimation.common import Budget
from learning.estimation.dataset import TransitionDataset, load_dataset
from learning.estimation.sampler import EstimatedSampler, save_estimate

__all__ = ["ESTIMATORS", "EstimateConfig", "estimate", "estimate_file"]


@dataclass
class EstimateConfig:
    """One estimation run. Every `goflow estimate` flag maps to a field."""

    method: str = "nfpde-softmax"
    seed: int = 0
    sim_budget: int = 100_000  # simulator calls (one call = one logged transition stepped once)
    workers: int = 1  # simulator processes
    options: dict[str, Any] = field(default_factory=dict)  # fields of the method's config dataclass

    def __post_init__(self) -> None:
        if self.method not in ESTIMATORS:
            raise ValueError(f"unknown estimation method {self.method!r}; expected one of {list(ESTIMATORS)}")
        if isinstance(self.sim_budget, bool) or int(self.sim_budget) < 1:
            raise ValueError(f"sim_budget must be a positive number of simulator calls, got {self.sim_budget!r}")

    def method_config(self) -> Any:
        """The method's config dataclass with `options` applied (ValueError naming unknown keys)."""
        from learning.estimation.bayessim import BayesSimConfig
        from learning.estimation.dropo import DROPOConfig
        from learning.estimation.nfpde import NFPDEConfig

        cls = {"dropo": DROPOConfig, "bayessim": BayesSimConfig}.get(self.method, NFPDEConfig)
        opts = dict(self.options)
        if self.method.startswith("nfpde-"):
            opts["likelihood"] = self.method.split("-", 1)[1]
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(opts) - known)
        if unknown:
            raise ValueError(f"{self.method}: unknown option(s) {unknown}; known: {sorted(known)}")
        return cls(**opts)


def estimate(data: TransitionDataset, config: EstimateConfig, sim: Any = None
             ) -> tuple[EstimatedSampler, dict[str, Any], Budget]:
    """Fit `config.method` to `data` (the simulator: `sim`, else the dataset's env id); return the
    estimate as a Sampler, a JSON-able info dict and the Budget (its trace holds the snapshots)."""
    from learning.estimation.bayessim import fit_bayessim
    from learning.estimation.dropo import fit_dropo
    from learning.estimation.nfpde import fit_nfpde

    method_config = config.method_config()
    own = sim is None
    if own:
        sim = ParallelTransitionSim(data.env_id, workers=config.workers)
    if sim.space != data.space:
        raise ValueError(f"the dataset's parameters differ from the simulator's ({data.env_id}): "
                         + "; ".join(data.space.diff(sim.space)))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small networks: threads only contend with the simulator processes
    try:
        budget = Budget(data, sim, int(config.sim_budget))
        fit = {"dropo": fit_dropo, "bayessim": fit_bayessim}.get(config.method, fit_nfpde)
        dist, details = fit(budget, method_config, config.seed)
    finally:
        torch.set_num_threads(threads)
        if own and hasattr(sim, "close"):
            sim.close()
    info = {"method": config.method, "seed": config.seed, "sim_budget": int(config.sim_budget),
            "sim_calls": budget.calls, "seconds": budget.seconds, "details": details,
            "config": dataclasses.asdict(method_config), "env_id": data.env_id,
            "transitions": data.num_transitions, "episodes": data.num_episodes}
    return EstimatedSampler(data.space, dist), info, budget


def estimate_file(data_path: str | Path, out: str | Path, config: EstimateConfig, command: str = "") -> dict[str, Any]:
    """Read a dataset (without its truth), estimate, save the estimate file; return its info
    (`command` is recorded as provenance)."""
    data = load_dataset(data_path)
    sampler, info, _ = estimate(data, config)
    info["data"] = str(data_path)
    info["command"] = command
    save_estimate(out, sampler, config.method, data.env_id, info)
    return info
