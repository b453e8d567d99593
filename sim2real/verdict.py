"""The verdict and how far: the excess's interval, the structure left, the closed gap, friction."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sim2real.config import DiagnosisConfig
from sim2real.effects import Candidate
from sim2real.fitting import Design
from sim2real.log import PHASES
from sim2real.structure import structure_gains
from sim2real.where import rms_table

if TYPE_CHECKING:
    from sim2real.evidence import Evidence

__all__ = ["excess_interval", "structure_left", "verdict_of", "how_far_table", "friction_table", "FRICTION_SPEEDS"]

Array = NDArray[np.float64]


def excess_interval(
    before: Array, after: Array, n_rows: Array, level: float, n_boot: int, rng: np.random.Generator
) -> dict[str, float | None]:
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
    return {
        "before": before_v,
        "before_interval": q(eb),
        "after": after_v,
        "after_interval": q(ea),
        "closed": float((before_v - after_v) / before_v) if before_v > 0 else None,
        "closed_interval": q(closed) if before_v > 0 else None,
    }


def verdict_of(
    c: DiagnosisConfig,
    chosen: list[Candidate],
    structure: list[dict[str, Any]],
    excess: dict[str, Any],
    e0: float,
    e_final: float,
    level: float,
) -> dict[str, Any]:
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
    where_left = (
        " in "
        + " and in ".join(
            f"{st['basis']} ({100 * min(st['share'], 9.99):.0f} % of the excess, "
            f"{100 * min(st['share_rest'], 1.0):.0f} % of what is left)"
            for st in left
        )
        if left
        else ""
    )
    lo, hi = excess["before_interval"]
    if not chosen and not left and not significant:
        return {
            "label": "no gap",
            "closed": 0.0,
            "text": f"no catalogue effect lowers the held-out residual significantly and nothing generic predicts "
            f"it; its excess over the noise floor, {e0 - level:.2f} noise variances (95 %: {lo:.2f} to "
            f"{hi:.2f}), is within the floor's uncertainty ({c.floor_tolerance:g})",
        }
    if not chosen:
        text = (
            f"the residual exceeds the noise floor by {e0 - level:.2f} noise variances (95 %: {lo:.2f} to {hi:.2f})"
            f" and no catalogue effect closes a significant part of it on held-out data"
        )
        if left:
            text += f"; it has structure{where_left}"
        return {"label": "unexplained", "closed": 0.0, "text": text}
    names = ", ".join(x.name for x in chosen)
    verb = "closes" if len(chosen) == 1 else "close"
    if (closed < c.explained and significant) or left:
        return {
            "label": "unexplained",
            "closed": float(closed),
            "partial": [x.name for x in chosen],
            "text": f"{names} {verb} {100 * closed:.0f} % of the held-out excess; the rest ({e_final - level:.2f} "
            f"noise variances above the floor) has structure{where_left} no catalogue effect explains"
            if left
            else f"{names} {verb} {100 * closed:.0f} % of the held-out excess; the rest ({e_final - level:.2f} "
            "noise variances above the floor) is more than the selection explains",
        }
    if not significant:
        text = (
            f"a faint gap: {names} lower{'s' if len(chosen) == 1 else ''} the held-out residual by "
            f"{e0 - e_final:.3f} noise variances, significantly, where the excess over the floor is "
            f"{e0 - level:.3f} (within the floor's uncertainty)"
        )
    else:
        ci = excess["closed_interval"]
        text = (
            f"{names} {verb} {100 * closed:.0f} % (95 %: {100 * min(ci[0], 1.0):.0f} to "
            f"{100 * min(ci[1], 1.0):.0f} %) of the held-out excess over the noise floor"
        )
    return {"label": "explained", "closed": float(closed), "effects": [x.name for x in chosen], "text": text}


def structure_left(
    design: Design,
    residual: Array,
    valid: NDArray[np.bool_],
    folds,
    bases: dict[str, Array],
    excess0: float,
    e_final: float,
    level: float,
    c: DiagnosisConfig,
    rng: np.random.Generator,
) -> list[dict[str, Any]]:
    """What a generic function of the state (`bases`, sim2real/structure.py) predicts of the
    `residual` the selection left, per basis: gain with interval, its share of the excess and of
    what is left, and whether it counts as structure left ("left")."""
    if not bases:
        return []
    structure = structure_gains(residual, design.w, valid, design.starts, folds, bases, c.bootstrap, rng)
    rest = max(e_final - level, c.min_gain_abs)  # what the selection leaves above a log with no gap
    for st in structure:
        st["share"] = float(st["gain"] / max(excess0, 1e-12))
        st["share_rest"] = float(st["gain"] / rest)
        st["left"] = bool(
            st["low"] > 0
            and st["gain"] >= c.min_gain_abs
            and (st["gain"] >= c.structure * excess0 or st["gain"] >= c.structure_rest * rest)
        )
    return structure


def how_far_table(ev: Evidence, design: Design, floor: Array, pred: Array, level: float) -> dict[str, Any]:
    """The held-out RMS before and after the selected effects (`pred`, out of fold) per channel,
    joint and phase, and the share of the gap (in RMS) closed toward the floor."""
    y = design.y
    after = y - pred
    valid = ev.valid
    phase = ev.phase

    def table(mask: NDArray[np.bool_]) -> dict[str, Any]:
        b = rms_table(y, floor, mask.astype(float))["rms"]
        a = rms_table(after, floor, mask.astype(float))["rms"]
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
    return {
        "overall": overall,
        "phases": per_phase,
        "weighted_before": float(wb),
        "weighted_after": float(wa),
        "closed_total": closed,
    }


#: Speeds [rad/s] at which the friction table reads the fitted friction.
FRICTION_SPEEDS: tuple[float, ...] = (0.05, 0.2, 0.5, 1.0)


def friction_table(
    selected: list[dict[str, Any]], damping: Array, speeds: tuple[float, ...] = FRICTION_SPEEDS
) -> dict[str, Any] | None:
    """The joints' friction torque [N m] opposing motion at each of `speeds` (the model's joint
    damping plus the selected coulomb, stribeck and viscous effects), with 95 % intervals from the
    selection's block bootstrap; None when no friction effect is selected.

    Arguments:
        selected: the diagnosis's selected effects, each with its fitted "params" and the bootstrap
            "_samples" of them.
        damping: the nominal model's joint damping (7,) [N m s/rad].
    """
    fric = [r for r in selected if r["effect"] in ("coulomb", "stribeck", "viscous")]
    if not fric:
        return None
    v = np.asarray(speeds, dtype=float)[:, None]

    def curve(params: dict[str, dict[str, Any]]) -> Array:
        total = np.asarray(damping, dtype=float)[None, :] * v
        for name, p in params.items():
            if name == "coulomb":
                total = total + np.asarray(p["fc"]) * np.tanh(v / p["v_smooth"])
            elif name == "stribeck":
                total = total + np.asarray(p["fs"]) * np.exp(-((v / p["vs"]) ** 2)) * np.tanh(v / 0.002)
            elif name == "viscous":
                total = total + np.asarray(p["fv"]) * v
        return total

    value = curve({r["effect"]: {k: x["value"] for k, x in r["params"].items()} for r in fric})
    n = min(len(r["_samples"]) for r in fric)
    boots = np.array([curve({r["effect"]: r["_samples"][i] for r in fric}) for i in range(n)])
    lo, hi = np.quantile(boots, [0.025, 0.975], axis=0)
    return {
        "speeds": list(speeds),
        "value": value.tolist(),
        "low": lo.tolist(),
        "high": hi.tolist(),
        "effects": [r["effect"] for r in fric],
    }
