"""Wall time of one sampler update per method and parameter dimension, and the training round it
needs for the update to stay within the 5 % share of training time (issue 4's speed target).

    .venv/bin/python -m benchmarks.sampler_update [--dims 1 3 5] [--batch 32] [--repeats 5] [--json PATH]

Each update gets a validation-sized batch (`--batch` uniform draws, ADR its own draws, with
returns that peak in the box's centre), as `goflow train` gives it. One torch thread, as in training. The GoFlow rows also
time zuko's own NSF class beside ours (`learning.samplers.spline_flow.build_spline_flow`, the same
function with a cheaper bin softmax), and each GoFlow mode (the constrained mode learns from 0/1
successes, 1 where the return >= 0.6), side by side in one process. "round for 5 %" is 19 x the
update: the round's training + validation time at which the update is 5 % of the total.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import zuko

import learning.samplers.spline_flow as goflow_module
from assembly.params import Param, ParamSpace
from learning.samplers.registry import METHODS, make_sampler, protocol_sampler_kwargs
from goflow_common.files import write_json


def _zuko_nsf(features: int, transforms: int, hidden_features: tuple[int, ...], bins: int) -> zuko.flows.Flow:
    return zuko.flows.NSF(features=features, transforms=transforms, hidden_features=hidden_features, bins=bins)


def time_update(method: str, d: int, batch: int, repeats: int, config: dict | None = None) -> float:
    """Median seconds of `repeats` updates of a fresh `method` sampler (options `config`) on a
    d-dimensional unit box."""
    space = ParamSpace(tuple(Param(f"p{i}", 0.0, 1.0, "1") for i in range(d)))
    config = dict(config or {})
    sampler = make_sampler(method, space, 0.5, protocol_sampler_kwargs(method, config))
    successes = config.get("mode") == "constrained"  # learns from 0/1 successes
    rng = np.random.default_rng(0)
    times = []
    for _ in range(repeats + 1):  # the first update warms up torch and scipy
        # ADR learns only from its own boundary draws (the training phase's); the others get the
        # uniform validation batch
        xi = sampler.sample(batch, rng) if method == "adr" else rng.uniform(0.0, 1.0, (batch, d))
        returns = 1.0 - np.linalg.norm(xi - 0.5, axis=1)
        if successes:
            returns = (returns >= 0.6).astype(float)
        t0 = time.perf_counter()
        sampler.update(xi, returns)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dims", type=int, nargs="+", default=[1, 3, 5])
    parser.add_argument("--batch", type=int, default=32, help="validation episodes per update")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    ours = goflow_module.build_spline_flow
    for d in args.dims:
        for method in METHODS:
            variants = (
                [("", ours, {})]
                if method != "goflow"
                else [
                    (" (entropy)", ours, {"mode": "entropy"}),
                    (" (constrained)", ours, {"mode": "constrained"}),
                    (
                        " (constrained, k-NN, flow alone)",
                        ours,
                        {"mode": "constrained", "feasible_model": "knn", "feasible_level": 0.8, "truncate": False},
                    ),
                    (" (paper)", ours, {"mode": "paper"}),
                    (" (paper, zuko NSF class)", _zuko_nsf, {"mode": "paper"}),
                ]
            )
            for suffix, builder, config in variants:
                goflow_module.build_spline_flow = builder
                try:
                    seconds = time_update(method, d, args.batch, args.repeats, config)
                finally:
                    goflow_module.build_spline_flow = ours
                rows.append(
                    {
                        "method": method + suffix,
                        "dim": d,
                        "batch": args.batch,
                        "update_s": seconds,
                        "round_for_5pct_s": 19.0 * seconds,
                    }
                )
    print(f"{'method':<28} {'d':>2} {'update [s]':>11} {'round for 5 % [s]':>18}")
    for r in rows:
        print(f"{r['method']:<28} {r['dim']:>2} {r['update_s']:>11.3f} {r['round_for_5pct_s']:>18.2f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, {"command": "benchmarks/sampler_update.py", "rows": rows})


if __name__ == "__main__":
    main()
