"""Fit the close view's reshaping per gear against the light's brightness
(`LikelihoodConfig.close_reshaping`) from calibration results.

Pooled over five fresh calibration sets (seeds 19000-23000, 2250 close views a group), the close
view was calibrated per group but not per gear and light: the large gear's was over-wide under the
brighter light on every set (58.8 % of truths inside its 50 % region), the medium gear's
over-confident under the dimmer one on every set (43.6 %) and over-wide under the nominal one
(about 53-56 %). The gears' colours answer the light differently (the large gear's yellow
saturates, the medium gear's contrast against the table falls with the light), and the colour
scale follows the light with one exponent for every gear (docs/perception.md, Tempering, item 10).
This script reads `goflow bench calibration` results (their rows: each close posterior's truth
level, gear, reshaping exponent and the light's brightness g, the mean colour gain the scorer read
off the table) and fits for each gear the factor (a g^c)^w on the view's reshaping (c = c_dim
below g = 1, c_bright above; w = `teeth_resolved`, 1 in the close view) whose truth levels are
closest to uniform in every perturbation group, on top of the reshaping the rows were made with.
A factor on the reshaping moves no cell; each truth's level moves as a 3-D Gaussian's would
(`perception_far_view.moved_levels`).

Rows made before the brightness was recorded take their group's headlight intensity
(`perception.calibration.row_brightness`: 0.5 dim, 1.6 bright, 1 for the others under the
headlight; the scorer reads 0.498-0.500, 1.600-1.601 and 0.999-1.003 there); the oblique light's
rows, whose gain varies with the view (0.70-1.0), are left out of the fit unless they recorded it.

    .venv/bin/python -m benchmarks.perception_close_view \
        --results docs/results/perception_calibration_seed{19,20,21,22,23}000.json --json runs/close_view_fit.json

prints, per gear and group, the coverage at 50/68/80/90/95 % before and after, and the fit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2


from goflow_common.errors import InputError
from goflow_common.files import check_output_file, write_json
from perception.calibration import LEVELS, row_brightness
from perception.likelihood import close_factor
from benchmarks.perception_far_view import fit_parser, moved_levels, result_rows
from benchmarks.perception_tempering import FIT_LEVELS, coverage

AMPLITUDES = np.round(np.geomspace(0.5, 2.0, 81), 4)
EXPONENTS = np.round(np.linspace(-3.0, 3.0, 121), 3)
NOMINAL = 0.02  # |g - 1| within which a light counts as the nominal one (fits a alone)


def close_rows(paths: list[Path]) -> list[dict]:
    """The informative close-view rows of calibration results with a brightness (recorded, or
    their group's), pooled; InputError if a file is not one or holds none."""
    rows = []
    for r in result_rows(paths):
        if (
            r.get("view") == "inspect"
            and r.get("informative")
            and all(k in r for k in ("level", "gsd", "gear", "shape", "group"))
        ):
            g = row_brightness(r)
            if g is not None:
                rows.append({**r, "brightness": g})
    if not rows:
        raise InputError(f"{[str(p) for p in paths]}: no informative close-view rows with a brightness")
    return rows


def _loss(log_q: np.ndarray, shape: np.ndarray, log_factor: np.ndarray, groups: np.ndarray) -> float:
    """Squared coverage error at FIT_LEVELS, summed over the groups, of levels moved by factors
    exp(log_factor) (compared in chi-square quantiles: F(f^g q) < p iff g log f + log q < log F^-1(p))."""
    thresholds = np.log(chi2.ppf(FIT_LEVELS, 3))
    below = (log_q + shape * log_factor)[:, None] < thresholds[None, :]
    return float(sum(((below[groups == g].mean(axis=0) - FIT_LEVELS) ** 2).sum() for g in np.unique(groups)))


def fit_gear(rows: list[dict]) -> tuple[float, float, float]:
    """(a, c_dim, c_bright) of one gear's rows: a on the rows under the nominal light, then each
    exponent on the rows under a dimmer or a brighter one (0 where there are none)."""
    q = chi2.ppf(np.clip(np.array([r["level"] for r in rows]), 1e-12, 1 - 1e-12), 3)
    log_q, shape = np.log(q), np.array([r["shape"] for r in rows])
    log_g = np.log(np.array([r["brightness"] for r in rows]))
    groups = np.array([r["group"] for r in rows])
    nominal = np.abs(log_g) < np.log1p(NOMINAL)
    if not nominal.any():
        raise InputError(f"the {rows[0]['gear']} gear has no close views under the nominal light to fit a on")
    a = min(
        AMPLITUDES,
        key=lambda x: _loss(log_q[nominal], shape[nominal], np.full(nominal.sum(), np.log(x)), groups[nominal]),
    )
    exponents = []
    for side in (log_g < 0, log_g > 0):
        m = side & ~nominal
        exponents.append(
            0.0
            if not m.any()
            else float(min(EXPONENTS, key=lambda c: _loss(log_q[m], shape[m], np.log(a) + c * log_g[m], groups[m])))
        )
    return float(a), exponents[0], exponents[1]


def report(rows: list[dict], fit: tuple[float, float, float]) -> list[str]:
    """Markdown rows: coverage at LEVELS per group, before and after the fit's factor."""
    levels = np.array([r["level"] for r in rows])
    factors = np.array([close_factor(r["gsd"], r["brightness"], *fit) for r in rows])
    moved = moved_levels(levels, np.array([r["shape"] for r in rows]), factors)
    groups = np.array([r["group"] for r in rows])
    out = []
    for g in dict.fromkeys(r["group"] for r in rows):
        m = groups == g
        before = "/".join(f"{100 * c:.0f}" for c in coverage(levels[m], np.array(LEVELS)))
        after = "/".join(f"{100 * c:.0f}" for c in coverage(moved[m], np.array(LEVELS)))
        out.append(f"| {rows[0]['gear']} | {g} | {m.sum()} | {before} | {after} |")
    return out


def main(argv: list[str] | None = None) -> int:
    args = fit_parser(__doc__).parse_args(argv)
    try:
        out = check_output_file(args.json, "--json") if args.json else None
        rows = close_rows(args.results)
        fits, lines = {}, ["| gear | group | n | before, % at 50/68/80/90/95 | after |", "|---|---|---|---|---|"]
        for gear in sorted({r["gear"] for r in rows}):
            sub = [r for r in rows if r["gear"] == gear]
            fits[gear] = list(fit_gear(sub))
            lines += report(sub, tuple(fits[gear]))
    except (InputError, OSError, ValueError) as e:
        print(f"perception_close_view: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    print(f"close_reshaping (a, c_dim, c_bright) on top of the rows' own: {fits}")
    if out is not None:
        write_json(
            out,
            {
                "close_reshaping": fits,
                "posteriors": len(rows),
                "results": [str(x) for x in args.results],
                "table": lines,
            },
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
