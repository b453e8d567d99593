"""Our Drake locomotion envs against gymnasium's MuJoCo originals (issue 20, item 2).

For each env, at nominal xi: uniform-random-action episodes in both (mean return and length),
the per-step reward distribution (mean, std, two-sample KS statistic), and open-loop divergence
from one shared initial state under the same actions (zero and random) after 0.1 s and 1 s: the
largest generalized-position difference, x excluded. Prints a table; --json writes it.

    .venv/bin/python -m benchmarks.mujoco_fidelity --episodes 100 --json docs/results/mujoco_fidelity.json

Needs the `mujoco` extra (`make test` installs it where it can).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np

import assembly  # noqa: F401
from assembly.envs.mujoco_reference import ORIGINALS, paired_rollout, random_action_episodes, reference_env
from goflow_common.files import write_json


def step_rewards(env, steps: int, seed: int, options=None) -> np.ndarray:
    """Per-step rewards of `steps` uniform-random-action steps, resetting at episode ends."""
    rng = np.random.default_rng(seed)
    out = []
    env.reset(seed=seed, options=options)
    n = 0
    while len(out) < steps:
        _, r, terminated, truncated, _ = env.step(rng.uniform(env.action_space.low, env.action_space.high))
        out.append(r)
        n += 1
        if terminated or truncated or n >= 1000:
            env.reset(options=options)
            n = 0
    return np.array(out)


def ks_statistic(a: np.ndarray, b: np.ndarray) -> float:
    grid = np.sort(np.concatenate([a, b]))
    fa = np.searchsorted(np.sort(a), grid, side="right") / a.size
    fb = np.searchsorted(np.sort(b), grid, side="right") / b.size
    return float(np.max(np.abs(fa - fb)))


def compare(env_id: str, episodes: int, rollouts: int, overrides: dict) -> dict:
    ours = gymnasium.make(env_id, **overrides).unwrapped
    ref = reference_env(env_id)
    nominal = {"xi": ours.space.nominal()}
    row: dict = {"env": env_id, "original": ORIGINALS[env_id], "overrides": overrides}
    t = time.perf_counter()
    r_ours, l_ours = random_action_episodes(ours, episodes, 0, reset_options=nominal)
    t_ours = time.perf_counter() - t
    t = time.perf_counter()
    r_ref, l_ref = random_action_episodes(ref, episodes, 0)
    t_ref = time.perf_counter() - t
    row.update(
        return_ours=r_ours.mean(),
        return_ours_se=r_ours.std(ddof=1) / np.sqrt(episodes),
        return_ref=r_ref.mean(),
        return_ref_se=r_ref.std(ddof=1) / np.sqrt(episodes),
        length_ours=l_ours.mean(),
        length_ref=l_ref.mean(),
        steps_per_s_ours=l_ours.sum() / t_ours,
        steps_per_s_ref=l_ref.sum() / t_ref,
    )
    s_ours, s_ref = step_rewards(ours, 2000, 1, nominal), step_rewards(ref, 2000, 1)
    row.update(
        step_reward_ours=[s_ours.mean(), s_ours.std()],
        step_reward_ref=[s_ref.mean(), s_ref.std()],
        step_reward_ks=ks_statistic(s_ours, s_ref),
    )
    dt = ours.control_dt
    n01, n1 = max(1, int(round(0.1 / dt))), int(round(1.0 / dt))
    for mode in ("zero", "random"):
        d01, d1 = [], []
        for s in range(rollouts):
            shape = (n1, ours.action_space.shape[0])
            actions = (
                np.zeros(shape)
                if mode == "zero"
                else np.random.default_rng(100 + s).uniform(ours.action_space.low, ours.action_space.high, shape)
            )
            p = paired_rollout(ours, ref, actions, seed=100 + s)
            d01.append(p.divergence(n01))
            d1.append(p.divergence(n1))
        row[f"divergence_{mode}_0.1s"] = float(np.median(d01))
        row[f"divergence_{mode}_1s"] = float(np.median(d1))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(ORIGINALS))
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--rollouts", type=int, default=10)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="env config overrides")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.episodes < 2 or args.rollouts < 1:
        raise SystemExit(f"--episodes must be >= 2 and --rollouts >= 1, got {args.episodes}, {args.rollouts}")
    unknown = [e for e in args.envs if e not in ORIGINALS]
    if unknown:
        raise SystemExit(f"unknown env(s) {unknown}; expected some of {list(ORIGINALS)}")
    overrides = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected KEY=VALUE")
        try:
            overrides[key] = float(value)
        except ValueError:
            overrides[key] = value
    rows = []
    print(
        f"{'env':<22} {'return ours':>16} {'return MuJoCo':>16} {'diff':>6} {'len ours':>8} {'len MuJoCo':>10} "
        f"{'diff':>6} {'KS':>5} {'div0.1 z/r':>12} {'div1 z/r':>12} {'steps/s':>13}"
    )
    for env_id in args.envs:
        r = compare(env_id, args.episodes, args.rollouts, overrides)
        rows.append(r)
        dr = (r["return_ours"] - r["return_ref"]) / abs(r["return_ref"])
        dl = (r["length_ours"] - r["length_ref"]) / r["length_ref"]
        print(
            f"{env_id:<22} {r['return_ours']:9.1f}+-{r['return_ours_se']:<5.1f} {r['return_ref']:9.1f}+-"
            f"{r['return_ref_se']:<5.1f} {100 * dr:5.0f}% {r['length_ours']:8.1f} {r['length_ref']:10.1f} "
            f"{100 * dl:5.0f}% {r['step_reward_ks']:5.2f} "
            f"{r['divergence_zero_0.1s']:5.3f}/{r['divergence_random_0.1s']:<6.3f}"
            f"{r['divergence_zero_1s']:5.2f}/{r['divergence_random_1s']:<6.2f} "
            f"{r['steps_per_s_ours']:5.0f}/{r['steps_per_s_ref']:<6.0f}",
            flush=True,
        )
    if args.json:
        write_json(
            args.json,
            {
                "command": "benchmarks/mujoco_fidelity.py",
                "episodes": args.episodes,
                "rollouts": args.rollouts,
                "rows": rows,
            },
        )


if __name__ == "__main__":
    main()
