"""BayesSim (Ramos et al. 2019): a mixture density network posterior q(xi | x) over summary statistics
x of trajectory data, trained on simulations with xi drawn from the uniform prior on the box.

Offline form used here (same data and simulator interface as NFPDE and DROPO): a "trajectory" is a
segment of L consecutive logged transitions; simulating it under xi means one-step predictions
from each logged state with the logged action. Summary statistics of a segment with deltas
D_t = (s'_t - s_t) / sigma (sigma: the data's per-dimension std of s' - s): the mean and std of
D over the segment and the mean of D_t a_t^T (BayesSim's state-action cross-correlation), then
standardized with the training set's mean and std. The MDN (our own, torch) maps them to a
K-component diagonal Gaussian mixture over y = logit(u). The estimate of the parameter
distribution is the average of the posteriors of all logged segments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from learning.estimation.common import Budget, segment_rows
from learning.estimation.distributions import EPS, GaussianMixtureAggregate, logit

__all__ = ["BayesSimConfig", "MDN", "fit_bayessim", "summary_stats"]


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
            if int(getattr(self, name)) < 1:
                raise ValueError(f"BayesSimConfig.{name} must be >= 1, got {getattr(self, name)!r}")
        self.hidden = tuple(self.hidden)


def summary_stats(states: np.ndarray, actions: np.ndarray, next_states: np.ndarray,
                  scale: np.ndarray) -> np.ndarray:
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
        mean = out[:, k:k + k * d].reshape(-1, k, d)
        std = nn.functional.softplus(out[:, k + k * d:].reshape(-1, k, d)) + self.min_std
        return logw, mean, std

    def log_prob(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """log q(y | x), (n,)."""
        logw, mean, std = self(x)
        comp = torch.distributions.Normal(mean, std).log_prob(y[:, None, :]).sum(-1)
        return torch.logsumexp(logw + comp, dim=-1)


def fit_bayessim(budget: Budget, config: BayesSimConfig, seed: int) -> tuple[GaussianMixtureAggregate, dict]:
    """Simulate segments under prior draws until the budget is spent, train the MDN, and average its
    posteriors over the logged segments."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    data = budget.data
    d = data.space.dim
    segs = segment_rows(data, config.segment_length)
    n_sims = budget.remaining() // config.segment_length
    if n_sims < 2:
        raise ValueError(f"BayesSim: a budget of {budget.remaining()} calls buys fewer than 2 simulated "
                         f"segments of {config.segment_length} transitions")
    u_train = rng.uniform(EPS, 1 - EPS, size=(n_sims, d))
    which = segs[rng.integers(len(segs), size=n_sims)]  # (n, L)
    # One batch per chunk of draws: each draw simulates its own segment.
    stats = []
    chunk = 256
    for start in range(0, n_sims, chunk):
        u = u_train[start:start + chunk]
        rows = which[start:start + chunk]
        pred = budget.step_rows(rows.reshape(-1), np.repeat(u, config.segment_length, axis=0))
        pred = pred.reshape(len(u), config.segment_length, -1)
        stats.append(summary_stats(data.states[rows], data.actions[rows], pred, budget.scale))
    x_train = np.concatenate(stats)
    ok = np.all(np.isfinite(x_train), axis=1)  # failed simulations carry no information
    x_train, y_train = x_train[ok], logit(u_train[ok])
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-8
    x_obs = summary_stats(data.states[segs], data.actions[segs], data.next_states[segs], budget.scale)
    xt = torch.as_tensor((x_train - mu) / sd, dtype=torch.float32)
    yt = torch.as_tensor(y_train, dtype=torch.float32)
    mdn = MDN(xt.shape[1], d, config.components, config.hidden, config.min_std)
    opt = torch.optim.Adam(mdn.parameters(), lr=config.lr)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(config.epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for start in range(0, len(xt), config.batch_size):
            idx = perm[start:start + config.batch_size]
            loss = -mdn.log_prob(xt[idx], yt[idx]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        logw, mean, std = mdn(torch.as_tensor((x_obs - mu) / sd, dtype=torch.float32))
    dist = GaussianMixtureAggregate(logw.exp().double().numpy(), mean.double().numpy(), std.double().numpy())
    budget.snapshot(dist, simulations=int(ok.sum()))
    with torch.no_grad():
        final_nll = float(-mdn.log_prob(xt, yt).mean())
    return dist, {"simulations": int(n_sims), "valid_simulations": int(ok.sum()),
                  "train_nll": final_nll if math.isfinite(final_nll) else None,
                  "observed_segments": int(len(segs))}
