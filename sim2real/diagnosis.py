"""The three answers for an arm log: where the gap lies, which effect causes it, how far it shrinks.

1. Where: the nominal model's residual per channel and joint, per phase and per state region
   (velocity sign, reversals, speed, load), each as its RMS over the noise floor estimated from
   the data (the spread of sample-to-sample differences, robustly).
2. Which: each catalogue effect is fitted on training blocks and scored on held-out blocks
   (blocked cross-validation in time; block bootstrap intervals); forward selection adds effects
   while the held-out gain is significant, backward elimination drops those the others make
   redundant, and the selected effects are ordered by what each adds to the final set. Fitted parameters come with bootstrap intervals and
   bound hits; two effects that explain the same residual get an identifiability warning; a gap
   the selection does not close is "unexplained", not given to the nearest effect.
3. How far: the held-out gap before and after the selected effects, per channel, joint and
   phase, as the fraction closed toward the noise floor.
The model audit asks the same of the nominal model's own terms (rotor inertia, damping, end
effector): a term whose removal improves the held-out fit is reported as making it worse.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.checks import check_int, check_number
from common.errors import InputError
from sim2real.arm import END_EFFECTORS, ArmModel
from sim2real.band import Band, BandConfig, band_candidate, band_floor, band_pool, choose_band
from sim2real.catalogue import CATALOGUE
from sim2real.clean import CleanConfig, clean
from sim2real.effects import Candidate, candidates, untestable
from sim2real.fitting import Design, Model, bootstrap_mean
from sim2real.structure import hat_basis, structure_gains, trend_basis
from sim2real.log import PHASES, RobotLog
from sim2real.phases import segment_phases
from sim2real.replay import Replay, ReplayConfig, replay

__all__ = ["DiagnosisConfig", "Diagnosis", "Evidence", "diagnose", "analyse", "arm_evidence", "noise_floor"]

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


@dataclasses.dataclass(frozen=True)
class DiagnosisConfig:
    """blocks: contiguous time blocks (folds are groups of them); folds: cross-validation folds;
    bootstrap: resamples for intervals; effects: the catalogue effects to consider (None: all
    that the log's channels can show); max_effects: most effects forward selection may add;
    min_gain: least held-out gain, as a fraction of the nominal excess over the noise floor, for
    an effect to be added, and min_gain_abs the least in noise variances (2 % of the noise
    variance: below it an effect is too weak to tell from the model's own small misfits, which
    reach 0.3 % on the simulated reality's nominal logs); explained: fraction of the excess the selection must close for the
    verdict "explained"; structure: the least share of the excess that structure left in the
    residual after the selection (a generic function of the joint velocity, a trend in time:
    sim2real/structure.py) must predict on held-out data for the verdict to read "unexplained"
    although the selection closes `explained` of it; structure_rest: the same, as a share of
    what the selection leaves above the level of a log with no gap (a large effect outside the
    catalogue that several catalogue effects mimic leaves a small share of its excess, but most
    of what is left is structure); floor_tolerance: the excess over the noise floor [noise
    variances] within the floor's own uncertainty (a floor read 10 % low in standard deviation
    reads a log with no gap 0.23 high): an excess whose interval's lower end is below it is not a
    gap by itself; seed: of the bootstrap; replay, clean, band: the stages' settings (band None:
    every sample, the fast-part/variogram floor of the version before the band).""" 

    blocks: int = 20
    folds: int = 5
    bootstrap: int = 300
    effects: tuple[str, ...] | None = None
    max_effects: int = 4
    min_gain: float = 0.005
    min_gain_abs: float = 0.02
    explained: float = 0.6
    structure: float = 0.05
    structure_rest: float = 0.25
    floor_tolerance: float = 0.25
    seed: int = 0
    replay: ReplayConfig = dataclasses.field(default_factory=ReplayConfig)
    clean: CleanConfig = dataclasses.field(default_factory=CleanConfig)
    band: BandConfig | None = dataclasses.field(default_factory=BandConfig)

    def __post_init__(self) -> None:
        check_int(self.blocks, "DiagnosisConfig.blocks", 4)
        check_int(self.folds, "DiagnosisConfig.folds", 2)
        if self.blocks % self.folds:
            raise InputError(f"DiagnosisConfig.blocks = {self.blocks}; expected a multiple of folds = {self.folds}")
        check_int(self.bootstrap, "DiagnosisConfig.bootstrap", 20)
        check_int(self.max_effects, "DiagnosisConfig.max_effects", 1)
        check_number(self.min_gain, "DiagnosisConfig.min_gain", 0.0, 1.0)
        check_number(self.explained, "DiagnosisConfig.explained", 0.0, 1.0)
        check_number(self.structure, "DiagnosisConfig.structure", 0.0, 1.0)
        check_number(self.structure_rest, "DiagnosisConfig.structure_rest", 0.0, 1.0)
        check_number(self.floor_tolerance, "DiagnosisConfig.floor_tolerance", 0.0, 100.0)
        for name in self.effects or ():
            if name not in CATALOGUE:
                raise InputError(f"DiagnosisConfig.effects has {name!r}; expected names from {sorted(CATALOGUE)}")


def noise_floor(residual: Array, valid: NDArray[np.bool_], window: int = 101,
                kernel: Array | None = None, reach: int | None = None) -> Array:
    """Per column of a (T, k) residual: the standard deviation of its noise, i.e. of what varies
    faster than any effect of the state can (vibration, sensor noise, derivative noise).

    The fast-part estimate: the residual minus its cubic Savitzky-Golay smoothing over `window`
    samples, robustly (1.4826 MAD), corrected for the part of the noise the smoothing keeps
    (divided by sqrt(1 - h0), h0 the filter's centre weight, for white noise; with a `kernel`, for
    white noise smoothed by it, a replay's torque filter). Slow model error gives ~0, but noise
    bluer than assumed (derivative noise) reads too high. With `reach`, the noise's correlation
    length in samples, the nugget of the residual's semivariogram is a second estimate: beyond
    that lag the noise's share of the semivariogram is its whole variance, so a + b lag^2 fitted
    at lags reach .. 3 reach gives it at a = lag 0 whatever the noise's spectrum; slow model error
    makes it read high. The floor is the smaller of the two, and no lower than the fast part's
    spread over the smoothing's largest high-pass gain (no noise spectrum keeps more)."""
    from scipy.signal import savgol_coeffs, savgol_filter

    r = residual[valid]
    window = min(window, (len(r) // 2) * 2 - 1)
    if window < 7:  # too few samples to tell fast from slow: the whole spread, conservatively
        return np.maximum(np.std(r, axis=0), 1e-9)
    fast = r - savgol_filter(r, window, 3, axis=0)
    if kernel is None:
        kept = 1.0 - savgol_coeffs(window, 3)[window // 2]
    else:  # the fast part of kernel-smoothed white noise: (I - SG) * kernel
        impulse = np.zeros(window + 2 * len(kernel))
        impulse[len(impulse) // 2] = 1.0
        seen = np.convolve(impulse, kernel[::-1], mode="same")
        kept = float(np.sum((seen - savgol_filter(seen, window, 3)) ** 2) / np.sum(kernel ** 2))
    spread = 1.4826 * np.median(np.abs(fast - np.median(fast, axis=0)), axis=0)
    floor = spread / np.sqrt(kept)
    if reach is not None and len(r) >= 12 * reach:
        # the fast part keeps at most the smoothing's largest high-pass gain of any noise
        highpass = -savgol_coeffs(window, 3)
        highpass[window // 2] += 1.0
        gain = float(np.max(np.abs(np.fft.rfft(highpass, 8 * window))))
        floor = np.clip(_nugget(r, reach), spread / gain, floor)
    scale = np.sqrt(np.mean(r ** 2, axis=0))
    return np.maximum(floor, 1e-6 * np.maximum(scale, 1e-12) + 1e-9)


def _nugget(r: Array, reach: int) -> Array:
    """The standard deviation at lag 0 of the semivariogram gamma(lag) = E (r[t + lag] - r[t])^2 / 2
    of each column of r (T, k), extrapolated from lags reach .. 3 reach by a + b lag^2 (0 where
    the fit's a is not positive)."""
    lags = np.unique(np.linspace(reach, 3 * reach, 12).astype(int))
    gamma = np.array([0.5 * np.mean((r[k:] - r[:-k]) ** 2, axis=0) for k in lags])
    x = (lags / reach) ** 2.0
    design = np.stack([np.ones_like(x), x], axis=1)
    a = np.linalg.lstsq(design, gamma, rcond=None)[0][0]
    return np.sqrt(np.maximum(a, 0.0))


@dataclasses.dataclass
class Diagnosis:
    """Everything the report shows; `summary()` is plain JSON-compatible data."""

    log_meta: dict[str, Any]
    channels: tuple[str, ...]
    where: dict[str, Any]
    audit: list[dict[str, Any]]
    ranking: list[dict[str, Any]]
    selected: list[dict[str, Any]]
    warnings: list[str]
    how_far: dict[str, Any]
    verdict: dict[str, Any]
    arrays: dict[str, Array]
    labels: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    x_label: str = "dq [rad/s]"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        return {"log": self.log_meta, "channels": list(self.channels),
                "columns": {c: self.labels.get(c, [f"joint {j + 1}" for j in range(7)]) for c in self.channels},
                "where": self.where, "audit": self.audit, "ranking": self.ranking, "selected": self.selected,
                "warnings": self.warnings, "how_far": self.how_far, "verdict": self.verdict, **self.extra}


@dataclasses.dataclass
class Evidence:
    """What the analysis needs from a replayed log, whatever the model.

    residual: channel -> (T, 7) measured minus nominal; labels: channel -> the 7 columns' names;
    valid: (T,) samples the fits use; phase: (T,) labels indexing PHASES; regions: name -> (T, 7)
    state-region masks; pool: effect -> its candidates; audit: the model audit (or None);
    x: (T, 7) what the residual figure plots it against, x_label its name; time: (T,); floor_min:
    the least noise floor per channel; floor: a channel's noise floor when the evidence knows it
    (else it is estimated from the residual by `noise_floor`); reach: the residual noise's
    correlation length in samples, where known (`noise_floor`); structure: bases (T, 7, K) of the
    state in which the verdict looks for structure the selection left (sim2real/structure.py)."""

    residual: dict[str, Array]
    labels: dict[str, list[str]]
    valid: NDArray[np.bool_]
    phase: NDArray[np.int64]
    regions: dict[str, NDArray[np.bool_]]
    pool: dict[str, list[Candidate]]
    audit: Callable[..., list[dict[str, Any]]] | None
    x: Array
    x_label: str
    time: Array
    meta: dict[str, Any]
    floor_min: dict[str, float | Array] = dataclasses.field(default_factory=dict)
    notes: list[str] = dataclasses.field(default_factory=list)
    floor: dict[str, Array] = dataclasses.field(default_factory=dict)
    reach: int | None = None
    structure: dict[str, Array] = dataclasses.field(default_factory=dict)
    preprocessing: dict[str, Any] = dataclasses.field(default_factory=dict)


#: The least noise floor per arm channel: a torque resolution of 1e-3 N m (a channel the model
#: reproduces to rounding, as the control law does, is not infinitely precise evidence).
ARM_FLOOR_MIN: dict[str, float] = {"tau": 1e-3, "cmd": 1e-3, "ctrl": 1e-3, "dq": 1e-5}


# --------------------------------------------------------------------------------------------
# Where
# --------------------------------------------------------------------------------------------

def arm_regions(rep: Replay) -> dict[str, NDArray[np.bool_]]:
    """State regions per joint (T, 7) masks: velocity sign, reversals, speed, load."""
    dq = rep.dq
    load = np.abs(rep.terms.total)
    lo, hi = np.quantile(load[rep.valid], [1 / 3, 2 / 3], axis=0)
    speed = np.abs(dq)
    return {"dq>0": dq > 0, "dq<0": dq < 0, "reversal (|dq|<0.05)": speed < 0.05,
            "slow (0.05-0.3)": (speed >= 0.05) & (speed < 0.3), "medium (0.3-1)": (speed >= 0.3) & (speed < 1.0),
            "fast (>1 rad/s)": speed >= 1.0,
            "load low": load < lo, "load mid": (load >= lo) & (load < hi), "load high": load >= hi}


def _rms_table(y: Array, floor: Array, mask: Array) -> dict[str, Any]:
    """RMS (C, 7) of y (T, C, 7) over mask (T, 7) or (T,), and its ratio to the floor."""
    m = mask if mask.ndim == 2 else np.repeat(mask[:, None], 7, axis=1)
    n = m.sum(axis=0)  # (7,)
    ms = np.einsum("tj,tcj->cj", m, y ** 2) / np.maximum(n, 1)
    rms = np.sqrt(ms)
    return {"rms": rms, "ratio": rms / floor, "samples": n}


def _where(ev: Evidence, design: Design, floor: Array) -> dict[str, Any]:
    y = design.y
    valid = ev.valid
    base = _rms_table(y, floor, valid.astype(float))
    excess = np.maximum(base["rms"] ** 2 - floor ** 2, 0.0) / floor ** 2  # in noise variances
    share = excess / max(excess.sum(), 1e-12)
    channels = []
    for ci, c in enumerate(design.channels):
        for j in range(7):
            rms, fl = float(base["rms"][ci, j]), float(floor[ci, j])
            channels.append({"channel": c, "joint": j + 1, "column": ev.labels[c][j], "rms": rms, "floor": fl,
                             "ratio": float(base["ratio"][ci, j]), "excess_share": float(share[ci, j]),
                             "excess_rms": float(np.sqrt(max(rms ** 2 - fl ** 2, 0.0)))})
    # ranked by the excess in the channel's own unit (N m): the joint with the largest torque error
    # first, whatever its noise (a quiet wrist joint's small error is a large ratio, not a large torque)
    channels.sort(key=lambda r: -r["excess_rms"])
    phases = {}
    for k, name in enumerate(PHASES):
        m = (ev.phase == k) & valid
        if m.sum() < 10:
            continue
        t = _rms_table(y, floor, m.astype(float))
        phases[name] = {"samples": int(m.sum()), "ratio": t["ratio"].tolist(),
                        "excess": float(np.sum(np.maximum(t["ratio"] ** 2 - 1, 0)))}
    regions = {}
    for name, m in ev.regions.items():
        t = _rms_table(y, floor, (m & valid[:, None]).astype(float))
        regions[name] = {"ratio": t["ratio"].tolist(), "samples": t["samples"].tolist()}
    # which channel-joints carry the excess: the fewest that hold 80 % of it, ratio >= 1.5
    carry = []
    total = 0.0
    for r in channels:
        if total >= 0.8 or r["ratio"] < 1.5:
            break
        carry.append(f"{r['channel']} {r['column']}")
        total += r["excess_share"]
    dominant_phase = max(phases, key=lambda p: phases[p]["excess"] / phases[p]["samples"]) if phases else "free"
    region_lift = {}
    for name, r in regions.items():  # mean ratio^2 in the region over the overall one, per channel
        ratio = np.asarray(r["ratio"])
        region_lift[name] = float(np.nanmean(ratio ** 2 / np.maximum(base["ratio"] ** 2, 1e-12)))
    return {"channels": channels, "phases": phases, "regions": regions, "carry": carry,
            "dominant_phase": dominant_phase, "region_lift": region_lift,
            "excess_total": float(excess.sum() / excess.size)}


# --------------------------------------------------------------------------------------------
# Which
# --------------------------------------------------------------------------------------------

@dataclasses.dataclass
class _Scored:
    cands: list[Candidate]
    sse: Array  # held-out per block
    thetas: list[Array]


def _folds(design: Design, n_folds: int) -> list[NDArray[np.int64]]:
    per = design.n_blocks // n_folds
    return [np.arange(k * per, (k + 1) * per) for k in range(n_folds)]


REFINE_STEPS = 4  # halvings of a one-parameter family's bracket around its best grid setting


def _best_setting(design: Design, options: list[Candidate], base: list[Candidate]) -> Candidate:
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


def _score(design: Design, cands: list[Candidate], folds) -> _Scored:
    sse, thetas = Model(design, cands).cross_validate(folds)
    return _Scored(cands, sse, thetas)


def _params_with_intervals(design: Design, cands: list[Candidate], n: int, rng: np.random.Generator
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
        b = bounds[k:k + len(coef)]
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
        out.append({"effect": cand.name, "params": params, "bound_hits": hits})
    return out


def _overlap(design: Design, a: Candidate, b: Candidate) -> float:
    """How much of b's best fit to the residual a's columns can reproduce (0..1)."""
    ones = np.ones(design.n_blocks)
    mb = Model(design, [b])
    pb = design.predict([b], mb.fit(ones))
    target = {c: pb[:, i] for i, c in enumerate(design.channels)}
    sub = Design(target, design.channels, 1.0 / np.sqrt(design.w), design.mask > 0, design.n_blocks)
    ma = Model(sub, [_rebind(a)])
    sse = ma.block_sse(ma.fit(ones)).sum()
    return float(1.0 - sse / max(sub.yy.sum(), 1e-12))


def _rebind(c: Candidate) -> Candidate:
    """A copy of a candidate (the Design caches columns by object identity)."""
    return dataclasses.replace(c)


# --------------------------------------------------------------------------------------------
# The audit of the nominal model's own terms
# --------------------------------------------------------------------------------------------

def _term_candidate(rep: Replay, name: str, torque: Array, channels: tuple[str, ...] = ("tau", "cmd")
                    ) -> Candidate:
    """A fixed change of the model's torque prediction by `torque` (T, 7) in `channels` and dq."""
    off: dict[str, Array] = {}
    for c in channels:
        if c in rep.residual:
            off[c] = torque
    if "dq" in rep.residual:
        off["dq"] = -rep.forward(torque)
    return Candidate(name, {}, {}, off, [], np.zeros((0, 2)), lambda coef: {})


def _audit_verdict(change: str, after: float, before: float) -> str:
    better = after < before * 0.98
    if change.startswith("with "):  # a term the model leaves out, put in
        return "the log asks for it: the model is missing it" if better else "the model is right to leave it out"
    if change.startswith("without "):
        return "the model makes the fit worse here" if better else "the model term is supported"
    return "the log fits the alternative better" if better else "the model's choice is supported"


def _arm_audit(rep: Replay, band: Band | None, design: Design, folds, base_sse: Array, excess0: float,
               n_rows: Array) -> list[dict[str, Any]]:
    terms = rep.terms
    items = [("without the joint damping", -terms.damping, ("tau", "cmd"))]
    if rep.rotor_in_tau:
        items.append(("without the reflected rotor inertia", -terms.rotor, ("tau", "cmd")))
    else:
        items.append(("without the reflected rotor inertia (motor side)", -terms.rotor, ("cmd",)))
        items.append(("with the reflected rotor inertia in the measured torque", terms.rotor, ("tau",)))
    ee = rep.model.end_effector
    for other in END_EFFECTORS:
        if other == ee or (other.startswith("hand+gear") and not ee.startswith("hand")):
            continue
        if other.startswith("hand+gear") and other != "hand+gear_medium" and ee != "hand":
            continue
        alt = ArmModel(other).terms(rep.q, rep.dq, rep.ddq)
        items.append((f"end effector {other!r} instead of {ee!r}", alt.rigid - terms.rigid, ("tau", "cmd")))
    out = []
    base = base_sse.sum() / n_rows.sum()
    for label, torque, chans in items:
        if not np.any(torque) or not any(ch in rep.residual for ch in chans):
            continue
        cand = _term_candidate(rep, label, torque, chans)
        if band is not None:
            cand = band_candidate(cand, band, {})
        s = _score(design, [cand], folds)
        e = s.sse.sum() / n_rows.sum()
        out.append({"change": label, "heldout_before": base, "heldout_after": float(e),
                    "closed": float((base - e) / max(excess0, 1e-12)),
                    "verdict": _audit_verdict(label, e, base)})
    out.sort(key=lambda r: r["heldout_after"])
    return out


# --------------------------------------------------------------------------------------------
# How far
# --------------------------------------------------------------------------------------------

def _heldout_prediction(design: Design, scored: _Scored, folds) -> Array:
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


def _how_far(ev: Evidence, design: Design, floor: Array, pred: Array, level: float) -> dict[str, Any]:
    y = design.y
    after = y - pred
    valid = ev.valid
    phase = ev.phase

    def table(mask: NDArray[np.bool_]) -> dict[str, Any]:
        b = _rms_table(y, floor, mask.astype(float))["rms"]
        a = _rms_table(after, floor, mask.astype(float))["rms"]
        gap = b - floor
        closed = np.where(gap > 0.05 * floor, (b - a) / np.maximum(gap, 1e-12), np.nan)
        return {"before": b.tolist(), "after": a.tolist(), "floor": floor.tolist(), "closed": closed.tolist()}

    per_phase = {}
    for k, name in enumerate(PHASES):
        m = (phase == k) & valid
        if m.sum() >= 10:
            per_phase[name] = table(m)
    overall = table(valid)
    wb = np.einsum("tcj,cj->", y[valid] ** 2, design.w) / (valid.sum() * y.shape[1] * 7)
    wa = np.einsum("tcj,cj->", after[valid] ** 2, design.w) / (valid.sum() * y.shape[1] * 7)
    # the RMS gap toward the floor (sqrt(level) in these units: what a log with no gap reads), the
    # after-RMS taken no lower than the floor; None where there is no gap to close (the RMS within
    # 2 % of the floor)
    at_floor = np.sqrt(level)
    b, a = np.sqrt(wb), max(np.sqrt(wa), at_floor)
    closed = None if b < 1.02 * at_floor else float(min((b - a) / (b - at_floor), 1.0))
    return {"overall": overall, "phases": per_phase, "weighted_before": float(wb), "weighted_after": float(wa),
            "closed_total": closed}


# --------------------------------------------------------------------------------------------
# The diagnosis
# --------------------------------------------------------------------------------------------

def _excess_interval(before: Array, after: Array, n_rows: Array, level: float, n_boot: int,
                     rng: np.random.Generator) -> dict[str, float | None]:
    """The held-out excess over the level of a log with no gap, before and after the selection,
    and the fraction closed, each with its 95 % Bayesian block-bootstrap interval (noise variances)."""
    rows = np.maximum(n_rows, 1)
    w = rng.dirichlet(np.ones(len(before)), size=n_boot) * rows[None]
    w /= w.sum(axis=1, keepdims=True)
    eb = (w @ (before / rows)) - level
    ea = (w @ (after / rows)) - level
    closed = (eb - ea) / np.maximum(eb, 1e-12)
    q = lambda x: [float(v) for v in np.quantile(x, [0.025, 0.975])]  # noqa: E731
    before_v = float(before.sum() / n_rows.sum() - level)
    after_v = float(after.sum() / n_rows.sum() - level)
    return {"before": before_v, "before_interval": q(eb), "after": after_v, "after_interval": q(ea),
            "closed": float((before_v - after_v) / before_v) if before_v > 0 else None,
            "closed_interval": q(closed) if before_v > 0 else None}


def _verdict(c: DiagnosisConfig, chosen: list[Candidate], structure: list[dict[str, Any]],
             excess: dict[str, Any], e0: float, e_final: float, level: float) -> dict[str, Any]:
    """The verdict from the selection, the structure left and the held-out excess's interval.

    - "no gap": nothing selected, no structure left, and the excess's lower end within the floor's
      own uncertainty (`DiagnosisConfig.floor_tolerance` noise variances);
    - "explained": effects selected, closing at least `explained` of the excess (or a faint gap
      whose excess is within the floor's uncertainty), and no structure left;
    - "unexplained": structure left that the selection does not explain (a generic function of the
      velocity or of time predicts the rest on held-out data), or an excess well above the floor
      that nothing closes.
    """
    left = [st for st in structure if st["left"]]
    excess0 = max(e0 - level, 0.0)
    closed = min((e0 - e_final) / max(excess0, 1e-12), 1.0)
    significant = excess["before_interval"][0] > c.floor_tolerance
    where_left = (" in " + " and in ".join(f"{st['basis']} ({100 * min(st['share'], 9.99):.0f} % of the excess, "
                                           f"{100 * min(st['share_rest'], 1.0):.0f} % of what is left)"
                                           for st in left) if left else "")
    lo, hi = excess["before_interval"]
    if not chosen and not left and not significant:
        return {"label": "no gap", "closed": 0.0,
                "text": f"no catalogue effect lowers the held-out residual significantly and nothing generic predicts "
                        f"it; its excess over the noise floor, {e0 - level:.2f} noise variances (95 %: {lo:.2f} to "
                        f"{hi:.2f}), is within the floor's uncertainty ({c.floor_tolerance:g})"}
    if not chosen:
        text = (f"the residual exceeds the noise floor by {e0 - level:.2f} noise variances (95 %: {lo:.2f} to {hi:.2f})"
                f" and no catalogue effect closes a significant part of it on held-out data")
        if left:
            text += f"; it has structure{where_left}"
        return {"label": "unexplained", "closed": 0.0, "text": text}
    names = ", ".join(x.name for x in chosen)
    verb = "closes" if len(chosen) == 1 else "close"
    if (closed < c.explained and significant) or left:
        return {"label": "unexplained", "closed": float(closed), "partial": [x.name for x in chosen],
                "text": f"{names} {verb} {100 * closed:.0f} % of the held-out excess; the rest ({e_final - level:.2f} "
                        f"noise variances above the floor) has structure{where_left} no catalogue effect explains"
                        if left else
                        f"{names} {verb} {100 * closed:.0f} % of the held-out excess; the rest ({e_final - level:.2f} "
                        "noise variances above the floor) is more than the selection explains"}
    if not significant:
        text = (f"a faint gap: {names} lower{'s' if len(chosen) == 1 else ''} the held-out residual by "
                f"{e0 - e_final:.3f} noise variances, significantly, where the excess over the floor is "
                f"{e0 - level:.3f} (within the floor's uncertainty)")
    else:
        ci = excess["closed_interval"]
        text = (f"{names} {verb} {100 * closed:.0f} % (95 %: {100 * min(ci[0], 1.0):.0f} to "
                f"{100 * min(ci[1], 1.0):.0f} %) of the held-out excess over the noise floor")
    return {"label": "explained", "closed": float(closed), "effects": [x.name for x in chosen], "text": text}


def _nominal_fit(rep: Replay) -> float:
    """The torque channels' residual mean square relative to the measured torque's, summed over
    joints (scale-free: every joint counts alike)."""
    total = 0.0
    signals = {"tau": rep.log.tau, "cmd": rep.tau_cmd}
    for ch in ("tau", "cmd"):
        if ch in rep.residual:
            r = rep.residual[ch][rep.valid]
            x = signals[ch][rep.valid]
            total += float(np.sum(np.mean(r ** 2, axis=0) / np.maximum(np.mean(x ** 2, axis=0), 1e-12)))
    return total


def arm_evidence(log: RobotLog, config: DiagnosisConfig | None = None) -> Evidence:
    """The arm's evidence: the log cleaned (stale repeats dropped, a uniform grid: sim2real/clean.py),
    replayed against the nominal model, seen through the analysis band with its noise floor
    (sim2real/band.py; `config.band` None: every sample, the fast-part/variogram floor), its state
    regions and the catalogue's arm effects the log's channels can show."""
    c = config or DiagnosisConfig()
    cleaned = clean(log, c.clean)
    log = cleaned.log
    notes = list(cleaned.notes)
    ees = ["none", "hand"] if c.replay.end_effector is None and (
        log.meta.get("end_effector") is None or log.meta.get("end_effector_assumed")) else [None]
    sources = ["q", "dq"] if c.band is not None else [c.replay.velocity_source]
    options = {(ee, src): replay(log, dataclasses.replace(c.replay, end_effector=ee or c.replay.end_effector,
                                                          velocity_source=src))
               for ee in ees for src in sources}
    if len(ees) > 1:
        # the log does not say what the arm carries: the bare arm or the hand, whichever the
        # nominal residual supports (a held gear or tool shows as a payload effect)
        score = {ee: _nominal_fit(options[(ee, sources[0])]) for ee in ees}
        best = min(score, key=score.get)
        notes.append(f"the log does not state its end effector; the data support {best!r} "
                     f"(nominal residual {score[best]:.3g} against {max(score.values()):.3g})")
        options = {k: r for k, r in options.items() if k[0] == best}
    if len(sources) > 1:
        # the velocity and acceleration from the encoder's position or from the measured velocity,
        # whichever leaves the less noise in the band (a log's position can carry its stamps'
        # rounding; its velocity the noise of the robot's own estimate)
        probe = {src: _band_noise(r, c.band) for (ee, src), r in options.items()}
        chosen_source = min(probe, key=probe.get)
        notes.append(f"velocity and acceleration from the measured {'position' if chosen_source == 'q' else 'velocity'}"
                     f" (its in-band torque noise {probe[chosen_source]:.3g} N m, geometric mean over joints, against "
                     f"{max(probe.values()):.3g} from the {'velocity' if chosen_source == 'q' else 'position'})")
        options = {k: r for k, r in options.items() if k[1] == chosen_source}
    rep = next(iter(options.values()))
    rep.valid &= cleaned.fresh
    phase = segment_phases(rep.log)
    if rep.log.phase is None and np.any(phase != 0):
        notes.append("the log has no phase labels: phases segmented from its external force (sim2real/phases.py)")
    labels = {ch: [f"joint {j + 1}" for j in range(7)] for ch in rep.channels}
    meta = {**log.meta, "end_effector": rep.model.end_effector}
    pool = candidates(rep, c.effects)
    structure = {"joint velocity": hat_basis(rep.dq), "time": trend_basis(rep.log.time, 7)}
    preprocessing: dict[str, Any] = {"clean": cleaned.report,
                                     "untestable": {k: v for k, v in untestable(rep).items()
                                                    if c.effects is None or k in c.effects}}
    if c.band is None:
        # the filtered torque channels' noise: kernel-smoothed white noise's share of the fast
        # part, or the variogram's nugget (noise_floor)
        floor = {ch: noise_floor(rep.residual[ch], rep.valid, kernel=rep.kernel, reach=rep.reach)
                 for ch in rep.unfiltered}
        return Evidence(residual=rep.residual, labels=labels, valid=rep.valid, phase=phase, regions=arm_regions(rep),
                        pool=pool, audit=functools.partial(_arm_audit, rep, None), x=rep.log.dq,
                        x_label="dq [rad/s]", time=rep.log.time, meta=meta, floor_min=dict(ARM_FLOOR_MIN),
                        notes=notes, floor=floor, reach=rep.reach, structure=structure, preprocessing=preprocessing)
    band = choose_band(rep.dq, rep.dt, c.band)
    valid = rep.valid.copy()
    valid[:band.settle] = False
    valid[-band.settle:] = False
    floor = {}
    detail = {}
    for ch in rep.channels:
        # the acceleration's own noise is not added: the position's high frequencies on a robot
        # in closed loop are mostly real motion (which the measured torque holds too), not
        # encoder noise, so they cannot tell it (band_floor's position term is for known noise)
        floor[ch], detail[ch] = band_floor(rep.residual[ch], valid, band, rep.kernel if ch in rep.unfiltered else None,
                                           *_derivative(rep, ch))
    preprocessing["band"] = band.summary()
    preprocessing["floor"] = {ch: {"in_band": floor[ch].tolist(), **detail[ch]} for ch in rep.channels}
    notes.append(f"the residual is judged below {band.cutoff:.3g} Hz ({band.reason}), sampled at "
                 f"{1.0 / (band.dt * band.stride):.3g} Hz; noise floor from its spectrum in "
                 f"{band.cutoff:.3g}-{band.reference * band.cutoff:.3g} Hz")
    return Evidence(residual={ch: band.apply(r) for ch, r in rep.residual.items()}, labels=labels,
                    valid=band.rows(valid), phase=band.rows(phase),
                    regions={k: band.rows(m) for k, m in arm_regions(rep).items()},
                    pool=band_pool(pool, band), audit=functools.partial(_arm_audit, rep, band),
                    x=band.rows(rep.dq), x_label="dq [rad/s]", time=band.rows(rep.log.time), meta=meta,
                    floor_min=dict(ARM_FLOOR_MIN), notes=notes, floor=floor, reach=None,
                    structure={k: band.apply(b) for k, b in structure.items()}, preprocessing=preprocessing)


def _band_noise(rep: Replay, config: BandConfig) -> float:
    """The geometric mean over joints of a replay's in-band noise floor in its first torque channel,
    read flat from the reference band (one rule for both sources: a fair comparison)."""
    ch = next((c for c in ("tau", "cmd") if c in rep.residual), rep.channels[0])
    band = choose_band(rep.dq, rep.dt, config)
    valid = rep.valid.copy()
    valid[:band.settle] = False
    valid[-band.settle:] = False
    floor, _ = band_floor(rep.residual[ch], valid, band, rep.kernel if ch in rep.unfiltered else None)
    return float(np.exp(np.mean(np.log(floor))))


def _derivative(rep: Replay, channel: str) -> tuple[int | None, int, Array | None, Array | None]:
    """What band_floor needs of the acceleration a torque channel's prediction holds, where its
    noise rises with frequency: the derivative's order, its window, the measurement differentiated
    and the mass matrix it enters through (the links', plus the reflected rotor inertia where the
    channel holds it). Only for a velocity differentiated once (its noise rising as f^2 into the
    band: the Panda's velocity estimate); an encoder's position, differentiated twice, adds little
    in the band, and a spectrum rising at the reference band's top (the arm's vibration setting in)
    would be read as its f^4 noise: (None, ...), the floor read flat, as for other channels."""
    if channel not in ("tau", "cmd") or rep.velocity_source == "q":
        return None, rep.window, None, None
    rotor = channel == "cmd" or rep.rotor_in_tau
    mass = rep.terms.mass + (np.eye(7)[None] * rep.model.reflected_inertia[None, :, None] if rotor else 0.0)
    return 1, rep.window, rep.log.dq, mass


def diagnose(log: RobotLog, config: DiagnosisConfig | None = None, progress: Progress | None = None
             ) -> Diagnosis:
    """Answer where, which and how far for an arm log (see the module docstring)."""
    say = progress or (lambda what, i, n: None)
    say("replay", 0, 1)
    return analyse(arm_evidence(log, config), config, progress)


def analyse(ev: Evidence, config: DiagnosisConfig | None = None, progress: Progress | None = None) -> Diagnosis:
    """The three answers from a replayed log's evidence (any model: arm or station)."""
    c = config or DiagnosisConfig()
    say = progress or (lambda what, i, n: None)
    rng = np.random.default_rng(c.seed)
    chans = tuple(ch for ch in ("tau", "cmd", "ctrl", "dq", "tool", "pose") if ch in ev.residual)
    y = np.stack([ev.residual[ch] for ch in chans], axis=1)
    # per channel its noise: the evidence's where it knows it (the filtered torques; one row per
    # scene, with no time to smooth over), else estimated from the residual
    noise = np.stack([ev.floor[ch] if ch in ev.floor else np.zeros(7) for ch in chans])
    free = [i for i, ch in enumerate(chans) if ch not in ev.floor]
    if free:
        noise[free] = noise_floor(y[:, free].reshape(len(y), -1), ev.valid, reach=ev.reach).reshape(len(free), 7)
    floor = np.stack([np.maximum(noise[i], ev.floor_min.get(ch, 0.0)) for i, ch in enumerate(chans)])
    # what a log with no gap reads, in noise variances: 1 per column, less where the floor is the
    # channel's resolution (a control law reproduced to rounding)
    level = float(np.mean((noise / floor) ** 2))
    design = Design(ev.residual, chans, floor, ev.valid, c.blocks)
    folds = _folds(design, c.folds)
    n_rows = design.count
    where = _where(ev, design, floor)

    base = _score(design, [], folds)
    e0 = base.sse.sum() / n_rows.sum()
    excess0 = max(e0 - level, 0.0)

    say("effects", 0, 1)
    pool = ev.pool
    ranking = []
    best_single: dict[str, Candidate] = {}
    for i, (name, options) in enumerate(pool.items()):
        say("effects", i, len(pool))
        cand = _best_setting(design, options, [])
        best_single[name] = cand
        s = _score(design, [cand], folds)
        e = s.sse.sum() / n_rows.sum()
        diff = (base.sse - s.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        ranking.append({"effect": name, "setting": cand.setting, "heldout": float(e),
                        "gain": float(e0 - e), "gain_low": lo, "gain_high": hi,
                        "closed": float((e0 - e) / excess0) if excess0 >= 0.05 else None,
                        "significant": bool(lo > 0)})
    say("effects", len(pool), len(pool))
    ranking.sort(key=lambda r: -r["gain"])

    # forward selection
    say("selection", 0, 1)
    chosen: list[Candidate] = []
    current = base
    steps = []
    while len(chosen) < c.max_effects:
        best = None
        for name in pool:
            if any(x.name == name for x in chosen):
                continue
            cand = _best_setting(design, pool[name], chosen) if len(pool[name]) > 1 else best_single[name]
            s = _score(design, chosen + [cand], folds)
            if best is None or s.sse.sum() < best[1].sse.sum():
                best = (cand, s)
        if best is None:
            break
        cand, s = best
        diff = (current.sse - s.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        gain = float((current.sse.sum() - s.sse.sum()) / n_rows.sum())
        if lo <= 0 or gain < max(c.min_gain * excess0, c.min_gain_abs):
            break
        chosen.append(cand)
        steps.append({"effect": cand.name, "setting": cand.setting, "gain": gain, "gain_low": lo, "gain_high": hi,
                      "heldout_after": float(s.sse.sum() / n_rows.sum())})
        current = s
    # backward elimination: drop a selected effect the others make redundant (greedy forward steps
    # can take a flexible effect first that the right ones later explain away); then order the
    # effects by what each adds to the final set (its held-out loss when removed)
    def _marginal(k: int) -> tuple[float, float, float, _Scored]:
        rest = _score(design, chosen[:k] + chosen[k + 1:], folds)
        diff = (rest.sse - current.sse) / np.maximum(n_rows, 1)
        lo, hi = bootstrap_mean(diff, c.bootstrap, rng)
        return float((rest.sse.sum() - current.sse.sum()) / n_rows.sum()), lo, hi, rest

    while len(chosen) > 1:
        margins = [_marginal(k) for k in range(len(chosen))]
        k = int(np.argmin([m[0] for m in margins]))
        loss, lo, _, rest = margins[k]
        if lo > 0 and loss >= max(c.min_gain * excess0, c.min_gain_abs):
            break
        del chosen[k]
        current = rest
    if len(chosen) > 1:
        margins = [_marginal(k) for k in range(len(chosen))]
        order = np.argsort([-m[0] for m in margins])
        chosen = [chosen[k] for k in order]
        steps = [{"effect": chosen[i].name, "setting": chosen[i].setting, "gain": margins[k][0],
                  "gain_low": margins[k][1], "gain_high": margins[k][2],
                  "heldout_after": float(current.sse.sum() / n_rows.sum())} for i, k in enumerate(order)]
    else:
        steps = [st for st in steps if chosen and st["effect"] == chosen[0].name]
    say("selection", 1, 1)

    selected = []
    if chosen:
        fitted = _params_with_intervals(design, chosen, min(c.bootstrap, 200), rng)
        for step, fit in zip(steps, fitted):
            selected.append({**step, **fit, "meaning": CATALOGUE[step["effect"]].meaning,
                             "place": CATALOGUE[step["effect"]].place})

    # identifiability: significant single effects that the selection's first effects reproduce
    warnings = []
    sig = [r for r in ranking if r["significant"] and (r["closed"] or 0.0) > 0.1]
    for r in sig:
        if any(x.name == r["effect"] for x in chosen):
            continue
        for x in chosen:
            ov = _overlap(design, x, best_single[r["effect"]])
            if ov > 0.5:
                warnings.append(f"{r['effect']} alone closes {100 * (r['closed'] or 0.0):.0f} % of the excess, but "
                                f"{x.name} reproduces {100 * ov:.0f} % of its fit: the log cannot tell them "
                                "apart well (the selection kept " + x.name + ")")
                break

    say("audit", 0, 1)
    audit = ev.audit(design, folds, base.sse, excess0, n_rows) if ev.audit is not None else []
    say("audit", 1, 1)
    pred = _heldout_prediction(design, current, folds)
    how_far = _how_far(ev, design, floor, pred, level)

    e_final = current.sse.sum() / n_rows.sum()
    # structure the selection left: what a generic function of the state predicts of the rest
    structure = []
    if ev.structure:
        structure = structure_gains(design.y - pred, design.w, ev.valid, design.starts, folds, ev.structure,
                                    c.bootstrap, rng)
        rest = max(e_final - level, c.min_gain_abs)  # what the selection leaves above a log with no gap
        for st in structure:
            st["share"] = float(st["gain"] / max(excess0, 1e-12))
            st["share_rest"] = float(st["gain"] / rest)
            st["left"] = bool(st["low"] > 0 and st["gain"] >= c.min_gain_abs
                              and (st["gain"] >= c.structure * excess0 or st["gain"] >= c.structure_rest * rest))
    excess = _excess_interval(base.sse, current.sse, n_rows, level, c.bootstrap, rng)
    verdict = _verdict(c, chosen, structure, excess, e0, e_final, level)
    verdict["heldout_before"] = float(e0)
    verdict["heldout_after"] = float(e_final)
    verdict["floor_level"] = level
    verdict["excess"] = excess
    verdict["structure"] = structure

    meta = {k: v for k, v in ev.meta.items() if k != "truth"}
    arrays = {"residual": design.y, "after": design.y - pred, "floor": floor, "x": ev.x,
              "time": ev.time, "valid": ev.valid}
    return Diagnosis(log_meta=meta, channels=chans, where=where, audit=audit, ranking=ranking,
                     selected=selected, warnings=warnings, how_far=how_far, verdict=verdict, arrays=arrays,
                     labels=ev.labels, x_label=ev.x_label,
                     extra={"notes": list(ev.notes), "preprocessing": ev.preprocessing})
