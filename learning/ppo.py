"""PPO for continuous actions with a privileged critic, on gymnasium 1.x vector environments.

Written after CleanRL's `ppo_continuous_action.py`. The actor sees `obs`; the critic sees
`info["critic_obs"]` = concat(obs, normalized xi) that every goflow env returns, each with its own
running normalizer. A truncated step (time limit or failed physics step) bootstraps from
V(final critic_obs); a terminated one does not (`compute_gae`).

Conventions a caller needs:
- `collect` requires `autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP`: an ended
  episode's last observation and info are in info["final_obs"][i] and info["final_info"][key][i].
- Seeding: networks, action sampling and minibatches draw from generators seeded by `config.seed`
  (the global RNGs are untouched); `collect` resets the vector env itself with seed
  `rollout_seed(iteration)` at the first rollout and (`reset_each_rollout=True`, the default) at
  every rollout, or with `reset_seed=`. Build the envs deterministically; the rest follows.
- Exact resume: `state_dict()` holds networks, optimizer, normalizers, RNG states and counters, so
  a run resumed at an iteration boundary continues exactly as the uninterrupted one (with
  `reset_each_rollout=False`, only statistically).
- Episodes still running at a rollout's end are cut there (bootstrapped, not reported as
  completed): choose num_steps as a multiple of the episode length where you can.

Design notes (the three departures from CleanRL, autoreset, seeding, why every rollout starts from
a seeded reset): docs/learning.md#ppo.

References: Schulman et al., "Proximal Policy Optimization Algorithms", arXiv:1707.06347, 2017;
CleanRL (github.com/vwxyzjn/cleanrl, cleanrl/ppo_continuous_action.py).
"""

from __future__ import annotations

import dataclasses
import math
import os
import weakref
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray
from torch import nn

from goflow_common.checks import check_int, check_layer_sizes, check_number
from goflow_common.errors import InputError
from learning.networks import Actor, Critic, RunningMeanStd
from learning.ppo_checkpoint import (
    CHECKPOINT_FORMAT,
    check_loadable,
    is_checkpoint,
    read_checkpoint,
    saved_action_space,
    saved_config,
    write_checkpoint,
)
from learning.vector_env_contract import NonFiniteError, check_finite, check_vec_env, read_final_info, read_obs

__all__ = ["PPOConfig", "PPO", "RolloutStats", "compute_gae"]

# Purposes mixed into derived seeds (np.random.SeedSequence([seed, purpose, ...])).
_SEED_INIT, _SEED_ROLLOUT, _SEED_EVAL, _SEED_ACT, _SEED_SAMPLE, _SEED_SHUFFLE = 0, 1, 2, 3, 4, 5


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters. Defaults follow CleanRL's ppo_continuous_action where they apply."""

    num_envs: int = 8  # sub-environments of the vector env given to collect()
    num_steps: int = 128  # steps per sub-env per rollout (batch = num_envs * num_steps)
    gamma: float = 0.99  # discount
    gae_lambda: float = 0.95  # GAE lambda
    num_minibatches: int = 8  # minibatches per epoch (must divide the batch)
    update_epochs: int = 10  # passes over the batch per update
    clip_coef: float = 0.2  # PPO ratio clip (and value clip when clip_vloss)
    ent_coef: float = 0.0  # entropy bonus coefficient
    vf_coef: float = 0.5  # value-loss coefficient
    max_grad_norm: float = 0.5  # global gradient-norm clip
    learning_rate: float = 3e-4  # Adam step size (eps 1e-5 as in CleanRL)
    anneal_lr: bool = False  # linearly anneal the learning rate to 0 over total_iterations
    total_iterations: int | None = None  # required when anneal_lr
    norm_adv: bool = True  # standardize advantages per minibatch
    clip_vloss: bool = True  # clipped value loss
    target_kl: float | None = None  # stop the epochs early when approx KL exceeds this
    hidden_sizes: tuple[int, ...] = (64, 64)  # tanh MLP widths of actor and critic
    init_log_std: float = 0.0  # initial log std of the Gaussian policy
    normalize_obs: bool = True  # running normalization of obs and critic_obs
    obs_clip: float = 10.0  # normalized observations are clipped to +-obs_clip
    normalize_rewards: bool = True  # scale rewards by the running std of the discounted return
    reward_clip: float = 10.0  # scaled rewards are clipped to +-reward_clip
    reset_each_rollout: bool = True  # every rollout starts at vec_env.reset(seed=rollout_seed(it))
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("num_envs", "num_steps", "num_minibatches", "update_epochs"):
            check_int(getattr(self, name), f"PPOConfig.{name}", 1)
        check_number(self.gamma, "PPOConfig.gamma", 0.0, 1.0)
        check_number(self.gae_lambda, "PPOConfig.gae_lambda", 0.0, 1.0)
        for name in ("clip_coef", "max_grad_norm", "learning_rate", "obs_clip", "reward_clip"):
            check_number(getattr(self, name), f"PPOConfig.{name}", 0.0, low_open=True)
        for name in ("ent_coef", "vf_coef"):
            check_number(getattr(self, name), f"PPOConfig.{name}", 0.0)
        check_number(self.init_log_std, "PPOConfig.init_log_std", -20.0, 2.0)
        if self.target_kl is not None:
            check_number(self.target_kl, "PPOConfig.target_kl", 0.0, low_open=True)
        if self.anneal_lr and self.total_iterations is None:
            raise InputError(
                "PPOConfig: anneal_lr=True needs total_iterations (the learning rate "
                "goes linearly from learning_rate to 0 over that many updates)"
            )
        if self.total_iterations is not None:
            check_int(self.total_iterations, "PPOConfig.total_iterations", 1)
        object.__setattr__(self, "hidden_sizes", check_layer_sizes(self.hidden_sizes, "PPOConfig.hidden_sizes"))
        check_int(self.seed, "PPOConfig.seed", 0)
        batch = self.batch_size
        if batch % self.num_minibatches != 0:
            raise InputError(
                f"PPOConfig: num_minibatches ({self.num_minibatches}) must divide the batch "
                f"num_envs * num_steps = {batch}"
            )
        if batch // self.num_minibatches < 2:
            raise InputError(
                f"PPOConfig: minibatches of {batch // self.num_minibatches} sample(s) are too small "
                "(need >= 2 to standardize advantages); use fewer num_minibatches"
            )

    @property
    def batch_size(self) -> int:
        """Transitions per rollout: num_envs * num_steps."""
        return int(self.num_envs) * int(self.num_steps)

    @property
    def minibatch_size(self) -> int:
        """batch_size // num_minibatches."""
        return self.batch_size // int(self.num_minibatches)


@dataclass
class RolloutStats:
    """What one `collect` saw: the episodes that ended during it, in the order they ended
    (step by step, sub-env index within a step)."""

    steps: int  # transitions collected (num_envs * num_steps)
    global_step: int  # env steps collected by this PPO so far, this rollout included
    mean_reward: float  # mean raw (unscaled) reward per transition
    episode_returns: NDArray[np.float64]  # (n,) undiscounted returns (info["episode_return"])
    episode_lengths: NDArray[np.int64]  # (n,) steps of each episode seen by this PPO
    successes: NDArray[np.bool_]  # (n,) info["success"] (return >= J_T)
    xi: NDArray[np.float64]  # (n, d) each episode's parameters (info["xi"])
    terminated: NDArray[np.bool_]  # (n,) True: the task ended it; False: truncated
    sim_errors: int = 0  # episodes ended by a failed physics step (info["sim_error"])

    @property
    def num_episodes(self) -> int:
        """Episodes that ended during the rollout."""
        return int(len(self.episode_returns))

    @property
    def mean_return(self) -> float:
        """Mean undiscounted return of the ended episodes (NaN if none ended)."""
        return float(self.episode_returns.mean()) if self.num_episodes else math.nan

    @property
    def success_rate(self) -> float:
        """Fraction of ended episodes that succeeded (NaN if none ended)."""
        return float(self.successes.mean()) if self.num_episodes else math.nan


def compute_gae(
    rewards: ArrayLike,
    values: ArrayLike,
    next_values: ArrayLike,
    terminated: ArrayLike,
    ended: ArrayLike,
    gamma: float,
    gae_lambda: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Generalized advantage estimation with truncation-aware bootstrapping; arrays (T, N).

    For step t of sub-env i: `values[t]` = V(s_t); `next_values[t]` = V of the state after the
    step: V(s_{t+1}) inside an episode and at the end of the rollout, V(final critic obs) when the
    step truncated the episode (ignored when it terminated it); `terminated[t]`: the task ended the
    episode (no bootstrap); `ended[t]`: the episode ended by termination or truncation (the
    advantage recursion stops there). Then

        delta_t = r_t + gamma * (1 - terminated_t) * next_values_t - values_t
        A_t     = delta_t + gamma * lambda * (1 - ended_t) * A_{t+1},   A_T = 0

    and the value targets are A_t + values_t. Returns (advantages, returns), float64.
    """
    r = np.asarray(rewards, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    nv = np.asarray(next_values, dtype=np.float64)
    term = np.asarray(terminated, dtype=bool)
    end = np.asarray(ended, dtype=bool)
    if not (r.shape == v.shape == nv.shape == term.shape == end.shape) or r.ndim != 2:
        raise ValueError(
            "compute_gae: rewards, values, next_values, terminated, ended must all have the same "
            f"shape (T, N); got {r.shape}, {v.shape}, {nv.shape}, {term.shape}, {end.shape}"
        )
    if np.any(term & ~end):
        raise ValueError("compute_gae: a terminated step must also be marked ended")
    adv = np.zeros_like(r)
    last = np.zeros(r.shape[1])
    for t in range(r.shape[0] - 1, -1, -1):
        delta = r[t] + gamma * np.where(term[t], 0.0, nv[t]) - v[t]
        last = delta + gamma * gae_lambda * np.where(end[t], 0.0, last)
        adv[t] = last
    return adv, adv + v


def _derive_seed(seed: int, *keys: int) -> int:
    """A 32-bit seed derived from (seed, *keys): independent streams for independent purposes."""
    return int(np.random.SeedSequence([int(seed), *(int(k) for k in keys)]).generate_state(1)[0])


class PPO:
    """PPO agent: Gaussian actor on obs, privileged critic on critic_obs = concat(obs, normalized xi).

    Typical use (the envs must be built with autoreset_mode=AutoresetMode.SAME_STEP):

        envs = gymnasium.vector.SyncVectorEnv([...], autoreset_mode=AutoresetMode.SAME_STEP)
        ppo = PPO(obs_dim, critic_obs_dim, envs.single_action_space, PPOConfig(num_envs=envs.num_envs))
        for _ in range(n):
            stats, logs = ppo.train_iteration(envs)   # collect() + update()
            ppo.save("ckpt.pt")                        # between iterations
    """

    def __init__(
        self, obs_dim: int, critic_obs_dim: int, action_space: spaces.Box, config: PPOConfig | None = None
    ) -> None:
        self.config = config or PPOConfig()
        check_int(obs_dim, "PPO obs_dim", 1)
        check_int(critic_obs_dim, "PPO critic_obs_dim", 1)
        if not isinstance(action_space, spaces.Box) or len(action_space.shape) != 1:
            raise ValueError(f"PPO: action_space must be a 1-D gymnasium.spaces.Box, got {action_space!r}")
        self.obs_dim, self.critic_obs_dim = int(obs_dim), int(critic_obs_dim)
        self.action_space = action_space
        self.action_dim = int(action_space.shape[0])
        self._low = np.asarray(action_space.low, dtype=np.float32)
        self._high = np.asarray(action_space.high, dtype=np.float32)
        cfg = self.config

        init_gen = torch.Generator().manual_seed(_derive_seed(cfg.seed, _SEED_INIT))
        self.actor = Actor(self.obs_dim, self.action_dim, cfg.hidden_sizes, cfg.init_log_std, init_gen)
        self.critic = Critic(self.critic_obs_dim, cfg.hidden_sizes, init_gen)
        self.optimizer = torch.optim.Adam(self._parameters(), lr=cfg.learning_rate, eps=1e-5)
        self.obs_rms = RunningMeanStd((self.obs_dim,), clip=cfg.obs_clip)
        self.critic_obs_rms = RunningMeanStd((self.critic_obs_dim,), clip=cfg.obs_clip)
        self.reward_rms = RunningMeanStd((), clip=math.inf)

        self.torch_rng = torch.Generator().manual_seed(_derive_seed(cfg.seed, _SEED_SAMPLE))  # rollout actions
        self.act_rng = torch.Generator().manual_seed(_derive_seed(cfg.seed, _SEED_ACT))  # act()
        self.rng = np.random.Generator(np.random.PCG64(_derive_seed(cfg.seed, _SEED_SHUFFLE)))  # minibatches
        self.iteration = 0  # completed updates
        self.global_step = 0  # env transitions collected
        self.gradient_steps = 0

        T, N = cfg.num_steps, cfg.num_envs
        self._buf_obs = np.zeros((T, N, self.obs_dim), dtype=np.float32)
        self._buf_critic_obs = np.zeros((T, N, self.critic_obs_dim), dtype=np.float32)
        self._buf_actions = np.zeros((T, N, self.action_dim), dtype=np.float32)
        self._buf_logprobs = np.zeros((T, N), dtype=np.float32)
        self._buf_values = np.zeros((T, N), dtype=np.float32)
        self._advantages = np.zeros((T, N), dtype=np.float32)
        self._returns = np.zeros((T, N), dtype=np.float32)
        self._rollout_ready = False
        self._clear_env_state()

    # -- helpers -------------------------------------------------------------------------------

    def _parameters(self) -> list[nn.Parameter]:
        return list(self.actor.parameters()) + list(self.critic.parameters())

    def _clear_env_state(self) -> None:
        """Forget the running episodes (the next collect resets the vector env)."""
        self._env_ref: weakref.ref | None = None
        self._obs: NDArray[np.float32] | None = None
        self._critic_obs: NDArray[np.float32] | None = None
        self._ep_len = np.zeros(self.config.num_envs, dtype=np.int64)
        self._disc_return = np.zeros(self.config.num_envs, dtype=np.float64)

    def rollout_seed(self, iteration: int) -> int:
        """The seed collect() resets the vector env with before rollout `iteration`."""
        return _derive_seed(self.config.seed, _SEED_ROLLOUT, iteration)

    def _norm_obs(self, obs: NDArray[Any]) -> NDArray[np.float32]:
        return (self.obs_rms.normalize(obs) if self.config.normalize_obs else np.asarray(obs)).astype(np.float32)

    def _norm_critic_obs(self, cobs: NDArray[Any]) -> NDArray[np.float32]:
        if self.config.normalize_obs:
            return self.critic_obs_rms.normalize(cobs).astype(np.float32)
        return np.asarray(cobs, dtype=np.float32)

    # -- rollout -------------------------------------------------------------------------------

    def collect(self, vec_env: gymnasium.vector.VectorEnv, *, reset_seed: int | None = None) -> RolloutStats:
        """Run num_steps steps on every sub-env, fill the buffer and compute advantages.

        The vector env is reset (with `reset_seed`, else `rollout_seed(iteration)`) when
        `reset_seed` is given, when config.reset_each_rollout, at the first call, and when the
        running episodes were forgotten (after load_state_dict, or an evaluate() on this env).
        Otherwise the episodes running at the end of the previous rollout continue.
        """
        cfg = self.config
        n = check_vec_env(vec_env, "collect", self.obs_dim, self.action_space)
        if n != cfg.num_envs:
            raise ValueError(f"PPO.collect: the vector env has {n} sub-envs, config.num_envs = {cfg.num_envs}")
        carried = self._obs is not None and self._env_ref is not None and self._env_ref() is vec_env
        if self._obs is not None and not carried and reset_seed is None and not cfg.reset_each_rollout:
            raise ValueError(
                "PPO.collect: this is not the vector env the previous rollout ran on; pass "
                "reset_seed= to start its episodes"
            )
        if reset_seed is not None or cfg.reset_each_rollout or not carried:
            seed = self.rollout_seed(self.iteration) if reset_seed is None else int(reset_seed)
            obs, info = vec_env.reset(seed=seed)
            self._obs, self._critic_obs = read_obs(
                obs, info, n, self.obs_dim, self.critic_obs_dim, "vec_env.reset", None
            )
            self._env_ref = weakref.ref(vec_env)
            self._ep_len[:] = 0
            self._disc_return[:] = 0.0

        T = cfg.num_steps
        rewards = np.zeros((T, n), dtype=np.float64)
        raw_reward_sum = 0.0
        next_values = np.zeros((T, n), dtype=np.float64)
        terminated = np.zeros((T, n), dtype=bool)
        ended = np.zeros((T, n), dtype=bool)
        ep_returns: list[float] = []
        ep_lengths: list[int] = []
        ep_success: list[bool] = []
        ep_xi: list[NDArray[np.float64]] = []
        ep_term: list[bool] = []
        sim_errors = 0

        for t in range(T):
            if cfg.normalize_obs:
                self.obs_rms.update(self._obs)
                self.critic_obs_rms.update(self._critic_obs)
            o = self._norm_obs(self._obs)
            c = self._norm_critic_obs(self._critic_obs)
            with torch.no_grad():
                action, logp = self.actor.sample(torch.from_numpy(o), self.torch_rng)
                value = self.critic(torch.from_numpy(c))
            action_np = action.numpy()
            self._buf_obs[t], self._buf_critic_obs[t] = o, c
            self._buf_actions[t], self._buf_logprobs[t], self._buf_values[t] = action_np, logp.numpy(), value.numpy()

            env_action = np.clip(action_np, self._low, self._high)
            obs, reward, term, trunc, info = vec_env.step(env_action)
            reward = np.asarray(reward, dtype=np.float64)
            if reward.shape != (n,):
                raise ValueError(f"PPO.collect: vec_env.step returned rewards of shape {reward.shape}, expected ({n},)")
            check_finite(reward, "reward", t)
            self._obs, self._critic_obs = read_obs(obs, info, n, self.obs_dim, self.critic_obs_dim, "vec_env.step", t)
            term = np.asarray(term, dtype=bool)
            done = term | np.asarray(trunc, dtype=bool)
            terminated[t], ended[t] = term, done
            raw_reward_sum += float(reward.sum())
            self._ep_len += 1

            if cfg.normalize_rewards:  # scale by the running std of the discounted return (CleanRL/gymnasium)
                self._disc_return = self._disc_return * cfg.gamma + reward
                self.reward_rms.update(self._disc_return)
                reward = np.clip(
                    reward / math.sqrt(self.reward_rms.var + self.reward_rms.eps), -cfg.reward_clip, cfg.reward_clip
                )
                self._disc_return[done] = 0.0
            rewards[t] = reward

            if done.any():
                final = read_final_info(info, done, self.critic_obs_dim, t)
                final_c = self._norm_critic_obs(final["critic_obs"])
                with torch.no_grad():
                    final_v = self.critic(torch.from_numpy(final_c)).numpy()
                for j, i in enumerate(np.flatnonzero(done)):
                    next_values[t, i] = final_v[j]  # used only where truncated (compute_gae)
                    ep_returns.append(float(final["episode_return"][j]))
                    ep_lengths.append(int(self._ep_len[i]))
                    ep_success.append(bool(final["success"][j]))
                    ep_xi.append(np.asarray(final["xi"][j], dtype=np.float64))
                    ep_term.append(bool(term[i]))
                    sim_errors += int(final["sim_error"][j])
                self._ep_len[done] = 0

        c = self._norm_critic_obs(self._critic_obs)  # V of the state after the rollout, for bootstrapping
        with torch.no_grad():
            last_v = self.critic(torch.from_numpy(c)).numpy().astype(np.float64)
        values = self._buf_values.astype(np.float64)
        following = np.concatenate([values[1:], last_v[None]], axis=0)
        next_values = np.where(ended, next_values, following)
        adv, ret = compute_gae(rewards, values, next_values, terminated, ended, cfg.gamma, cfg.gae_lambda)
        self._advantages[:], self._returns[:] = adv, ret
        self._rollout_ready = True
        self.global_step += T * n

        d = self.critic_obs_dim - self.obs_dim
        return RolloutStats(
            steps=T * n,
            global_step=self.global_step,
            mean_reward=raw_reward_sum / (T * n),
            episode_returns=np.asarray(ep_returns, dtype=np.float64),
            episode_lengths=np.asarray(ep_lengths, dtype=np.int64),
            successes=np.asarray(ep_success, dtype=bool),
            xi=np.stack(ep_xi) if ep_xi else np.zeros((0, max(d, 0))),
            terminated=np.asarray(ep_term, dtype=bool),
            sim_errors=sim_errors,
        )

    # -- optimization --------------------------------------------------------------------------

    def current_learning_rate(self) -> float:
        """The learning rate the next update uses (annealed linearly when config.anneal_lr)."""
        cfg = self.config
        if not cfg.anneal_lr:
            return cfg.learning_rate
        return cfg.learning_rate * (1.0 - self.iteration / cfg.total_iterations)

    def update(self) -> dict[str, float]:
        """PPO update on the last collected rollout; returns the mean losses and diagnostics."""
        if not self._rollout_ready:
            raise RuntimeError("PPO.update: no collected rollout to learn from; call collect() first")
        cfg = self.config
        if cfg.anneal_lr and self.iteration >= cfg.total_iterations:
            raise RuntimeError(
                f"PPO.update: anneal_lr reached learning rate 0 after total_iterations="
                f"{cfg.total_iterations} updates; raise total_iterations to train longer"
            )
        lr = self.current_learning_rate()
        for group in self.optimizer.param_groups:
            group["lr"] = lr

        B, mb = cfg.batch_size, cfg.minibatch_size
        obs = torch.from_numpy(self._buf_obs.reshape(B, self.obs_dim))
        cobs = torch.from_numpy(self._buf_critic_obs.reshape(B, self.critic_obs_dim))
        actions = torch.from_numpy(self._buf_actions.reshape(B, self.action_dim))
        old_logp = torch.from_numpy(self._buf_logprobs.reshape(B))
        old_v = torch.from_numpy(self._buf_values.reshape(B))
        adv_all = torch.from_numpy(self._advantages.reshape(B))
        ret = torch.from_numpy(self._returns.reshape(B))
        if not (torch.isfinite(adv_all).all() and torch.isfinite(ret).all()):
            raise NonFiniteError("PPO.update: non-finite advantages or value targets (the critic diverged?)")

        sums = {
            "policy_loss": 0.0,
            "value_loss": 0.0,
            "entropy": 0.0,
            "approx_kl": 0.0,
            "old_approx_kl": 0.0,
            "clipfrac": 0.0,
        }
        count, epochs_run = 0, 0
        for _ in range(cfg.update_epochs):
            epochs_run += 1
            perm = torch.from_numpy(self.rng.permutation(B))
            epoch_kl = []
            for start in range(0, B, mb):
                idx = perm[start : start + mb]
                new_logp, entropy = self.actor.evaluate(obs[idx], actions[idx])
                new_v = self.critic(cobs[idx])
                logratio = new_logp - old_logp[idx]
                ratio = logratio.exp()
                with torch.no_grad():
                    old_approx_kl = (-logratio).mean()
                    approx_kl = ((ratio - 1.0) - logratio).mean()  # the k3 estimator (CleanRL)
                    clipfrac = ((ratio - 1.0).abs() > cfg.clip_coef).float().mean()
                adv = adv_all[idx]
                if cfg.norm_adv:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1.0 - cfg.clip_coef, 1.0 + cfg.clip_coef)).mean()
                if cfg.clip_vloss:
                    v_clipped = old_v[idx] + (new_v - old_v[idx]).clamp(-cfg.clip_coef, cfg.clip_coef)
                    v_loss = 0.5 * torch.max((new_v - ret[idx]) ** 2, (v_clipped - ret[idx]) ** 2).mean()
                else:
                    v_loss = 0.5 * ((new_v - ret[idx]) ** 2).mean()
                ent = entropy.mean()
                loss = pg_loss - cfg.ent_coef * ent + cfg.vf_coef * v_loss
                if not torch.isfinite(loss):
                    raise NonFiniteError(
                        f"PPO.update: non-finite loss (policy {pg_loss.item()}, value {v_loss.item()}, "
                        f"entropy {ent.item()}) at gradient step {self.gradient_steps}"
                    )
                self.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(self._parameters(), cfg.max_grad_norm)
                self.optimizer.step()
                self.gradient_steps += 1
                for k, v in (
                    ("policy_loss", pg_loss),
                    ("value_loss", v_loss),
                    ("entropy", ent),
                    ("approx_kl", approx_kl),
                    ("old_approx_kl", old_approx_kl),
                    ("clipfrac", clipfrac),
                ):
                    sums[k] += float(v.item())
                count += 1
                epoch_kl.append(float(approx_kl.item()))
            if cfg.target_kl is not None and epoch_kl[-1] > cfg.target_kl:
                break

        values_np, returns_np = self._buf_values.reshape(-1), self._returns.reshape(-1)
        var_ret = float(np.var(returns_np))
        explained = math.nan if var_ret == 0 else 1.0 - float(np.var(returns_np - values_np)) / var_ret
        self.iteration += 1
        self._rollout_ready = False
        logs = {k: v / count for k, v in sums.items()}
        logs.update(
            explained_variance=explained,
            learning_rate=lr,
            epochs=float(epochs_run),
            action_std=float(self.actor.log_std.exp().mean().item()),
            iteration=float(self.iteration),
            global_step=float(self.global_step),
        )
        return logs

    def train_iteration(
        self, vec_env: gymnasium.vector.VectorEnv, *, reset_seed: int | None = None
    ) -> tuple[RolloutStats, dict[str, float]]:
        """collect(vec_env) then update(): (rollout stats, update logs)."""
        stats = self.collect(vec_env, reset_seed=reset_seed)
        return stats, self.update()

    # -- acting and evaluation -----------------------------------------------------------------

    def act(self, obs: ArrayLike, deterministic: bool = False) -> NDArray[np.float32]:
        """Actions for raw observations (obs_dim,) or (n, obs_dim), clipped to the action space.

        Uses the normalizer statistics without updating them, and its own RNG (`act_rng`) so that
        acting never changes the training run."""
        x = np.asarray(obs, dtype=np.float32)
        single = x.ndim == 1
        batch = x[None] if single else x
        if batch.ndim != 2 or batch.shape[1] != self.obs_dim:
            raise ValueError(f"PPO.act: obs has shape {x.shape}, expected ({self.obs_dim},) or (n, {self.obs_dim})")
        check_finite(batch, "observation given to act()")
        actions = self._policy(batch, deterministic, self.act_rng)
        return actions[0] if single else actions

    def value(self, critic_obs: NDArray[Any]) -> NDArray[np.float32]:
        """The critic's V for raw critic observations (n, critic_obs_dim), with the normalizer's
        statistics (not updated); float32, shape (n,)."""
        with torch.no_grad():
            return self.critic(torch.from_numpy(self._norm_critic_obs(critic_obs))).numpy()

    def _policy(self, obs: NDArray[np.float32], deterministic: bool, gen: torch.Generator) -> NDArray[np.float32]:
        o = torch.from_numpy(self._norm_obs(obs))
        with torch.no_grad():
            a = self.actor.mean(o) if deterministic else self.actor.sample(o, gen)[0]
        return np.clip(a.numpy(), self._low, self._high)

    def evaluate(
        self,
        vec_env: gymnasium.vector.VectorEnv,
        n_episodes: int,
        deterministic: bool = False,
        seed: int | None = None,
        progress: bool = False,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Run n_episodes full episodes without learning: (xi (n, d), returns (n,), successes (n,)).

        Nothing of the training run changes: no normalizer update, no parameter update, and the
        actions are drawn from a generator seeded with `seed` (default: derived from config.seed and
        the iteration), which also seeds vec_env.reset. Each sub-env contributes episodes in turn
        (round k takes the k-th episode of every sub-env), so short episodes are not over-represented.
        If vec_env is the env collect() runs on, its running episodes are forgotten and the next
        collect resets it. `progress` shows a bar of the episodes finished.
        """
        from tqdm import tqdm

        check_int(n_episodes, "PPO.evaluate n_episodes", 1)
        n = check_vec_env(vec_env, "evaluate", self.obs_dim, self.action_space)
        if self._env_ref is not None and self._env_ref() is vec_env:
            self._clear_env_state()
        seed = _derive_seed(self.config.seed, _SEED_EVAL, self.iteration) if seed is None else int(seed)
        gen = torch.Generator().manual_seed(seed)
        obs, info = vec_env.reset(seed=seed)
        obs, _ = read_obs(obs, info, n, self.obs_dim, self.critic_obs_dim, "vec_env.reset", None)
        quota = -(-int(n_episodes) // n)
        got: list[list[tuple[NDArray[np.float64], float, bool]]] = [[] for _ in range(n)]
        step = 0
        with tqdm(total=int(n_episodes), disable=not progress, desc="evaluate", unit="episode") as bar:
            while any(len(g) < quota for g in got):
                obs, reward, term, trunc, info = vec_env.step(self._policy(obs, deterministic, gen))
                check_finite(np.asarray(reward, dtype=np.float64), "reward", step)
                obs, _ = read_obs(obs, info, n, self.obs_dim, self.critic_obs_dim, "vec_env.step", step)
                done = np.asarray(term, dtype=bool) | np.asarray(trunc, dtype=bool)
                if done.any():
                    final = read_final_info(info, done, self.critic_obs_dim, step)
                    for j, i in enumerate(np.flatnonzero(done)):
                        if len(got[i]) < quota:
                            got[i].append(
                                (
                                    np.asarray(final["xi"][j], dtype=np.float64),
                                    float(final["episode_return"][j]),
                                    bool(final["success"][j]),
                                )
                            )
                    bar.update(min(sum(map(len, got)), int(n_episodes)) - bar.n)
                step += 1
        ordered = [got[i][k] for k in range(quota) for i in range(n)][:n_episodes]
        xi = np.stack([e[0] for e in ordered])
        return xi, np.array([e[1] for e in ordered]), np.array([e[2] for e in ordered], dtype=bool)

    # -- checkpoints ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs (loadable with torch.load(weights_only=True)).

        Take it between iterations (after update()); the vector env's state is not in it (see the
        module docstring: with reset_each_rollout the next rollout starts from a seeded reset)."""
        if self._rollout_ready:
            raise RuntimeError(
                "PPO.state_dict: a collected rollout has not been used by update() yet; "
                "checkpoint between iterations (after update())"
            )
        return {
            "format": CHECKPOINT_FORMAT,
            "config": dataclasses.asdict(self.config),
            "obs_dim": self.obs_dim,
            "critic_obs_dim": self.critic_obs_dim,
            "action_low": self._low.tolist(),
            "action_high": self._high.tolist(),
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_rms": self.obs_rms.state_dict(),
            "critic_obs_rms": self.critic_obs_rms.state_dict(),
            "reward_rms": self.reward_rms.state_dict(),
            "torch_rng": self.torch_rng.get_state(),
            "act_rng": self.act_rng.get_state(),
            "numpy_rng": self.rng.bit_generator.state,
            "counters": {
                "iteration": self.iteration,
                "global_step": self.global_step,
                "gradient_steps": self.gradient_steps,
            },
        }

    def load_state_dict(self, state: dict[str, Any], strict_config: bool = True, optimizer: bool = True) -> None:
        """Restore a state_dict. ValueError if it is not a PPO checkpoint, if the dimensions or action
        bounds differ, or (strict_config) if any hyperparameter differs from this PPO's config.
        optimizer=False keeps this PPO's own (fresh) Adam state: for a state saved to act, not to
        resume training, which may lack it."""
        dims = {
            "obs_dim": self.obs_dim,
            "critic_obs_dim": self.critic_obs_dim,
            "action_low": self._low.tolist(),
            "action_high": self._high.tolist(),
        }
        check_loadable(state, dims, self.config, strict_config)
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        if optimizer:
            self.optimizer.load_state_dict(state["optimizer"])
        self.obs_rms.load_state_dict(state["obs_rms"])
        self.critic_obs_rms.load_state_dict(state["critic_obs_rms"])
        self.reward_rms.load_state_dict(state["reward_rms"])
        self.torch_rng.set_state(state["torch_rng"])
        self.act_rng.set_state(state["act_rng"])
        self.rng.bit_generator.state = state["numpy_rng"]
        counters = state["counters"]
        self.iteration, self.global_step = int(counters["iteration"]), int(counters["global_step"])
        self.gradient_steps = int(counters["gradient_steps"])
        self._rollout_ready = False
        self._clear_env_state()

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the state_dict atomically (tensors and plain data: loadable with weights_only=True)."""
        write_checkpoint(path, self.state_dict())

    def load(self, path: str | os.PathLike[str], strict_config: bool = True) -> None:
        """Load a checkpoint written by save() (as data only)."""
        self.load_state_dict(read_checkpoint(path, check=False), strict_config)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike[str]) -> "PPO":
        """A PPO built with the checkpoint's dimensions, action bounds and config, then loaded."""
        return cls.from_state_dict(read_checkpoint(path))

    @classmethod
    def from_state_dict(cls, state: dict[str, Any], optimizer: bool = True) -> "PPO":
        """A PPO built with a state_dict's dimensions, action bounds and config, then loaded
        (optimizer: as in load_state_dict)."""
        if not is_checkpoint(state):
            raise ValueError("PPO.from_state_dict: not a PPO state_dict")
        ppo = cls(
            state["obs_dim"], state["critic_obs_dim"], saved_action_space(state), PPOConfig(**saved_config(state))
        )
        ppo.load_state_dict(state, optimizer=optimizer)
        return ppo
