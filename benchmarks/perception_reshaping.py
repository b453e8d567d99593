"""Fit one side of the posterior's reshaping, its factor and shape exponent where the teeth are
resolved (the close view) or not (the scene view), from calibration results and tuning rows.

The reshaping turns a posterior's log-evidence deficit D from its peak into (f D)^e once the cells
are fixed (`LikelihoodConfig.posterior_factor` and `shape_exponent`, (unresolved, resolved) pairs
blended by `teeth_resolved`), so it moves no cell, only the truths' levels. Two sources:

- *Calibration results* (`--results`, `goflow bench calibration`), read: a truth whose raw deficit
  grows as a 3-D Gaussian's (D = r^2 / 2 in whitened units), in a posterior reshaped with (f, e),
  has P(3 / (2e), (f D)^e) of the mass inside its deficit, P the regularized lower incomplete gamma
  function (the chi-square reading of `perception_far_view.py` at e = 1). Each row's recorded
  (factor, shape) gives its truth's D, and any other pair its level (`shape_levels`).
- *Tuning rows* (`--tuning-rows`, `perception_tempering.py --rows`), exact: their levels recorded
  at shape exponents x tempering factors. The reading was checked against them (docs/perception.md,
  Tempering, item 11): within about a point at every level near the fit.

For each source the script searches the side's pair on a grid, the other side and the per-gear
far- and close-view factors held, for the levels closest to uniform in every perturbation group x
view cell, and prints each source's fit and the coverage per view and group under the shipped
pair and the fits.

    .venv/bin/python -m benchmarks.perception_reshaping --side resolved \
        --results docs/results/perception_calibration_seed{19,20,21,22,23,24,25}000.json \
        --tuning-rows runs/tempering/seed6500.json --json runs/reshaping_resolved.json
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.special import gammainc, gammaincinv


from goflow_common.errors import InputError
from goflow_common.files import check_output_file, write_json
from perception.calibration import LEVELS, resampled_set_count
from perception.likelihood import LikelihoodConfig, blend_reshaping, teeth_resolved
from benchmarks.perception_far_view import fit_parser, result_rows
from benchmarks.perception_tempering import Rows, cell_loss, coverage, held_factors, load_rows

SIDES = {"unresolved": 0, "resolved": 1}  # index into the (unresolved, resolved) pairs
FACTORS = np.round(np.geomspace(0.5, 2.0, 49), 4)  # the side's factor searched (1 included)
EXPONENTS = np.round(np.arange(1.0, 1.601, 0.05), 2)  # ... and its shape exponent
KEYS = ("level", "gsd", "gear", "pixels", "posterior_factor", "shape", "group", "view")


def raw_deficits(levels: np.ndarray, factor: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """The truths' raw deficits D of posteriors reshaped with (factor, shape) where they have
    these levels, read as a 3-D Gaussian truth's (module docstring)."""
    u = gammaincinv(1.5 / shape, np.clip(levels, 1e-12, 1 - 1e-12))
    return u ** (1.0 / shape) / factor


def shape_levels(
    levels: np.ndarray, factor0: np.ndarray, shape0: np.ndarray, factor1: np.ndarray, shape1: np.ndarray
) -> np.ndarray:
    """The truth levels of posteriors reshaped with (factor0, shape0) once reshaped with
    (factor1, shape1) instead, read as a 3-D Gaussian truth's (module docstring)."""
    return gammainc(1.5 / shape1, (factor1 * raw_deficits(levels, factor0, shape0)) ** shape1)


def shape_rows(paths: list[Path]) -> list[dict]:
    """The informative rows of calibration results that recorded their reshaping, pooled
    (InputError if a file is not one or holds none)."""
    rows = [r for r in result_rows(paths) if r.get("informative") and all(r.get(k) is not None for k in KEYS)]
    if not rows:
        raise InputError(f"{[str(p) for p in paths]}: no informative rows with their reshaping")
    return rows


def with_pair(base: LikelihoodConfig, side: int, factor: float, exponent: float) -> LikelihoodConfig:
    """`base` with side `side`'s (0 unresolved, 1 resolved) reshaping pair replaced."""
    fs, gs = list(base.posterior_factor), list(base.shape_exponent)
    fs[side], gs[side] = float(factor), float(exponent)
    return replace(base, posterior_factor=tuple(fs), shape_exponent=tuple(gs))


class Reading:
    """Rows of calibration results, their truth levels under `base` with either side's pair
    replaced (the per-gear far- and close-view factors held), by the reading."""

    def __init__(self, rows: list[dict], base: LikelihoodConfig) -> None:
        self.rows, self.base = rows, base
        self.deficits = raw_deficits(
            np.array([r["level"] for r in rows]),
            np.array([r["posterior_factor"] for r in rows], float),
            np.array([r["shape"] for r in rows], float),
        )
        self.resolved = np.array([teeth_resolved(r["gsd"]) for r in rows])
        self.held = held_factors(rows, base)
        self.cells = [f"{r['group']}/{r['view']}" for r in rows]

    def at(self, side: int = 1, factor: float | None = None, exponent: float | None = None) -> np.ndarray:
        """Every row's truth level with side `side`'s pair (factor, exponent) (`base`'s if None)."""
        cfg = with_pair(
            self.base,
            side,
            self.base.posterior_factor[side] if factor is None else factor,
            self.base.shape_exponent[side] if exponent is None else exponent,
        )
        f1, g1 = blend_reshaping(cfg.posterior_factor, cfg.shape_exponent, self.resolved)
        return gammainc(1.5 / g1, (f1 * self.held * self.deficits) ** g1)


class Exact:
    """Tuning rows with shaped levels (perception_tempering.py), their exact truth levels under
    `base` with either side's pair replaced."""

    def __init__(self, paths: list[Path], base: LikelihoodConfig) -> None:
        rows, factors, shapes = load_rows(paths)
        if shapes is None:
            raise InputError(
                f"{[str(p) for p in paths]}: no shaped levels (collect them with "
                "perception_tempering.py, every file at the same shape exponents)"
            )
        self.data, self.base = Rows(rows, factors, shapes), base
        self.rows = rows
        self.cells = [f"{r['group']}/{r['view']}" for r in rows]
        self.resolved = np.array([teeth_resolved(r["gsd"]) for r in rows])
        self.held = self.data.tempering_ratio(base) * held_factors(rows, base)  # computed once

    def at(self, side: int = 1, factor: float | None = None, exponent: float | None = None) -> np.ndarray:
        """Every row's exact truth level with side `side`'s pair (`base`'s if None), interpolated
        between the recorded factors and shape exponents."""
        cfg = with_pair(
            self.base,
            side,
            self.base.posterior_factor[side] if factor is None else factor,
            self.base.shape_exponent[side] if exponent is None else exponent,
        )
        f1, g1 = blend_reshaping(cfg.posterior_factor, cfg.shape_exponent, self.resolved)
        return self.data.levels(f1 * self.held, shape=g1)


def fit_pair(
    data: Reading | Exact, side: int, factors: np.ndarray = FACTORS, exponents: np.ndarray = EXPONENTS
) -> tuple[float, float, float]:
    """(loss, factor, exponent): side `side`'s pair from the grid `factors` x `exponents` whose
    levels are closest to uniform in every perturbation group x view cell (`cell_loss`)."""
    return min((cell_loss(data.at(side, f, e), data.cells), float(f), float(e)) for f in factors for e in exponents)


def report(data: Reading | Exact, columns: dict[str, np.ndarray]) -> list[str]:
    """Markdown rows: coverage at LEVELS per view (all groups, then each) in each column."""
    fmt = lambda m, x: "/".join(f"{100 * c:.1f}" for c in coverage(x[m], np.array(LEVELS)))  # noqa: E731
    views = np.array([r["view"] for r in data.rows])
    groups = np.array([r["group"] for r in data.rows])
    out = [f"| view | group | n | {' | '.join(columns)} |", "|---" * (3 + len(columns)) + "|"]
    for view in dict.fromkeys(views):
        for group in ("all", *dict.fromkeys(groups)):
            m = (views == view) & ((groups == group) | (group == "all"))
            out.append(f"| {view} | {group} | {m.sum()} | {' | '.join(fmt(m, x) for x in columns.values())} |")
    return out


def main(argv: list[str] | None = None) -> int:
    p = fit_parser(__doc__)
    p.add_argument(
        "--side",
        choices=tuple(SIDES),
        default="resolved",
        help="the reshaping pair to fit (default: resolved, the close view's)",
    )
    p.add_argument(
        "--tuning-rows",
        type=Path,
        nargs="+",
        default=None,
        help="perception_tempering.py rows with shaped levels (exact), pooled",
    )
    p.add_argument(
        "--sets",
        type=int,
        nargs="+",
        default=[],
        help="also the mean cells within +-5 of sets of these many scenes resampled from "
        "the calibration results, under the shipped pairs (e.g. 150 300 600)",
    )
    args = p.parse_args(argv)
    side = SIDES[args.side]
    if any(n < 1 for n in args.sets):
        print(f"perception_reshaping: --sets {args.sets}: expected scene counts >= 1", file=sys.stderr)
        return 2
    base = LikelihoodConfig()
    try:
        out = check_output_file(args.json, "--json") if args.json else None
        sources = {"calibration results (read)": Reading(shape_rows(args.results), base)}
        if args.tuning_rows:
            sources["tuning rows (exact)"] = Exact(args.tuning_rows, base)
    except (InputError, OSError, ValueError) as e:
        print(f"perception_reshaping: {e}", file=sys.stderr)
        return 2
    fits = {name: fit_pair(data, side) for name, data in sources.items()}
    shipped = (base.posterior_factor[side], base.shape_exponent[side])
    lines = []
    for name, data in sources.items():
        columns = {f"shipped {shipped}": data.at(side)}
        for other, (_, f, e) in fits.items():
            columns[f"{other}'s fit ({f}, {e})"] = data.at(side, f, e)
        losses = ", ".join(f"{k.split(' (')[0]} {cell_loss(x, data.cells):.4f}" for k, x in columns.items())
        lines += ["", f"{name}, {len(data.rows)} posteriors; loss: {losses}", *report(data, columns)]
    print("\n".join(lines))
    summary = {
        name: {"posterior_factor": f, "shape_exponent": e, "loss": round(loss, 5)}
        for name, (loss, f, e) in fits.items()
    }
    print(f"{args.side} reshaping (factor, shape exponent): shipped {shipped}, fits {summary}")
    resampled = {}
    if args.sets:
        read = sources["calibration results (read)"]
        shipped_rows = [{**r, "level": float(x)} for r, x in zip(read.rows, read.at(side))]  # once for every size
        resampled = {n: resampled_set_count(shipped_rows, n) for n in args.sets}
    if resampled:
        print(
            "cells within +-5 of sets resampled from the calibration results, shipped pairs: "
            + ", ".join(f"{n} scenes {c:.1f}" for n, c in resampled.items())
        )
    if out is not None:
        write_json(
            out,
            {
                "side": args.side,
                "shipped": list(shipped),
                "fits": summary,
                "results": [str(x) for x in args.results],
                "tuning_rows": [str(x) for x in args.tuning_rows or []],
                "table": lines,
                "resampled_sets": {str(n): c for n, c in resampled.items()},
            },
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
