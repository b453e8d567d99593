"""Where each method's final sampler puts its mass: the fraction of its draws inside a region of the
parameter box (e.g. Quadrotor's hoverable masses), beside its entropy and the run's last returns.

    .venv/bin/python benchmarks/sampler_mass.py --runs runs/quadrotor --low 0.01 --high 1.47 [--json PATH]
    .venv/bin/python benchmarks/sampler_mass.py --runs runs/toy2d-circle --env-feasible-set [--json PATH]

`--runs` is a `goflow experiment` output folder (<runs>/<method>/seed<k>/checkpoint.pt). `--low` and
`--high` give the region, one number per parameter. `--env-feasible-set` takes instead the run
environment's own feasible set (an env with `feasible_set(points)`, e.g. Toy2D) and adds the
sampler's coverage of it: the share of the set where its density exceeds 10 % and 1 % of the
uniform-on-set density (learning.feasible_sets.coverage). Returns are the mean over the last
three rounds: "uniform" on the validation episodes (xi uniform on the box), "training" on the
training episodes (xi from the sampler).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learning.experiment import load_run, probe_env
from learning.feasible_sets import mass_on, report_on
from learning.samplers.registry import METHODS
from goflow_common.files import write_json


def region_mass(run: Path, low: np.ndarray | None, high: np.ndarray | None, draws: int = 4000) -> dict:
    """The final sampler's mass in [low, high] (or, when both are None, on the run env's feasible
    set, with its coverage of that set), its entropy and the run's last returns."""
    loaded = load_run(run)
    rng = np.random.default_rng(0)
    row = {}
    if low is None:
        env = probe_env(loaded.config.env, loaded.config.env_kwargs)
        if not hasattr(env, "feasible_set"):
            raise ValueError(f"{loaded.config.env} has no feasible_set(points); give --low and --high")
        row = report_on(loaded.sampler, env.feasible_set, loaded.space, rng, draws)
        mass = row.pop("mass_on")
    else:
        if len(low) != loaded.space.dim or len(high) != loaded.space.dim:
            raise ValueError(f"--low/--high need {loaded.space.dim} numbers ({', '.join(loaded.space.names)}), "
                             f"got {len(low)} and {len(high)}")
        mass = mass_on(loaded.sampler.sample(draws, rng), lambda x: np.all((x >= low) & (x <= high), axis=1))
    log = loaded.state["log"]
    return {"mass": mass, **row,
            "entropy": float(loaded.sampler.entropy()),
            "final_success": float(log["curve"][-1][1]),
            "uniform_return": float(np.mean([c[2] for c in log["curve"][-3:]])),
            "training_return": float(np.mean([c[2] for c in log["train_curve"][-3:]]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, required=True)
    parser.add_argument("--low", type=float, nargs="+")
    parser.add_argument("--high", type=float, nargs="+")
    parser.add_argument("--env-feasible-set", action="store_true",
                        help="the run env's own feasible set instead of --low/--high, with coverage")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    box_given = args.low is not None or args.high is not None
    if args.env_feasible_set == box_given or (args.low is None) != (args.high is None):
        raise SystemExit("give either --low and --high, or --env-feasible-set")
    low, high = (None, None) if args.env_feasible_set else (np.asarray(args.low), np.asarray(args.high))
    table = {}
    for method in METHODS:
        runs = sorted(p.parent for p in (args.runs / method).glob("seed*/checkpoint.pt"))
        if runs:
            table[method] = [region_mass(run, low, high) for run in runs]
    if not table:
        raise SystemExit(f"no runs under {args.runs} (expected <method>/seed<k>/checkpoint.pt)")
    print(f"{'method':<9} {'seeds':>5} {'mass in region':>15} {'coverage 10 %':>14} {'entropy':>8} "
          f"{'final success':>14} {'uniform return':>15} {'training return':>16}")
    for method, rows in table.items():
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        cover = f"{mean['coverage10']:>14.3f}" if "coverage10" in mean else f"{'-':>14}"
        print(f"{method:<9} {len(rows):>5} {mean['mass']:>15.3f} {cover} {mean['entropy']:>8.2f} "
              f"{mean['final_success']:>14.3f} {mean['uniform_return']:>15.2f} {mean['training_return']:>16.2f}")
    if args.json:
        write_json(args.json, {"runs": str(args.runs), "low": args.low, "high": args.high,
                               "env_feasible_set": args.env_feasible_set, "methods": table})


if __name__ == "__main__":
    main()
