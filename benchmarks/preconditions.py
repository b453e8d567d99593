"""The insert skills' preconditions measured: V_T (the paper's J_T on our critic's discounted
scale) from rollouts, and how well each form of precondition tells a success from a failure.

    .venv/bin/python -m benchmarks.preconditions --episodes 200 --json docs/results/preconditions.json \
        [--thresholds planning/data/insert_thresholds.json]

Per gear: `episodes` rollouts of the shipped skill (fast variant, deterministic policy) at grasp
errors drawn from its flow and moved by N(0, 3 mm) in x and y, so that both outcomes occur. For
Eq. 6 (V > V_T), the flow alone (p > eps x uniform) and Eq. 7 (both), the true-positive rate
(successes passed) and true-negative rate (failures refused) over eps. `--thresholds` writes
{"thresholds": {gear: V_T}}: the file the planner loads (the shipped one is written only when
named).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from assembly.gearset import GEAR_NAMES  # noqa: E402
from benchmarks.provenance import command  # noqa: E402
from goflow_common.files import check_output_file, write_json  # noqa: E402
from goflow_common.pool import map_calls  # noqa: E402

EPS = (0.0, 0.1, 1.0, 10.0, 100.0, 1000.0)


def measure(gear: str, episodes: int, spread: float, seed: int) -> dict:
    import torch

    from learning.skill_file import load_skill
    from planning.precondition import calibrate_value_threshold

    torch.set_num_threads(1)
    skill = load_skill("insert", gear)
    t0 = time.perf_counter()
    cal = calibrate_value_threshold(skill, episodes, spread, seed)
    uniform = 1.0 / float(np.prod(skill.space.high - skill.space.low))
    density = skill.density(cal.xi) / uniform
    value_ok = cal.value > cal.threshold

    def rates(passed):
        tpr = float(np.mean(passed[cal.success])) if cal.success.any() else float("nan")
        tnr = float(np.mean(~passed[~cal.success])) if (~cal.success).any() else float("nan")
        return {"tpr": tpr, "tnr": tnr}

    return {
        "gear": gear,
        "episodes": episodes,
        "spread_m": spread,
        "seed": seed,
        "seconds": time.perf_counter() - t0,
        "success_rate": float(cal.success.mean()),
        "value_threshold": cal.threshold,
        "balanced_accuracy_value": cal.balanced_accuracy,
        "eq6": rates(value_ok),
        "flow": {f"{e:g}": rates(density > e) for e in EPS},
        "eq7": {f"{e:g}": rates(value_ok & (density > e)) for e in EPS},
        "value_success_pct": np.percentile(cal.value[cal.success], [5, 50, 95]).tolist() if cal.success.any() else [],
        "value_failure_pct": np.percentile(cal.value[~cal.success], [5, 50, 95]).tolist()
        if (~cal.success).any()
        else [],
    }


def table(rows: list[dict]) -> str:
    head = (
        "| gear | success | V_T | Eq. 6 TPR / TNR | "
        + " | ".join(f"Eq. 7 eps={e:g} TPR / TNR" for e in (1.0, 10.0, 100.0))
        + " |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        cells = [f"{r['eq7'][f'{e:g}']['tpr']:.2f} / {r['eq7'][f'{e:g}']['tnr']:.2f}" for e in (1.0, 10.0, 100.0)]
        lines.append(
            f"| {r['gear']} | {r['success_rate']:.2f} of {r['episodes']} | {r['value_threshold']:.3f} | "
            f"{r['eq6']['tpr']:.2f} / {r['eq6']['tnr']:.2f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--spread", type=float, default=0.003, help="x-y noise on the flow's draws [m]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gears", nargs="+", default=list(GEAR_NAMES), choices=list(GEAR_NAMES))
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--json", type=Path, help="write every measurement")
    p.add_argument("--thresholds", type=Path, help="write {thresholds: {gear: V_T}} for the planner")
    args = p.parse_args(argv)
    if args.episodes < 4 or args.workers < 1 or not np.isfinite(args.spread) or args.spread < 0:
        p.error(
            f"--episodes {args.episodes}, --workers {args.workers}, --spread {args.spread}: "
            "expected >= 4, >= 1 and >= 0"
        )
    for path in (args.json, args.thresholds):
        if path is not None:
            check_output_file(path)
    rows = map_calls(measure, [(gear, args.episodes, args.spread, args.seed) for gear in args.gears], args.workers)
    print(table(rows))
    if args.json:
        write_json(args.json, {"command": command("preconditions", argv), "rows": rows})
    if args.thresholds:
        write_json(
            args.thresholds,
            {"command": command("preconditions", argv), "thresholds": {r["gear"]: r["value_threshold"] for r in rows}},
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
