"""Reach over the placement region: how close the inspect and pick motions bring the tool to their
targets, on an x, y grid of the region, for each gear and from two starts.

Each grid point (x, y) where `validate_gear_pose` accepts the gear (clear of the plate, in reach)
runs, in a station without gears (nothing to touch: the arm's reach alone), the planner's motions
as `planning.system` builds them:

  inspect   from the start pose (the arm at `q_arm_start`), or from above a shaft after an
            insert (`--starts shaft`: the tool heading pi/2 there), `append_inspect` to the
            gear; the error is the tool's distance to the inspect pose at the end of the hold for
            the picture (the planned picture time);
  pick      then `append_pick` at tool heading pi/2 -+ half a tooth pitch (alternating over the
            grid: the headings the planner's pick aims at), up to the end of the "steady at
            gear" pause just before the fingers close; the error is the tool's distance to its
            grasp pose there.

A joint-limit hit is a run in which some arm joint came within `--hit` rad (default 0.01) of a
position limit. The table: per motion, max / median error [mm], the count above 1 mm, the hits.

    .venv/bin/python -m benchmarks.reach                       # 5 x 5 grid, 3 gears, 2 starts
    .venv/bin/python -m benchmarks.reach --nx 9 --ny 9 --workers 2 --json docs/results/reach.json
    .venv/bin/python -m benchmarks.reach --limit-stiffness 0   # the law without joint-limit avoidance
    .venv/bin/python -m benchmarks.reach --joint-clearance none --pick-heading default  # as before
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["ReachCase", "grid_cases", "measure_case", "main", "reach_summary"]

GEARS = ("small", "medium", "large")
STARTS = ("home", "shaft")
# Above a shaft after an insert: the tool at the retreat height over the medium shaft, heading pi/2.
SHAFT_GEAR = "medium"


@dataclass(frozen=True)
class ReachCase:
    """One run: `gear` at (x, y); `start` "home" (the start pose) or "shaft" (above a shaft after
    an insert); `heading` the pick's tool heading [rad]; the controller's joint-limit avoidance
    (`limit_stiffness` [N m/rad], `limit_margin` [rad]; ImpedanceGains); the inspect's
    `joint_clearance` (InspectConfig; None: the hand's yaw kept) and `pick_heading` "reachable"
    (the pick adapted as the planner adapts it) or "default" (never)."""

    gear: str
    x: float
    y: float
    start: str
    heading: float
    limit_stiffness: float
    limit_margin: float
    joint_clearance: float | None = 0.15
    pick_heading: str = "reachable"


def grid_cases(
    nx: int,
    ny: int,
    gears: tuple[str, ...] = GEARS,
    starts: tuple[str, ...] = STARTS,
    limit_stiffness: float | None = None,
    limit_margin: float | None = None,
    joint_clearance: float | None = 0.15,
    pick_heading: str = "reachable",
) -> list[ReachCase]:
    """The cases of an nx x ny grid over PLACEMENT_X x PLACEMENT_Y (corners included) where the
    gear may lie; the controller's defaults where a limit option is None."""
    from assembly.gearset import gear_spec
    from assembly.impedance import ImpedanceGains
    from assembly.world import PLACEMENT_X, PLACEMENT_Y, WorldConfig, validate_gear_pose

    defaults = ImpedanceGains()
    k = defaults.limit_stiffness if limit_stiffness is None else float(limit_stiffness)
    m = defaults.limit_margin if limit_margin is None else float(limit_margin)
    ImpedanceGains(limit_stiffness=k, limit_margin=m)  # one-line errors for bad options
    if pick_heading not in ("reachable", "default"):
        raise ValueError(f"pick_heading = {pick_heading!r}; expected 'reachable' or 'default'")
    plate = WorldConfig().plate_pose
    cases = []
    for gear in gears:
        half_pitch = 0.5 * gear_spec(gear).tooth_pitch_angle
        for i, x in enumerate(np.linspace(*PLACEMENT_X, nx)):
            for j, y in enumerate(np.linspace(*PLACEMENT_Y, ny)):
                try:
                    validate_gear_pose(gear, (float(x), float(y), 0.0), plate)
                except ValueError:
                    continue
                heading = math.pi / 2 + (half_pitch if (i + j) % 2 == 0 else -half_pitch)
                for start in starts:
                    cases.append(
                        ReachCase(
                            gear,
                            round(float(x), 4),
                            round(float(y), 4),
                            start,
                            heading,
                            k,
                            m,
                            joint_clearance,
                            pick_heading,
                        )
                    )
    return cases


def _shaft_start_pose(station):
    """The tool pose above the shaft of SHAFT_GEAR after its insert (retreat height, heading pi/2)."""
    from assembly.gearset import GEAR_THICKNESS
    from assembly.scripted_motion import ScriptedInsertionConfig, down_pose

    c = ScriptedInsertionConfig()
    p_S = station.models.X_WS(SHAFT_GEAR).translation()
    return down_pose(p_S + [0.0, 0.0, GEAR_THICKNESS + c.retreat_height], math.pi / 2)


def measure_case(case: ReachCase) -> dict:
    """Run one case (see the module docstring); its row: errors [m], worst joint margin [rad]."""
    from pydrake.systems.analysis import Simulator

    from assembly.cameras import CamerasConfig
    from assembly.impedance import ImpedanceGains
    from assembly.inspection import InspectConfig, append_inspect
    from assembly.scripted_motion import (
        KeyframePlayer,
        ScriptedInsertionConfig,
        append_move,
        append_pick,
        carry_height,
        gripper_widths,
        start_keyframe_plan,
    )
    from assembly.station import StationConfig, build_station, drive_station
    from assembly.world import WorldConfig, planar_pose

    gains = ImpedanceGains(limit_stiffness=case.limit_stiffness, limit_margin=case.limit_margin)
    world = WorldConfig(gears=())
    cameras = CamerasConfig()
    station = build_station(StationConfig(world=world, gains=gains, cameras=CamerasConfig(scene=None, wrist=None)))
    controller = station.controller
    motion = ScriptedInsertionConfig()
    X_WT0 = controller.tool_pose(np.asarray(world.q_arm_start, dtype=float))
    plan = start_keyframe_plan(X_WT0, world.finger_width_start)
    if case.start == "shaft":
        append_move(plan, _shaft_start_pose(station), world.finger_width_start, "above the shaft", motion.speed, 0.5)
        plan.append(0.5, plan.keyframes[-1].X_WT, world.finger_width_start, "steady")
    t_inspect = append_inspect(
        plan, case.gear, (case.x, case.y), cameras.wrist, InspectConfig(joint_clearance=case.joint_clearance)
    )
    X_inspect = plan.keyframes[-1].X_WT
    carry_z = carry_height(case.gear, station.models.X_WS(case.gear), motion)
    tool = np.array([case.x, case.y, case.heading])
    descend_speed = None
    if case.pick_heading == "reachable":
        from planning.pick import reachable_pick

        tool, descend_speed = reachable_pick(
            case.gear, tool, (0.0, 0.0, 0.0), tool, plate_pose=world.plate_pose, motion=motion
        )
    if plan.keyframes[-1].width < gripper_widths(case.gear, motion)[0]:  # as the planner opens first
        plan.append(motion.gripper_time, plan.keyframes[-1].X_WT, gripper_widths(case.gear, motion)[0], "open")
    append_pick(plan, case.gear, planar_pose(tool[0], tool[1], 0.0), float(tool[2]), carry_z, motion, descend_speed)
    steady = next(k for k in plan.keyframes if k.label == f"{case.gear}: steady at gear")
    simulator = Simulator(drive_station(station, KeyframePlayer(plan)))
    simulator.Initialize()
    context = simulator.get_context()
    plant_context = station.plant_context(context)
    worst = np.full(7, np.inf)
    errors = {}
    t, dt = 0.0, 0.04
    for name, t_end, X_target in (("inspect", t_inspect, X_inspect), ("pick", steady.t, steady.X_WT)):
        while t < t_end - 1e-9:
            t = min(t + dt, t_end)
            simulator.AdvanceTo(t)
            q = station.plant.GetPositions(plant_context, station.models.arm)
            worst = np.minimum(worst, controller.joint_limit_margin(q))
        errors[name] = float(np.linalg.norm(station.tool_pose(context).translation() - X_target.translation()))
    return {
        "gear": case.gear,
        "x": case.x,
        "y": case.y,
        "start": case.start,
        "heading": case.heading,
        "pick_heading": float(tool[2]),
        "descend_speed": motion.speed if descend_speed is None else descend_speed,
        "inspect_error_m": errors["inspect"],
        "pick_error_m": errors["pick"],
        "joint_margin_rad": worst.tolist(),
    }


def reach_summary(rows: list[dict], hit: float = 0.01) -> list[dict]:
    """Per motion (and per gear): max / median error [mm], count above 1 mm, joint-limit hits."""
    out = []
    groups = [("all", rows)] + [(g, [r for r in rows if r["gear"] == g]) for g in GEARS]
    for motion in ("inspect", "pick"):
        for label, group in groups:
            if not group:
                continue
            e = np.array([r[f"{motion}_error_m"] for r in group]) * 1e3
            hits = sum(min(r["joint_margin_rad"]) < hit for r in group)
            worst = group[int(np.argmax(e))]
            out.append(
                {
                    "motion": motion,
                    "gears": label,
                    "runs": len(group),
                    "max_mm": float(e.max()),
                    "median_mm": float(np.median(e)),
                    "over_1mm": int(np.sum(e > 1.0)),
                    "limit_hits": int(hits),
                    "worst_at": f"{worst['gear']} ({worst['x']:.3f}, {worst['y']:.3f}) {worst['start']}",
                }
            )
    return out


def format_table(summary: list[dict]) -> str:
    lines = [
        "| motion | gears | runs | max [mm] | median [mm] | > 1 mm | joint-limit hits | worst at |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(
            f"| {s['motion']} | {s['gears']} | {s['runs']} | {s['max_mm']:.2f} | {s['median_mm']:.2f} | "
            f"{s['over_1mm']} | {s['limit_hits']} | {s['worst_at']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reach", description=__doc__.splitlines()[0])
    parser.add_argument("--nx", type=int, default=5, help="grid points along x (default 5)")
    parser.add_argument("--ny", type=int, default=5, help="grid points along y (default 5)")
    parser.add_argument("--gears", nargs="+", default=list(GEARS), choices=GEARS)
    parser.add_argument("--starts", nargs="+", default=list(STARTS), choices=STARTS)
    parser.add_argument("--limit-stiffness", type=float, default=None, help="N m/rad; 0: no joint-limit avoidance")
    parser.add_argument("--limit-margin", type=float, default=None, help="rad")
    parser.add_argument(
        "--joint-clearance",
        default="0.15",
        help="InspectConfig.joint_clearance [rad]; 'none': the inspect view keeps the hand's yaw (as before)",
    )
    parser.add_argument(
        "--pick-heading",
        choices=("reachable", "default"),
        default="reachable",
        help="reachable: the pick as the planner adapts it (planning.pick.reachable_pick); default: as before",
    )
    parser.add_argument("--hit", type=float, default=0.01, help="a joint this close to a limit [rad] is a hit")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", default=None, metavar="FILE", help="write the rows and the table as JSON")
    args = parser.parse_args(argv)
    from goflow_common.checks import check_int
    from goflow_common.files import check_output_file
    from goflow_common.pool import ProcessPool

    check_int(args.nx, "--nx", 2)
    check_int(args.ny, "--ny", 2)
    check_int(args.workers, "--workers", 1)
    if args.json:
        check_output_file(args.json)
    clearance = None if args.joint_clearance.lower() == "none" else float(args.joint_clearance)
    cases = grid_cases(
        args.nx,
        args.ny,
        tuple(args.gears),
        tuple(args.starts),
        args.limit_stiffness,
        args.limit_margin,
        clearance,
        args.pick_heading,
    )
    t0 = time.time()
    rows: list[dict] = []
    if args.workers == 1:
        rows = [measure_case(c) for c in cases]
    else:
        with ProcessPool(args.workers) as pool:
            rows = pool.map(measure_case, [(c,) for c in cases])
    summary = reach_summary(rows, args.hit)
    c0 = cases[0] if cases else None
    print(
        f"{len(rows)} runs, {args.nx} x {args.ny} grid, limit_stiffness "
        f"{c0.limit_stiffness if c0 else '-'} N m/rad, limit_margin {c0.limit_margin if c0 else '-'} rad, "
        f"joint_clearance {clearance} rad, pick heading {args.pick_heading}, "
        f"{time.time() - t0:.0f} s wall"
    )
    print(format_table(summary))
    if args.json:
        from goflow_common.files import write_json

        write_json(args.json, {"args": vars(args), "summary": summary, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
