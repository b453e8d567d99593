"""What the constrained mode's feasible-set estimate allows on uniform batches (issue 21): the mass
and coverage of the ideal sampler on F-hat at each level, against rounds and `memory`; and the
same for the skills' measured feasible sets, fitted from their grids as the skill refit does.

    .venv/bin/python -m benchmarks.classifier_frontier --layouts tiny --seeds 0 1 2 --rounds 100 200 300 \\
        --memory 16384 131072 [--boundary-memory 0 16384] [--levels 0.3 0.5 0.6 0.7 0.8 0.9] [--json PATH]
    .venv/bin/python -m benchmarks.classifier_frontier --skills small medium large --per-cell 1 10 --seeds 0

Each (layout, seed, memory, boundary memory) feeds uniform batches of `--batch` points with their
0/1 success to an `SignalMemory` of a window of `memory` rows and up to `boundary memory` older rows on
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

With `--skills`, the rows are a shipped skill's measured feasible set (`Skill.feasible`, the
union of the grid cells where its frozen policy succeeded): `--per-cell` points uniform in each
cell with the cell's label (the refit's first update uses one; more are free, the label is the
cell's), fitted once from scratch with the refit's classifier steps (`FlowRefitConfig`, ten times
them for a first fit). F-hat is read against the measured set on points drawn half in the grid's
fine region and half on the box, weighted back to uniform on the box.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch


from assembly.gearset import GEARS
from goflow_common.checks import InputErrorParser, check_int, check_number
from goflow_common.errors import GoflowError, InputError
from goflow_common.files import check_output_file, write_json
from learning.feasible_grid import FeasibleSet, FlowRefitConfig
from learning.feasible_sets import LAYOUTS, Layout
from learning.samplers.signal_memory import SignalMemory
from learning.samplers.feasibility import SuccessClassifier
from learning.samplers.goflow_config import GoFlowConfig
from learning.skill_file import load_skill

NAME = "classifier_frontier"
TARGET_MASS, TARGET_COVERAGE, COVERAGE_LEVEL = 0.99, 0.95, 0.1


def read_levels(
    p_hat: np.ndarray,
    in_f: np.ndarray,
    p_inside: np.ndarray,
    levels: Sequence[float],
    share: float,
    delta: float,
    weights: np.ndarray | None = None,
) -> list[dict[str, float]]:
    """Mass, cov10 and recall of (1 - delta) U(F-hat) + delta U(rest) for F-hat = {P >= level}:
    `p_hat` and `in_f` at points of the box, uniform or with importance `weights` to uniform,
    `p_inside` at points uniform on F."""
    w = np.ones(len(p_hat)) if weights is None else np.asarray(weights, np.float64)
    rows = []
    for level in levels:
        hat = p_hat >= level
        share_hat = float(w[hat].sum() / w.sum())
        if share_hat == 0.0:
            # no F-hat: the constrained mode samples the flow alone, uniform at first
            rows.append({"level": level, "share": 0.0, "mass": share, "cov10": 0.0, "recall": 0.0})
            continue
        rest = float(np.average(in_f[~hat], weights=w[~hat])) if (~hat).any() else 0.0
        mass = (1.0 - delta) * float(np.average(in_f[hat], weights=w[hat])) + delta * rest
        covered_inside = (1.0 - delta) / share_hat > COVERAGE_LEVEL / share
        covered_outside = share_hat < 1.0 and delta / (1.0 - share_hat) > COVERAGE_LEVEL / share
        in_hat = p_inside >= level
        cov = float(np.mean(np.where(in_hat, covered_inside, covered_outside)))
        rows.append({"level": level, "share": share_hat, "mass": mass, "cov10": cov, "recall": float(in_hat.mean())})
    return rows


def run(
    layout: Layout,
    seed: int,
    memory: int,
    rounds: Sequence[int],
    levels: Sequence[float],
    batch: int,
    points: int,
    boundary_memory: int = 0,
) -> list[dict[str, Any]]:
    """The frontier of one (layout, seed, memory, boundary_memory) at each round of `rounds` (ascending)."""
    cfg = GoFlowConfig(mode="constrained")
    d = layout.dim
    evidence = SignalMemory(d, memory, cfg.neighbours, (0.0, 1.0), boundary_memory)
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
            out.append(
                {
                    "layout": layout.name,
                    "seed": seed,
                    "memory": memory,
                    "boundary_memory": boundary_memory,
                    "round": r,
                    "rows": len(evidence),
                    "kept": evidence.kept,
                    "successes": int(evidence.signal.sum()),
                    "levels": read_levels(p_hat, in_f, p_inside, levels, layout.share, cfg.delta),
                }
            )
    return out


def grid_rows(feasible: FeasibleSet, per_cell: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """`per_cell` points uniform in each measured cell, unit-box coordinates, and their 0/1 labels
    (the first pass with seed 0 is the refit's first update: `FeasibleSet.points`)."""
    space = feasible.space
    xs, labels = zip(*(feasible.points(np.random.default_rng([seed, k])) for k in range(per_cell)))
    return (np.concatenate(xs) - space.low) / (space.high - space.low), np.concatenate(labels).astype(np.float64)


def skill_feasible_set(gear: str) -> FeasibleSet:
    """The measured feasible set of the shipped insert skill for `gear` (InputError without one)."""
    feasible = load_skill("insert", gear=gear).feasible
    if feasible is None:
        raise InputError(
            f"--skills: the shipped {gear} skill has no measured feasible set; "
            f"expected one (goflow skill refit --gear {gear})"
        )
    return feasible


def run_skill(
    gear: str, feasible: FeasibleSet, seed: int, per_cell: int, levels: Sequence[float], points: int
) -> dict[str, Any]:
    """The frontier of `gear`'s measured feasible set, fitted once from `per_cell` labelled points
    per cell (module docstring)."""
    cfg, refit = GoFlowConfig(mode="constrained"), FlowRefitConfig()
    space, d = feasible.space, feasible.space.dim
    xi, success = grid_rows(feasible, per_cell, seed)
    evidence = SignalMemory(d, len(xi), cfg.neighbours, (0.0, 1.0))
    evidence.add(xi, success)
    classifier = SuccessClassifier(d, cfg.classifier_layers(d), seed)
    classifier.fit_evidence(
        evidence, steps=refit.classifier_steps, batch=cfg.fit_batch, gen=torch.Generator().manual_seed(seed)
    )
    check = np.random.default_rng([seed, 2])
    width = space.high - space.low
    fine_low, fine_high = (feasible.fine_low - space.low) / width, (feasible.fine_high - space.low) / width
    half = points // 2
    u = np.concatenate([fine_low + (fine_high - fine_low) * check.random((half, d)), check.random((points - half, d))])
    fine_share = float(np.prod(fine_high - fine_low))
    in_fine = np.all((u >= fine_low) & (u <= fine_high), axis=1)
    weights = 1.0 / (0.5 * in_fine / fine_share + 0.5)  # uniform on the box over the half-and-half proposal
    inside, share = feasible.sample_box(points, check)
    in_f = feasible.contains(space.low + width * u)
    p_hat, p_inside = classifier.probability(u), classifier.probability((inside - space.low) / width)
    return {
        "layout": f"{gear} gear",
        "seed": seed,
        "per_cell": per_cell,
        "rows": len(xi),
        "successes": int(success.sum()),
        "share": share,
        "levels": read_levels(p_hat, in_f, p_inside, levels, share, refit.delta, weights),
    }


def meets(level_row: dict[str, float]) -> bool:
    return level_row["mass"] >= TARGET_MASS and level_row["cov10"] >= TARGET_COVERAGE


def table(records: list[dict[str, Any]], levels: Sequence[float]) -> str:
    """Markdown: per (layout, memory, boundary memory, round), the mean over seeds of mass / cov10 at
    each level and the seeds that have a level meeting both targets."""
    groups: dict[tuple[str, int, int, int], list[dict[str, Any]]] = {}
    for rec in records:
        groups.setdefault((rec["layout"], rec["memory"], rec.get("boundary_memory", 0), rec["round"]), []).append(rec)
    head = (
        "| layout | memory | boundary | round | successes | "
        + " | ".join(f"{lv:g}" for lv in levels)
        + " | seeds meeting both |"
    )
    lines = [head, "|" + "---|" * (len(levels) + 6)]
    for (name, memory, boundary, r), recs in groups.items():
        cells = []
        for i in range(len(levels)):
            mass = np.mean([rec["levels"][i]["mass"] for rec in recs])
            cov = np.mean([rec["levels"][i]["cov10"] for rec in recs])
            cells.append(f"{mass:.3f} / {cov:.3f}")
        good = sum(any(meets(lv) for lv in rec["levels"]) for rec in recs)
        successes = np.mean([rec["successes"] for rec in recs])
        lines.append(
            f"| {name} | {memory} | {boundary} | {r} | {successes:.0f} | "
            + " | ".join(cells)
            + f" | {good} of {len(recs)} |"
        )
    return "\n".join(lines)


def skill_table(records: list[dict[str, Any]], levels: Sequence[float]) -> str:
    """Markdown: per (skill, points per cell), the mean over seeds of mass / cov10 / recall at each
    level and the seeds that have a level meeting both targets."""
    groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for rec in records:
        groups.setdefault((rec["layout"], rec["per_cell"]), []).append(rec)
    head = (
        "| measured set | share | points per cell | rows | "
        + " | ".join(f"{lv:g}" for lv in levels)
        + " | seeds meeting both |"
    )
    lines = [head, "|" + "---|" * (len(levels) + 5)]
    for (name, per_cell), recs in groups.items():
        cells = [
            " / ".join(f"{np.mean([rec['levels'][i][k] for rec in recs]):.3f}" for k in ("mass", "cov10", "recall"))
            for i in range(len(levels))
        ]
        good = sum(any(meets(lv) for lv in rec["levels"]) for rec in recs)
        lines.append(
            f"| {name} | {recs[0]['share']:.4%} | {per_cell} | {recs[0]['rows']} | "
            + " | ".join(cells)
            + f" | {good} of {len(recs)} |"
        )
    return "\n".join(lines)


def make_parser() -> argparse.ArgumentParser:
    """The benchmark's flags."""
    p = InputErrorParser(prog="benchmarks/classifier_frontier.py", description=__doc__.splitlines()[0])
    p.add_argument(
        "--layouts", nargs="+", default=None, help=f"some of {list(LAYOUTS)} (default: tiny, or none with --skills)"
    )
    p.add_argument(
        "--skills", nargs="+", default=[], help=f"shipped insert skills' measured sets: some of {list(GEARS)}"
    )
    p.add_argument(
        "--per-cell",
        nargs="+",
        type=int,
        default=[1],
        help="with --skills: labelled points drawn in each measured cell",
    )
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--rounds", nargs="+", type=int, default=[100, 200, 300], help="rounds at which F-hat is read")
    p.add_argument("--memory", nargs="+", type=int, default=[GoFlowConfig.memory], help="SignalMemory rows kept")
    p.add_argument(
        "--boundary-memory",
        nargs="+",
        type=int,
        default=[GoFlowConfig.boundary_memory],
        help="boundary rows kept beyond the window (0: none)",
    )
    p.add_argument("--levels", nargs="+", type=float, default=[0.3, 0.5, 0.6, 0.7, 0.8, 0.9])
    p.add_argument("--batch", type=int, default=256, help="uniform points per round")
    p.add_argument("--points", type=int, default=1_000_000, help="uniform points of the box, and points on F")
    p.add_argument("--json", type=Path, default=None, help="write every reading here")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with one line on stderr for bad input."""
    try:
        args = make_parser().parse_args(argv)
        if args.layouts is None:
            args.layouts = [] if args.skills else ["tiny"]
        for gear in args.skills:
            if gear not in GEARS:
                raise InputError(f"--skills: {gear!r} is not a gear; expected some of {list(GEARS)}")
        for k in args.per_cell:
            check_int(k, "--per-cell entry", 1)
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
        skill_records = []
        for gear in args.skills:
            feasible = skill_feasible_set(gear)
            for per_cell in args.per_cell:
                for seed in args.seeds:
                    skill_records.append(run_skill(gear, feasible, seed, per_cell, levels, args.points))
                    print(f"{NAME}: {gear} gear, {per_cell} per cell, seed {seed} done", flush=True)
        if records:
            print(table(records, levels))
        if skill_records:
            print("mass / cov10 / recall at each level:")
            print(skill_table(skill_records, levels))
        if args.json is not None:
            write_json(
                args.json,
                {
                    "benchmark": NAME,
                    "command": "benchmarks/classifier_frontier.py "
                    + " ".join(argv if argv is not None else sys.argv[1:]),
                    "targets": {"mass": TARGET_MASS, "cov10": TARGET_COVERAGE},
                    "batch": args.batch,
                    "points": args.points,
                    "records": records,
                    "skill_records": skill_records,
                },
            )
            print(f"{NAME}: -> {args.json}")
        return 0
    except GoflowError as exc:
        print(f"{NAME}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
