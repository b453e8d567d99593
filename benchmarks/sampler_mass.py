"""Where each method's final sampler puts its mass: the fraction of its draws inside a region of the
parameter box (e.g. Quadrotor's hoverable masses), beside its entropy and the run's last returns.

    .venv/bin/python benchmarks/sampler_mass.py --runs runs/quadrotor --low 0.01 --high 1.47 [--json PATH]

`--runs` is a `goflow experiment` output folder (<runs>/<method>/seed<k>/checkpoint.pt). `--low` and
`--high` give the region, one number per parameter. Returns are the mean over the last three
rounds: "uniform" on the validation episodes (xi uniform on the box), "training" on the training
episodes (xi from the sampler).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learning.experiment import load_run
from learning.samplers.registry import METHODS
from common.files import write_json


def region_mass(run: Path, low: np.ndarray, high: np.ndarray, draws: int = 4000) -> dict:
    """The final sampler's mass in [low, high], its entropy and the run's last returns."""
    loaded = load_run(run)
    if len(low) != loaded.space.dim or len(high) != loaded.space.dim:
        raise ValueError(f"--low/--high need {loaded.space.dim} numbers ({', '.join(loaded.space.names)}), "
                         f"got {len(low)} and {len(high)}")
    xi = loaded.sampler.sample(draws, np.random.default_rng(0))
    log = loaded.state["log"]
    return {"mass": float(np.mean(np.all((xi >= low) & (xi <= high), axis=1))),
            "entropy": float(loaded.sampler.entropy()),
            "uniform_return": float(np.mean([c[2] for c in log["curve"][-3:]])),
            "training_return": float(np.mean([c[2] for c in log["train_curve"][-3:]]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, required=True)
    parser.add_argument("--low", type=float, nargs="+", required=True)
    parser.add_argument("--high", type=float, nargs="+", required=True)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    low, high = np.asarray(args.low), np.asarray(args.high)
    table = {}
    for method in METHODS:
        runs = sorted(p.parent for p in (args.runs / method).glob("seed*/checkpoint.pt"))
        if runs:
            table[method] = [region_mass(run, low, high) for run in runs]
    if not table:
        raise SystemExit(f"no runs under {args.runs} (expected <method>/seed<k>/checkpoint.pt)")
    print(f"{'method':<9} {'seeds':>5} {'mass in region':>15} {'entropy':>8} {'uniform return':>15} {'training return':>16}")
    for method, rows in table.items():
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        print(f"{method:<9} {len(rows):>5} {mean['mass']:>15.3f} {mean['entropy']:>8.2f} {mean['uniform_return']:>15.2f} "
              f"{mean['training_return']:>16.2f}")
    if args.json:
        write_json(args.json, {"runs": str(args.runs), "low": args.low, "high": args.high,
                                         "methods": table})


if __name__ == "__main__":
    main()
