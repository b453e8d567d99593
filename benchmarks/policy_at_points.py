"""A trained run's final policy evaluated at fixed parameter points: where in the box it succeeds.

    .venv/bin/python benchmarks/policy_at_points.py --runs runs/quadrotor-1m/fulldr/seed0 ... --points 0.05 0.775 3.0 [--episodes 16] [--json PATH]

`--runs` are `goflow train` / `goflow experiment` run folders (<folder>/checkpoint.pt). Each value
of `--points` is one parameter vector, its numbers separated by commas (e.g. `1,1,0.2` for
Cartpole's pole mass, cart mass and friction). Every point gets `--episodes` episodes of the
stochastic policy, as in validation, with the same seed for every run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

import assembly  # noqa: F401  (registers the goflow/* ids)
from assembly.samplers import NoDR
from learning.experiment import make_vector_env, load_run
from goflow_common.files import write_json

VECTOR_ENVS = 4


def evaluate_at(run: Path, points: list[np.ndarray], episodes: int, seed: int = 0) -> list[dict]:
    """Success rate and mean return of the run's final policy with the env's parameters fixed at each point."""
    loaded = load_run(run)
    vec_env = make_vector_env(loaded.config, VECTOR_ENVS)
    rows = []
    for point in points:
        if len(point) != loaded.space.dim:
            raise ValueError(f"point {point.tolist()} has {len(point)} numbers; {run} needs {loaded.space.dim} "
                             f"({', '.join(loaded.space.names)})")
        vec_env.set_attr("sampler", NoDR(loaded.space, point=point))  # NoDR raises if the point is outside the box
        _, returns, success = loaded.agent.evaluate(vec_env, episodes, seed=seed)
        rows.append({"point": point.tolist(), "success": float(success.mean()), "return": float(returns.mean())})
    vec_env.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True)
    parser.add_argument("--points", nargs="+", required=True, help="parameter vectors, e.g. 0.775 or 1,1,0.2")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")
    try:
        points = [np.array([float(v) for v in p.split(",")]) for p in args.points]
    except ValueError as exc:
        raise SystemExit(f"--points: each point is numbers separated by commas ({exc})") from exc
    torch.set_num_threads(1)
    rows = []
    print(f"{'run':44} {'point':>16} {'success':>8} {'return':>9}")
    for run in args.runs:
        for row in evaluate_at(run, points, args.episodes):
            rows.append({"run": str(run), **row})
            print(f"{str(run):44} {','.join(f'{v:g}' for v in row['point']):>16} {row['success']:>8.3f} {row['return']:>9.2f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, {"episodes": args.episodes, "rows": rows})


if __name__ == "__main__":
    main()
