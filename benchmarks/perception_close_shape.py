"""Fit the reshaping where the teeth are resolved, its factor and shape exponent (the second
entries of `LikelihoodConfig.posterior_factor` and `shape_exponent`), from calibration results.

The reshaping turns a posterior's log-evidence deficit D from its peak into (f D)^e once the cells
are fixed, so it moves no cell, only the truths' levels. Read as a truth whose raw deficit grows
as a 3-D Gaussian's (D = r^2 / 2 in whitened units), a posterior reshaped with (f, e) holds
P(3 / (2e), (f D)^e) of its mass inside the truth's deficit, P the regularized lower incomplete
gamma function: the chi-square reading of `perception_far_view.py` at e = 1. Each row's recorded
(factor, shape) gives its truth's D, and any other pair its level. Checked against the exact levels
that `perception_tempering.py` records on tuning rows (docs/perception.md, Tempering, item 11):
within about a point at every level for the pairs near the fit.

This script reads `goflow bench calibration` results (both views: the resolved pair reaches the
scene view too, blended by `teeth_resolved`), re-reads every row under the shipped likelihood,
and searches the resolved pair on a grid, the other reshaping held, for the levels closest to
uniform in every perturbation group x view cell.

    .venv/bin/python benchmarks/perception_close_shape.py \
        --results docs/results/perception_calibration_seed{19,20,21,22,23,24,25}000.json \
        --json runs/close_shape_fit.json

prints the coverage at 50/68/80/90/95 % per view and group under the shipped pair and the fitted
one, and the fit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.special import gammainc, gammaincinv

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common.errors import InputError  # noqa: E402
from common.files import check_output_file, write_json  # noqa: E402
from perception.calibration import LEVELS, row_brightness  # noqa: E402
from perception.likelihood import LikelihoodConfig, blend_reshaping, teeth_resolved  # noqa: E402
from perception_far_view import fit_parser, result_rows  # noqa: E402
from perception_tempering import cell_loss, coverage  # noqa: E402

FACTORS = np.round(np.geomspace(0.8, 1.25, 21), 4)  # the resolved factor searched (1 included)
EXPONENTS = np.round(np.arange(1.0, 1.601, 0.05), 2)  # ... and its shape exponent
KEYS = ("level", "gsd", "gear", "pixels", "posterior_factor", "shape", "group", "view")


def shape_levels(levels: np.ndarray, factor0: np.ndarray, shape0: np.ndarray,
                 factor1: np.ndarray, shape1: np.ndarray) -> np.ndarray:
    """The truth levels of posteriors reshaped with (factor0, shape0) once reshaped with
    (factor1, shape1) instead, read as a 3-D Gaussian truth's (module docstring)."""
    u = gammaincinv(1.5 / shape0, np.clip(levels, 1e-12, 1 - 1e-12))
    deficit = u ** (1.0 / shape0) / factor0
    return gammainc(1.5 / shape1, (factor1 * deficit) ** shape1)


def shape_rows(paths: list[Path]) -> list[dict]:
    """The informative rows of calibration results that recorded their reshaping, pooled
    (InputError if a file is not one or holds none)."""
    rows = [r for r in result_rows(paths) if r.get("informative")
            and all(r.get(k) is not None for k in KEYS)]
    if not rows:
        raise InputError(f"{[str(p) for p in paths]}: no informative rows with their reshaping")
    return rows


class Reading:
    """Rows of calibration results and their truth levels under `base` with any resolved pair
    (its far- and close-view factors per gear held)."""

    def __init__(self, rows: list[dict], base: LikelihoodConfig) -> None:
        self.rows, self.base = rows, base
        self.levels0 = np.array([r["level"] for r in rows])
        self.factor0 = np.array([r["posterior_factor"] for r in rows], float)
        self.shape0 = np.array([r["shape"] for r in rows], float)
        self.resolved = np.array([teeth_resolved(r["gsd"]) for r in rows])
        self.held = np.array([base.far_factor_for(r["gsd"], r["gear"], r["pixels"])
                              * base.close_factor_for(r["gsd"], r["gear"], row_brightness(r, 1.0))
                              for r in rows])
        self.cells = [f"{r['group']}/{r['view']}" for r in rows]

    def at(self, factor: float | None = None, exponent: float | None = None) -> np.ndarray:
        """Every row's truth level with the resolved pair (factor, exponent) (`base`'s if None)."""
        fs = (self.base.posterior_factor[0], self.base.posterior_factor[1] if factor is None else factor)
        gs = (self.base.shape_exponent[0], self.base.shape_exponent[1] if exponent is None else exponent)
        f1, g1 = blend_reshaping(fs, gs, self.resolved)
        return shape_levels(self.levels0, self.factor0, self.shape0, f1 * self.held, g1)


def fit_shape(data: Reading, factors: np.ndarray = FACTORS,
              exponents: np.ndarray = EXPONENTS) -> tuple[float, float]:
    """The resolved pair (factor, exponent) from the grid `factors` x `exponents` whose levels
    are closest to uniform in every perturbation group x view cell (the rest of the reading's
    likelihood held)."""
    options = [(cell_loss(data.at(f, e), data.cells), float(f), float(e))
               for f in factors for e in exponents]
    _, factor, exponent = min(options)
    return factor, exponent


def report(data: Reading, before: np.ndarray, after: np.ndarray) -> list[str]:
    """Markdown rows: coverage at LEVELS per view (all groups, then each), before and after."""
    fmt = lambda m, x: "/".join(f"{100 * c:.1f}" for c in coverage(x[m], np.array(LEVELS)))  # noqa: E731
    views = np.array([r["view"] for r in data.rows])
    groups = np.array([r["group"] for r in data.rows])
    out = ["| view | group | n | shipped, % at 50/68/80/90/95 | fitted |", "|---|---|---|---|---|"]
    for view in dict.fromkeys(views):
        for group in ("all", *dict.fromkeys(groups)):
            m = (views == view) & ((groups == group) | (group == "all"))
            out.append(f"| {view} | {group} | {m.sum()} | {fmt(m, before)} | {fmt(m, after)} |")
    return out


def main(argv: list[str] | None = None) -> int:
    args = fit_parser(__doc__).parse_args(argv)
    try:
        out = check_output_file(args.json, "--json") if args.json else None
        data = Reading(shape_rows(args.results), LikelihoodConfig())
    except (InputError, OSError, ValueError) as e:
        print(f"perception_close_shape: {e}", file=sys.stderr)
        return 2
    base = data.base
    factor, exponent = fit_shape(data)
    lines = report(data, data.at(), data.at(factor, exponent))
    fit = {"posterior_factor": factor, "shape_exponent": exponent}
    print("\n".join(lines))
    print(f"resolved reshaping (factor, shape exponent): shipped ({base.posterior_factor[1]}, "
          f"{base.shape_exponent[1]}), fitted ({factor}, {exponent})")
    if out is not None:
        write_json(out, {"fit": fit, "posteriors": len(data.rows),
                         "results": [str(x) for x in args.results], "table": lines})
    return 0


if __name__ == "__main__":
    sys.exit(main())
