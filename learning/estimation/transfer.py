"""Does a better estimate train a better policy? PPO with domain randomization drawn from an
estimated distribution (any Sampler), evaluated on episodes whose parameters come from the TRUE
distribution (the seed's Fig. 3). The same PPO and vector-env machinery as `goflow train`
(learning/experiment.py), with the training sampler fixed instead of adapted."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium
import numpy as np
import torch

import assembly  # noqa: F401  (registers the environment ids)
from assembly.samplers import Sampler
from learning.experiment import TrainConfig, _make_vector_env
from learning.ppo import PPO, PPOConfig

__all__ = ["TransferConfig", "train_and_evaluate"]


@dataclass
class TransferConfig:
    """One training run on a fixed sampler, evaluated on the truth every `eval_every` iterations."""

    env: str = "goflow/Cartpole-v0"
    seed: int = 0
    iterations: int = 20  # PPO iterations (each num_envs * num_steps env steps)
    eval_every: int = 5
    eval_episodes: int = 32
    # docs/results/cartpole.json's settings: 240-step rollouts, lr 1e-3
    ppo: PPOConfig = field(default_factory=lambda: PPOConfig(num_steps=240, learning_rate=1e-3))

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.eval_every < 1 or self.eval_episodes < 1:
            raise ValueError(f"TransferConfig: iterations, eval_every and eval_episodes must be >= 1, got "
                             f"{self.iterations}, {self.eval_every}, {self.eval_episodes}")


def train_and_evaluate(train_sampler: Sampler, true_sampler: Sampler, config: TransferConfig) -> dict[str, Any]:
    """Train PPO on xi ~ train_sampler; return {"curve": [[steps, mean return, success rate], ...]
    on xi ~ true_sampler, "final_mean_return", "final_success", "seconds"}."""
    torch.manual_seed(config.seed)
    probe = gymnasium.make(config.env).unwrapped
    space = probe.space
    for name, s in (("train_sampler", train_sampler), ("true_sampler", true_sampler)):
        if s.space != space:
            raise ValueError(f"{name}'s ParamSpace differs from {config.env}'s: " + "; ".join(space.diff(s.space)))
    ppo_config = replace(config.ppo, seed=config.seed)
    obs_dim = int(np.prod(probe.observation_space.shape))
    agent = PPO(obs_dim, obs_dim + space.dim, probe.action_space, ppo_config)
    envs_config = TrainConfig(env=config.env, method="fulldr", seed=config.seed)
    train_envs = _make_vector_env(envs_config, ppo_config.num_envs)
    eval_envs = _make_vector_env(envs_config, ppo_config.num_envs)
    train_envs.set_attr("sampler", train_sampler)
    eval_envs.set_attr("sampler", true_sampler)
    curve = []
    t0 = time.perf_counter()
    try:
        for it in range(1, config.iterations + 1):
            agent.train_iteration(train_envs)
            if it % config.eval_every == 0 or it == config.iterations:
                _, returns, success = agent.evaluate(eval_envs, config.eval_episodes, seed=config.seed * 7919 + it)
                curve.append([it * ppo_config.num_envs * ppo_config.num_steps, float(returns.mean()),
                              float(success.mean())])
    finally:
        train_envs.close()
        eval_envs.close()
    return {"curve": curve, "final_mean_return": curve[-1][1], "final_success": curve[-1][2],
            "seconds": time.perf_counter() - t0}
