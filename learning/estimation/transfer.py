"""Does a better estimate train a better policy? A policy trained with domain randomization drawn
from an estimated distribution (any Sampler), evaluated on episodes whose parameters come from the
TRUE distribution (the NFPDE paper's Fig. 3). Two learners:
  "ppo"  our PPO with its privileged critic, on the same vector-env machinery as `goflow train`
         (learning/experiment.py), with the training sampler fixed instead of adapted;
  "sac"  stable-baselines3's SAC with its defaults, as the paper used (the optional extra `sb3`,
         imported only when asked for)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import gymnasium
import numpy as np
import torch
from numpy.typing import NDArray

import assembly  # noqa: F401  (registers the environment ids)
from assembly.samplers import Sampler
from goflow_common.checks import check_choice, check_int
from learning.experiment import TrainConfig, make_vector_env
from learning.ppo import PPO, PPOConfig

__all__ = ["ALGOS", "SACConfig", "TransferConfig", "run_episodes", "train_and_evaluate"]

ALGOS = ("ppo", "sac")


@dataclass(frozen=True)
class SACConfig:
    """stable-baselines3 SAC: its defaults (256-256 ReLU MLPs, lr 3e-4, batch 256, one gradient
    step per env step, automatic entropy), trained for `steps` env steps, evaluated every
    `eval_every` steps."""

    steps: int = 30_000
    eval_every: int = 5_000
    learning_starts: int = 100  # sb3's default

    def __post_init__(self) -> None:
        check_int(self.steps, "SACConfig.steps", 1)
        check_int(self.eval_every, "SACConfig.eval_every", 1)
        check_int(self.learning_starts, "SACConfig.learning_starts", 0)


@dataclass
class TransferConfig:
    """One training run on a fixed sampler, evaluated on the truth as it learns. `iterations` and
    `eval_every` (in PPO iterations) and `ppo` configure algo "ppo"; `sac` configures "sac"."""

    env: str = "goflow/Cartpole-v0"
    seed: int = 0
    algo: str = "ppo"
    iterations: int = 20  # PPO iterations (each num_envs * num_steps env steps)
    eval_every: int = 5
    eval_episodes: int = 32
    # docs/results/cartpole.json's settings: 240-step rollouts, lr 1e-3
    ppo: PPOConfig = field(default_factory=lambda: PPOConfig(num_steps=240, learning_rate=1e-3))
    sac: SACConfig = field(default_factory=SACConfig)

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.eval_every < 1 or self.eval_episodes < 1:
            raise ValueError(
                f"TransferConfig: iterations, eval_every and eval_episodes must be >= 1, got "
                f"{self.iterations}, {self.eval_every}, {self.eval_episodes}"
            )
        check_choice(self.algo, ALGOS, "TransferConfig.algo")


def train_and_evaluate(train_sampler: Sampler, true_sampler: Sampler, config: TransferConfig) -> dict[str, Any]:
    """Train config.algo on xi ~ train_sampler; return {"curve": [[steps, mean return, success rate],
    ...] on xi ~ true_sampler, "final_mean_return", "final_success", "seconds"}.

    Raises ValueError if a sampler's ParamSpace is not the env's, ImportError naming the extra if
    algo "sac" is asked for without stable-baselines3."""
    torch.manual_seed(config.seed)
    probe = gymnasium.make(config.env).unwrapped
    space = probe.space
    for name, s in (("train_sampler", train_sampler), ("true_sampler", true_sampler)):
        if s.space != space:
            raise ValueError(f"{name}'s ParamSpace differs from {config.env}'s: " + "; ".join(space.diff(s.space)))
    t0 = time.perf_counter()
    run = _train_sac if config.algo == "sac" else _train_ppo
    curve = run(probe, train_sampler, true_sampler, config)
    return {
        "curve": curve,
        "final_mean_return": curve[-1][1],
        "final_success": curve[-1][2],
        "seconds": time.perf_counter() - t0,
    }


def _train_ppo(probe: Any, train_sampler: Sampler, true_sampler: Sampler, config: TransferConfig) -> list[list[float]]:
    ppo_config = replace(config.ppo, seed=config.seed)
    obs_dim = int(np.prod(probe.observation_space.shape))
    agent = PPO(obs_dim, obs_dim + probe.space.dim, probe.action_space, ppo_config)
    envs_config = TrainConfig(env=config.env, method="fulldr", seed=config.seed)
    train_envs = make_vector_env(envs_config, ppo_config.num_envs)
    eval_envs = make_vector_env(envs_config, ppo_config.num_envs)
    train_envs.set_attr("sampler", train_sampler)
    eval_envs.set_attr("sampler", true_sampler)
    curve = []
    try:
        for it in range(1, config.iterations + 1):
            agent.train_iteration(train_envs)
            if it % config.eval_every == 0 or it == config.iterations:
                _, returns, success = agent.evaluate(eval_envs, config.eval_episodes, seed=config.seed * 7919 + it)
                curve.append(
                    [it * ppo_config.num_envs * ppo_config.num_steps, float(returns.mean()), float(success.mean())]
                )
    finally:
        train_envs.close()
        eval_envs.close()
    return curve


def _train_sac(probe: Any, train_sampler: Sampler, true_sampler: Sampler, config: TransferConfig) -> list[list[float]]:
    try:
        from stable_baselines3 import SAC
    except ImportError as exc:
        raise ImportError(
            "TransferConfig(algo='sac') needs stable-baselines3: pip install -e '.[sb3]' (`make test` installs it)"
        ) from exc
    torch.set_num_threads(1)  # small networks: a second thread only contends with the other runs
    train_env = gymnasium.make(config.env)
    train_env.unwrapped.sampler = train_sampler
    eval_env = gymnasium.make(config.env)
    eval_env.unwrapped.sampler = true_sampler
    cfg = config.sac
    model = SAC("MlpPolicy", train_env, seed=config.seed, learning_starts=cfg.learning_starts, device="cpu", verbose=0)

    def act(obs: NDArray[np.float64]) -> NDArray[np.float64]:
        return model.predict(obs, deterministic=True)[0]

    curve = []
    try:
        done = 0
        while done < cfg.steps:
            chunk = min(cfg.eval_every, cfg.steps - done)
            model.learn(chunk, reset_num_timesteps=False)
            done += chunk
            returns, success = run_episodes(act, eval_env, config.eval_episodes, seed=config.seed * 7919 + done)
            curve.append([done, float(returns.mean()), float(success.mean())])
    finally:
        train_env.close()
        eval_env.close()
    return curve


def run_episodes(
    act: Callable[[NDArray[np.float64]], NDArray[np.float64]], env: gymnasium.Env, n_episodes: int, seed: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """n_episodes whole episodes of `act` on `env`, reset with seeds seed, seed+1, ...: their
    undiscounted returns and successes (info["success"] at the episode's end; False for envs that
    do not report it, such as gymnasium's originals)."""
    returns, success = np.zeros(n_episodes), np.zeros(n_episodes, dtype=bool)
    for k in range(n_episodes):
        obs, _ = env.reset(seed=seed + k)
        while True:
            obs, reward, term, trunc, info = env.step(act(obs))
            returns[k] += float(reward)
            if term or trunc:
                success[k] = bool(info.get("success", False))
                break
    return returns, success
