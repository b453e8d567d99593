"""The diagnosis written out: report.md for people, report.json for programs, and four figures.

Figures: residual against joint velocity per joint, before and after the selected effects
(residual_vs_velocity.png); the where-map of residual over noise floor by channel, joint and
phase/region (where.png); the effect ranking with held-out gain intervals (ranking.png); the
held-out gap per channel and joint before and after (before_after.png). Every file is written
atomically, after all of them have been made.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from goflow_common.files import check_output_dir, to_strict_json, write_atomic
from sim2real.diagnosis import Diagnosis

__all__ = ["write_report", "render_markdown"]


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def render_markdown(d: Diagnosis, title: str = "Sim-to-real gap diagnosis") -> str:
    """The report as Markdown: verdict, where, model audit, ranking, selected effects, how far."""
    s = d.summary()
    v = s["verdict"]
    L = [f"# {title}", ""]
    src = s["log"].get("source", "")
    L += [
        f"Log: {src or 'in memory'}; end effector {s['log'].get('end_effector', 'hand')!r}; "
        f"channels {', '.join(s['channels'])}.",
        "",
    ]
    pre = s.get("preprocessing", {})
    if pre:
        L += ["## The log as the diagnosis reads it", ""]
        cl = pre.get("clean", {})
        if cl:
            L.append(
                f"- {cl['samples_in']} samples; {cl['stale_dropped']} stale repeats dropped "
                f"({100 * cl['stale_share']:.1f} %); period {1e3 * cl['period']:.3f} ms"
                + (
                    ""
                    if cl["uniform"]
                    else f" (resampled; steps {cl['step_percentiles_ms']['1']:.2f}-"
                    f"{cl['step_percentiles_ms']['99']:.2f} ms, 1-99 %)"
                )
                + (
                    f"; {cl['gaps']} gaps (longest {cl['longest_gap_ms']:.1f} ms), their {cl['not_fresh']} "
                    "grid points not fitted"
                    if cl["gaps"]
                    else ""
                )
            )
        b = pre.get("band")
        if b:
            L.append(
                f"- analysis band: below {b['cutoff_hz']:.3g} Hz ({b['reason']}), sampled at "
                f"{b['rate_hz']:.3g} Hz; the noise floor is read from the residual's spectrum in "
                f"{b['reference_hz'][0]:.3g}-{b['reference_hz'][1]:.3g} Hz"
            )
        for ch, f in pre.get("floor", {}).items():
            L.append(
                f"- noise floor of {ch} in the band: {_fmt(f['in_band'])} (broadband spread {_fmt(f['broadband_std'])})"
            )
        for name, why in pre.get("untestable", {}).items():
            L.append(f"- not testable on this log: {name}: {why}")
        L.append("")
    L += [
        "## Verdict",
        "",
        f"**{v['label']}**: {v['text']}.",
        f"Held-out residual, in noise-floor variances: {v['heldout_before']:.3g} before, "
        f"{v['heldout_after']:.3g} after (a log with no gap reads {v.get('floor_level', 1.0):.3g}: 1 per column "
        "at its noise floor, less where the floor is the channel's resolution).",
        "",
    ]
    if v.get("structure"):
        L += [
            "Structure left after the selection (what a generic function predicts of the rest on held-out "
            "blocks, beyond a constant; a share of the excess or of what the selection leaves of at least its "
            "threshold turns the verdict unexplained):",
            "",
            "| in | gain [noise var.] | 95 % interval | share of the excess | share of what is left | left |",
            "|---|---|---|---|---|---|",
        ]
        for st in v["structure"]:
            L.append(
                f"| {st['basis']} | {st['gain']:.3g} | {st['low']:.3g} .. {st['high']:.3g} | "
                f"{100 * st['share']:.1f} % | {100 * st['share_rest']:.1f} % | "
                f"{'yes' if st['left'] else 'no'} |"
            )
        L.append("")
    w = s["where"]
    L += [
        "## Where",
        "",
        "Residual RMS against the noise floor per channel and joint, the largest excess (in the "
        "channel's unit, N m for torques) first:",
        "",
        "| channel | column | RMS | noise floor | excess RMS | ratio | share of excess (noise var.) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in w["channels"][:14]:
        L.append(
            f"| {r['channel']} | {r['column']} | {r['rms']:.3g} | {r['floor']:.3g} | {r.get('excess_rms', 0.0):.3g} | "
            f"{r['ratio']:.3g} | {100 * r['excess_share']:.0f} % |"
        )
    L += [
        "",
        f"Carrying the excess: {', '.join(w['carry']) or 'nothing above 1.5 x the floor'}. "
        f"Phase with the largest excess per sample: {w['dominant_phase']}.",
        "",
        "Regions (mean squared ratio in the region over the overall one; > 1: the gap concentrates there):",
        "",
        "| region | lift |",
        "|---|---|",
    ]
    for name, lift in sorted(w["region_lift"].items(), key=lambda kv: -kv[1]):
        L.append(f"| {name} | {lift:.2f} |")
    L += [
        "",
        "## Model audit",
        "",
        "| change to the nominal model | held-out after | closed | verdict |",
        "|---|---|---|---|",
    ]
    for a in s["audit"]:
        L.append(f"| {a['change']} | {a['heldout_after']:.3g} | {100 * a['closed']:.0f} % | {a['verdict']} |")
    L += [
        "",
        "## Which effect",
        "",
        "Each catalogue effect fitted alone on training blocks, scored on held-out "
        "blocks (gain in noise variances, 95 % block-bootstrap interval):",
        "",
        "| effect | setting | held-out | gain | interval | closes | significant |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in s["ranking"]:
        closes = "-" if r["closed"] is None else f"{100 * r['closed']:.0f} %"
        L.append(
            f"| {r['effect']} | {_fmt(r['setting']) if r['setting'] else ''} | {r['heldout']:.3g} | "
            f"{r['gain']:.3g} | [{r['gain_low']:.3g}, {r['gain_high']:.3g}] | {closes} | "
            f"{'yes' if r['significant'] else 'no'} |"
        )
    L += ["", "Selection (forward, then backward elimination; ordered by what each adds to the final set):", ""]
    if not s["selected"]:
        L.append("No effect improves the held-out fit significantly.")
    for r in s["selected"]:
        L.append(
            f"- **{r['effect']}** ({r['place']}: {r['meaning']}): gain {r['gain']:.3g} "
            f"[{r['gain_low']:.3g}, {r['gain_high']:.3g}]"
        )
        for pname, p in r["params"].items():
            L.append(f"  - {pname} = {_fmt(p['value'])} {p['unit']} (95 %: {_fmt(p['low'])} .. {_fmt(p['high'])})")
        if r["bound_hits"]:
            L.append(f"  - at a bound of its range: {', '.join(r['bound_hits'])}")
    for note in s.get("notes", []):
        L.append(f"- note: {note}")
    if s["warnings"]:
        L += ["", "Identifiability:", ""] + [f"- {x}" for x in s["warnings"]]
    fr = s.get("friction")
    if fr:
        L += [
            "",
            "Friction opposing motion (the model's joint damping plus "
            + ", ".join(fr["effects"])
            + ") [N m], 95 % intervals, per joint and speed:",
            "",
            "| speed [rad/s] | " + " | ".join(f"J{j + 1}" for j in range(7)) + " |",
            "|---|" + "---|" * 7,
        ]
        for i, v_ in enumerate(fr["speeds"]):
            L.append(
                f"| {v_:g} | "
                + " | ".join(
                    f"{fr['value'][i][j]:.3g} ({fr['low'][i][j]:.3g}..{fr['high'][i][j]:.3g})" for j in range(7)
                )
                + " |"
            )
    hf = s["how_far"]
    closed = (
        "no gap to close"
        if hf["closed_total"] is None
        else f"{100 * hf['closed_total']:.0f} % of the gap (in RMS) closed toward the floor"
    )
    L += [
        "",
        "## How far",
        "",
        f"Overall, weighted: {hf['weighted_before']:.3g} -> {hf['weighted_after']:.3g} noise variances; {closed}.",
        "",
        "| channel | column | before | after | floor | closed |",
        "|---|---|---|---|---|---|",
    ]
    o = hf["overall"]
    for ci, c in enumerate(s["channels"]):
        for j in range(7):
            cl = o["closed"][ci][j]
            L.append(
                f"| {c} | {s['columns'][c][j]} | {o['before'][ci][j]:.3g} | {o['after'][ci][j]:.3g} | {o['floor'][ci][j]:.3g} | "
                f"{'-' if cl is None or cl != cl else f'{100 * cl:.0f} %'} |"
            )
    if len(hf["phases"]) > 1:
        L += [
            "",
            "Per phase (mean over joints of the RMS, first channel):",
            "",
            "| phase | before | after |",
            "|---|---|---|",
        ]
        for name, t in hf["phases"].items():
            L.append(f"| {name} | {np.mean(t['before'][0]):.3g} | {np.mean(t['after'][0]):.3g} |")
    for key in ("downstream",):
        if key in s:
            L += ["", "## Downstream", "", s[key]["text"]]
    return "\n".join(L) + "\n"


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def _subplots(figsize: tuple[float, float], *grid: int, **kwargs: Any):
    """A Figure made without pyplot (no backend chosen or switched) and its axes."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **kwargs)


def _figures(d: Diagnosis) -> dict[str, bytes]:

    a = d.arrays
    s = d.summary()
    valid = a["valid"]
    out = {}
    fig, axes = _subplots((21, 3 * len(d.channels)), len(d.channels), 7, squeeze=False)
    step = max(1, int(valid.sum() // 3000))
    for ci, c in enumerate(d.channels):
        for j in range(7):
            ax = axes[ci, j]
            x = a["x"][valid, j][::step]
            ax.plot(x, a["residual"][valid, ci, j][::step], ".", ms=1.5, alpha=0.5, label="nominal")
            label = d.labels.get(c, [f"joint {k + 1}" for k in range(7)])[j]
            ax.plot(x, a["after"][valid, ci, j][::step], ".", ms=1.5, alpha=0.5, label="with effects")
            ax.axhspan(-a["floor"][ci, j], a["floor"][ci, j], color="0.85", zorder=0)
            ax.set_title(f"{c} {label}", fontsize=9)
            if j == 0:
                ax.set_ylabel("residual")
            if ci == len(d.channels) - 1:
                ax.set_xlabel(d.x_label)
    axes[0, 0].legend(fontsize=7, markerscale=5)
    out["residual_vs_velocity.png"] = _png(fig)

    w = s["where"]
    labels = ["all"] + list(w["phases"]) + list(w["regions"])
    mats = [
        np.array(
            [
                [next(r["ratio"] for r in w["channels"] if r["channel"] == c and r["joint"] == j + 1) for j in range(7)]
                for c in d.channels
            ]
        )
    ]
    mats += [np.asarray(w["phases"][p]["ratio"]) for p in w["phases"]]
    mats += [np.asarray(w["regions"][r]["ratio"]) for r in w["regions"]]
    grid = np.concatenate(mats, axis=0)
    ylabels = [f"{lab}: {c}" for lab in labels for c in d.channels]
    fig, ax = _subplots((7, 0.3 * len(ylabels) + 1.5))
    im = ax.imshow(np.log10(np.maximum(grid, 1e-3)), aspect="auto", cmap="magma")
    ax.set_yticks(range(len(ylabels)), ylabels, fontsize=7)
    ax.set_xticks(range(7), [str(j + 1) for j in range(7)])
    ax.set_xlabel("column (joint, or tool x y z fx fy fz mz)")
    fig.colorbar(im, ax=ax, label="log10(RMS / noise floor)")
    ax.set_title("where: residual over the noise floor")
    out["where.png"] = _png(fig)

    fig, ax = _subplots((7, 0.4 * max(len(s["ranking"]), 1) + 1.5))
    names = [r["effect"] for r in s["ranking"]][::-1]
    gains = np.array([r["gain"] for r in s["ranking"]][::-1])
    lo = np.array([r["gain_low"] for r in s["ranking"]][::-1])
    hi = np.array([r["gain_high"] for r in s["ranking"]][::-1])
    ax.barh(
        names,
        gains,
        xerr=[np.maximum(gains - lo, 0), np.maximum(hi - gains, 0)],
        color=["C2" if r else "C7" for r in [x["significant"] for x in s["ranking"]][::-1]],
    )
    ax.set_xlabel("held-out gain [noise variances] (95 % interval)")
    ax.set_title("which effect: each alone")
    out["ranking.png"] = _png(fig)

    o = s["how_far"]["overall"]
    fig, ax = _subplots((10, 3.5))
    labels = [f"{c}{j + 1}" for c in d.channels for j in range(7)]
    x = np.arange(len(labels))
    before = np.array(o["before"]).ravel()
    after = np.array(o["after"]).ravel()
    floor = np.array(o["floor"]).ravel()
    ax.bar(x - 0.2, before, 0.4, label="nominal")
    ax.bar(x + 0.2, after, 0.4, label="with selected effects")
    ax.plot(x, floor, "k_", ms=12, label="noise floor")
    ax.set_xticks(x, labels, rotation=90, fontsize=7)
    ax.set_ylabel("held-out RMS")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title("how far: held-out gap before and after")
    out["before_after.png"] = _png(fig)
    return out


def write_report(
    d: Diagnosis, out: str | Path, title: str = "Sim-to-real gap diagnosis", extra: dict[str, Any] | None = None
) -> list[Path]:
    """Write report.md, report.json and the figures into folder `out` (checked first); `extra`
    is merged into report.json. Returns the paths written."""
    folder = check_output_dir(out, "diagnosis output folder")
    summary = d.summary()
    if extra:
        summary.update(extra)
    import json

    files: dict[str, bytes] = {
        "report.json": (json.dumps(to_strict_json(summary), indent=1, allow_nan=False) + "\n").encode(),
        "report.md": render_markdown(d, title).encode(),
    }
    files.update(_figures(d))
    return [write_atomic(folder / name, data) for name, data in files.items()]
