"""Global detection benchmark: on fresh random scenes (perception.scenes: all three gears in the
placement region, the plate, the station's scene camera) under each perturbation, how often every
gear is found, how far the detection's centre is from the truth, how often the truth lies outside
the proposed prior box, and the seconds detect_gears takes per scene (rendering not counted).

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python -m benchmarks.detection --scenes 100 --seed 1

prints a markdown table (and writes every row with --json PATH).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from goflow_common.errors import OutputPathError
from goflow_common.files import check_output_file, write_json
from perception.detection import DetectionConfig, detect_gears
from perception.scenes import PERTURBATIONS, SceneRenderer, random_scenes

DEFAULT_PERTURBATIONS = (
    "clean",
    "depth_noise",
    "dropout_10",
    "dim",
    "bright",
    "oblique",
    "occluded_hand",
    "occluded_gear",
)


def evaluate(
    scenes: int,
    seed: int,
    perturbations: tuple[str, ...] = DEFAULT_PERTURBATIONS,
    config: DetectionConfig | None = None,
    renderer: SceneRenderer | None = None,
) -> list[dict]:
    """One row per (perturbation, scene, gear): seen, reason, centre error [m], truth inside the
    prior box, half-width, and the scene's detection time [s]."""
    for p in perturbations:
        if p not in PERTURBATIONS:
            raise ValueError(f"unknown perturbation {p!r}; expected some of {list(PERTURBATIONS)}")
    renderer = renderer or SceneRenderer()
    rows = []
    for scene in random_scenes(seed, scenes):
        for p in perturbations:
            view = renderer.render_view(scene, "scene", None, p, scene.rng("scene", p))
            start = time.perf_counter()
            found = detect_gears(view.obs, config=config)
            seconds = time.perf_counter() - start
            for gear, det in found.items():
                x, y, _ = scene.poses[gear]
                row = {
                    "perturbation": p,
                    "scene": scene.index,
                    "gear": gear,
                    "seen": det.seen,
                    "reason": det.reason,
                    "score": det.score,
                    "visible": det.visible,
                    "std_m": det.std,
                    "edges": det.edges,
                    "pixels": det.pixels,
                    "occluded": view.gear == gear,
                    "hidden_fraction": (view.hidden_fraction if view.gear == gear else None),
                    "visible_truth": view.visible.get(gear, 0.0),
                    "seconds": seconds,
                    "truth": [x, y],
                }
                if det.seen:
                    dx, dy = det.prior.x - x, det.prior.y - y
                    row.update(
                        error_m=float(np.hypot(dx, dy)),
                        half_width=det.prior.half_width,
                        inside=bool(max(abs(dx), abs(dy)) <= det.prior.half_width),
                        centre=[det.prior.x, det.prior.y],
                    )
                rows.append(row)
    return rows


def detection_summary(rows: list[dict], perturbations: tuple[str, ...], visible: float = 0.5) -> list[dict]:
    """Per perturbation: gears found (of all, and of those at least `visible` visible), scenes
    with every gear found, occluded targets found, gears seen although less than `visible`
    visible, centre error median / 95th percentile / max, truth outside the box, median
    half-width, detection time per scene."""
    out = []
    for p in perturbations:
        mine = [r for r in rows if r["perturbation"] == p]
        seen = [r for r in mine if r["seen"]]
        scenes = sorted({r["scene"] for r in mine})
        all_found = [all(r["seen"] for r in mine if r["scene"] == s) for s in scenes]
        occluded = [r for r in mine if r["occluded"]]
        shown = [r for r in mine if r["visible_truth"] >= visible]
        err = np.array([r["error_m"] for r in seen]) if seen else np.array([np.nan])
        times = {r["scene"]: r["seconds"] for r in mine}
        out.append(
            {
                "perturbation": p,
                "gears": len(mine),
                "found": len(seen) / max(len(mine), 1),
                "visible_gears": len(shown),
                "found_of_visible": sum(r["seen"] for r in shown) / max(len(shown), 1),
                "seen_mostly_hidden": sum(r["seen"] for r in mine if r["visible_truth"] < visible),
                "mostly_hidden": sum(r["visible_truth"] < visible for r in mine),
                "scenes_all_found": float(np.mean(all_found)) if all_found else float("nan"),
                "occluded_found": (sum(r["seen"] for r in occluded) / len(occluded) if occluded else None),
                "error_median_m": float(np.median(err)),
                "error_p95_m": float(np.percentile(err, 95)),
                "error_max_m": float(np.max(err)),
                "outside_box": sum(not r["inside"] for r in seen) / max(len(seen), 1),
                "outside_box_count": sum(not r["inside"] for r in seen),
                "half_width_median_m": float(np.median([r["half_width"] for r in seen])) if seen else None,
                "half_width_max_m": float(np.max([r["half_width"] for r in seen])) if seen else None,
                "seconds_median": float(np.median(list(times.values()))),
                "seconds_max": float(np.max(list(times.values()))),
            }
        )
    return out


def table(summary: list[dict]) -> str:
    """The summary as a markdown table (errors in mm)."""
    lines = [
        "| perturbation | gears found | of gears >= 50 % visible | scenes with all 3 | "
        "occluded target found | seen, < 50 % visible | centre error median / p95 / max [mm] "
        "| truth outside box | half-width median / max [mm] | s per scene (median / max) |",
        "|" + "---|" * 10,
    ]
    for s in summary:
        occ = "-" if s["occluded_found"] is None else f"{100 * s['occluded_found']:.0f} %"
        hw = (
            "-"
            if s["half_width_median_m"] is None
            else (f"{1e3 * s['half_width_median_m']:.1f} / {1e3 * s['half_width_max_m']:.1f}")
        )
        lines.append(
            f"| {s['perturbation']} | {100 * s['found']:.1f} % of {s['gears']} | "
            f"{100 * s['found_of_visible']:.1f} % of {s['visible_gears']} | "
            f"{100 * s['scenes_all_found']:.0f} % | {occ} | "
            f"{s['seen_mostly_hidden']} of {s['mostly_hidden']} | "
            f"{1e3 * s['error_median_m']:.2f} / {1e3 * s['error_p95_m']:.2f} / "
            f"{1e3 * s['error_max_m']:.2f} | {100 * s['outside_box']:.1f} % "
            f"({s['outside_box_count']}) | {hw} | "
            f"{s['seconds_median']:.3f} / {s['seconds_max']:.3f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=100, help="random scenes per perturbation")
    parser.add_argument("--seed", type=int, default=1, help="seed of the random scenes")
    parser.add_argument(
        "--perturbations", nargs="+", default=list(DEFAULT_PERTURBATIONS), choices=list(PERTURBATIONS), metavar="NAME"
    )
    parser.add_argument("--json", metavar="PATH", help="write the summary and every row here")
    args = parser.parse_args()
    if args.scenes < 1 or args.seed < 0:
        parser.error(f"--scenes {args.scenes}, --seed {args.seed}: expected >= 1 and >= 0")
    if args.json:
        try:
            check_output_file(args.json, "--json")
        except OutputPathError as exc:
            parser.error(str(exc))
    perturbations = tuple(args.perturbations)
    rows = evaluate(args.scenes, args.seed, perturbations)
    summary = detection_summary(rows, perturbations)
    print(table(summary))
    # Failures: a gear at least half visible not seen, or the truth outside a proposed box.
    failed = [r for r in rows if (not r["seen"] and r["visible_truth"] >= 0.5) or (r["seen"] and not r["inside"])]
    for r in failed[:20]:
        what = (
            "not seen: " + r["reason"]
            if not r["seen"]
            else (
                f"truth outside the box: error {1e3 * r['error_m']:.1f} mm, half-width {1e3 * r['half_width']:.1f} mm"
            )
        )
        print(
            f"- {r['perturbation']} scene {r['scene']} {r['gear']} ({100 * r['visible_truth']:.0f} % visible): {what}"
        )
    print(
        f"{len(failed)} failures; not seen, less than half visible: "
        f"{sum(not r['seen'] and r['visible_truth'] < 0.5 for r in rows)}"
    )
    if args.json:
        write_json(
            args.json,
            {
                "scenes": args.scenes,
                "seed": args.seed,
                "config": vars(DetectionConfig()),
                "summary": summary,
                "rows": rows,
            },
        )


if __name__ == "__main__":
    main()
