"""Where the gap lies: the residual's RMS against the noise floor per channel, joint, phase and state region."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sim2real.fitting import Design
from sim2real.log import PHASES

if TYPE_CHECKING:
    from sim2real.evidence import Evidence

__all__ = ["rms_table", "where_table", "rank_by_prediction"]

Array = NDArray[np.float64]


def rms_table(y: Array, floor: Array, mask: Array) -> dict[str, Any]:
    """RMS (C, 7) of y (T, C, 7) over mask (T, 7) or (T,), and its ratio to the floor."""
    m = mask if mask.ndim == 2 else np.repeat(mask[:, None], 7, axis=1)
    n = m.sum(axis=0)  # (7,)
    ms = np.einsum("tj,tcj->cj", m, y**2) / np.maximum(n, 1)
    rms = np.sqrt(ms)
    return {"rms": rms, "ratio": rms / floor, "samples": n}


def where_table(ev: Evidence, design: Design, floor: Array) -> dict[str, Any]:
    """The where-table: per channel and joint the residual's RMS, its floor, ratio, excess (RMS
    above the floor, in the channel's unit) and share of the excess, ranked by the excess; per
    phase and per state region the ratios; the columns carrying 80 % of the excess; the phase with
    the most excess per sample and each region's lift."""
    y = design.y
    valid = ev.valid
    base = rms_table(y, floor, valid.astype(float))
    excess = np.maximum(base["rms"] ** 2 - floor**2, 0.0) / floor**2  # in noise variances
    share = excess / max(excess.sum(), 1e-12)
    channels = []
    for ci, c in enumerate(design.channels):
        for j in range(7):
            rms, fl = float(base["rms"][ci, j]), float(floor[ci, j])
            channels.append(
                {
                    "channel": c,
                    "joint": j + 1,
                    "column": ev.labels[c][j],
                    "rms": rms,
                    "floor": fl,
                    "ratio": float(base["ratio"][ci, j]),
                    "excess_share": float(share[ci, j]),
                    "excess_rms": float(np.sqrt(max(rms**2 - fl**2, 0.0))),
                }
            )
    # ranked by the excess in the channel's own unit (N m): the joint with the largest torque error
    # first, whatever its noise (a quiet wrist joint's small error is a large ratio, not a large torque)
    channels.sort(key=lambda r: -r["excess_rms"])
    phases = {}
    for k, name in enumerate(PHASES):
        m = (ev.phase == k) & valid
        if m.sum() < 10:
            continue
        t = rms_table(y, floor, m.astype(float))
        phases[name] = {
            "samples": int(m.sum()),
            "ratio": t["ratio"].tolist(),
            "excess": float(np.sum(np.maximum(t["ratio"] ** 2 - 1, 0))),
        }
    regions = {}
    for name, m in ev.regions.items():
        t = rms_table(y, floor, (m & valid[:, None]).astype(float))
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
        region_lift[name] = float(np.nanmean(ratio**2 / np.maximum(base["ratio"] ** 2, 1e-12)))
    return {
        "channels": channels,
        "phases": phases,
        "regions": regions,
        "carry": carry,
        "dominant_phase": dominant_phase,
        "region_lift": region_lift,
        "excess_total": float(excess.sum() / excess.size),
    }


def rank_by_prediction(where: dict[str, Any], design: Design, pred: Array, valid: NDArray[np.bool_]) -> None:
    """Rank the where-table's columns by the gap the selected effects predict there out of fold
    (RMS, the channel's unit): the noise-free estimate of where the gap lies (the excess over the
    floor is noisy where the floor is large). In place; `pred` (T, C, 7)."""
    rms = np.sqrt(np.sum(pred[valid] ** 2, axis=0) / max(int(valid.sum()), 1))
    index = {c: i for i, c in enumerate(design.channels)}
    for r in where["channels"]:
        r["explained_rms"] = float(rms[index[r["channel"]], r["joint"] - 1])
    where["channels"].sort(key=lambda r: -r["explained_rms"])
    where["ranked_by"] = "the selected effects' out-of-fold prediction (RMS)"
