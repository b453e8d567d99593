"""How long does DROPO need to match NFPDE-Softmax? One DROPO run with `--factor` times the table's
simulator budget on Cartpole's mixed-Gaussian target (dataset and estimator seed 0), compared with
the NFPDE-Softmax runs of docs/results/nfpde_runs.json on the same dataset: when (wall time,
simulator calls) each first reaches a given OT. Writes docs/results/nfpde_long_dropo.json.

Usage: .venv/bin/python benchmarks/nfpde_long_dropo.py --factor 5
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nfpde_table import RESULTS, run_one  # noqa: E402
from common.files import write_json  # noqa: E402


def first_reach(trace: list[dict], level: float) -> dict | None:
    """The first snapshot with OT <= level (None if never)."""
    return next(({"seconds": t["seconds"], "calls": t["calls"], "ot": t["ot"]} for t in trace if t["ot"] <= level), None)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="goflow/Cartpole-v0")
    p.add_argument("--target", default="mixture")
    p.add_argument("--factor", type=float, default=5.0)
    args = p.parse_args()
    runs = json.loads((RESULTS / "nfpde_runs.json").read_text())["runs"]
    nf = next(r for r in runs if (r["env"], r["target"], r["method"], r["seed"]) == (args.env, args.target, "nfpde-softmax", 0))
    dropo = next(r for r in runs if (r["env"], r["target"], r["method"], r["seed"]) == (args.env, args.target, "dropo", 0))
    budget = int(args.factor * nf["sim_budget"])
    long = run_one(args.env, args.target, "dropo", 0, budget, 48, {})
    levels = sorted({round(nf["ot"] * 1.1, 4), round(dropo["ot"], 4), 0.2})
    out = {"env": args.env, "target": args.target, "budget_nfpde": nf["sim_budget"], "budget_dropo_long": budget,
           "nfpde_softmax": {"ot": nf["ot"], "seconds_total": nf["seconds_total"]},
           "dropo_long": {"ot": long["ot"], "seconds_total": long["seconds_total"], "trace": long["trace"],
                          "details": long["details"]},
           "reach": {str(level): {"nfpde-softmax": first_reach(nf["trace"], level),
                                  "dropo (long)": first_reach(long["trace"], level)} for level in levels},
           "command": "python benchmarks/nfpde_long_dropo.py " + " ".join(sys.argv[1:])}
    write_json(RESULTS / "nfpde_long_dropo.json", out)
    print(json.dumps({k: v for k, v in out.items() if k != "dropo_long"}, indent=1))
    print("dropo long: OT", round(long["ot"], 3), "in", round(long["seconds_total"], 1), "s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
