"""How long does DROPO need to match NFPDE-Softmax? One DROPO run with `--factor` times the table's
simulator budget on one (env, target) cell of a `benchmarks/nfpde_table.py` runs file (dataset and
estimator seed `--seed`), compared with that cell's NFPDE-Softmax and DROPO runs: when (wall time,
simulator calls) each first reaches a given OT, and the ratio DROPO / NFPDE-Softmax at each level
(a lower bound, marked, where the long DROPO run never reaches it).

Levels: 1.1 x NFPDE-Softmax's final OT (DROPO matching NFPDE), DROPO's final OT at the table's budget
(NFPDE matching DROPO), and 0.2. Writes docs/results/<name>_long_dropo-<env>-<target>.json.

Usage: .venv/bin/python benchmarks/nfpde_long_dropo.py --factor 5
       .venv/bin/python benchmarks/nfpde_long_dropo.py --name nfpde_locomotion --env goflow/Hopper-v0 --target mixture5
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nfpde_table import RESULTS, run_one  # noqa: E402
from goflow_common.files import check_output_file, read_json, write_json  # noqa: E402
from learning.estimation.targets import TARGETS  # noqa: E402


def cell_of(record: dict) -> tuple:
    """The (env, target, seed) a run or an output of this script belongs to."""
    return record.get("env"), record.get("target"), record.get("seed")


def find_run(runs: list[dict], cell: tuple, method: str) -> dict | None:
    """The run of `method` on `cell` in a runs file's list (None if there is none)."""
    return next((r for r in runs if cell_of(r) == cell and r["method"] == method), None)


def first_reach(trace: list[dict], level: float) -> dict | None:
    """The first snapshot with OT <= level (None if never)."""
    return next(({"seconds": t["seconds"], "calls": t["calls"], "ot": t["ot"]} for t in trace if t["ot"] <= level), None)


def ratio(slow: dict | None, fast: dict | None, slow_run: dict) -> dict | None:
    """DROPO's time and calls to a level over NFPDE-Softmax's; where DROPO never got there, its
    whole run over NFPDE's (a lower bound, `at_least`). None where NFPDE never got there, or where
    both were there from their first snapshot (no time to compare)."""
    if fast is None or (fast["calls"] == 0 and (slow is None or slow["calls"] == 0)):
        return None
    if slow is None:
        return {"seconds": slow_run["seconds_total"] / max(fast["seconds"], 1e-9),
                "calls": slow_run["sim_calls"] / max(fast["calls"], 1), "at_least": True}
    return {"seconds": slow["seconds"] / max(fast["seconds"], 1e-9), "calls": slow["calls"] / max(fast["calls"], 1),
            "at_least": False}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--name", default="nfpde", help="stem of the nfpde_table runs file")
    p.add_argument("--env", default="goflow/Cartpole-v0")
    p.add_argument("--target", default="mixture", choices=TARGETS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--factor", type=float, default=5.0)
    p.add_argument("--json", type=Path, default=None,
                   help="output file (default docs/results/<name>_long_dropo-<env>-<target>.json)")
    p.add_argument("--reference", type=Path, default=None,
                   help="a runs file whose NFPDE-Softmax run of the cell to time against (default the table's), "
                        "e.g. one measured on the machine that ran the long DROPO")
    p.add_argument("--dropo-from", type=Path, default=None,
                   help="an earlier output of this script whose long DROPO run to reuse instead of running one")
    args = p.parse_args()
    stem = args.env.split("/")[-1].split("-v")[0].lower()
    out_path = args.json or RESULTS / f"{args.name}_long_dropo-{stem}-{args.target}.json"
    check_output_file(out_path)
    runs = read_json(RESULTS / f"{args.name}_runs.json", "nfpde_table runs file")["runs"]
    cell = (args.env, args.target, args.seed)
    nf, dropo = find_run(runs, cell, "nfpde-softmax"), find_run(runs, cell, "dropo")
    if nf is None or dropo is None:
        raise SystemExit(f"nfpde_long_dropo: {args.name}_runs.json has no nfpde-softmax and dropo runs for {cell}; "
                         f"run benchmarks/nfpde_table.py on that cell first")
    if args.reference is not None:
        nf = find_run(read_json(args.reference, "reference runs file")["runs"], cell, "nfpde-softmax")
        if nf is None:
            raise SystemExit(f"nfpde_long_dropo: {args.reference} has no nfpde-softmax run for {cell}")
    if args.dropo_from is not None:
        earlier = read_json(args.dropo_from, "earlier nfpde_long_dropo output")
        if cell_of(earlier) != cell:
            raise SystemExit(f"nfpde_long_dropo: {args.dropo_from} is for {cell_of(earlier)}, not {cell}")
        long, budget = earlier["dropo_long"], earlier["budget_dropo_long"]
        long = {**long, "command": long.get("command", earlier.get("command"))}  # the command that ran it
    else:
        budget = int(args.factor * nf["sim_budget"])
        long = run_one(args.env, args.target, "dropo", args.seed, budget, len(nf["true_u"]), {})
    levels = {"1.1 x nfpde-softmax final": round(nf["ot"] * 1.1, 4), "dropo final": round(dropo["ot"], 4),
              "0.2": 0.2}
    reach = {}
    for label, level in levels.items():
        nf_at, long_at = first_reach(nf["trace"], level), first_reach(long["trace"], level)
        reach[label] = {"level": level, "nfpde-softmax": nf_at, "dropo (long)": long_at,
                        "dropo / nfpde-softmax": ratio(long_at, nf_at, long)}
    out = {"env": args.env, "target": args.target, "seed": args.seed, "budget_nfpde": nf["sim_budget"],
           "budget_dropo_long": budget,
           "nfpde_softmax": {"ot": nf["ot"], "seconds_total": nf["seconds_total"],
                             "runs_file": str(args.reference or RESULTS / f"{args.name}_runs.json")},
           "dropo": {"ot": dropo["ot"], "seconds_total": dropo["seconds_total"]},
           "dropo_long": {"ot": long["ot"], "seconds_total": long["seconds_total"], "sim_calls": long["sim_calls"],
                          "trace": long["trace"], "details": long["details"],
                          **({"command": long["command"]} if "command" in long else {})},
           "reach": reach,
           "command": "python benchmarks/nfpde_long_dropo.py " + " ".join(sys.argv[1:])}
    write_json(out_path, out)
    print(json.dumps({k: v for k, v in out.items() if k != "dropo_long"}, indent=1))
    print(f"dropo long: OT {long['ot']:.3f} in {long['seconds_total']:.1f} s ({long['sim_calls']} calls); "
          f"written {out_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
