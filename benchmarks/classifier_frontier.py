"""What the constrained mode's feasible-set estimate allows on uniform batches (issue 21): the mass
and coverage of the ideal sampler on F-hat at each level, against rounds and `memory`.

    .venv/bin/python benchmarks/classifier_frontier.py --layouts tiny --seeds 0 1 2 --rounds 100 200 300 \\
        --memory 16384 131072 [--boundary-memory 0 16384] [--levels 0.3 0.5 0.6 0.7 0.8 0.9] [--json PATH]

Each (layout, seed, memory, boundary memory) feeds uniform batches of `--batch` points with their
0/1 success to an `Evidence` of a window of `memory` rows and up to `boundary memory` older rows on
the class boundary (GoFlowConfig.boundary_memory), and fits GoFlow's success classifier to it
after every batch, exactly as the constrained mode's update does (`SuccessClassifier.fit_evidence`,
GoFlowConfig's steps, minibatch and layers); no flow is trained. At each round of `--rounds` the
estimate F-hat = {P >= level} is read at every level of `--levels` as the sampler the constrained
mode aims at, (1 - delta) x uniform on F-hat + delta x uniform on the rest of the box, on
`--points` uniform points and as many points uniform on F:
- mass: that sampler's mass on F;
- cov10: the share of F where its density exceeds 10 % of the uniform-on-F density;
- recall: the share of F inside F-hat.
A level where mass >= 0.99 and cov10 >= 0.95 exists only if the classifier separates F well
enough; where none does, no choice of the level (the dual ascent's job) and no flow can meet both
targets from these rows. The table prints the mean over seeds and how many seeds have such a level.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.checks import InputErrorParser, check_int, check_number  # noqa: E402
from common.errors import GoflowError, InputError  # noqa: E402
from common.files import check_output_file, write_json  # noqa: E402
from learning.feasible_sets import LAYOUTS, Layout  # noqa: E402
from learning.samplers.evidence import Evidence  # noqa: E402
from learning.samplers.feasibility import SuccessClassifier  # noqa: E402
from learning.samplers.goflow import GoFlowConfig  # noqa: E402

NAME = "classifier_frontier"
TARGET_MASS, TARGET_COVERAGE, COVERAGE_LEVEL = 0.99, 0.95, 0.1


def read_levels(p_hat: np.ndarray, in_f: np.ndarray, p_inside: np.ndarray, levels: Sequence[float],
                share: float, delta: float) -> list[dict[str, float]]:
    """Mass, cov10 and recall of (1 - delta) U(F-hat) + delta U(rest) for F-hat = {P >= level}:
    `p_hat` and `in_f` at uniform points of the box, `p_inside` at points uniform on F."""
    rows = []
    for level in levels:
        hat = p_hat >= level
        share_hat = float(hat.mean())
        if share_hat == 0.0:
            # no F-hat: the constrained mode samples the flow alone, uniform at first
            rows.append({"level": level, "share": 0.0, "mass": share, "cov10": 0.0, "recall": 0.0})
            continue
        rest = float(in_f[~hat].mean()) if (~hat).any() else 0.0
        mass = (1.0 - delta) * float(in_f[hat].mean()) + delta * rest
        covered_inside = (1.0 - delta) / share_hat > COVERAGE_LEVEL / share
        covered_outside = share_hat < 1.0 and delta / (1.0 - share_hat) > COVERAGE_LEVEL / share
        in_hat = p_inside >= level
        cov = float(np.mean(np.where(in_hat, covered_inside, covered_outside)))
        rows.append({"level": level, "share": share_hat, "mass": mass, "cov10": cov, "recall": float(in_hat.mean())})
    return rows


def run(layout: Layout, seed: int, memory: int, rounds: Sequence[int], levels: Sequence[float], batch: int,
        points: int, boundary_memory: int = 0) -> list[dict[str, Any]]:
    """The frontier of one (layout, seed, memory, boundary_memory) at each round of `rounds` (ascending)."""
    cfg = GoFlowConfig(mode="constrained")
    d = layout.dim
    evidence = Evidence(d, memory, cfg.neighbours, (0.0, 1.0), boundary_memory)
    classifier = SuccessClassifier(d, cfg.classifier_layers(d), seed)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng([seed, 1])
    check = np.random.default_rng([seed, 2])
    u = check.random((points, d))
    in_f = layout.contains(u)
    inside = layout.sample_inside(points, check)
    out = []
    for r in range(1, max(rounds) + 1):
        x = rng.random((batch, d))
        evidence.add(x, layout.contains(x).astype(np.float64))
        if np.ptp(evidence.signal) > 0:
            classifier.fit_evidence(evidence, steps=cfg.classifier_steps, batch=cfg.fit_batch, gen=gen)
        if r in rounds:
            p_hat, p_inside = classifier.probability(u), classifier.probability(inside)
            out.append({"layout": layout.name, "seed": seed, "memory": memory, "boundary_memory": boundary_memory,
                        "round": r, "rows": len(evidence), "kept": evidence.kept,
                        "successes": int(evidence.signal.sum()),
                        "levels": read_levels(p_hat, in_f, p_inside, levels, layout.share, cfg.delta)})
    return out


def meets(level_row: dict[str, float]) -> bool:
    return level_row["mass"] >= TARGET_MASS and level_row["cov10"] >= TARGET_COVERAGE


def table(records: list[dict[str, Any]], levels: Sequence[float]) -> str:
    """Markdown: per (layout, memory, boundary memory, round), the mean over seeds of mass / cov10 at
    each level and the seeds that have a level meeting both targets."""
    groups: dict[tuple[str, int, int, int], list[dict[str, Any]]] = {}
    for rec in records:
        groups.setdefault((rec["layout"], rec["memory"], rec.get("boundary_memory", 0), rec["round"]), []).append(rec)
    head = ("| layout | memory | boundary | round | successes | " + " | ".join(f"{lv:g}" for lv in levels)
            + " | seeds meeting both |")
    lines = [head, "|" + "---|" * (len(levels) + 6)]
    for (name, memory, boundary, r), recs in groups.items():
        cells = []
        for i in range(len(levels)):
            mass = np.mean([rec["levels"][i]["mass"] for rec in recs])
            cov = np.mean([rec["levels"][i]["cov10"] for rec in recs])
            cells.append(f"{mass:.3f} / {cov:.3f}")
        good = sum(any(meets(lv) for lv in rec["levels"]) for rec in recs)
        successes = np.mean([rec["successes"] for rec in recs])
        lines.append(f"| {name} | {memory} | {boundary} | {r} | {successes:.0f} | " + " | ".join(cells)
                     + f" | {good} of {len(recs)} |")
    return "\n".join(lines)


def make_parser() -> argparse.ArgumentParser:
    """The benchmark's flags."""
    p = InputErrorParser(prog="benchmarks/classifier_frontier.py", description=__doc__.splitlines()[0])
    p.add_argument("--layouts", nargs="+", default=["tiny"], help=f"some of {list(LAYOUTS)}")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--rounds", nargs="+", type=int, default=[100, 200, 300],
                   help="rounds at which F-hat is read")
    p.add_argument("--memory", nargs="+", type=int, default=[GoFlowConfig.memory], help="Evidence rows kept")
    p.add_argument("--boundary-memory", nargs="+", type=int, default=[GoFlowConfig.boundary_memory],
                   help="boundary rows kept beyond the window (0: none)")
    p.add_argument("--levels", nargs="+", type=float, default=[0.3, 0.5, 0.6, 0.7, 0.8, 0.9])
    p.add_argument("--batch", type=int, default=256, help="uniform points per round")
    p.add_argument("--points", type=int, default=1_000_000, help="uniform points of the box, and points on F")
    p.add_argument("--json", type=Path, default=None, help="write every reading here")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with one line on stderr for bad input."""
    try:
        args = make_parser().parse_args(argv)
        for name in args.layouts:
            if name not in LAYOUTS:
                raise InputError(f"--layouts: {name!r} is not a layout; expected some of {list(LAYOUTS)}")
        for r in args.rounds:
            check_int(r, "--rounds entry", 1)
        for m in args.memory:
            check_int(m, "--memory entry", 1)
        for m in args.boundary_memory:
            check_int(m, "--boundary-memory entry", 0)
        for s in args.seeds:
            check_int(s, "--seeds entry", 0)
        for lv in args.levels:
            check_number(lv, "--levels entry", 0.0, 1.0, low_open=True, high_open=True)
        check_int(args.batch, "--batch", 1)
        check_int(args.points, "--points", 1)
        if args.json is not None:
            check_output_file(args.json, "--json")
        torch.set_num_threads(1)
        rounds, levels = sorted(set(args.rounds)), list(args.levels)
        records = []
        for name in args.layouts:
            for memory in args.memory:
                for boundary in args.boundary_memory:
                    for seed in args.seeds:
                        records += run(LAYOUTS[name], seed, memory, rounds, levels, args.batch, args.points, boundary)
                        print(f"{NAME}: {name} memory {memory} boundary {boundary} seed {seed} done", flush=True)
        records.sort(key=lambda rec: (rec["layout"], rec["memory"], rec["boundary_memory"], rec["round"], rec["seed"]))
        print(table(records, levels))
        if args.json is not None:
            write_json(args.json, {"benchmark": NAME, "command": "benchmarks/classifier_frontier.py " +
                                   " ".join(argv if argv is not None else sys.argv[1:]),
                                   "targets": {"mass": TARGET_MASS, "cov10": TARGET_COVERAGE},
                                   "batch": args.batch, "points": args.points, "records": records})
            print(f"{NAME}: -> {args.json}")
        return 0
    except GoflowError as exc:
        print(f"{NAME}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
