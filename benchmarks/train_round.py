"""Where a training round's wall time goes: rollouts (env steps + policy), the PPO update,
validation episodes and the sampler's update, for today's SyncVectorEnv and the batched env.

    .venv/bin/python benchmarks/train_round.py [--envs goflow/Cartpole-v0 ...] [--rounds 2]
        [--method goflow] [--json docs/results/train_round.json]

Each cell is one `learning.experiment.train` run of `--rounds` rounds at the default settings
(TrainConfig, PPOConfig) with only the vectorization changed; the phases are timed by wrapping
PPO.collect, PPO.update, PPO.evaluate and the sampler's update. The issue's target: the PPO update
at most a third of a round.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import assembly  # noqa: F401  (registers the ids)
from goflow_common.files import check_output_file, write_json
from learning.experiment import TrainConfig, train
from learning.ppo import PPO

ENVS = ("goflow/Cartpole-v0", "goflow/Quadrotor-v0", "goflow/GearInsertion-v0")
TIMED_CALLS = {"collect": (PPO, "collect"), "update": (PPO, "update"), "evaluate": (PPO, "evaluate")}


def timed_round(env: str, vectorization: str, rounds: int, method: str) -> dict[str, float]:
    """Seconds per phase (and "total", "sampler" = the rest: sampler update and bookkeeping) of
    `rounds` training rounds."""
    spent = {name: 0.0 for name in TIMED_CALLS}
    originals = {}
    for name, (owner, attr) in TIMED_CALLS.items():
        inner = getattr(owner, attr)
        originals[name] = inner

        def wrapper(*args, _inner=inner, _name=name, **kwargs):
            t0 = time.perf_counter()
            try:
                return _inner(*args, **kwargs)
            finally:
                spent[_name] += time.perf_counter() - t0

        setattr(owner, attr, wrapper)
    try:
        config = TrainConfig(env=env, method=method, vectorization=vectorization)
        steps = config.steps_per_round() * rounds
        config = TrainConfig(env=env, method=method, vectorization=vectorization, total_steps=steps)
        t0 = time.perf_counter()
        train(config, progress=False)
        total = time.perf_counter() - t0
    finally:
        for name, (owner, attr) in TIMED_CALLS.items():
            setattr(owner, attr, originals[name])
    spent["total"] = total
    spent["other"] = total - sum(spent[name] for name in TIMED_CALLS)
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--method", default="goflow")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error(f"--rounds {args.rounds}: expected >= 1")
    if args.json:
        check_output_file(args.json)
    header = (
        f"{'env':<26} {'vectorization':<13} {'round s':>8} {'collect':>8} {'update':>8} "
        f"{'evaluate':>9} {'other':>7} {'update share':>13}"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for env in args.envs:
        for vectorization in ("sync", "batched"):
            spent = timed_round(env, vectorization, args.rounds, args.method)
            per = {k: v / args.rounds for k, v in spent.items()}
            share = per["update"] / per["total"]
            rows.append({"env": env, "vectorization": vectorization, "seconds_per_round": per, "update_share": share})
            print(
                f"{env:<26} {vectorization:<13} {per['total']:>8.1f} {per['collect']:>8.1f} {per['update']:>8.1f} "
                f"{per['evaluate']:>9.1f} {per['other']:>7.1f} {100 * share:>12.0f}%",
                flush=True,
            )
    if args.json:
        write_json(
            args.json,
            {"command": "benchmarks/train_round.py", "rounds": args.rounds, "method": args.method, "rows": rows},
        )


if __name__ == "__main__":
    main()
