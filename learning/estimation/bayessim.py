"""BayesSim (Ramos, Possas and Fox, "BayesSim: adaptive domain randomization via probabilistic
inference for robotics simulators", RSS 2019): a mixture density network posterior q(xi | x) over
summary statistics x of trajectory data, trained on simulations with xi drawn from the uniform prior
on the box.

Offline form used here (same data and simulator interface as NFPDE and DROPO): a "trajectory" is a
segment of L consecutive logged transitions; simulating it under xi means one-step predictions
from each logged state with the logged action. Summary statistics of a segment with deltas
D_t = (s'_t - s_t) / sigma (sigma: the data's per-dimension std of s' - s): the mean and std of
D over the segment and the mean of D_t a_t^T (BayesSim's state-action cross-correlation), then
standardized with the training set's mean and std. The MDN (our own, torch) maps them to a
K-component diagonal Gaussian mixture over y = logit(u). The estimate of the parameter
distribution is the average of the posteriors of all logged segments.

Why our MDN and not `sbi`'s (Tejero-Cantero et al., "sbi: a toolkit for simulation-based
inference", JOSS 2020; neural posterior estimation with `posterior_nn(model="mdn")`): measured on
the docs/nfpde.md table (same simulations, prior, statistics and seeds; docs/results/bayessim_sbi.json),
sbi 0.27's MDN ended with a higher OT cost in all 8 (env, target) cells, by 2.6 to 7.6 standard errors
with its own training recipe, and still on PointMass's mixture and Cartpole with ours, where it took
2.3-2.8x our training CPU time. docs/nfpde.md has the table; benchmarks/bayessim_sbi.py reruns it
(`simulate_bayessim` and `fit_mdn` are the two steps it shares with `fit_bayessim`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from goflow_common.checks import check_int
from learning.estimation.budget import Budget, check_sim_budget
from learning.estimation.dataset import TransitionDataset, segment_rows
from learning.estimation.distributions import EPS, GaussianMixtureAggregate, logit

__all__ = [
    "BayesSimConfig",
    "BayesSimSimulations",
    "MDN",
    "fit_bayessim",
    "fit_mdn",
    "min_sim_calls",
    "simulate_bayessim",
    "summary_stats",
]


@dataclass
class BayesSimConfig:
    """BayesSim hyperparameters (defaults: the ones the results in docs/nfpde.md use)."""

    segment_length: int = 16  # transitions per simulated "trajectory"
    components: int = 5  # K mixture components
    hidden: tuple[int, ...] = (64, 64)
    epochs: int = 200
    batch_size: int = 128
    lr: float = 1e-3
    min_std: float = 1e-2  # floor on component stds (logit units)

    def __post_init__(self) -> None:
        for name in ("segment_length", "components", "epochs", "batch_size"):
            setattr(self, name, check_int(getattr(self, name), f"BayesSimConfig.{name}", 1))
        self.hidden = tuple(self.hidden)


def min_sim_calls(config: BayesSimConfig, data: TransitionDataset) -> tuple[int, str]:
    """Simulator calls BayesSim needs at least: 2 simulated segments (a mean and a spread of the
    summary statistics), and how they add up (InputError if no trajectory holds one segment)."""
    segment_rows(data, config.segment_length)
    return 2 * config.segment_length, (
        f"2 simulated segments x {config.segment_length} transitions, set by the option segment_length"
    )


def summary_stats(states: np.ndarray, actions: np.ndarray, next_states: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Summary statistics of segments: inputs (..., L, ds/da); output (..., 2 ds + ds da)."""
    delta = (next_states - states) / scale
    cross = np.einsum("...tk,...tl->...kl", delta, actions) / delta.shape[-2]
    return np.concatenate([delta.mean(-2), delta.std(-2), cross.reshape(*cross.shape[:-2], -1)], axis=-1)


class MDN(nn.Module):
    """x -> mixture of K diagonal Gaussians over d dims (logits, means, log stds)."""

    def __init__(self, n_in: int, d: int, components: int, hidden: tuple[int, ...], min_std: float) -> None:
        super().__init__()
        layers, width = [], n_in
        for h in hidden:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        self.body = nn.Sequential(*layers)
        self.head = nn.Linear(width, components * (1 + 2 * d))
        self.k, self.d, self.min_std = components, d, min_std

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(log weights (n, K), means (n, K, d), stds (n, K, d))."""
        out = self.head(self.body(x))
        k, d = self.k, self.d
        logw = torch.log_softmax(out[:, :k], dim=-1)
        mean = out[:, k : k + k * d].reshape(-1, k, d)
        std = nn.functional.softplus(out[:, k + k * d :].reshape(-1, k, d)) + self.min_std
        return logw, mean, std

    def log_prob(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """log q(y | x), (n,)."""
        logw, mean, std = self(x)
        comp = torch.distributions.Normal(mean, std).log_prob(y[:, None, :]).sum(-1)
        return torch.logsumexp(logw + comp, dim=-1)


@dataclass
class BayesSimSimulations:
    """BayesSim's training pairs and observations: what its simulation step hands to the MDN."""

    u: np.ndarray  # (n, d) prior draws (unit box) of the valid simulations
    stats: np.ndarray  # (n, n_stats) summary statistics of their simulated segments (not standardized)
    observed: np.ndarray  # (S, n_stats) summary statistics of the logged segments
    simulations: int  # simulated segments, failed ones included


def simulate_bayessim(budget: Budget, config: BayesSimConfig, seed: int) -> BayesSimSimulations:
    """Simulate segments under prior draws until the budget is spent and take their summary
    statistics (failed simulations dropped), and those of the logged segments. The seed fixes the
    prior draws and the segments."""
    rng = np.random.default_rng(seed)
    data = budget.data
    d = data.space.dim
    check_sim_budget(budget.remaining(), "bayessim", min_sim_calls(config, data))
    segs = segment_rows(data, config.segment_length)
    n_sims = budget.remaining() // config.segment_length
    u_train = rng.uniform(EPS, 1 - EPS, size=(n_sims, d))
    which = segs[rng.integers(len(segs), size=n_sims)]  # (n, L)
    # One batch per chunk of draws: each draw simulates its own segment.
    stats = []
    chunk = 256
    for start in range(0, n_sims, chunk):
        u = u_train[start : start + chunk]
        rows = which[start : start + chunk]
        pred = budget.step_rows(rows.reshape(-1), np.repeat(u, config.segment_length, axis=0))
        pred = pred.reshape(len(u), config.segment_length, -1)
        stats.append(summary_stats(data.states[rows], data.actions[rows], pred, budget.scale))
    x_train = np.concatenate(stats)
    ok = np.all(np.isfinite(x_train), axis=1)  # failed simulations carry no information
    x_obs = summary_stats(data.states[segs], data.actions[segs], data.next_states[segs], budget.scale)
    return BayesSimSimulations(u=u_train[ok], stats=x_train[ok], observed=x_obs, simulations=int(n_sims))


def fit_mdn(sims: BayesSimSimulations, config: BayesSimConfig, seed: int) -> tuple[GaussianMixtureAggregate, dict]:
    """Train the MDN on the simulations (standardized statistics -> logit(u)) and average its
    posteriors over the observed segments. The seed fixes the MDN's initialization and its batches
    (the caller's torch RNG state is left as it was)."""
    d = sims.u.shape[1]
    x_train, y_train = sims.stats, logit(sims.u)
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-8
    x_obs = sims.observed
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    xt = torch.as_tensor((x_train - mu) / sd, dtype=torch.float32)
    yt = torch.as_tensor(y_train, dtype=torch.float32)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        mdn = MDN(xt.shape[1], d, config.components, config.hidden, config.min_std)
    opt = torch.optim.Adam(mdn.parameters(), lr=config.lr)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(config.epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for start in range(0, len(xt), config.batch_size):
            idx = perm[start : start + config.batch_size]
            loss = -mdn.log_prob(xt[idx], yt[idx]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        logw, mean, std = mdn(torch.as_tensor((x_obs - mu) / sd, dtype=torch.float32))
        final_nll = float(-mdn.log_prob(xt, yt).mean())
    dist = GaussianMixtureAggregate(logw.exp().double().numpy(), mean.double().numpy(), std.double().numpy())
    train_wall, train_cpu = time.perf_counter() - t_wall, time.process_time() - t_cpu
    return dist, {
        "train_nll": final_nll if math.isfinite(final_nll) else None,
        "train_seconds": train_wall,
        "train_cpu_seconds": train_cpu,
    }


def fit_bayessim(budget: Budget, config: BayesSimConfig, seed: int) -> tuple[GaussianMixtureAggregate, dict]:
    """Simulate segments under prior draws until the budget is spent (`simulate_bayessim`), train
    the MDN, and average its posteriors over the logged segments (`fit_mdn`). The seed fixes the
    prior draws, the segments, the MDN's initialization and its batches (the caller's torch RNG
    state is left as it was)."""
    sims = simulate_bayessim(budget, config, seed)
    dist, fit = fit_mdn(sims, config, seed)
    budget.snapshot(dist, simulations=len(sims.u))
    return dist, {
        "simulations": sims.simulations,
        "valid_simulations": len(sims.u),
        "train_nll": fit["train_nll"],
        "observed_segments": len(sims.observed),
        "train_seconds": fit["train_seconds"],
        "train_cpu_seconds": fit["train_cpu_seconds"],
    }
