"""The full gearbox assembly: gears placed at random, the station driven by the belief-space
planner (planning.system), and the score read off the plant at the end (the only place the true
gear poses are read).

    summary = run_planned_assembly(seed=0)     # {"seed", "plan", "executed", "replans", "gears", ...}
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator
from tqdm import tqdm

from assembly.cameras import CamerasConfig, extrinsic_error, with_extrinsic_error
from assembly.gearset import GEAR_NAMES
from assembly.rgbd_sensor import D405, D415, CameraSensor
from assembly.station import StationConfig, build_station
from assembly.world import WorldConfig, random_gear_poses
from goflow_common.checks import check_choice, check_int
from planning.domain import PlannerConfig, gearbox_domain
from planning.system import BeliefSpacePlanner, PlannerSystemConfig, connect_planner


#: The station's cameras a planned assembly can carry: name -> the (scene, wrist) sensor models.
CAMERA_CHOICES = {"ideal": (None, None), "realsense": (D415, D405)}


@dataclass
class PlannedAssemblyConfig:
    """seed: of the gears' random placement (assembly.world.random_gear_poses); planner: the
    decision's settings; system: the skills' motions and the state machine's; max_time: simulated
    seconds before giving up; camera_error: (translation [m], rotation [rad]) std of the scene
    camera's true extrinsics around the calibrated ones the robot is given, drawn per seed
    (assembly.cameras.extrinsic_error; (0, 0): perfectly calibrated). Whether the planner knows
    that uncertainty is `system.scene_extrinsic_std`. cameras: "realsense" (the default): the
    scene camera a RealSense D415 and the wrist camera a D405
    (assembly.rgbd_sensor: their depth noise, depth unit, depth scale error, occlusion shadows,
    colour noise, and extrinsics off the calibrated ones by their calibration std, all drawn per
    seed; `camera_error`, when set, replaces the scene camera's), the planner told each camera's
    calibration std unless `system` states a larger one; or "ideal" (perfect images and
    calibration)."""

    seed: int = 0
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    system: PlannerSystemConfig = field(default_factory=PlannerSystemConfig)
    max_time: float = 150.0
    camera_error: tuple[float, float] = (0.0, 0.0)
    cameras: str = "realsense"

    def __post_init__(self) -> None:
        check_int(self.seed, "seed", minimum=0)
        check_choice(self.cameras, CAMERA_CHOICES, "cameras")
        if len(self.camera_error) != 2 or not all(np.isfinite(v) and v >= 0 for v in self.camera_error):
            raise ValueError(f"camera_error = {self.camera_error}; expected (translation [m], rotation [rad]) std >= 0")
        if not (np.isfinite(self.max_time) and self.max_time > 0):
            raise ValueError(f"max_time = {self.max_time}; expected > 0 s")


@dataclass
class PlannedAssembly:
    """A built planned assembly: the station (with the gears placed), the planner system and a
    Simulator at t = 0."""

    station: object
    planner: BeliefSpacePlanner
    simulator: Simulator
    placement: dict

    @property
    def root_context(self):
        return self.simulator.get_context()

    def run(self):
        """The planner's state now."""
        return self.planner.run(self.planner.GetMyContextFromRoot(self.root_context))


def real_cameras(
    config: PlannedAssemblyConfig, calibrated: CamerasConfig
) -> tuple[CamerasConfig, dict[str, CameraSensor], PlannerSystemConfig]:
    """The cameras as they really are for `config.seed` (their true mountings, the robot being
    given `calibrated`), their sensors, and the planner's settings told the cameras' calibration
    std (see PlannedAssemblyConfig)."""
    cameras, sensors, system = calibrated, {}, config.system
    extrinsic = {}
    for k, (name, model) in enumerate(zip(("scene", "wrist"), CAMERA_CHOICES[config.cameras])):
        if model is None:
            continue
        sensors[name] = CameraSensor(model, model.draw_scale(np.random.default_rng([config.seed, 19, k])), config.seed)
        extrinsic[name] = model.extrinsic_std
    if any(config.camera_error):
        extrinsic["scene"] = config.camera_error
    for name, std in extrinsic.items():
        X_CE = extrinsic_error(*std, np.random.default_rng([config.seed, 17 + (name == "wrist")]))
        cameras = replace(cameras, **{name: with_extrinsic_error(getattr(calibrated, name), X_CE)})
    if config.cameras != "ideal":
        told = {
            f"{name}_extrinsic_std": tuple(np.maximum(getattr(system, f"{name}_extrinsic_std"), extrinsic[name]))
            for name in ("scene", "wrist")
        }
        system = replace(system, **told)
    return cameras, sensors, system


def build_planned_assembly(
    config: PlannedAssemblyConfig | None = None, skills: dict | None = None, meshcat: Meshcat | None = None
) -> PlannedAssembly:
    """The station with the gears placed for `config.seed`, driven by the planner."""
    from learning.skill_file import load_skill

    config = config or PlannedAssemblyConfig()
    poses = random_gear_poses(np.random.default_rng(config.seed))
    world = WorldConfig(gear_start_poses=poses)
    calibrated = CamerasConfig()
    cameras, sensors, system = real_cameras(config, calibrated)
    station = build_station(
        StationConfig(world=world, cameras=cameras, sensors=sensors, wrench_seed=config.seed), meshcat
    )
    skills = skills or {g: load_skill("insert", g) for g in GEAR_NAMES}
    domain = gearbox_domain(config.planner, skills=skills)
    X_WT0 = station.controller.tool_pose(np.asarray(world.q_arm_start, dtype=float))
    # The planner is given what the robot knows: the skills, the shafts (from the plate's known
    # pose), the cameras and its own start; never the gear poses.
    planner = BeliefSpacePlanner(
        skills,
        domain,
        {g: station.models.X_WS(g) for g in domain.goal},
        calibrated,
        X_WT0,
        world.finger_width_start,
        system,
        meshcat,
    )
    simulator = Simulator(connect_planner(station, planner))
    simulator.Initialize()
    return PlannedAssembly(station, planner, simulator, poses)


def run_planned_assembly(
    config: PlannedAssemblyConfig | None = None,
    skills: dict | None = None,
    meshcat: Meshcat | None = None,
    record: Path | None = None,
    progress: bool = False,
    built: PlannedAssembly | None = None,
) -> dict:
    """Place the gears for `config.seed`, let the planner assemble them, and score the result:
    {"seed", "cameras", "plan": [[skill, gear], ...] (the first plan), "plans" (every plan made),
    "executed": [{"skill", "gear", "t_start", "t_end", "outcome", "precondition_prob"}],
    "replans", "status" (done | failed | timeout), "reason", "gears": {gear: {"inserted",
    "lateral_error_m", "height_error_m"}}, "placement", "sim_time_s", "wall_time_s"} and "sim_error"
    if a physics step failed. `built`: an assembly already built (and perhaps advanced)."""
    config = config or PlannedAssemblyConfig()
    wall0 = time.perf_counter()
    built = built or build_planned_assembly(config, skills, meshcat)
    station, planner, simulator, poses = built.station, built.planner, built.simulator, built.placement
    root = simulator.get_context()
    context = planner.GetMyContextFromRoot(root)
    vis = station.meshcat_visualizer
    if record is not None:
        if vis is None:
            raise ValueError("recording needs a Meshcat; pass meshcat=make_meshcat()")
        vis.StartRecording(False)
    error = None
    bar = tqdm(total=round(config.max_time), unit="sim s", disable=not progress, desc="assembly")
    t = root.get_time()
    try:
        while t < config.max_time and not planner.run(context).finished:
            t = min(t + 0.5, config.max_time)
            simulator.AdvanceTo(t)
            bar.update(round(t - bar.n, 2))
    except RuntimeError as exc:  # a failed physics step is reported, never hidden
        error = f"simulation failed at t = {root.get_time():.3f} s: {exc}"
    finally:
        bar.close()
    if record is not None:
        vis.StopRecording()
        vis.PublishRecording()
        Path(record).write_text(meshcat.StaticHtml())
    run = planner.run(context)
    gears = {}
    for gear in GEAR_NAMES:  # scoring: the only place the true poses are read
        err = station.insertion_error(root, gear)
        gears[gear] = {
            "inserted": bool(err.inserted),
            "lateral_error_m": float(err.lateral_m),
            "height_error_m": float(abs(err.height_m)),
        }
    summary = {
        "seed": config.seed,
        "cameras": config.cameras,
        "plan": run.plans[0] if run.plans else [],
        "plans": list(run.plans),
        "executed": list(run.executed),
        "replans": run.replans,
        "status": run.phase.value if run.finished else "timeout",
        "reason": run.reason,
        "gears": gears,
        "placement": {g: list(p) for g, p in poses.items()},
        "sim_time_s": float(root.get_time()),
        "wall_time_s": time.perf_counter() - wall0,
    }
    if error is not None:
        summary["sim_error"] = error
    return summary


def format_planned(summary: dict) -> str:
    """The plan, each executed skill with its outcome and precondition probability, and the
    per-gear result."""
    cameras = f" ({summary['cameras']} cameras)" if "cameras" in summary else ""
    lines = [f"seed {summary['seed']}{cameras}: plan " + ", ".join(f"{s}({g})" for s, g in summary["plan"])]
    for e in summary["executed"]:
        lines.append(
            f"  {e['t_start']:6.2f}-{e['t_end']:6.2f} s  {e['skill']:<8} {e['gear']:<7} "
            f"P = {e['precondition_prob']:.2f}  {e['outcome']}"
        )
    lines.append(
        f"replans: {summary['replans']}; status: {summary['status']}"
        + (f" ({summary['reason']})" if summary["reason"] else "")
    )
    lines.append(f"{'gear':<8} {'inserted':<9} {'lateral [mm]':>12} {'height [mm]':>12}")
    for name, g in summary["gears"].items():
        lines.append(
            f"{name:<8} {str(g['inserted']):<9} {1e3 * g['lateral_error_m']:>12.2f} {1e3 * g['height_error_m']:>12.2f}"
        )
    lines.append(f"sim {summary['sim_time_s']:.1f} s in {summary['wall_time_s']:.1f} s wall")
    if "sim_error" in summary:
        lines.append(f"SIMULATION ERROR: {summary['sim_error']}")
    return "\n".join(lines)


__all__ = [
    "PlannedAssembly",
    "PlannedAssemblyConfig",
    "build_planned_assembly",
    "format_planned",
    "run_planned_assembly",
]
