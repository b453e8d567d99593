"""Fit the likelihood's tempering on tuning scenes (never the calibration benchmark's).

A posterior's tempering exponent (perception.likelihood.LikelihoodConfig) is the shared law

    tau = min(1, g0^2 (gsd / g0)^k / (l r_tip))

times a factor per gear, A (gsd / g0)^B (`gear_tempering`), times the evidence factor set once
the best pose is known: visible^(-gamma w) (b_d / hypot(b_d, depth noise))^eta, times
lamp_discount^(1 - w) where the light was fitted (`evidence_factor`; w: how well the view resolves
the teeth). This script runs the calibration pipeline (detection, far posterior, inspect view,
close posterior) on tuning scenes, records for every posterior the truth's credible level with its
tempering multiplied by each of a grid of factors (PosePosterior.tempered: rescaling the tempering
moves no MAP, only the posterior) and at each of a grid of shape exponents too (the posterior
before its reshaping, PosePosterior.reshaped), and fits so that the truths' levels are closest to
uniform in every perturbation group x view cell: on rows without shaped levels, gamma, eta and the
discount (grids; 150 combinations, ~9 minutes on one core), for each combination every gear's
(A, B) (grids); on rows with them, the posterior's reshaping (a factor and a shape exponent for
unresolved and for resolved teeth, `fit_reshaping`, about a minute) with the search's tempering
held at the shipped values. The reshaping acts once the posterior's cells are fixed, so its fit
predicts the pipeline; a change of the search's tempering moves the cells, and its fit does not
(docs/perception.md, Tempering, items 6 and 7).

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.perception_tempering --scenes 30 --seed 400 \
        --workers 2 --rows runs/tempering/seed400.json

prints the coverage at 50/68/80/90/95 % with the tempering the rows were made with and with the
fitted one, per gear x view and per group x view, and the fitted values (what GEAR_TEMPERING,
occlusion_exponent, noise_exponent, lamp_discount, posterior_factor and shape_exponent hold). `--rows PATH` stores the rows there; existing files
are read back instead (nothing rendered again) and pooled, a later file's groups replacing an
earlier one's of the same scene seed (rows made under another colour model, say). `--likelihood
KEY=VALUE ...` collects and fits under other LikelihoodConfig values than the shipped ones (give
the same when reading the rows back), e.g. `colour_scale_factor=[1,2]` (Tempering, item 8). The colour
scale's brightness exponent changes the pixels' scores, not only their weight, so it cannot be
fitted this way: it was chosen from the dim and bright groups and checked by collecting them
again (docs/perception.md). `--resolved-only` fits the resolved side of the reshaping alone, the
unresolved one held at the shipped values (Tempering, item 11; `perception_reshaping.py` fits
either side from calibration results and these rows together).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from goflow_common.config import config_to_dict, config_with_overrides, key_values
from goflow_common.errors import InputError
from goflow_common.files import check_output_file, read_json, write_json
from perception.calibration import HELD_OUT_SEED, LEVELS, CalibrationConfig, row_brightness, run_calibration
from perception.likelihood import LikelihoodConfig, blend_reshaping, teeth_resolved
from perception.search import SearchConfig

FACTORS = tuple(float(f) for f in np.geomspace(0.25, 4.0, 33))
FIT_LEVELS = np.linspace(0.05, 0.95, 19)  # the levels whose coverage the fit matches
AMPLITUDES = np.geomspace(0.5, 2.0, 41)
EXPONENTS = np.linspace(-0.75, 0.75, 31)
OCCLUSION = np.linspace(0.0, 1.0, 5)
NOISE = np.linspace(0.0, 2.0, 5)
LAMP = np.linspace(0.5, 1.0, 6)
SHAPES = (0.9, 1.0, 1.1, 1.2, 1.25, 1.3, 1.35, 1.4, 1.45, 1.5, 1.6)  # posterior shape exponents recorded per row
SHAPE_GRID = np.round(np.arange(0.9, 1.601, 0.05), 2)  # ... and searched (interpolated between)
RESHAPE_FACTORS = np.round(np.geomspace(0.5, 2.0, 25), 4)  # the reshaping's factors searched


def collect(
    scenes: int,
    seed: int,
    workers: int,
    groups: tuple[str, ...] | None = None,
    likelihood: LikelihoodConfig | None = None,
) -> dict:
    """The calibration pipeline's rows on tuning scenes (of `groups`, every perturbation group if
    None), with each posterior's scaled levels, under `likelihood` (the shipped one if None)."""
    if seed + scenes > HELD_OUT_SEED:
        raise InputError(
            f"--seed {seed} with --scenes {scenes} reaches the benchmark's scenes "
            f"(seeds from {HELD_OUT_SEED}); tune on seeds below it"
        )
    config = CalibrationConfig(
        scenes=scenes,
        seed=seed,
        workers=workers,
        tempering_factors=FACTORS,
        shape_exponents=SHAPES,
        search=SearchConfig(likelihood=likelihood or LikelihoodConfig()),
    )
    if groups:
        config = replace(config, groups=tuple(groups))
    result = run_calibration(config, progress=True)
    result["config"]["tempering_factors"] = list(FACTORS)
    result["config"]["shape_exponents"] = list(SHAPES)
    result["config"]["likelihood"] = config_to_dict(config.search.likelihood)
    return result


def coverage(levels: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """Observed coverage at each nominal level."""
    return (levels[:, None] < nominal[None, :]).mean(axis=0)


class Rows:
    """The informative posteriors' rows as arrays, and their truth levels at any tempering (and,
    where the rows hold `shaped_levels` at `shapes`, at any shape exponent between those)."""

    def __init__(self, rows: list[dict], factors: np.ndarray, shapes: np.ndarray | None = None) -> None:
        self.rows = rows
        self.logf = np.log(factors)
        self.table = np.array([r["scaled_levels"] for r in rows])
        self.gsd = np.array([r["gsd"] for r in rows])
        self.shapes = None if shapes is None or not len(shapes) else np.asarray(shapes, float)
        if self.shapes is not None:
            self.shaped = np.array([r["shaped_levels"] for r in rows])  # (rows, shapes, factors)

    def levels(self, scale: np.ndarray, mask: np.ndarray | None = None, shape: np.ndarray | None = None) -> np.ndarray:
        """Each row's (of `mask`'s) truth level with its tempering multiplied by scale[i]
        (interpolated in log factor between the recorded ones, clipped to their range) and, when
        `shape` is given, its shape exponent shape[i] (interpolated between the recorded ones)."""
        s = np.clip(np.log(scale), self.logf[0], self.logf[-1])
        idx = np.clip(np.searchsorted(self.logf, s) - 1, 0, len(self.logf) - 2)
        t = (s - self.logf[idx]) / (self.logf[idx + 1] - self.logf[idx])
        n = np.arange(len(s))
        if shape is None:
            table = self.table if mask is None else self.table[mask]
            return table[n, idx] * (1 - t) + table[n, idx + 1] * t
        table = self.shaped if mask is None else self.shaped[mask]
        g = np.clip(shape, self.shapes[0], self.shapes[-1])
        j = np.clip(np.searchsorted(self.shapes, g) - 1, 0, len(self.shapes) - 2)
        u = (g - self.shapes[j]) / (self.shapes[j + 1] - self.shapes[j])
        at = lambda jj: table[n, jj, idx] * (1 - t) + table[n, jj, idx + 1] * t  # noqa: E731
        return at(j) * (1 - u) + at(j + 1) * u

    def tempering_ratio(self, config: LikelihoodConfig) -> np.ndarray:
        """Per row: the search's tempering `config` gives it over the one it was recorded with."""
        return np.array(
            [
                config.tempering_for(r["gear"], r["gsd"])
                * config.evidence_factor(
                    r["gsd"], r["inlier_fraction"], r.get("pixel_noise", r["depth_noise"]), r.get("light") is not None
                )
                / r["tempering"]
                for r in self.rows
            ]
        )

    def scale(self, config: LikelihoodConfig) -> np.ndarray:
        """Per row: the factor on its recorded posterior's tempering under `config`: the search's
        tempering ratio times the reshaping's factor (the levels are recorded before it)."""
        # an oblique row made before the brightness was recorded: the nominal light's
        factor = np.array(
            [config.reshaping_for(r["gsd"], r["gear"], r["pixels"], row_brightness(r, 1.0))[0] for r in self.rows]
        )
        return self.tempering_ratio(config) * factor

    def shape(self, config: LikelihoodConfig) -> np.ndarray | None:
        """Per row: the shape exponent `config` gives it (None without shaped levels)."""
        if self.shapes is None:
            return None
        return np.array(
            [config.reshaping_for(r["gsd"], r["gear"], r["pixels"], row_brightness(r, 1.0))[1] for r in self.rows]
        )

    def at(self, config: LikelihoodConfig) -> np.ndarray:
        """Every row's truth level under `config`."""
        return self.levels(self.scale(config), shape=self.shape(config))


def cell_loss(levels: np.ndarray, keys: list[str]) -> float:
    """Squared coverage error at FIT_LEVELS, summed over the cells each row's key names."""
    keys = np.asarray(keys)
    return float(sum(((coverage(levels[keys == k], FIT_LEVELS) - FIT_LEVELS) ** 2).sum() for k in np.unique(keys)))


def fit(
    data: Rows,
    base: LikelihoodConfig,
    occlusion: np.ndarray = OCCLUSION,
    noise: np.ndarray = NOISE,
    lamp: np.ndarray = LAMP,
) -> LikelihoodConfig:
    """`base` with the occlusion and noise exponents and the fitted lamp's discount (from the grids
    `occlusion`, `noise`, `lamp`) and, for each, every gear's (A, B) (grids AMPLITUDES x
    EXPONENTS): the set whose truth levels are closest to uniform in every perturbation group x
    view cell, on the levels before the reshaping (the returned config has it off: fit it
    after, with `fit_reshaping`, on rows collected under the new tempering)."""
    base = replace(base, posterior_factor=(1.0, 1.0), shape_exponent=(1.0, 1.0), far_reshaping={}, close_reshaping={})
    g0 = base.reference_gsd
    views = [r["view"] for r in data.rows]
    cells = [f"{r['group']}/{r['view']}" for r in data.rows]
    gears = np.array([r["gear"] for r in data.rows])
    best = (np.inf, base)
    for gamma, eta, discount in itertools.product(occlusion, noise, lamp):
        cfg = replace(
            base,
            gear_tempering={},
            occlusion_exponent=float(gamma),
            noise_exponent=float(eta),
            lamp_discount=float(discount),
        )
        scale, shape = data.scale(cfg), data.shape(cfg)
        per_gear = {}
        for gear in np.unique(gears):
            m = gears == gear
            sub = [v for v, k in zip(views, m) if k]
            ratio = data.gsd[m] / g0
            sh = None if shape is None else shape[m]
            options = [
                (cell_loss(data.levels(scale[m] * a * ratio**b, m, sh), sub), a, b)
                for a in AMPLITUDES
                for b in EXPONENTS
            ]
            _, a, b = min(options)
            per_gear[str(gear)] = (float(a), float(b))
        cfg = replace(cfg, gear_tempering=per_gear)
        loss = cell_loss(data.at(cfg), cells)
        if loss < best[0]:
            best = (loss, cfg)
    return best[1]


def held_factors(rows: list[dict], base: LikelihoodConfig) -> np.ndarray:
    """Per row: `base`'s per-gear far- and close-view factors on its reshaping (held by the fits
    of the shared pairs)."""
    return np.array(
        [
            base.far_factor_for(r["gsd"], r["gear"], r["pixels"])
            * base.close_factor_for(r["gsd"], r["gear"], row_brightness(r, 1.0))
            for r in rows
        ]
    )


def fit_reshaping(
    data: Rows,
    base: LikelihoodConfig,
    factors: np.ndarray = RESHAPE_FACTORS,
    shapes: np.ndarray = SHAPE_GRID,
    rounds: int = 2,
    sides: tuple[int, ...] = (1, 0),
) -> LikelihoodConfig:
    """`base` with the posterior's reshaping fitted, the search's tempering held: the
    (posterior_factor, shape_exponent) pair of each of `sides` (1: resolved teeth, 0: unresolved;
    the other side keeps `base`'s), each from the grid `factors` x `shapes`, `rounds` times in
    turn, whose truth levels are closest to uniform in every perturbation group x view cell,
    `base`'s far- and close-view factors per gear held (`far_reshaping`, `close_reshaping`). The reshaping moves no cell, so the rows' levels under it are the
    pipeline's (docs/perception.md, Tempering, item 7)."""
    if data.shapes is None:
        raise InputError(
            "the rows hold no shaped levels; collect them with this script (every file at the same shape exponents)"
        )
    cells = [f"{r['group']}/{r['view']}" for r in data.rows]
    ratio = data.tempering_ratio(base) * held_factors(data.rows, base)
    w = np.array([teeth_resolved(g) for g in data.gsd])
    factor, shape = list(base.posterior_factor), list(base.shape_exponent)
    for _ in range(rounds):
        for side in sides:
            options = []
            for f, g in itertools.product(factors, shapes):
                fs, gs = list(factor), list(shape)
                fs[side], gs[side] = float(f), float(g)
                rows_f, rows_g = blend_reshaping(fs, gs, w)
                options.append((cell_loss(data.levels(ratio * rows_f, shape=rows_g), cells), float(f), float(g)))
            _, factor[side], shape[side] = min(options)
    return replace(
        base,
        posterior_factor=(round(factor[0], 4), round(factor[1], 4)),
        shape_exponent=(round(shape[0], 4), round(shape[1], 4)),
    )


def _table(data: Rows, today: np.ndarray, fitted: np.ndarray, key) -> list[str]:
    """Markdown rows: coverage at LEVELS today and fitted, per value of key(row)."""
    nominal = np.asarray(LEVELS)
    fmt = lambda c: "/".join(f"{100 * x:.0f}" for x in c)  # noqa: E731
    keys = [key(r) for r in data.rows]
    out = []
    for k in dict.fromkeys(keys):
        m = np.array([x == k for x in keys])
        out.append(
            f"| {' | '.join(k)} | {m.sum()} | {fmt(coverage(today[m], nominal))} | "
            f"{fmt(coverage(fitted[m], nominal))} |"
        )
    return out


def load_rows(paths: list[Path]) -> tuple[list[dict], np.ndarray, np.ndarray | None]:
    """The informative rows of every file, pooled, their tempering factors and their shape
    exponents (None unless every file has shaped levels at the same ones); a later file's groups
    replace an earlier one's of the same scene seed."""
    rows: dict[tuple[int, str], list[dict]] = {}
    factors = None
    shapes: list = []
    for path in paths:
        result = read_json(path, "calibration rows")
        f = np.asarray(result["config"]["tempering_factors"])
        if factors is not None and not np.allclose(f, factors):
            raise InputError(f"{path}: its tempering factors differ from the first file's")
        factors = f
        shapes.append(tuple(result["config"].get("shape_exponents", ())))
        usable = fit_rows(result)
        for group in result["config"]["groups"]:
            rows[result["config"]["seed"], group] = [r for r in usable if r["group"] == group]
    same = len(set(shapes)) == 1 and shapes[0]
    return ([r for group in rows.values() for r in group], factors, np.asarray(shapes[0]) if same else None)


def fit_rows(result: dict) -> list[dict]:
    """The rows of a calibration result the fit can use: informative, with scaled levels."""
    return [r for r in result["rows"] if r.get("informative") and "scaled_levels" in r]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=30)
    p.add_argument("--seed", type=int, default=400, help=f"first tuning scene seed (< {HELD_OUT_SEED})")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument(
        "--groups",
        nargs="+",
        default=None,
        metavar="GROUP",
        help="collect these perturbation groups only (default: all); pooled with --rows "
        "files of the same seed, they replace those groups' rows",
    )
    p.add_argument(
        "--rows",
        type=Path,
        nargs="+",
        default=None,
        help="store the rows here (one path), or read them from existing files, pooled (a "
        "later file's groups replace an earlier one's of the same seed)",
    )
    p.add_argument("--json", type=Path, default=None, help="write the fit and the tables here")
    p.add_argument(
        "--resolved-only",
        action="store_true",
        help="on rows with shaped levels, fit the reshaping where the teeth are resolved "
        "(the close view) only, the other side held at the shipped values",
    )
    p.add_argument(
        "--likelihood",
        nargs="+",
        default=None,
        metavar="KEY=VALUE",
        help="LikelihoodConfig fields to collect and fit under instead of the shipped "
        "ones, e.g. colour_scale_factor=[1,2]",
    )
    args = p.parse_args(argv)
    try:
        out = check_output_file(args.json, "--json") if args.json else None
        base = config_with_overrides(
            LikelihoodConfig, key_values(args.likelihood, "--likelihood"), owner="--likelihood"
        )
        if args.rows and all(path.exists() for path in args.rows):
            rows, factors, shapes = load_rows(args.rows)
        else:
            if args.rows and len(args.rows) > 1:
                raise InputError(f"--rows: {[str(x) for x in args.rows if not x.exists()]} missing")
            if args.rows:
                check_output_file(args.rows[0], "--rows")
            result = collect(args.scenes, args.seed, args.workers, args.groups, base)
            if args.rows:
                write_json(args.rows[0], result)
            rows, factors, shapes = fit_rows(result), np.asarray(FACTORS), np.asarray(SHAPES)
    except (InputError, OSError, ValueError) as e:
        print(f"perception_tempering: {e}", file=sys.stderr)
        return 2
    data = Rows(rows, factors, shapes)
    today = np.array([r["level"] for r in rows])  # the levels the rows were made with
    if data.shapes is None:
        config = fit(data, base)
    else:  # the search's tempering held at the shipped values, the reshaping fitted
        if args.resolved_only:
            config = fit_reshaping(data, base, sides=(1,), rounds=1)
        else:
            config = fit_reshaping(data, replace(base, posterior_factor=(1.0, 1.0), shape_exponent=(1.0, 1.0)))
    fitted = data.at(config)
    head = "| {} | n | as collected 50/68/80/90/95 | fitted |"
    lines = [head.format("gear | view"), "|---|---|---|---|---|"]
    lines += _table(data, today, fitted, lambda r: (r["gear"], r["view"]))
    lines += ["", head.format("group | view"), "|---|---|---|---|---|"]
    lines += _table(data, today, fitted, lambda r: (r["group"], r["view"]))
    print("\n".join(lines))
    fits = {
        "gear_tempering": {g: [round(a, 4), round(b, 4)] for g, (a, b) in config.gear_tempering.items()},
        "occlusion_exponent": config.occlusion_exponent,
        "noise_exponent": config.noise_exponent,
        "lamp_discount": config.lamp_discount,
        "posterior_factor": list(config.posterior_factor),
        "shape_exponent": list(config.shape_exponent),
        "posteriors": len(rows),
    }
    print(f"fitted: {fits}")
    if out is not None:
        write_json(out, {"fit": fits, "table": lines})
    return 0


if __name__ == "__main__":
    sys.exit(main())
