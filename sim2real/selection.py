"""Which effect: each candidate fitted on training blocks and scored on held-out ones, ranked,
selected forward and eliminated backward, its parameters with block-bootstrap intervals."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim2real.catalogue import CATALOGUE
from sim2real.config import DiagnosisConfig
from sim2real.effects import Candidate
from sim2real.fitting import Design, Model, bootstrap_mean

__all__ = [
    "Scored",
    "Selection",
    "block_folds",
    "best_setting",
    "score",
    "rank_effects",
    "select",
    "greedy",
    "exchange",
    "order_by_contribution",
    "params_with_intervals",
    "selected_effects",
    "simplest_within_error",
    "complexity",
    "overlap",
    "identifiability_warnings",
    "heldout_prediction",
    "REFINE_STEPS",
]

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


@dataclasses.dataclass
class Scored:
    """A set of candidates scored by cross-validation: held-out SSE per block, per-fold fits."""

    cands: list[Candidate]
    sse: Array  # held-out per block
    thetas: list[Array]


def block_folds(design: Design, n_folds: int) -> list[NDArray[np.int64]]:
    """`n_folds` folds of contiguous blocks (block indices per fold)."""
    per = design.n_blocks // n_folds
    return [np.arange(k * per, (k + 1) * per) for k in range(n_folds)]


REFINE_STEPS = 4  # halvings of a one-parameter family's bracket around its best grid setting


def best_setting(design: Design, options: list[Candidate], base: list[Candidate]) -> Candidate:
    """The candidate (nonlinear setting) whose joint fit with `base` has the least training SSE
    over all blocks; a member of a one-parameter family is then refined between its grid
    neighbours (geometric bisection, REFINE_STEPS halvings: the setting to about 1/16 of the
    grid's step)."""
    if len(options) == 1 and options[0].family is None:
        return options[0]
    ones = np.ones(design.n_blocks)

    def sse(cand: Candidate) -> float:
        m = Model(design, base + [cand])
        return float(m.block_sse(m.fit(ones)).sum())

    best_sse, best = min(((sse(c), c) for c in options), key=lambda x: x[0])
    fam = best.family
    if fam is None:
        return best
    v = best.setting[fam.key]
    lo, hi = fam.bracket(v)
    for _ in range(REFINE_STEPS):
        left, right = np.sqrt(lo * v), np.sqrt(v * hi)
        trials = [(sse(fam.at(x)), x) for x in (left, right) if fam.low <= x <= fam.high and x != v]
        win = min(trials, default=(np.inf, v))
        if win[0] < best_sse:
            best_sse, best = win[0], fam.at(win[1])
            lo, hi = (lo, v) if win[1] < v else (v, hi)
            v = win[1]
        else:
            lo, hi = left, right
    return best


def score(design: Design, cands: list[Candidate], folds) -> Scored:
    """The candidates fitted together on the other folds and scored on each held-out fold."""
    sse, thetas = Model(design, cands).cross_validate(folds)
    return Scored(cands, sse, thetas)


def params_with_intervals(
    design: Design, cands: list[Candidate], n: int, rng: np.random.Generator
) -> list[dict[str, Any]]:
    """Each candidate's fitted catalogue parameters (all blocks) with block-bootstrap 95 %
    intervals and bound hits."""
    model = Model(design, cands)
    nb = design.n_blocks
    theta = model.fit(np.ones(nb))
    boots = []
    for _ in range(n):
        w = np.bincount(rng.integers(0, nb, nb), minlength=nb).astype(float)
        boots.append(model.fit(w))
    out = []
    bounds = model.bounds
    free_all = model.free_params(theta)
    k = 0
    for i, (cand, coef) in enumerate(free_all):
        values = cand.to_params(coef)
        samples = [cand.to_params(model.free_params(b)[i][1]) for b in boots]
        b = bounds[k : k + len(coef)]
        hits = [cand.names[m] for m in range(len(coef)) if np.isclose(coef[m], b[m, 0]) or np.isclose(coef[m], b[m, 1])]
        k += len(coef)
        params = {}
        for pname, value in values.items():
            spec = CATALOGUE[cand.name].param(pname)
            arr = np.array([s[pname] for s in samples], dtype=float)
            lo, hi = np.quantile(arr, [0.025, 0.975], axis=0)
            params[pname] = {"value": value, "low": lo.tolist(), "high": hi.tolist(), "unit": spec.unit}
            outside = np.atleast_1d((np.asarray(value) < spec.low - 1e-9) | (np.asarray(value) > spec.high + 1e-9))
            if outside.any():  # a derived parameter (a payload's com = h / dm) beyond its range
                hits.append(f"{pname} outside [{spec.low:g}, {spec.high:g}] {spec.unit} (implausible)")
        out.append({"effect": cand.name, "params": params, "bound_hits": hits, "_samples": samples})
    return out


def overlap(design: Design, a: Candidate, b: Candidate) -> float:
    """How much of b's best fit to the residual a's columns can reproduce (0..1)."""
    ones = np.ones(design.n_blocks)
    mb = Model(design, [b])
    pb = design.predict([b], mb.fit(ones))
    target = {c: pb[:, i] for i, c in enumerate(design.channels)}
    sub = Design(target, design.channels, 1.0 / np.sqrt(design.w), design.mask > 0, design.n_blocks)
    ma = Model(sub, [rebind(a)])
    sse = ma.block_sse(ma.fit(ones)).sum()
    return float(1.0 - sse / max(sub.yy.sum(), 1e-12))


def rebind(c: Candidate) -> Candidate:
    """A copy of a candidate (the Design caches columns by object identity)."""
    return dataclasses.replace(c)


def heldout_prediction(design: Design, scored: Scored, folds) -> Array:
    """The scored candidates' prediction (T, C, 7), each fold's rows by the fit on the others."""
    pred = np.zeros_like(design.y)
    for fold, theta in zip(folds, scored.thetas):
        rows = np.zeros(design.y.shape[0], dtype=bool)
        for b in fold:
            start = design.starts[b]
            stop = design.starts[b + 1] if b + 1 < design.n_blocks else design.y.shape[0]
            rows[start:stop] = True
        if scored.cands:
            pred[rows] = design.predict(scored.cands, theta)[rows]
    return pred


@dataclasses.dataclass
class Selection:
    """The selected candidates in the order of what each adds to the final set, their steps (gain
    and interval each), the final set's scores, and each effect's best single candidate."""

    chosen: list[Candidate]
    steps: list[dict[str, Any]]
    current: Scored
    best_single: dict[str, Candidate]


def rank_effects(
    design: Design,
    pool: dict[str, list[Candidate]],
    folds,
    base: Scored,
    excess0: float,
    c: DiagnosisConfig,
    rng: np.random.Generator,
    say: Progress,
) -> tuple[list[dict[str, Any]], dict[str, Candidate]]:
    """Each effect of the pool alone at its best setting: held-out residual, gain over the nominal
    with its 95 % Bayesian block-bootstrap interval, closed share and significance; sorted by gain.
    Returns (ranking, the best single candidate per effect)."""
    n_rows = design.count
    e0 = base.sse.sum() / n_rows.sum()
    ranking = []
    best_single: dict[str, Candidate] = {}
    for i, (name, options) in enumerate(pool.items()):
        say("effects", i, len(pool))
        cand = best_setting(design, options, [])
        best_single[name] = cand
        s = score(design, [cand], folds)
        e = s.sse.sum() / n_rows.sum()
        diff = (base.sse - s.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        ranking.append(
            {
                "effect": name,
                "setting": cand.setting,
                "heldout": float(e),
                "gain": float(e0 - e),
                "gain_low": lo,
                "gain_high": hi,
                "closed": float((e0 - e) / excess0) if excess0 >= 0.05 else None,
                "significant": bool(lo > 0),
            }
        )
    say("effects", len(pool), len(pool))
    ranking.sort(key=lambda r: -r["gain"])
    return ranking, best_single


def greedy(
    design: Design,
    pool: dict[str, list[Candidate]],
    folds,
    base: Scored,
    best_single: dict[str, Candidate],
    excess0: float,
    c: DiagnosisConfig,
    rng: np.random.Generator,
) -> Selection:
    """Forward selection (add the effect that lowers the held-out residual most with those chosen,
    while its added gain is significant and at least max(min_gain x excess, min_gain_abs)), then
    backward elimination (drop one whose removal costs less), the rest ordered by what each adds."""
    n_rows = design.count
    chosen: list[Candidate] = []
    current = base
    steps = []
    while len(chosen) < c.max_effects:
        trials = []
        for name in pool:
            if any(x.name == name for x in chosen):
                continue
            cand = best_setting(design, pool[name], chosen) if len(pool[name]) > 1 else best_single[name]
            trials.append(([cand], score(design, chosen + [cand], folds)))
        if not trials:
            break
        (cand,), s = simplest_within_error(trials)
        diff = (current.sse - s.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        gain = float((current.sse.sum() - s.sse.sum()) / n_rows.sum())
        if lo <= 0 or gain < max(c.min_gain * excess0, c.min_gain_abs):
            break
        chosen.append(cand)
        steps.append(
            {
                "effect": cand.name,
                "setting": cand.setting,
                "gain": gain,
                "gain_low": lo,
                "gain_high": hi,
                "heldout_after": float(s.sse.sum() / n_rows.sum()),
            }
        )
        current = s

    # backward elimination: drop a selected effect the others make redundant (greedy forward steps
    # can take a flexible effect first that the right ones later explain away); then order the
    # effects by what each adds to the final set (its held-out loss when removed)
    def marginal(k: int) -> tuple[float, float, float, Scored]:
        rest = score(design, chosen[:k] + chosen[k + 1 :], folds)
        diff = (rest.sse - current.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        return float((rest.sse.sum() - current.sse.sum()) / n_rows.sum()), lo, hi, rest

    while len(chosen) > 1:
        margins = [marginal(k) for k in range(len(chosen))]
        k = int(np.argmin([m[0] for m in margins]))
        loss, lo, _, rest = margins[k]
        if lo > 0 and loss >= max(c.min_gain * excess0, c.min_gain_abs):
            break
        del chosen[k]
        current = rest
    if len(chosen) > 1:
        return order_by_contribution(design, folds, chosen, current, best_single, c, rng)
    steps = [st for st in steps if chosen and st["effect"] == chosen[0].name]
    return Selection(chosen, steps, current, best_single)


def select(
    design: Design,
    pool: dict[str, list[Candidate]],
    folds,
    base: Scored,
    best_single: dict[str, Candidate],
    excess0: float,
    c: DiagnosisConfig,
    rng: np.random.Generator,
) -> Selection:
    """Forward selection, backward elimination and exchange (see `greedy` and `exchange`), the
    final set ordered by what each effect adds to it, with the gain's interval."""
    first = greedy(design, pool, folds, base, best_single, excess0, c, rng)
    if len(first.chosen) < 2:
        return first
    chosen, current = exchange(design, pool, folds, first.chosen, first.current)
    if [x.name for x in chosen] == [x.name for x in first.chosen]:
        return first
    return order_by_contribution(design, folds, chosen, current, best_single, c, rng)


def order_by_contribution(
    design: Design,
    folds,
    chosen: list[Candidate],
    current: Scored,
    best_single: dict[str, Candidate],
    c: DiagnosisConfig,
    rng: np.random.Generator,
) -> Selection:
    """The set ordered by what each effect adds to it (its held-out loss when removed), with the
    loss's 95 % block-bootstrap interval."""
    n_rows = design.count
    margins = []
    for k in range(len(chosen)):
        rest = score(design, chosen[:k] + chosen[k + 1 :], folds)
        diff = (rest.sse - current.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        margins.append((float((rest.sse.sum() - current.sse.sum()) / n_rows.sum()), lo, hi))
    order = np.argsort([-m[0] for m in margins])
    steps = [
        {
            "effect": chosen[k].name,
            "setting": chosen[k].setting,
            "gain": margins[k][0],
            "gain_low": margins[k][1],
            "gain_high": margins[k][2],
            "heldout_after": float(current.sse.sum() / n_rows.sum()),
        }
        for k in order
    ]
    return Selection([chosen[k] for k in order], steps, current, best_single)


def complexity(cand: Candidate) -> int:
    """A candidate's free parameters: its linear coefficients plus its nonlinear setting's."""
    return cand.n_coef + (len(cand.setting) if cand.setting else 0)


def simplest_within_error(trials: list[tuple[list[Candidate], Scored]]) -> tuple[list[Candidate], Scored]:
    """Of candidate sets scored alike, the best (least held-out SSE) or, among those whose held-out
    SSE exceeds the best's by less than one standard error of the blocks' paired differences (the
    one-standard-error rule, Breiman et al. 1984), the one with the fewest parameters: a payload
    before the links' 44 inertial parameters that contain it, when the log cannot tell them apart."""
    best = min(trials, key=lambda t: t[1].sse.sum())
    n = len(best[1].sse)
    close = []
    for cands, s in trials:
        d = s.sse - best[1].sse
        if d.sum() <= np.std(d, ddof=1) * np.sqrt(n):  # mean difference within one standard error
            close.append((sum(complexity(x) for x in cands), s.sse.sum(), cands, s))
    _, _, cands, s = min(close, key=lambda t: (t[0], t[1]))
    return cands, s


def exchange(
    design: Design, pool: dict[str, list[Candidate]], folds, chosen: list[Candidate], current: Scored, rounds: int = 3
) -> tuple[list[Candidate], Scored]:
    """Exchange steps after the greedy selection: each selected effect replaced by each other
    effect of the pool (its setting chosen with the rest), the set kept by `simplest_within_error`
    among the current one and its exchanges; until nothing changes. A flexible effect taken first
    (the links' inertia absorbing a payload while the friction was still missing) gives way to the
    simpler one the final set supports."""
    for _ in range(rounds):
        trials = [(chosen, current)]
        for k in range(len(chosen)):
            rest = chosen[:k] + chosen[k + 1 :]
            for name, options in pool.items():
                if any(x.name == name for x in chosen):
                    continue
                cand = best_setting(design, options, rest)
                trials.append((rest[:k] + [cand] + rest[k:], score(design, rest[:k] + [cand] + rest[k:], folds)))
        new, scored = simplest_within_error(trials)
        if [x.name for x in new] == [x.name for x in chosen]:
            break
        chosen, current = list(new), scored
    return chosen, current


def selected_effects(
    design: Design, selection: Selection, c: DiagnosisConfig, rng: np.random.Generator
) -> list[dict[str, Any]]:
    """The selected effects as the report lists them: step, fitted parameters with intervals (and
    the bootstrap samples under "_samples"), meaning and place."""
    selected = []
    if selection.chosen:
        fitted = params_with_intervals(design, selection.chosen, min(c.bootstrap, 200), rng)
        for step, fit in zip(selection.steps, fitted):
            selected.append(
                {**step, **fit, "meaning": CATALOGUE[step["effect"]].meaning, "place": CATALOGUE[step["effect"]].place}
            )
    return selected


def identifiability_warnings(design: Design, ranking: list[dict[str, Any]], selection: Selection) -> list[str]:
    """A line for each significant single effect (closing > 10 %) left out that a selected one
    reproduces (> 50 % of its fit): the log cannot tell the two apart well."""
    warnings = []
    chosen = selection.chosen
    for r in ranking:
        if not (r["significant"] and (r["closed"] or 0.0) > 0.1) or any(x.name == r["effect"] for x in chosen):
            continue
        for x in chosen:
            ov = overlap(design, x, selection.best_single[r["effect"]])
            if ov > 0.5:
                warnings.append(
                    f"{r['effect']} alone closes {100 * (r['closed'] or 0.0):.0f} % of the excess, but "
                    f"{x.name} reproduces {100 * ov:.0f} % of its fit: the log cannot tell them "
                    "apart well (the selection kept " + x.name + ")"
                )
                break
    return warnings
