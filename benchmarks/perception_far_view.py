"""Fit the far view's reshaping per gear against its sampled pixel count
(`LikelihoodConfig.far_reshaping`) from calibration results.

Where the teeth are not resolved, a gear's sampled pixels (every m-th of its region, m the
search's stride) err about independently, so a far view's evidence grows with their number. The
tempering law treats the evidence as bound to the gear's outline, and the stride weights each
sampled pixel by m, so within the scene view a posterior's width does not follow the pixel count,
and the count jumps at each change of stride: the medium gear went from 57 % of truths inside its
50 % region with 672 sampled pixels to 38 % with 459 within one stride, the small gear's errors
grew twice as fast as its width with the distance (docs/perception.md, Tempering, item 9). This
script reads `goflow bench calibration` results (their rows: each posterior's truth level, gsd,
sampled pixels, gear and reshaping exponent) and fits for each gear the factor
(a (n / n_far)^b)^(1 - w) on the scene view's reshaping (n the sampled pixels at the MAP,
n_far = `far_reference_pixels`, w = `teeth_resolved`) whose truth levels are closest to uniform
in every perturbation group and in each fifth of the gear's pixel counts, on top of the
reshaping the rows were made with.

A factor f on the reshaping multiplies the truth's deficit D before the shape exponent g, so its
level moves as that of a Gaussian truth in 3 dimensions would: level' = F(f^g F^-1(level)), F the
chi-square distribution function with 3 degrees of freedom. Checked against the exact levels that
`perception_tempering.py` records on tuning rows (docs/perception.md, Tempering, item 9).

    .venv/bin/python -m benchmarks.perception_far_view \
        --results docs/results/perception_calibration_seed1{5,6,7,8,9}000.json \
        docs/results/perception_calibration_seed2{0,1}000.json --json runs/far_view_fit.json

prints, per gear, the fitted (a, b) and the coverage at 50 and 90 % in each fifth of its pixel
counts and of its gsd range, before and after. Rows made with another `far_reshaping` than none
are fitted on top of it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2


from goflow_common.errors import InputError
from goflow_common.files import check_output_file, write_json
from perception.calibration import load_result, named_by_set
from perception.likelihood import FAR_REFERENCE_PIXELS, far_factor, teeth_resolved
from benchmarks.perception_tempering import FIT_LEVELS, coverage

SLOPES = np.round(np.linspace(-4.0, 2.0, 61), 2)
AMPLITUDES = np.round(np.geomspace(0.5, 2.0, 41), 4)
BINS = 5  # parts of each gear's pixel counts (and gsd range), each a cell of the fit (and of the table)


def result_rows(paths: list[Path]) -> list[dict]:
    """Every row of the calibration results at `paths`, pooled, each scene named by its file's
    place in `paths` ("k/scene": two sets' scene 0 are two scenes) (InputError naming a file that
    is not one)."""
    rows: list[dict] = []
    for k, path in enumerate(paths):
        result = load_result(path)
        if not isinstance(result.get("rows"), list):
            raise InputError(f"{path}: no rows (a summary); expected a calibration run's --rows file")
        rows += named_by_set(result["rows"], k)
    return rows


def scene_rows(paths: list[Path]) -> list[dict]:
    """The informative scene-view rows of calibration results, pooled (InputError if a file is
    not one or holds none)."""
    rows = [
        r
        for r in result_rows(paths)
        if r.get("view") == "scene"
        and r.get("informative")
        and all(k in r for k in ("level", "gsd", "pixels", "gear", "shape", "group"))
    ]
    if not rows:
        raise InputError(f"{[str(p) for p in paths]}: no informative scene-view rows with levels")
    return rows


def moved_levels(levels: np.ndarray, shape: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """The truth levels after multiplying each posterior's reshaping factor by `factor` (its
    deficit scaled before the shape exponent `shape`), read as a 3-D Gaussian truth's."""
    q = chi2.ppf(np.clip(levels, 1e-12, 1 - 1e-12), 3)
    return chi2.cdf(factor**shape * q, 3)


def far_factors(gsd: np.ndarray, pixels: np.ndarray, a: float, b: float) -> np.ndarray:
    """`perception.likelihood.far_factor` of (a, b) at each row's gsd and pixel count."""
    return np.array([far_factor(g, n, a, b) for g, n in zip(gsd, pixels)])


def _fifths(values: np.ndarray) -> np.ndarray:
    """Each value's fifth (0..BINS-1) of the range of `values`, by quantiles."""
    edges = np.quantile(values, np.linspace(0.0, 1.0, BINS + 1))
    return np.clip(np.searchsorted(edges, values, side="right") - 1, 0, BINS - 1)


def _cells(rows: list[dict]) -> list[np.ndarray]:
    """Masks of the fit's cells: every group, and every fifth of the rows' pixel counts."""
    groups = np.array([r["group"] for r in rows])
    bins = _fifths(np.array([r["pixels"] for r in rows], dtype=float))
    return [groups == g for g in np.unique(groups)] + [bins == b for b in range(BINS)]


def fit_gear(rows: list[dict]) -> tuple[float, float]:
    """(a, b) whose moved levels are closest to uniform in every cell of `_cells` (the pixel cells
    counted twice)."""
    levels = np.array([r["level"] for r in rows])
    shape = np.array([r["shape"] for r in rows])
    gsd = np.array([r["gsd"] for r in rows])
    pixels = np.array([r["pixels"] for r in rows], dtype=float)
    q = chi2.ppf(np.clip(levels, 1e-12, 1 - 1e-12), 3)
    # `far_factor` in logs, log f = (1 - w) (log a + b log(n / n_far)), and each level's moved
    # value is F(f^g q): compare f^g q with the chi-square quantiles of FIT_LEVELS instead of
    # evaluating F, over the grid of (a, b)
    unresolved = 1.0 - np.array([teeth_resolved(g) for g in gsd])
    log_q, log_ratio = np.log(q), np.log(pixels / FAR_REFERENCE_PIXELS)
    thresholds = np.log(chi2.ppf(FIT_LEVELS, 3))
    cells = [m for m in _cells(rows) if m.any()]
    weights = np.array([1.0] * (len(cells) - BINS) + [2.0] * BINS)[-len(cells) :]
    member = np.array(cells, dtype=float)  # (cells, rows)
    sizes = member.sum(axis=1)
    best = (np.inf, 1.0, 0.0)
    for b in SLOPES:
        for a in AMPLITUDES:
            moved = log_q + shape * unresolved * (np.log(a) + b * log_ratio)  # log(f^g q)
            below = (moved[:, None] < thresholds[None, :]).astype(float)  # (rows, levels)
            cover = member @ below / sizes[:, None]
            loss = float((weights[:, None] * (cover - FIT_LEVELS) ** 2).sum())
            if loss < best[0]:
                best = (loss, float(a), float(b))
    return best[1], best[2]


def report(rows: list[dict], a: float, b: float) -> list[str]:
    """Markdown rows: coverage at 50 and 90 % per fifth of the pixel counts and of the gsd range,
    before and after."""
    levels = np.array([r["level"] for r in rows])
    gsd = np.array([r["gsd"] for r in rows])
    pixels = np.array([r["pixels"] for r in rows], dtype=float)
    moved = moved_levels(levels, np.array([r["shape"] for r in rows]), far_factors(gsd, pixels, a, b))
    out = []
    for name, values, unit in (("pixels", pixels, 1.0), ("gsd [mm]", gsd, 1e3)):
        bins = _fifths(values)
        for k in range(BINS):
            m = bins == k
            before, after = coverage(levels[m], np.array([0.5, 0.9])), coverage(moved[m], np.array([0.5, 0.9]))
            out.append(
                f"| {rows[0]['gear']} | {name} {unit * values[m].min():.3g}-{unit * values[m].max():.3g} | "
                f"{m.sum()} | {100 * before[0]:.0f} / {100 * before[1]:.0f} | "
                f"{100 * after[0]:.0f} / {100 * after[1]:.0f} |"
            )
    return out


def fit_parser(doc: str) -> argparse.ArgumentParser:
    """The command line of a fit from calibration results: --results (pooled) and --json; the
    description is `doc`'s first line."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument(
        "--results", type=Path, nargs="+", required=True, help="goflow bench calibration results (JSON), pooled"
    )
    p.add_argument("--json", type=Path, default=None, help="write the fit and the table here")
    return p


def main(argv: list[str] | None = None) -> int:
    args = fit_parser(__doc__).parse_args(argv)
    try:
        out = check_output_file(args.json, "--json") if args.json else None
        rows = scene_rows(args.results)
    except (InputError, OSError, ValueError) as e:
        print(f"perception_far_view: {e}", file=sys.stderr)
        return 2
    fits, lines = {}, ["| gear | fifth of | n | before, % at 50 / 90 | after |", "|---|---|---|---|---|"]
    for gear in sorted({r["gear"] for r in rows}):
        sub = [r for r in rows if r["gear"] == gear]
        a, b = fit_gear(sub)
        fits[gear] = [a, b]
        lines += report(sub, a, b)
    print("\n".join(lines))
    print(f"far_reshaping (a, b) on top of the rows' own: {fits}")
    if out is not None:
        write_json(
            out,
            {
                "far_reshaping": fits,
                "reference_pixels": FAR_REFERENCE_PIXELS,
                "posteriors": len(rows),
                "results": [str(x) for x in args.results],
                "table": lines,
            },
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
