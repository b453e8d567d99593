"""The scripted gearbox assembly: the station plays pick-and-insert for each gear in turn."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator
from tqdm import tqdm

from assembly.gearset import gear_spec
from assembly.scripted_motion import (
    KeyframePlan,
    KeyframePlayer,
    ScriptedInsertionConfig,
    append_pick_and_insert,
    append_return,
    start_keyframe_plan,
)
from assembly.station import Station, StationConfig, build_station, drive_station
from assembly.world import planar_pose


@dataclass
class AssemblyConfig:
    """A scripted run: which gears, in which order, and what the script believes."""

    station: StationConfig = field(default_factory=StationConfig)
    motion: ScriptedInsertionConfig = field(default_factory=ScriptedInsertionConfig)
    order: tuple[str, ...] = ("large", "medium", "small")
    # Per gear, how far (x, y in W, metres) the script's belief of the gear's position is off the
    # truth. Zero by default; a test sets one to show that contact, not the script, decides.
    belief_offsets: dict[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in list(self.order) + list(self.belief_offsets):
            gear_spec(name)
            if name not in self.station.world.gears:
                raise ValueError(f"gear {name!r} is not in the station's gears {list(self.station.world.gears)}")
        if len(set(self.order)) != len(self.order):
            raise ValueError(f"order {self.order} names a gear twice")


@dataclass
class AssemblyRun:
    """A built assembly: station, plan, diagram, simulator."""

    station: Station
    plan: KeyframePlan
    simulator: Simulator

    @property
    def root_context(self):
        return self.simulator.get_context()


def build_assembly(config: AssemblyConfig, meshcat: Meshcat | None = None) -> AssemblyRun:
    """Build station + plan player for `config` and a Simulator at t = 0."""
    station = build_station(config.station, meshcat)
    world = config.station.world
    X_WT0 = station.controller.tool_pose(np.asarray(world.q_arm_start, dtype=float))
    plan = start_keyframe_plan(X_WT0, world.finger_width_start)
    for gear in config.order:
        x, y, yaw = world.gear_start_poses[gear]
        dx, dy = config.belief_offsets.get(gear, (0.0, 0.0))
        append_pick_and_insert(plan, gear, planar_pose(x + dx, y + dy, yaw), station.models.X_WS(gear), config.motion)
    append_return(plan, X_WT0, config.motion)
    simulator = Simulator(drive_station(station, KeyframePlayer(plan)))
    simulator.Initialize()
    return AssemblyRun(station, plan, simulator)


def run_assembly(
    config: AssemblyConfig | None = None,
    meshcat: Meshcat | None = None,
    record: Path | None = None,
    realtime: bool = False,
    progress: bool = True,
) -> dict:
    """Run the scripted assembly to the end of its plan; return the per-gear summary
    {"gears": {name: {"inserted", "lateral_error_m", "height_error_m", "time_s"}}, "sim_time_s",
    "wall_time_s"} plus "sim_error" (a string) if a physics step failed."""
    config = config or AssemblyConfig()
    run = build_assembly(config, meshcat)
    if realtime:
        run.simulator.set_target_realtime_rate(1.0)
    vis = run.station.meshcat_visualizer
    if record is not None:
        if vis is None:
            raise ValueError("recording needs a Meshcat; pass meshcat=make_meshcat()")
        vis.StartRecording(False)
    end = run.plan.end_time
    error = None
    wall0 = time.perf_counter()
    bar = tqdm(total=round(end, 2), unit="sim s", disable=not progress, desc="scripted assembly")
    t = 0.0
    try:
        while t < end - 1e-9:
            t = min(t + 0.25, end)
            run.simulator.AdvanceTo(t)
            bar.update(round(t - bar.n, 2))
    except RuntimeError as exc:  # a failed physics step is reported, never hidden
        error = f"simulation failed at t = {run.root_context.get_time():.3f} s: {exc}"
    finally:
        bar.close()
    wall = time.perf_counter() - wall0
    if record is not None:
        vis.StopRecording()
        vis.PublishRecording()
        Path(record).write_text(meshcat.StaticHtml())
    summary = assembly_summary(run, config.order)
    summary["sim_time_s"] = float(run.root_context.get_time())
    summary["wall_time_s"] = float(wall)
    if error is not None:
        summary["sim_error"] = error
    return summary


def assembly_summary(run: AssemblyRun, gears: tuple[str, ...]) -> dict:
    """Per-gear insertion outcome at the run's current time."""
    out = {}
    for gear in gears:
        err = run.station.insertion_error(run.root_context, gear)
        t0, t1 = run.plan.gear_intervals[gear]
        out[gear] = {
            "inserted": bool(err.inserted),
            "lateral_error_m": err.lateral_m,
            "height_error_m": abs(err.height_m),
            "time_s": float(t1 - t0),
        }
    return {"gears": out}


def format_summary(summary: dict) -> str:
    """A small table of the per-gear outcome."""
    lines = [f"{'gear':<8} {'inserted':<9} {'lateral [mm]':>12} {'height [mm]':>12} {'time [s]':>9}"]
    for name, g in summary["gears"].items():
        lines.append(
            f"{name:<8} {str(g['inserted']):<9} {1e3 * g['lateral_error_m']:>12.2f} "
            f"{1e3 * g['height_error_m']:>12.2f} {g['time_s']:>9.1f}"
        )
    lines.append(
        f"sim {summary['sim_time_s']:.1f} s in {summary['wall_time_s']:.1f} s wall "
        f"({summary['sim_time_s'] / max(summary['wall_time_s'], 1e-9):.2f}x real time)"
    )
    if "sim_error" in summary:
        lines.append(f"SIMULATION ERROR: {summary['sim_error']}")
    return "\n".join(lines)


__all__ = ["AssemblyConfig", "AssemblyRun", "build_assembly", "run_assembly", "format_summary"]
