"""The full assembly over random placements, side by side (issue 17's benchmark):

    scripted   the scripted pick-and-insert from the gears' true poses (the upper bound)
    map        the planner, inserting at the scene view's belief with no precondition, no inspection
    inspect    the planner, inspecting every gear before picking it (Eq. 7 still checked)
    eq6        the planner with Eq. 6 (value only)
    eq7        the planner with Eq. 7 (value and flow; the default), inserting when P > eta
    eq7cost    Eq. 7 as a cost: the plan of least expected time plus failure cost
               (PlannerConfig(decision="cost"), planning.domain.SkillCosts)

    .venv/bin/python -m benchmarks.assembly_grid --seeds 0 50 --variants scripted eq7 --workers 2 \
        --out runs/assembly/rows.jsonl --json docs/results/assembly.json

--camera-error MM DEG runs the same grid with the scene camera's true extrinsics off the calibrated
ones by N(0, MM) per axis and N(0, DEG) about each axis, drawn per seed; the planner is told that
std (PlannerSystemConfig.scene_extrinsic_std), the "map" baseline ignores it (it has no
precondition), the scripted one never looks (it is left out of this condition):

    .venv/bin/python -m benchmarks.assembly_grid --seeds 0 20 --variants map inspect eq6 eq7 --camera-error 1 0.1 \
        --workers 2 --out runs/assembly/camera_error.jsonl --json docs/results/assembly_camera_error.json

--cameras realsense (the default, as `goflow demo`'s) or ideal chooses the station's cameras.
Each (variant, seed) is one row appended to --out as it finishes; a rerun skips the rows already
there (resumable; rows of another --camera-error, --cameras or --eta are kept and skipped). --eta sets the
precondition's bar of the planner variants (0.9 by default; docs/planning.md's sweep). Prints,
per variant: seeds with all three gears inserted (with the binomial standard error), gears
inserted, inspections, failed inserts (over the rows that list outcomes) and replans per
assembly, wall seconds per assembly.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.provenance import command  # noqa: E402
from goflow_common.files import check_output_file, write_json  # noqa: E402
from goflow_common.pool import ProcessPool, WorkerError  # noqa: E402

VARIANTS = ("scripted", "map", "inspect", "eq6", "eq7", "eq7cost")


def run_one(
    variant: str,
    seed: int,
    camera_error: tuple[float, float] = (0.0, 0.0),
    eta: float = 0.9,
    cameras: str = "realsense",
) -> dict:
    import torch

    from assembly.world import random_gear_poses

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    if variant == "scripted":
        from assembly.demo import AssemblyConfig, run_assembly
        from assembly.station import StationConfig
        from assembly.world import WorldConfig

        poses = random_gear_poses(np.random.default_rng(seed))
        s = run_assembly(
            AssemblyConfig(station=StationConfig(world=WorldConfig(gear_start_poses=poses))), progress=False
        )
        executed, replans, status = [], 0, "done" if "sim_error" not in s else "sim_error"
    else:
        from planning.assembly import PlannedAssemblyConfig, run_planned_assembly
        from planning.domain import PlannerConfig
        from planning.system import PlannerSystemConfig

        planner = {
            "map": PlannerConfig(blind=True, max_inspections=0),
            "inspect": PlannerConfig(min_inspections=1, eta=eta),
            "eq6": PlannerConfig(eps=None, eta=eta),
            "eq7": PlannerConfig(eta=eta),
            "eq7cost": PlannerConfig(decision="cost"),
        }[variant]
        s = run_planned_assembly(
            PlannedAssemblyConfig(
                seed=seed,
                planner=planner,
                camera_error=camera_error,
                system=PlannerSystemConfig(scene_extrinsic_std=camera_error),
                cameras=cameras,
            )
        )
        executed, replans, status = s["executed"], s["replans"], s["status"]
    gears = s["gears"]
    return {
        "variant": variant,
        "seed": seed,
        "camera_error": list(camera_error),
        "cameras": "none" if variant == "scripted" else cameras,
        "eta": eta,
        "status": status,
        "inserted": sum(g["inserted"] for g in gears.values()),
        "all_inserted": all(g["inserted"] for g in gears.values()),
        "inspections": sum(e["skill"] == "inspect" for e in executed),
        "replans": replans,
        "outcomes": [[e["skill"], e["gear"], e["outcome"]] for e in executed],
        "reason": s.get("reason", ""),
        "sim_error": s.get("sim_error", ""),
        "sim_time_s": s["sim_time_s"],
        "wall_time_s": time.perf_counter() - t0,
        "gears": gears,
    }


def grid_summary(rows: list[dict]) -> list[dict]:
    """One row per variant in `rows` (VARIANTS order): seeds, the fraction with all three gears
    inserted (and its binomial standard error), mean gears inserted, inspections, replans and
    failed inserts (None where no row lists outcomes), median and max wall seconds."""
    out = []
    for variant in VARIANTS:
        rs = [r for r in rows if r["variant"] == variant]
        if not rs:
            continue
        ok = np.array([r["all_inserted"] for r in rs], float)
        out.append(
            {
                "variant": variant,
                "seeds": len(rs),
                "all_inserted": float(ok.mean()),
                "all_inserted_se": float(np.sqrt(max(ok.mean() * (1 - ok.mean()), 1e-12) / len(rs))),
                "gears_inserted": float(np.mean([r["inserted"] for r in rs])),
                "inspections": float(np.mean([r["inspections"] for r in rs])),
                "replans": float(np.mean([r["replans"] for r in rs])),
                "failed_inserts": (
                    float(
                        np.mean(
                            [
                                sum(o[0] == "insert" and o[2] != "seated" for o in r["outcomes"])
                                for r in rs
                                if "outcomes" in r
                            ]
                        )
                    )
                    if any("outcomes" in r for r in rs)
                    else None
                ),
                "wall_s_median": float(np.median([r["wall_time_s"] for r in rs])),
                "wall_s_max": float(np.max([r["wall_time_s"] for r in rs])),
            }
        )
    return out


def table(summary: list[dict]) -> str:
    lines = [
        "| variant | seeds | all 3 inserted | gears inserted / 3 | inspections | failed inserts | replans "
        "| wall s median / max |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(
            f"| {s['variant']} | {s['seeds']} | {s['all_inserted']:.2f} +- {s['all_inserted_se']:.2f} | "
            f"{s['gears_inserted']:.2f} | {s['inspections']:.2f} | "
            f"{'n/a' if s['failed_inserts'] is None else format(s['failed_inserts'], '.2f')} | "
            f"{s['replans']:.2f} | "
            f"{s['wall_s_median']:.0f} / {s['wall_s_max']:.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs=2, default=(0, 50), metavar=("FIRST", "END"))
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", type=Path, default=Path("runs/assembly/rows.jsonl"), help="rows (resumable)")
    p.add_argument("--json", type=Path, help="write the summary and every row")
    p.add_argument(
        "--camera-error",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("MM", "DEG"),
        help="std of the scene camera's extrinsic error: translation [mm], rotation [deg]",
    )
    p.add_argument(
        "--cameras",
        choices=["realsense", "ideal"],
        default="realsense",
        help="the station's cameras (goflow demo --cameras; the scripted variant looks at nothing); rows "
        "written before the option had the ideal ones",
    )
    p.add_argument(
        "--eta",
        type=float,
        default=0.9,
        help="the precondition's bar (PlannerConfig.eta) for inspect, eq6, eq7; map and eq7cost have none",
    )
    args = p.parse_args(argv)
    first, end = args.seeds
    if first < 0 or end <= first or args.workers < 1:
        p.error(f"--seeds {first} {end}, --workers {args.workers}: expected 0 <= FIRST < END and >= 1")
    if not all(np.isfinite(v) and v >= 0 for v in args.camera_error):
        p.error(f"--camera-error {args.camera_error[0]} {args.camera_error[1]}: expected MM >= 0 and DEG >= 0")
    if not 0.0 <= args.eta < 1.0:
        p.error(f"--eta {args.eta}: expected 0 <= eta < 1")
    if any(args.camera_error) and "scripted" in args.variants:
        p.error("--camera-error with the scripted variant: it never looks; leave it out")
    camera_error = (1e-3 * args.camera_error[0], float(np.radians(args.camera_error[1])))
    check_output_file(args.out, "--out")
    if args.json:
        check_output_file(args.json, "--json")
    rows = [json.loads(line) for line in args.out.read_text().splitlines()] if args.out.exists() else []
    rows = [
        r
        for r in rows
        if np.allclose(r.get("camera_error", (0.0, 0.0)), camera_error)
        and (r["variant"] in ("scripted", "map", "eq7cost") or np.isclose(r.get("eta", 0.9), args.eta))
        and (r["variant"] == "scripted" or r.get("cameras", "ideal") == args.cameras)
    ]
    done = {(r["variant"], r["seed"]) for r in rows}
    todo = [(v, s) for s in range(first, end) for v in args.variants if (v, s) not in done]
    print(f"{len(todo)} runs to do ({len(done)} already in {args.out})", flush=True)
    with ProcessPool(args.workers) as pool:
        calls = [(v, s, camera_error, args.eta, args.cameras) for v, s in todo]
        for k, row in pool.imap(run_one, calls, errors="return"):
            variant, seed = todo[k]
            if isinstance(row, WorkerError):  # a crashed run is a failed row, reported, and the grid goes on
                e = row.__cause__ or row
                row = {
                    "variant": variant,
                    "seed": seed,
                    "camera_error": list(camera_error),
                    "cameras": args.cameras,
                    "eta": args.eta,
                    "status": "error",
                    "inserted": 0,
                    "all_inserted": False,
                    "inspections": 0,
                    "replans": 0,
                    "reason": f"{type(e).__name__}: {e}",
                    "sim_error": "",
                    "sim_time_s": 0.0,
                    "wall_time_s": 0.0,
                    "gears": {},
                }
            rows.append(row)
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(
                f"{row['variant']:<8} seed {row['seed']:>3}: {row['inserted']}/3 {row['status']} "
                f"inspections {row['inspections']} replans {row['replans']} {row['wall_time_s']:.0f} s",
                flush=True,
            )
    summary = grid_summary([r for r in rows if first <= r["seed"] < end and r["variant"] in args.variants])
    print(table(summary))
    if args.json:
        write_json(
            args.json,
            {
                "command": command("assembly_grid", argv),
                "seeds": [first, end],
                "camera_error": {"translation_m": camera_error[0], "rotation_rad": camera_error[1]},
                "eta": args.eta,
                "summary": summary,
                "rows": [r for r in rows if first <= r["seed"] < end],
            },
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
