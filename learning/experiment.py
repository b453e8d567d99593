"""The GoFlow protocol: alternate PPO on samples of the sampler with sampler updates.

Each round:
  1. training phase: PPO iterations on environments whose xi is drawn from the current sampler;
  2. validation phase: episodes on the *uniform* box with the current policy and no policy update;
     their success rate (return >= J_T) is the reported metric;
  3. the sampler is updated with the batch its method learns from (`TrainConfig.sampler_batch`):
     by default the validation batch (xi, returns) for GoFlow, LSDR and DORAEMON (told that its
     proposal is the uniform box, so its importance weights are right), and for ADR its own
     training-phase episodes (ADR learns only from episodes it pinned to a bound, which a uniform
     batch almost never contains). sampler_batch="training" makes GoFlow learn from the episodes
     drawn from the flow itself: its reward term is then the score-function gradient of E_q[R],
     which sees successes as often as the flow finds them (a departure from the paper, used to
     refine skills whose success region is a tiny part of the box: docs/skills.md).
A run writes `log.json` (config, curve, timings) and `checkpoint.pt` (policy, value function,
optimizer, normalizers, sampler, ParamSpace, round, RNG: tensors and plain data only, loaded with
`torch.load(weights_only=True)`) into its folder after every round; a run started on a folder that
holds a checkpoint resumes from it, and reproduces the uninterrupted run. A run holds an OS lock on
its folder while it works, so a second run into the same folder is refused at once.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np
import torch
from tqdm import tqdm

import assembly  # noqa: F401  (registers the environment ids)
from assembly.params import ParamSpace
from assembly.samplers import FullDR, Sampler
from goflow_common.checks import check_choice, check_int
from goflow_common.config import config_to_dict, config_with_overrides
from goflow_common.errors import InputError
from goflow_common.files import check_output_dir, load_tensors, run_folder_lock, save_tensors, write_json
from learning.execution import Backend, Job, make_backend, parse_ray_address, run_grid
from learning.ppo import PPO, PPOConfig
from learning.samplers.registry import (
    GRADIENT_METHODS,
    METHODS,
    SAMPLER_SIGNALS,
    THRESHOLD_METHODS,
    make_sampler,
    protocol_sampler_kwargs,
    sampler_config,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "TrainConfig",
    "Run",
    "load_run",
    "train",
    "SamplerFitConfig",
    "fit_sampler",
    "ExperimentConfig",
    "run_experiment",
    "experiment_summary",
    "format_summary",
    "plot_curves",
    "probe_env",
    "load_checkpoint",
    "experiment_jobs",
    "experiment_backend",
    "write_experiment",
]

#: What a checkpoint file is called in messages.
_CHECKPOINT = "goflow training checkpoint (checkpoint.pt of a `goflow train` run folder)"


def probe_env(env_id: str, env_kwargs: dict[str, Any]) -> gymnasium.Env:
    """Build environment `env_id` with `env_kwargs` once and return its unwrapped env.

    Raises InputError naming the id (and the registered goflow ids) when it is unknown, and the
    environment's own error (UnknownOptionError, InputError) for a bad option."""
    try:
        gymnasium.spec(env_id)
    except gymnasium.error.Error:
        known = sorted(k for k in gymnasium.registry if k.startswith("goflow/"))
        raise InputError(f"unknown environment id {env_id!r}; expected one of {known}") from None
    env = gymnasium.make(env_id, **env_kwargs)
    return env.unwrapped


#: TrainConfig.vectorization choices (make_vector_env).
VECTORIZATIONS = ("batched", "sync")


@dataclass
class TrainConfig:
    """One training run. Every `goflow train` flag maps to a field."""

    env: str = "goflow/Toy2D-v0"  # environment id, e.g. goflow/Cartpole-v0
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # the environment's config fields
    # the sampler: a domain-randomization method (learning.samplers.registry.METHODS), or
    # "estimated" (a fixed estimate, e.g. of `goflow estimate`, as sampler_kwargs["distribution"])
    method: str = "goflow"
    sampler_kwargs: dict[str, Any] = field(default_factory=dict)  # the sampler's config fields, e.g. alpha
    seed: int = 0  # of the policy, the sampler and the validation episodes
    total_steps: int = 198_656  # environment steps in training phases: 97 rounds of the default 2 x 8 x 128
    iterations_per_round: int = 2  # PPO iterations between validations
    eval_episodes: int = 64  # validation episodes per round, xi uniform on the box
    ppo: PPOConfig = field(default_factory=PPOConfig)
    out: Path | None = None  # run folder (log.json, checkpoint.pt); None: nothing written
    # the episodes the sampler learns from: "validation" (uniform box) or "training" (xi from the
    # sampler); None: the method's own ("training" for ADR, "validation" for the rest)
    sampler_batch: str | None = None
    # what the sampler learns: "return" (the episode return) or "success" (1 if return >= J_T else 0)
    sampler_signal: str = "return"
    # how the num_envs environments are stepped: "batched" (N copies in one Drake plant, where the
    # env id has a batched vector env; else "sync") or "sync" (N single envs in a SyncVectorEnv)
    vectorization: str = "batched"

    def __post_init__(self) -> None:
        if self.method not in (*METHODS, "estimated"):
            raise ValueError(f"unknown sampler {self.method!r}; expected one of {[*METHODS, 'estimated']}")
        if isinstance(self.seed, bool) or int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f"TrainConfig.seed = {self.seed!r}; expected an integer >= 0")
        if self.sampler_batch is None:
            self.sampler_batch = "training" if self.method == "adr" else "validation"
        if self.sampler_batch not in ("validation", "training"):
            raise ValueError(f"TrainConfig.sampler_batch = {self.sampler_batch!r}; expected 'validation' or 'training'")
        if self.sampler_signal not in SAMPLER_SIGNALS:
            raise ValueError(f"TrainConfig.sampler_signal = {self.sampler_signal!r}; expected one of {SAMPLER_SIGNALS}")
        if self.sampler_signal == "success" and self.method in THRESHOLD_METHODS:
            raise ValueError(f"{self.method} compares returns with J_T itself: sampler_signal must be 'return'")
        if self.method == "doraemon" and self.sampler_batch != "validation":
            raise ValueError(
                "DORAEMON's importance weights assume the uniform validation batch: sampler_batch must be 'validation'"
            )
        if self.method == "adr" and self.sampler_batch != "training":
            raise ValueError(
                "ADR learns only from its own boundary-pinned training episodes: sampler_batch must be 'training'"
            )
        if self.vectorization not in VECTORIZATIONS:
            raise ValueError(f"TrainConfig.vectorization = {self.vectorization!r}; expected one of {VECTORIZATIONS}")
        for name in ("total_steps", "iterations_per_round", "eval_episodes"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"TrainConfig.{name} = {getattr(self, name)}; expected >= 1")
        # Options are checked now, before any work: an unknown key or a bad value fails here.
        sampler_config(self.method, protocol_sampler_kwargs(self.method, self.sampler_kwargs))
        if self.out is not None:
            self.out = Path(self.out)

    def steps_per_round(self) -> int:
        """Training environment steps per round: iterations_per_round x num_envs x num_steps."""
        return self.iterations_per_round * self.ppo.num_envs * self.ppo.num_steps

    def to_json(self) -> dict:
        """Plain JSON data (the run's log["config"])."""
        return config_to_dict(self)

    @classmethod
    def from_json(cls, d: dict) -> TrainConfig:
        """The inverse of to_json (a run's log["config"])."""
        return config_with_overrides(cls, d)


def _sampler_signal(kind: str, returns: np.ndarray, successes: np.ndarray) -> np.ndarray:
    """What a sampler learns from a batch: its returns, or its 0/1 successes."""
    return returns if kind == "return" else successes.astype(np.float64)


@dataclass
class Run:
    """A `train` run folder's checkpoint, with its config, sampler and policy rebuilt."""

    state: dict[str, Any]  # the checkpoint as saved (agent, sampler, space, log, ...)
    config: TrainConfig
    space: ParamSpace
    sampler: Sampler
    agent: PPO


def load_checkpoint(path: Path | str) -> dict[str, Any]:
    """A `goflow train` checkpoint file as data (torch.load with weights_only=True).

    Raises FileNotFoundError if missing and FileFormatError (a ValueError) naming the file if it
    is empty, truncated, foreign or holds anything but tensors and plain data."""
    state = load_tensors(path, _CHECKPOINT)
    if not isinstance(state, dict) or not {"agent", "sampler", "space", "log"} <= set(state):
        raise InputError(f"{path}: not a {_CHECKPOINT} (it lacks agent, sampler, space or log)")
    return state


def load_run(run: Path | str) -> Run:
    """Load run folder `run`; FileNotFoundError if it holds no checkpoint, FileFormatError if the
    checkpoint is not one."""
    run = Path(run)
    checkpoint = run / "checkpoint.pt"
    if not checkpoint.is_file():
        raise FileNotFoundError(f"{run} has no checkpoint.pt: is it a `goflow train` run folder?")
    state = load_checkpoint(checkpoint)
    log = state["log"]
    config = TrainConfig.from_json(log["config"])
    space = ParamSpace.from_dict(state["space"])
    sampler = make_sampler(
        config.method, space, log["success_threshold"], protocol_sampler_kwargs(config.method, config.sampler_kwargs)
    )
    sampler.load_state_dict(state["sampler"])
    return Run(state, config, space, sampler, PPO.from_state_dict(state["agent"]))


def make_vector_env(config: TrainConfig, n: int) -> gymnasium.vector.VectorEnv:
    """n environments of `config.env` in this process, in the SAME_STEP autoreset layout PPO needs
    (runs parallelize across processes, one per run): the env id's batched vector env (n copies in
    one Drake plant, assembly/envs/batched.py) when `config.vectorization` is "batched" and the id
    has one, else n single envs in a SyncVectorEnv. The envs end their own episodes (t_max or
    horizon in env_kwargs): max_episode_steps=-1 keeps gymnasium's TimeLimit at the spec's default
    length from cutting a longer one (docs/envs.md, "Rendering and episode length")."""
    spec = gymnasium.spec(config.env)
    kwargs = {"max_episode_steps": -1, **config.env_kwargs}
    if config.vectorization == "batched" and spec.vector_entry_point is not None:
        return gymnasium.make_vec(config.env, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    return gymnasium.vector.SyncVectorEnv(
        [lambda: gymnasium.make(config.env, **kwargs) for _ in range(n)],
        autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP,
    )


def _same_run(saved: dict[str, Any], config: TrainConfig) -> list[str]:
    """What makes a checkpoint's run another run than `config`: the env, its options, the method
    or the seed (a later stage may change the budget, the round size or the batch, not these)."""
    return [
        f"{key}: checkpoint {saved.get(key)!r} vs now {getattr(config, key)!r}"
        for key in ("env", "env_kwargs", "method", "seed")
        if saved.get(key) != config_to_dict(getattr(config, key))
    ]


def train(config: TrainConfig, progress: bool = True) -> dict:
    """Run (or resume) the GoFlow protocol; return the log {"config", "curve": [[step, success,
    mean_return], ...] on the uniform box, "train_curve": the same on the training episodes (xi
    from the sampler), "seconds", "sampler_seconds", "rounds"}.

    With `config.out`, the run folder is checked and locked before any work (RunFolderBusyError if
    another run holds it), the checkpoint is written after every round, and a checkpoint of
    another run (env, env options, method, seed or ParamSpace) is refused. An interruption
    (KeyboardInterrupt) loses at most the round in progress: it is re-raised after the
    environments are closed, and the same call resumes from the last checkpoint.

    Torch runs on one thread: the networks are small, and a second thread only contends with the
    simulator (docs/learning.md, "Speed")."""
    probe = probe_env(config.env, config.env_kwargs)  # a bad env id or option fails before the folder exists
    if config.out is None:
        return _train(config, probe, progress)
    with run_folder_lock(config.out):
        return _train(config, probe, progress)


def _train(config: TrainConfig, probe: gymnasium.Env, progress: bool) -> dict:
    torch.set_num_threads(1)
    torch.manual_seed(config.seed)
    space, J_T = probe.space, float(probe.success_threshold)
    obs_dim = int(np.prod(probe.observation_space.shape))
    critic_dim = obs_dim + space.dim
    sampler = make_sampler(config.method, space, J_T, protocol_sampler_kwargs(config.method, config.sampler_kwargs))
    ppo_config = dataclasses.replace(config.ppo, seed=config.seed)
    agent = PPO(obs_dim, critic_dim, probe.action_space, ppo_config)
    train_envs = make_vector_env(config, ppo_config.num_envs)
    val_envs = make_vector_env(config, ppo_config.num_envs)
    val_envs.set_attr("sampler", FullDR(space))
    log = {
        "config": config.to_json(),
        "env": config.env,
        "method": config.method,
        "success_threshold": J_T,
        "curve": [],
        "seconds": 0.0,
        "sampler_seconds": 0.0,
        "rounds": 0,
    }
    checkpoint = config.out / "checkpoint.pt" if config.out else None
    if checkpoint is not None and checkpoint.exists():
        state = load_checkpoint(checkpoint)
        if ParamSpace.from_dict(state["space"]) != space:
            raise InputError(
                f"checkpoint {checkpoint} was trained on another ParamSpace: "
                + "; ".join(space.diff(ParamSpace.from_dict(state["space"])))
            )
        other = _same_run(state["log"]["config"], config)
        if other:
            raise InputError(
                f"{config.out} holds a checkpoint of another run ({'; '.join(other)}); "
                "choose another run folder, or remove it to start over"
            )
        agent.load_state_dict(state["agent"])
        sampler.load_state_dict(state["sampler"])
        log = state["log"]
        if log["config"] != config.to_json():  # a later stage continues the run with new settings
            log.setdefault("stages", []).append({"from_round": log["rounds"], "config": config.to_json()})
            log["config"] = config.to_json()
    steps_per_round = config.steps_per_round()
    # Rounds left from the training steps already done, so that a later stage with another round
    # size continues the run to config.total_steps (a fresh run does at least one round).
    done = log.get("steps", log["curve"][-1][0] if log["curve"] else 0)
    rounds = log["rounds"] + max(0 if done else 1, (config.total_steps - done) // steps_per_round)
    bar = tqdm(
        total=rounds,
        initial=log["rounds"],
        disable=not progress,
        desc=f"{config.method} seed {config.seed}",
        unit="round",
    )
    try:
        _rounds(config, log, rounds, done, agent, sampler, space, train_envs, val_envs, checkpoint, bar)
    finally:
        bar.close()
        train_envs.close()
        val_envs.close()
    return log


def _rounds(
    config: TrainConfig,
    log: dict,
    rounds: int,
    done: int,
    agent: PPO,
    sampler: Sampler,
    space: ParamSpace,
    train_envs: gymnasium.vector.VectorEnv,
    val_envs: gymnasium.vector.VectorEnv,
    checkpoint: Path | None,
    bar: tqdm,
) -> None:
    """The protocol's rounds until `rounds`, checkpointing after each; Ctrl-C stops after the
    round in progress (see `_stop_after_round`)."""
    with _stop_after_round() as stop_requested:
        _round_loop(
            config, log, rounds, done, agent, sampler, space, train_envs, val_envs, checkpoint, bar, stop_requested
        )


@contextmanager
def _stop_after_round() -> Iterator[Callable[[], bool]]:
    """In the main thread, a first Ctrl-C (SIGINT) only asks the rounds to stop once the round in
    progress is checkpointed (no asynchronous KeyboardInterrupt that a finalizer could swallow);
    a second one interrupts at once. An ignored SIGINT stays ignored."""
    import signal
    import threading

    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or previous is signal.SIG_IGN:
        yield lambda: False
        return
    requested = threading.Event()

    def ask(signum, frame) -> None:
        requested.set()
        signal.signal(signal.SIGINT, previous if callable(previous) else signal.default_int_handler)

    signal.signal(signal.SIGINT, ask)
    try:
        yield requested.is_set
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.default_int_handler)


def _round_loop(
    config: TrainConfig,
    log: dict,
    rounds: int,
    done: int,
    agent: PPO,
    sampler: Sampler,
    space: ParamSpace,
    train_envs: gymnasium.vector.VectorEnv,
    val_envs: gymnasium.vector.VectorEnv,
    checkpoint: Path | None,
    bar: tqdm,
    stop_requested: Callable[[], bool],
) -> None:
    steps_per_round = config.steps_per_round()
    while log["rounds"] < rounds:
        r = log["rounds"]
        t0 = time.perf_counter()
        train_envs.set_attr("sampler", sampler)
        episodes = []
        for _ in range(config.iterations_per_round):
            stats, _ = agent.train_iteration(train_envs)
            episodes.append(stats)
        xi, returns, successes = agent.evaluate(val_envs, config.eval_episodes, seed=config.seed * 100_003 + r)
        t1 = time.perf_counter()
        train_returns = np.concatenate([e.episode_returns for e in episodes])
        train_successes = np.concatenate([e.successes for e in episodes])
        if config.sampler_batch == "training":
            batch_xi, batch_returns, batch_successes = (
                np.concatenate([e.xi for e in episodes]),
                train_returns,
                train_successes,
            )
        else:
            batch_xi, batch_returns, batch_successes = xi, returns, successes
        signal = _sampler_signal(config.sampler_signal, batch_returns, batch_successes)
        diagnostics = sampler.update(batch_xi, signal) if len(signal) else {}
        t2 = time.perf_counter()
        log["rounds"] = r + 1
        done += steps_per_round
        log["steps"] = done
        log["curve"].append([done, float(np.mean(successes)), float(np.mean(returns))])
        # Training-phase episodes (xi from the sampler): how the policy does where it trains.
        log.setdefault("train_curve", []).append(
            [
                done,
                float(train_successes.mean()) if len(train_successes) else None,
                float(train_returns.mean()) if len(train_returns) else None,
            ]
        )
        log["seconds"] += t2 - t0
        log["sampler_seconds"] += t2 - t1
        log["last_sampler"] = {k: v for k, v in diagnostics.items() if isinstance(v, (int, float, bool, str))}
        if checkpoint is not None:
            save_tensors(
                checkpoint,
                {"agent": agent.state_dict(), "sampler": sampler.state_dict(), "space": space.to_dict(), "log": log},
            )
            write_json(config.out / "log.json", log)
        bar.set_postfix(success=f"{log['curve'][-1][1]:.2f}")
        bar.update(1)
        if stop_requested():
            raise KeyboardInterrupt


@dataclass
class SamplerFitConfig:
    """A last stage with the policy frozen: the sampler learns where the deterministic policy
    succeeds on the sampler's own draws, so that it describes the policy that is shipped."""

    rounds: int = 10  # sampler updates
    episodes: int = 64  # deterministic episodes per update, xi from the sampler
    signal: str = "success"  # "success" (1 if return >= J_T) or "return"

    def __post_init__(self) -> None:
        for name in ("rounds", "episodes"):
            check_int(getattr(self, name), f"SamplerFitConfig.{name}", 1)
        check_choice(self.signal, SAMPLER_SIGNALS, "SamplerFitConfig.signal")


def fit_sampler(run: Path | str, fit: SamplerFitConfig, progress: bool = True) -> dict:
    """Run (or resume) the frozen-policy stage on a `train` run folder: each round draws
    `fit.episodes` parameter vectors from the sampler, runs the deterministic policy on them and
    updates the sampler with their successes (or returns). log["sampler_fit"] holds [round,
    success, mean return, entropy] of the sampler each round evaluated, before its update.

    The update oscillates (a batch that all succeeds carries no signal, so the entropy term widens
    the flow until it fails again), so the stage keeps the evaluated sampler with the highest
    success (ties: the highest entropy), and when the rounds are done the checkpoint's sampler is
    that one (log["sampler_fit_best"]). The checkpoint is written after every round, and the run
    folder is locked while the stage works. Returns the log."""
    if not isinstance(fit, SamplerFitConfig):
        raise TypeError(f"fit must be a SamplerFitConfig, got {type(fit).__name__}")
    with run_folder_lock(run):
        return _fit_sampler(Path(run), fit, progress)


def _fit_sampler(run: Path, fit: SamplerFitConfig, progress: bool) -> dict:
    torch.set_num_threads(1)
    loaded = load_run(run)
    state, config, sampler, agent = loaded.state, loaded.config, loaded.sampler, loaded.agent
    if config.method not in GRADIENT_METHODS:
        raise ValueError(f"fit_sampler needs a gradient-updated sampler {GRADIENT_METHODS}, not {config.method!r}")
    if "sampler_fit_last" in state:  # go on from the last update, not from the selected sampler
        sampler.load_state_dict(state["sampler_fit_last"])
    log, checkpoint = state["log"], run / "checkpoint.pt"
    envs = make_vector_env(config, agent.config.num_envs)
    envs.set_attr("sampler", sampler)
    done = log.setdefault("sampler_fit", [])
    log["sampler_fit_config"] = dataclasses.asdict(fit)
    best = state.get("sampler_fit_best")  # {"round", "success", "entropy", "sampler"}
    bar = tqdm(total=fit.rounds, initial=len(done), disable=not progress, desc="fit sampler", unit="round")
    try:
        while len(done) < fit.rounds:
            r = len(done)
            t0 = time.perf_counter()
            entropy = float(sampler.entropy())
            xi, returns, successes = agent.evaluate(
                envs, fit.episodes, deterministic=True, seed=config.seed * 100_003 + 500_000 + r
            )
            t1 = time.perf_counter()
            success = float(successes.mean())
            if best is None or (success, entropy) > (best["success"], best["entropy"]):
                best = {"round": r + 1, "success": success, "entropy": entropy, "sampler": sampler.state_dict()}
            sampler.update(xi, _sampler_signal(fit.signal, returns, successes))
            done.append([r + 1, success, float(returns.mean()), entropy])
            log["seconds"] += time.perf_counter() - t0
            log["sampler_seconds"] += time.perf_counter() - t1
            last = sampler.state_dict()
            state = {**state, "sampler": last, "log": log, "sampler_fit_best": best, "sampler_fit_last": last}
            if len(done) == fit.rounds:  # finished: the checkpoint carries the selected sampler
                state["sampler"] = best["sampler"]
                log["sampler_fit_best"] = {k: best[k] for k in ("round", "success", "entropy")}
            save_tensors(checkpoint, state)
            write_json(run / "log.json", log)
            bar.set_postfix(success=f"{done[-1][1]:.2f}")
            bar.update(1)
    finally:
        bar.close()
        envs.close()
    return log


@dataclass
class ExperimentConfig:
    """Methods x seeds of one environment, run in parallel (local processes or Ray tasks)."""

    env: str = "goflow/Toy2D-v0"  # environment id
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # the environment's config fields
    methods: tuple[str, ...] = METHODS  # samplers compared
    seeds: int = 5  # runs per method, seeds first_seed .. first_seed + seeds - 1
    first_seed: int = 0  # the first of them (add seeds to a grid whose earlier seeds ran elsewhere)
    total_steps: int = 198_656  # training environment steps per run: 97 rounds of the default 2 x 8 x 128
    iterations_per_round: int = 2  # PPO iterations between validations
    eval_episodes: int = 64  # validation episodes per round, xi uniform on the box
    ppo: PPOConfig = field(default_factory=PPOConfig)
    sampler_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)  # per method
    sampler_signal: str = "return"  # TrainConfig.sampler_signal of every run (THRESHOLD_METHODS keep returns)
    workers: int = 2  # runs in parallel, one process each (with ray="local": the local Ray's CPUs)
    # None: a local process pool; "local": a Ray started on this machine; "auto" or HOST:PORT: join a
    # running Ray cluster (learning.execution, docs/cluster.md); the results are the same on each
    ray: str | None = None
    out: Path = Path("runs")  # run folders: <out>/<stem>/<method>/seed<k>
    # the result JSON and plots; the committed tables in docs/results are written only when asked
    results: Path = Path("runs/results")
    name: str | None = None  # results file stem; default derived from env id (+ kwargs)

    def __post_init__(self) -> None:
        for m in self.methods:
            if m not in METHODS:
                raise ValueError(f"unknown sampler {m!r}; expected one of {list(METHODS)}")
        extra = sorted(set(self.sampler_kwargs) - set(self.methods))
        if extra:
            raise ValueError(f"sampler options for {extra}, which are not among the methods {list(self.methods)}")
        if self.seeds < 1 or self.workers < 1:
            raise ValueError(f"seeds = {self.seeds}, workers = {self.workers}; expected >= 1")
        if self.first_seed < 0:
            raise ValueError(f"first_seed = {self.first_seed}; expected a seed >= 0")
        if self.ray is not None:
            parse_ray_address(self.ray, "ExperimentConfig.ray")
        self.out, self.results = Path(self.out), Path(self.results)

    def stem(self) -> str:
        if self.name:
            return self.name
        base = self.env.split("/")[-1].split("-v")[0].lower()
        extra = "-".join(f"{v}" for v in self.env_kwargs.values())
        return f"{base}-{extra}" if extra else base

    def runs(self) -> list[TrainConfig]:
        return [
            TrainConfig(
                env=self.env,
                env_kwargs=dict(self.env_kwargs),
                method=m,
                sampler_kwargs=dict(self.sampler_kwargs.get(m, {})),
                seed=s,
                total_steps=self.total_steps,
                iterations_per_round=self.iterations_per_round,
                eval_episodes=self.eval_episodes,
                ppo=self.ppo,
                sampler_signal="return" if m in THRESHOLD_METHODS else self.sampler_signal,
                out=self.out / self.stem() / m / f"seed{s}",
            )
            for m in self.methods
            for s in range(self.first_seed, self.first_seed + self.seeds)
        ]


def _mean_se(runs: list[dict], column: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-round mean over seeds of one column of the runs' uniform-box curves, and its s.e."""
    values = np.array([[point[column] for point in r["curve"][:n]] for r in runs])
    se = values.std(axis=0, ddof=1) / np.sqrt(len(runs)) if len(runs) > 1 else np.zeros(n)
    return values.mean(axis=0), se


def experiment_summary(logs: list[dict], steps: int, env: str) -> dict:
    """The experiment file: {"env", "steps", "methods": {name: {"final_success_mean",
    "final_success_se", "seeds", "curve": [[step, mean, se], ...]}}} plus the uniform-box return
    ("final_return_mean", "final_return_se", "return_curve") and timing shares."""
    out = {"env": env, "steps": steps, "methods": {}}
    for method in dict.fromkeys(log["method"] for log in logs):
        runs = [log for log in logs if log["method"] == method]
        n = min(len(r["curve"]) for r in runs)
        steps_axis = [int(r) for r, *_ in runs[0]["curve"][:n]]
        success, success_se = _mean_se(runs, 1, n)
        ret, ret_se = _mean_se(runs, 2, n)
        out["methods"][method] = {
            "final_success_mean": float(success[-1]),
            "final_success_se": float(success_se[-1]),
            "seeds": len(runs),
            "curve": [[s, float(m), float(e)] for s, m, e in zip(steps_axis, success, success_se)],
            "final_return_mean": float(ret[-1]),
            "final_return_se": float(ret_se[-1]),
            "return_curve": [[s, float(m), float(e)] for s, m, e in zip(steps_axis, ret, ret_se)],
            "sampler_time_share": float(
                sum(r["sampler_seconds"] for r in runs) / max(sum(r["seconds"] for r in runs), 1e-9)
            ),
        }
    return out


def plot_curves(summary: dict, path: Path) -> Figure:
    """Success (left) and mean return (right) on the uniform box vs training steps, mean and
    standard-error band per method; saved to `path` (a PNG). Returns the matplotlib Figure (made
    without pyplot: no backend is chosen or switched)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4))
    ax, ax_ret = fig.subplots(1, 2)
    for method, res in summary["methods"].items():
        for axis, key in ((ax, "curve"), (ax_ret, "return_curve")):
            c = np.array(res[key])
            axis.plot(c[:, 0], c[:, 1], label=method)
            axis.fill_between(c[:, 0], c[:, 1] - c[:, 2], c[:, 1] + c[:, 2], alpha=0.2)
    ax.set_ylabel("success rate on the uniform box")
    ax.set_ylim(-0.02, 1.02)
    ax_ret.set_ylabel("mean return on the uniform box")
    for axis in (ax, ax_ret):
        axis.set_xlabel("training steps")
    fig.suptitle(summary["env"])
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def _run_resources(config: TrainConfig) -> dict[str, float]:
    """What one training run asks of a worker: one CPU (torch runs on one thread, `train`), and a
    GPU where its PPO config names a CUDA device (PPO runs on the CPU today)."""
    device = str(getattr(config.ppo, "device", "cpu"))
    return {"num_cpus": 1.0, "num_gpus": 1.0 if device.startswith("cuda") else 0.0}


def _train_quiet(config: TrainConfig) -> dict:
    """One run of a grid, in a worker: `train` without its progress bar."""
    return train(config, progress=False)


def experiment_jobs(config: ExperimentConfig) -> list[Job]:
    """The experiment's runs as grid jobs (learning.execution), named <method>/seed<k>: each
    trains (or resumes) one run folder and returns its log."""
    return [Job(f"{run.method}/seed{run.seed}", _train_quiet, (run,), **_run_resources(run)) for run in config.runs()]


def experiment_backend(config: ExperimentConfig) -> Backend:
    """Where the experiment's runs go: Ray at `config.ray`, else `config.workers` local processes."""
    return make_backend(config.ray, config.workers)


def run_experiment(
    config: ExperimentConfig, progress: bool = True, command: str = "", backend: Backend | None = None
) -> dict:
    """Run every (method, seed) on `backend` (default: `experiment_backend(config)`: a pool of
    `config.workers` processes, or Ray at `config.ray`), resuming finished or interrupted runs from
    their checkpoints; write <results>/<stem>.json and .png (and, for Toy2D, the learned densities
    <stem>-densities.png) with `command` as provenance; return the summary, whose "figures" lists
    the figures written. The summary is the same on every backend but for timing shares.

    The environment and the options are checked, then the backend is started (a Ray cluster that
    cannot be reached is a ClusterError before anything is written), then the output folders are
    checked, before any run starts. A run that fails does not stop the others; GridError names it
    once they have ended (the runs keep their checkpoints: the same call goes on). On Ctrl-C the
    runs keep their last checkpoints and KeyboardInterrupt is raised."""
    config.runs()  # validates every run's options
    probe_env(config.env, config.env_kwargs)
    with backend or experiment_backend(config) as grid:
        check_output_dir(config.out, "run folder")
        check_output_dir(config.results, "results folder")
        logs = run_grid(experiment_jobs(config), grid, progress, f"experiment {config.stem()}")
    return write_experiment(config, logs, command)


def write_experiment(config: ExperimentConfig, logs: list[dict], command: str = "") -> dict:
    """Summarize the logs of `config`'s runs (in `runs()` order) and write the results file and
    figures into `config.results` (an existing folder); return the summary."""
    summary = experiment_summary(logs, config.total_steps, config.env)
    summary["command"] = command
    stem = config.results / config.stem()
    summary["figures"] = [str(stem) + ".png"]
    plot_curves(summary, Path(summary["figures"][0]))
    if gymnasium.spec(config.env).name == "Toy2D":
        from learning.plots import plot_toy2d_densities

        summary["figures"].append(str(stem) + "-densities.png")
        finals = {m: load_run(config.out / config.stem() / m / "seed0").sampler for m in config.methods}
        plot_toy2d_densities(config.env, config.env_kwargs, finals, Path(summary["figures"][-1]))
    write_json(str(stem) + ".json", summary)
    return summary


def format_summary(summary: dict) -> str:
    """A table of final success and return per method and the sampler update's share of wall time."""
    lines = [
        f"{summary['env']}  ({summary['steps']} steps per run)",
        f"{'method':<10} {'final success':>14} {'final return':>18} {'seeds':>6} {'sampler time':>13}",
    ]
    for method, res in summary["methods"].items():
        ret = f"{res['final_return_mean']:.1f} +- {res['final_return_se']:.1f}"
        lines.append(
            f"{method:<10} {res['final_success_mean']:>7.3f} +- {res['final_success_se']:<5.3f}"
            f" {ret:>18} {res['seeds']:>6} {100 * res['sampler_time_share']:>12.1f}%"
        )
    return "\n".join(lines)
