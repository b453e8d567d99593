"""Perception benchmark: renderers per hypothesis (Drake vs our ray caster, speed and depth
agreement), whole posteriors per gear, and the posterior plots of one gear seen close (wrist camera
after inspect) and far (scene camera). Calibration is `goflow bench calibration`.

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python -m benchmarks.perception_speed --out DIR

writes DIR/perception_bench.json, perception_posterior_close.png and perception_posterior_far.png
(docs/results holds the committed ones), and prints markdown tables.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from assembly.gearset import gear_spec
from assembly.inspection import run_inspect
from assembly.world import WorldConfig
from assembly.cameras import default_scene_camera
from perception.speed import BenchConfig, bench_posteriors, bench_renderers, close_camera
from perception.drake_scene import DrakeScene, SceneConfig
from perception.gear_model import gear_model
from perception.calibration import CalibrationConfig, pose_error, run_calibration
from perception.station_views import observe
from perception.likelihood import LikelihoodConfig
from perception.search import Prior, SearchConfig, estimate_pose
from goflow_common.files import write_json


def _renderer_table(rows: list[dict]) -> str:
    head = (
        "| gear | view | Drake full [hyp/s] | Drake crop [hyp/s] (px) | ours, all crop pixels "
        "[hyp/s] (px) | ours, search's sparse pixels [hyp/s] (px) | depth within 1 mm, "
        "off edges | within 1 mm, all both-gear px | max off-edge error [mm] |"
    )
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        lines.append(
            f"| {r['gear']} | {r['view']} | {r['drake_full_hypotheses_per_second']:.1f} | "
            f"{r['drake_crop_hypotheses_per_second']:.1f} ({r['drake_crop_pixels']}) | "
            f"{r['ours_all_hypotheses_per_second']:.1f} ({r['ours_all_pixels']}) | "
            f"{r['ours_sparse_hypotheses_per_second']:.0f} ({r['ours_sparse_pixels']}) | "
            f"{100 * r['within_1mm_interior']:.2f} % | {100 * r['within_1mm_all']:.2f} % | "
            f"{1e3 * r['max_error_interior_m']:.2f} |"
        )
    return "\n".join(lines)


def _inspect_figures(out: Path, gear: str = "medium") -> dict:
    """inspect(gear) with a belief 8 mm off the truth; the close and far posteriors and plots."""
    truth = np.array(WorldConfig().gear_start_poses[gear])
    belief = truth[:2] + [0.008, -0.006]
    run = run_inspect(gear, tuple(belief))
    prior = Prior(belief[0], belief[1], 0.03)
    result = {}
    for name, camera in (("close", "wrist"), ("far", "scene")):
        post = estimate_pose(observe(run.station, run.root_context, camera), gear, prior)
        post.plot(out / f"perception_posterior_{name}.png", truth=truth)
        d, e = pose_error(post.map_pose, truth, gear_spec(gear).tooth_pitch_angle)
        result[name] = {
            **post.summary(),
            "xy_error_m": d,
            "yaw_error_deg": float(np.degrees(e)),
            "truth_in_90": post.contains(truth, 0.9),
        }
    return result


def _symmetry(gear: str = "medium") -> list[dict]:
    """Plain and marked gear, far (scene camera) and close (15 cm above): how the yaw mass spreads
    over the tooth-pitch repeats (exp of the repeats' entropy; mass on the true repeat)."""
    truth = (0.41, -0.03, 0.7)
    prior = Prior(truth[0] + 0.01, truth[1] - 0.008, 0.03)
    teeth = gear_spec(gear).teeth
    pitch = 2 * np.pi / teeth
    rows = []
    for marked in (False, True):
        scene = DrakeScene(
            SceneConfig(gears={gear: truth}, marked=(gear,) if marked else (), plate_pose=(0.55, 0.0, np.pi / 2))
        )
        for view, camera in (("far", default_scene_camera()), ("close", close_camera(truth[0], truth[1]))):
            post = estimate_pose(scene.render(camera, camera.X_PC), gear_model(gear, marked), prior)
            m = np.array(
                [
                    post.probability(yaw=(truth[2] + (k - 0.5) * pitch, truth[2] + (k + 0.5) * pitch))
                    for k in range(teeth)
                ]
            )
            p = m[m > 0] / m.sum()
            rows.append(
                {
                    "gear": gear,
                    "marked": marked,
                    "view": view,
                    "teeth": teeth,
                    "effective_repeats": float(np.exp(-(p * np.log(p)).sum())),
                    "true_repeat_mass": float(m[0]),
                    "min_repeat_mass_x_teeth": float(m.min() * teeth),
                    "max_repeat_mass_x_teeth": float(m.max() * teeth),
                    "entropy": {d: post.marginal_entropy(d) for d in ("x", "y", "yaw")},
                    "seconds": post.info["seconds"],
                }
            )
    return rows


def _sweep_correlation_length(values: list[float], scenes: int, out: Path) -> None:
    """Coverage of the clean group's posteriors (tuning seed 0, both views) for several values of
    the tempering's correlation length (LikelihoodConfig.correlation_length)."""
    rows = []
    for length in values:
        search = SearchConfig(likelihood=LikelihoodConfig(correlation_length=length))
        calib = run_calibration(CalibrationConfig(scenes=scenes, seed=0, groups=("clean",), search=search))
        rows += [{"correlation_length_m": length, **s} for s in calib["summary"]]
    write_json(out / "perception_correlation_length.json", rows)
    print("| correlation length [mm] | view | coverage 50/68/80/90/95 [%] | median std x-y [mm] |")
    print("|---|---|---|---|")
    for r in rows:
        cov = "/".join(f"{100 * c:.0f}" for c in r["coverage"].values())
        print(f"| {1e3 * r['correlation_length_m']:.2f} | {r['view']} | {cov} | {r['std_xy_mm']['median']:.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hypotheses", type=int, default=40)
    parser.add_argument("--posteriors", type=int, default=5)
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument("--out", default="runs/bench/perception")
    parser.add_argument(
        "--sweep-correlation-length",
        type=float,
        nargs="+",
        metavar="METRES",
        help="only run the clean calibration (tuning seed 0) for each correlation "
        "length of the tempering and print coverage and widths (writes "
        "perception_correlation_length.json)",
    )
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.sweep_correlation_length:
        _sweep_correlation_length(args.sweep_correlation_length, args.scenes, out)
        return
    renderers = bench_renderers(BenchConfig(hypotheses=args.hypotheses))
    posteriors = bench_posteriors(BenchConfig(posteriors=args.posteriors))
    figures = _inspect_figures(out)
    symmetry = _symmetry()
    bench = {
        "cores": len(os.sched_getaffinity(0)),
        "renderers": renderers,
        "posteriors": posteriors,
        "inspect_medium": figures,
        "symmetry": symmetry,
    }
    write_json(out / "perception_bench.json", bench)

    print(_renderer_table(renderers))
    print()
    print("| gear | seconds per posterior | hypotheses | MAP x-y error [mm] |")
    print("|---|---|---|---|")
    for r in posteriors["rows"]:
        print(f"| {r['gear']} | {r['seconds']:.3f} | {r['hypotheses']} | {1e3 * r['xy_error_m']:.3f} |")
    print(
        f"\nmean {posteriors['seconds_per_posterior']:.3f} s per posterior, "
        f"{posteriors['hypotheses_per_second']:.0f} hypotheses/s on {bench['cores']} core(s)"
    )
    for name, f in figures.items():
        print(
            f"inspect medium, {name}: MAP error {1e3 * f['xy_error_m']:.2f} mm, "
            f"{f['yaw_error_deg']:.2f} deg (mod tooth pitch); std x,y "
            f"{1e3 * f['std'][0]:.3f}, {1e3 * f['std'][1]:.3f} mm; entropy x,y "
            f"{f['entropy']['x']:.2f}, {f['entropy']['y']:.2f} nats; truth in 90 %: {f['truth_in_90']}"
        )
    print(
        "\n| gear | marked | view | effective repeats (of teeth) | mass on true repeat | "
        "min, max repeat mass x teeth | entropy x, y, yaw [nats] | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in symmetry:
        e = r["entropy"]
        print(
            f"| {r['gear']} | {r['marked']} | {r['view']} | {r['effective_repeats']:.1f} of {r['teeth']} | "
            f"{r['true_repeat_mass']:.3f} | {r['min_repeat_mass_x_teeth']:.2f}, {r['max_repeat_mass_x_teeth']:.2f} | "
            f"{e['x']:.2f}, {e['y']:.2f}, {e['yaw']:.2f} | {r['seconds']:.2f} |"
        )


if __name__ == "__main__":
    main()
