"""A policy trained in one simulator, evaluated in the other (issue 20, item 2): stable-baselines3's
SAC (its defaults) trained on our Drake env at nominal xi and on gymnasium's MuJoCo original, each
final policy scored on both (deterministic actions, the same episode seeds). A transfer gap in
one direction only says which simulator's policy exploits what the other does not model.

Every finished run is appended to --json (a rerun skips it), then the table is printed.

    .venv/bin/python benchmarks/cross_sim_policy.py --envs goflow/Hopper-v0 --seeds 3 --steps 30000 \\
        --json docs/results/cross_sim_policy.json

Needs the extras `mujoco` and `sb3` (`make test` installs both where it can).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gymnasium
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import assembly  # noqa: E402,F401
from assembly.envs.mujoco_reference import ORIGINALS, reference_env  # noqa: E402
from assembly.samplers import NoDR  # noqa: E402
from goflow_common.errors import InputError  # noqa: E402
from goflow_common.files import check_output_file, write_json  # noqa: E402
from learning.estimation.transfer import run_episodes  # noqa: E402

SIMS = ("drake", "mujoco")


def make(env_id: str, sim: str) -> gymnasium.Env:
    """Our env at nominal xi (sim "drake"), or gymnasium's original with its time limit."""
    if sim == "mujoco":
        reference_env(env_id)  # a clear error without the mujoco package
        return gymnasium.make(ORIGINALS[env_id])
    env = gymnasium.make(env_id)
    env.unwrapped.sampler = NoDR(env.unwrapped.space)
    return env


def one_run(env_id: str, sim: str, seed: int, steps: int, episodes: int) -> dict:
    """Train SAC in `sim` for `steps` env steps; score the final policy in both simulators."""
    import torch
    from stable_baselines3 import SAC

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    model = SAC("MlpPolicy", make(env_id, sim), seed=seed, device="cpu", verbose=0)
    model.learn(steps)
    seconds = time.perf_counter() - t0
    row = {"env": env_id, "trained_in": sim, "seed": seed, "steps": steps, "train_seconds": seconds}
    for other in SIMS:
        returns, _ = run_episodes(lambda o: model.predict(o, deterministic=True)[0], make(env_id, other),
                                  episodes, seed=10_000 + seed * episodes)
        row[f"return_in_{other}"] = returns.tolist()
    return row


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["goflow/Hopper-v0"], choices=sorted(ORIGINALS))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--steps", type=int, default=30_000, help="SAC env steps per policy")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per simulator")
    p.add_argument("--json", default=None, help="results file (resumed if it exists)")
    args = p.parse_args()
    if args.steps < 1 or args.seeds < 1 or args.episodes < 1:
        p.error(f"--steps, --seeds and --episodes must be >= 1, got {args.steps}, {args.seeds}, {args.episodes}")
    try:
        path = check_output_file(args.json, "--json") if args.json else None
    except InputError as exc:
        p.error(str(exc))
    doc = json.loads(path.read_text()) if path and path.exists() else {"runs": []}
    doc["command"] = "python benchmarks/cross_sim_policy.py " + " ".join(sys.argv[1:])
    done = {(r["env"], r["trained_in"], r["seed"], r["steps"]) for r in doc["runs"]}
    for env_id in args.envs:
        for seed in range(args.seeds):
            for sim in SIMS:
                if (env_id, sim, seed, args.steps) in done:
                    continue
                row = one_run(env_id, sim, seed, args.steps, args.episodes)
                doc["runs"].append(row)
                if path:
                    write_json(path, doc)
                print(f"{env_id} trained in {sim} seed {seed}: drake {np.mean(row['return_in_drake']):.1f}, "
                      f"mujoco {np.mean(row['return_in_mujoco']):.1f} ({row['train_seconds']:.0f} s)", flush=True)
    print("| env | trained in | return in Drake | return in MuJoCo | policies |")
    print("|---|---|---|---|---|")
    for env_id in args.envs:
        for sim in SIMS:
            runs = [r for r in doc["runs"] if r["env"] == env_id and r["trained_in"] == sim and r["steps"] == args.steps]
            if not runs:
                continue
            cells = []
            for other in SIMS:
                per_policy = np.array([np.mean(r[f"return_in_{other}"]) for r in runs])
                se = per_policy.std(ddof=1) / np.sqrt(len(runs)) if len(runs) > 1 else 0.0
                cells.append(f"{per_policy.mean():.1f} +- {se:.1f}")
            print(f"| {env_id} | {sim} | {cells[0]} | {cells[1]} | {len(runs)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
