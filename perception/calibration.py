"""Calibration of the pose posterior on random synthetic scenes rendered by Drake: how often the
true pose lies in the posterior's credible region, and how far the MAP is from the truth."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from assembly.cameras import CameraConfig, look_at
from assembly.gearset import GEAR_NAMES, gear_spec
from perception.drake_scene import DrakeScene, SceneConfig
from perception.posterior import PosePosterior, wrap
from perception.search import Prior, SearchConfig, estimate_pose


@dataclass
class CalibrationConfig:
    """Random scenes: a gear at a uniform pose in a box on the table, seen from a camera
    `height` above the table looking down at a point up to `aim_jitter` off the gear; the
    prior's centre is off the truth by up to `prior_offset` per axis."""

    scenes: int = 30
    seed: int = 0
    level: float = 0.9
    gears: tuple[str, ...] = GEAR_NAMES
    x_range: tuple[float, float] = (0.35, 0.50)
    y_range: tuple[float, float] = (-0.20, 0.10)
    height: tuple[float, float] = (0.15, 0.35)
    aim_jitter: float = 0.03
    prior_offset: float = 0.012
    prior_half_width: float = 0.025
    search: SearchConfig = field(default_factory=SearchConfig)


def pose_error(estimate: np.ndarray, truth: np.ndarray, period: float) -> tuple[float, float]:
    """(x-y distance [m], yaw error [rad]) of an estimate, yaw compared modulo `period`."""
    d = float(np.hypot(*(np.asarray(estimate[:2]) - truth[:2])))
    e = float(abs(wrap((estimate[2] - truth[2]) * 2 * np.pi / period)) * period / (2 * np.pi))
    return d, e


def random_camera(rng: np.random.Generator, target: np.ndarray, height: float) -> CameraConfig:
    """A 60-degree camera `height` above the table, a little off to the side, looking at
    `target` (x, y) on the table."""
    eye = np.array([target[0] + rng.uniform(-0.04, 0.04), target[1] + rng.uniform(-0.04, 0.04), height])
    return CameraConfig("random", look_at(eye, [target[0], target[1], 0.0]),
                        fov_y=np.deg2rad(60.0), near=0.01, far=1.5)


def run_calibration(config: CalibrationConfig | None = None, progress: bool = False) -> dict:
    """Posteriors on `config.scenes` random scenes; returns per-scene rows and the coverage."""
    config = config or CalibrationConfig()
    rng = np.random.default_rng(config.seed)
    scenes = {g: DrakeScene(SceneConfig(gears={g: (0.4, 0.0, 0.0)})) for g in config.gears}
    rows = []
    for k in range(config.scenes):
        gear = config.gears[int(rng.integers(len(config.gears)))]
        truth = np.array([rng.uniform(*config.x_range), rng.uniform(*config.y_range),
                          rng.uniform(-np.pi, np.pi)])
        scenes[gear].set_gear_pose(gear, tuple(truth))
        aim = truth[:2] + rng.uniform(-config.aim_jitter, config.aim_jitter, 2)
        camera = random_camera(rng, aim, rng.uniform(*config.height))
        obs = scenes[gear].render(camera, camera.X_PC)
        centre = truth[:2] + rng.uniform(-config.prior_offset, config.prior_offset, 2)
        post = estimate_pose(obs, gear, Prior(centre[0], centre[1], config.prior_half_width),
                             config.search)
        rows.append(_row(gear, truth, post, config.level))
        if progress:
            print(f"scene {k}: {rows[-1]}", flush=True)
    covered = [r["covered"] for r in rows]
    return {"level": config.level, "scenes": len(rows), "coverage": float(np.mean(covered)),
            "rows": rows}


def _row(gear: str, truth: np.ndarray, post: PosePosterior, level: float) -> dict:
    d, e = pose_error(post.map_pose, truth, gear_spec(gear).tooth_pitch_angle)
    return {"gear": gear, "truth": truth.tolist(), "map": post.map_pose.tolist(),
            "xy_error_m": d, "yaw_error_rad": e, "covered": post.contains(truth, level),
            "informative": post.informative, "std": post.std().tolist(),
            "seconds": post.info.get("seconds", float("nan"))}
