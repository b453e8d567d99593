"""Networks and observation normalizers for PPO (see learning/ppo.py).

- `Actor`: obs -> mean of a diagonal Gaussian, with a state-independent log std (a free parameter
  vector). No tanh squashing: the sample is what the log-prob is computed for, and it is clipped to
  the action space only when it is sent to the environment (as in CleanRL's ppo_continuous_action).
- `Critic`: V(critic_obs), where critic_obs = concat(obs, normalized xi) (privileged: the actor
  never sees xi).
- `RunningMeanStd`: running mean and variance over a stream of batches (parallel-variance
  formula of Chan et al.), used to normalize observations and to scale rewards.

Initialization follows CleanRL: orthogonal weights with gain sqrt(2) in the hidden layers, zero
biases, gain 0.01 on the actor's output layer (the initial mean is ~0) and 1.0 on the critic's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import nn

__all__ = ["Actor", "Critic", "RunningMeanStd", "mlp"]


def _layer(in_features: int, out_features: int, gain: float, generator: torch.Generator | None) -> nn.Linear:
    layer = nn.Linear(in_features, out_features)
    nn.init.orthogonal_(layer.weight, gain=gain, generator=generator)
    nn.init.zeros_(layer.bias)
    return layer


def mlp(
    in_dim: int, hidden: Sequence[int], out_dim: int, out_gain: float, generator: torch.Generator | None = None
) -> nn.Sequential:
    """Tanh MLP with orthogonal init: hidden layers gain sqrt(2), output layer `out_gain`."""
    layers: list[nn.Module] = []
    prev = in_dim
    for width in hidden:
        layers += [_layer(prev, width, math.sqrt(2.0), generator), nn.Tanh()]
        prev = width
    layers.append(_layer(prev, out_dim, out_gain, generator))
    return nn.Sequential(*layers)


class Actor(nn.Module):
    """Diagonal Gaussian policy pi(a | obs) = N(mean(obs), exp(log_std)^2), unsquashed."""

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        hidden: Sequence[int] = (64, 64),
        init_log_std: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.mean = mlp(obs_dim, hidden, action_dim, 0.01, generator)
        self.log_std = nn.Parameter(torch.full((action_dim,), float(init_log_std)))

    def distribution(self, obs: torch.Tensor) -> torch.distributions.Normal:
        """The action distribution for a batch of (normalized) observations."""
        mean = self.mean(obs)
        return torch.distributions.Normal(mean, self.log_std.expand_as(mean).exp())

    def sample(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(unclipped action, its log-prob summed over action dims), drawn with `generator`."""
        mean = self.mean(obs)
        std = self.log_std.expand_as(mean).exp()
        action = mean + std * torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
        log_prob = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
        return action, log_prob

    def evaluate(self, obs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(log-prob of `action` summed over action dims, entropy summed over action dims)."""
        dist = self.distribution(obs)
        return dist.log_prob(action).sum(-1), dist.entropy().sum(-1)


class Critic(nn.Module):
    """State value V(critic_obs) with critic_obs = concat(obs, normalized xi)."""

    def __init__(
        self, critic_obs_dim: int, hidden: Sequence[int] = (64, 64), generator: torch.Generator | None = None
    ) -> None:
        super().__init__()
        self.value = mlp(critic_obs_dim, hidden, 1, 1.0, generator)

    def forward(self, critic_obs: torch.Tensor) -> torch.Tensor:
        """V, shape (batch,)."""
        return self.value(critic_obs).squeeze(-1)


class RunningMeanStd:
    """Running mean and variance of vectors of shape `shape`, merged batch by batch (float64).

    `normalize(x) = clip((x - mean) / sqrt(var + eps), -clip, clip)`. The count starts at `eps`
    (as in gymnasium's wrappers) so that a first batch of identical values gives variance ~0, not NaN.
    """

    def __init__(self, shape: tuple[int, ...], eps: float = 1e-8, clip: float = 10.0) -> None:
        self.shape = tuple(shape)
        self.eps = float(eps)
        self.clip = float(clip)
        self.mean = np.zeros(self.shape, dtype=np.float64)
        self.var = np.ones(self.shape, dtype=np.float64)
        self.count = 1e-4

    def update(self, batch: ArrayLike) -> None:
        """Merge a batch of shape (n, *shape)."""
        x = np.asarray(batch, dtype=np.float64)
        if x.shape[1:] != self.shape:
            raise ValueError(f"RunningMeanStd.update: batch has shape {x.shape}, expected (n, *{self.shape})")
        n = x.shape[0]
        if n == 0:
            return
        b_mean, b_var = x.mean(axis=0), x.var(axis=0)
        delta = b_mean - self.mean
        total = self.count + n
        self.mean = np.asarray(self.mean + delta * n / total, dtype=np.float64)
        m2 = self.var * self.count + b_var * n + delta**2 * self.count * n / total
        self.var = np.asarray(m2 / total, dtype=np.float64)
        self.count = total

    def normalize(self, x: ArrayLike) -> NDArray[np.float64]:
        """Standardize x (any leading shape) with the current statistics, then clip."""
        z = (np.asarray(x, dtype=np.float64) - self.mean) / np.sqrt(self.var + self.eps)
        return np.clip(z, -self.clip, self.clip)

    def state_dict(self) -> dict[str, Any]:
        """Statistics as tensors and floats (loadable with torch.load(weights_only=True))."""
        return {
            "mean": torch.from_numpy(self.mean.copy()),
            "var": torch.from_numpy(self.var.copy()),
            "count": float(self.count),
            "shape": list(self.shape),
            "eps": self.eps,
            "clip": self.clip,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore statistics; ValueError if the shape differs."""
        if tuple(state["shape"]) != self.shape:
            raise ValueError(
                f"RunningMeanStd.load_state_dict: saved shape {tuple(state['shape'])}, "
                f"this normalizer has shape {self.shape}"
            )
        self.mean = np.asarray(state["mean"], dtype=np.float64).copy()
        self.var = np.asarray(state["var"], dtype=np.float64).copy()
        self.count = float(state["count"])
        self.eps, self.clip = float(state["eps"]), float(state["clip"])
