"""How far GearInsertion-v0's "fast" and "panda" variants disagree for the same xi and actions.

For each xi (uniform over a box, seeded) and each open-loop action sequence, run both variants
and compare success, return and final insertion error. Prints a table; --json writes it.

    .venv/bin/python -m benchmarks.insertion_variants --episodes 20 --json docs/results/insertion_variants.json
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from assembly.envs.gear_insertion import GearInsertionEnv
from goflow_common.files import write_json


def action_sequences(steps: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Open-loop policies: push straight down; push down while circling (a spiral search)."""
    down = np.tile([0.0, 0.0, -1.0, 0.0], (steps, 1))
    t = np.arange(steps)
    radius = np.minimum(t / steps, 1.0) * 0.6
    spiral = np.stack(
        [
            radius * np.cos(0.6 * t),
            radius * np.sin(0.6 * t),
            -0.5 * np.ones(steps),
            0.3 * np.sin(0.2 * t + rng.uniform(0, 2 * np.pi)),
        ],
        axis=1,
    )
    return {"down": down, "spiral": spiral}


def rollout(env: GearInsertionEnv, xi: np.ndarray, actions: np.ndarray) -> dict:
    env.reset(seed=0, options={"xi": xi})
    total, info = 0.0, {}
    for a in actions:
        _, r, terminated, truncated, info = env.step(a)
        total += r
        if terminated or truncated:
            break
    lateral, height = env.insertion_error()
    return {
        "return": total,
        "success": bool(info.get("success", False)),
        "lateral_mm": 1e3 * lateral,
        "height_mm": 1e3 * height,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gear", default="medium")
    parser.add_argument("--episodes", type=int, default=20, help="xi per box")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    envs = {v: GearInsertionEnv(gear=args.gear, variant=v) for v in ("fast", "panda")}
    boxes = {
        "near (+-3 mm, +-0.2 rad)": np.array([0.003, 0.003, 0.2]),
        "seed box (+-5 cm, +-0.393 rad)": envs["fast"].space.high,
    }
    sequences = action_sequences(envs["fast"].max_episode_steps, rng)
    rows = []
    print(
        f"{'xi box':<32} {'actions':<7} {'n':>3} {'success agree':>13} {'fast succ':>9} "
        f"{'panda succ':>10} {'|dR| mean':>9} {'|d lat| mm':>10}"
    )
    for box_name, half in boxes.items():
        xis = rng.uniform(-half, half, size=(args.episodes, 3))
        for seq_name, actions in sequences.items():
            runs = {v: [] for v in envs}
            wall = {v: 0.0 for v in envs}
            for xi in xis:
                for v, env in envs.items():
                    t0 = time.perf_counter()
                    runs[v].append(rollout(env, xi, actions))
                    wall[v] += time.perf_counter() - t0
            f, p = runs["fast"], runs["panda"]
            row = {
                "box": box_name,
                "actions": seq_name,
                "episodes": len(xis),
                "success_agreement": float(np.mean([a["success"] == b["success"] for a, b in zip(f, p)])),
                "fast_success": float(np.mean([a["success"] for a in f])),
                "panda_success": float(np.mean([b["success"] for b in p])),
                "mean_abs_return_diff": float(np.mean([abs(a["return"] - b["return"]) for a, b in zip(f, p)])),
                "mean_abs_lateral_diff_mm": float(
                    np.mean([abs(a["lateral_mm"] - b["lateral_mm"]) for a, b in zip(f, p)])
                ),
                "sim_seconds_per_wall_second": {
                    v: len(xis) * envs[v].max_episode_steps * envs[v].control_dt / wall[v] for v in envs
                },
            }
            rows.append(row)
            print(
                f"{box_name:<32} {seq_name:<7} {len(xis):>3} {row['success_agreement']:>13.2f} "
                f"{row['fast_success']:>9.2f} {row['panda_success']:>10.2f} "
                f"{row['mean_abs_return_diff']:>9.2f} {row['mean_abs_lateral_diff_mm']:>10.2f}",
                flush=True,
            )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, {"gear": args.gear, "rows": rows})


if __name__ == "__main__":
    main()
