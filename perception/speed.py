"""Speed and faithfulness of rendering pose hypotheses, and speed of whole posteriors.

Two renderers of the same hypotheses: Drake's RenderEngineVtk, one full image per hypothesis (set
the gear's pose, render colour and depth), and our batched height-map ray caster over the pixels
that can see the gear. Faithful means: the depth of every pixel where both renderers see the gear,
away from its silhouette, agrees within 1 mm.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from assembly.cameras import CameraConfig, default_scene_camera, look_at
from assembly.gearset import GEAR_NAMES
from perception.detection import detect_gears
from perception.drake_scene import DrakeScene, SceneConfig, crop_info
from perception.gear_model import gear_model
from perception.likelihood import table_prediction
from perception.observation import Observation
from perception.renderer import NAME as RAYCAST_NAME
from perception.renderer import RayCaster
from perception.scenes import SceneRenderer, random_scenes
from perception.search import Prior, SearchConfig, estimate_pose

DRAKE_NAME = "drake-vtk"
DEPTH_TOL = 1e-3  # [m]


@dataclass
class BenchConfig:
    """hypotheses: poses rendered per gear and view; posteriors: close-view posteriors timed per
    gear; seed: of the random poses."""

    hypotheses: int = 20
    posteriors: int = 2
    seed: int = 0
    gears: tuple[str, ...] = GEAR_NAMES


def close_camera(x: float, y: float, height: float = 0.15) -> CameraConfig:
    """A wrist-like camera (60 degree field of view) `height` above the table over (x, y)."""
    return CameraConfig(
        "close", look_at([x + 0.01, y + 0.01, height], [x, y, 0.0]), fov_y=np.deg2rad(60.0), near=0.01, far=1.5
    )


def _views(x: float, y: float) -> dict[str, CameraConfig]:
    return {"close": close_camera(x, y), "scene": default_scene_camera()}


def gear_mask(obs: Observation) -> np.ndarray:
    """Pixels that see something above the table plane by more than 1 mm (here: the gear)."""
    k = obs.intrinsics
    v, u = np.mgrid[0 : k.height, 0 : k.width]
    origin, dirs = obs.rays_W(u.ravel(), v.ravel())
    plane, _ = table_prediction(origin, dirs, -obs.X_WC.rotation().matrix()[:, 2])
    return obs.valid & (np.abs(obs.depth - plane.reshape(k.height, k.width)) > 1e-3)


def _smooth(depth: np.ndarray, seen: np.ndarray, jump: float) -> np.ndarray:
    """Pixels whose 8 neighbours are also seen and within `jump` of their depth."""
    ok = seen.copy()
    d = np.where(seen, depth, np.nan)
    pad = np.pad(d, 1, constant_values=np.nan)
    h, w = d.shape
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            n = pad[1 + dv : 1 + dv + h, 1 + du : 1 + du + w]
            with np.errstate(invalid="ignore"):
                ok &= np.abs(n - d) <= jump
    return ok


def compare_depth(drake_depth: np.ndarray, drake_gear: np.ndarray, ours_depth: np.ndarray, jump: float = 0.005) -> dict:
    """Depth agreement where both renderers see the gear: over all such pixels, and over those
    away from depth edges (silhouette, bore and tooth edges: no neighbour differs by more than
    `jump` in either image), where a sub-pixel shift of an edge cannot flip a pixel."""
    ours_gear = np.isfinite(ours_depth)
    both = drake_gear & ours_gear
    interior = both & _smooth(drake_depth, drake_gear, jump) & _smooth(ours_depth, ours_gear, jump)
    err = np.abs(drake_depth - np.where(ours_gear, ours_depth, 0.0))
    frac = lambda m: float((err[m] <= DEPTH_TOL).mean()) if m.any() else float("nan")  # noqa: E731
    return {
        "pixels_both": int(both.sum()),
        "pixels_interior": int(interior.sum()),
        "within_1mm_all": frac(both),
        "within_1mm_interior": frac(interior),
        "max_error_interior_m": float(err[interior].max()) if interior.any() else float("nan"),
        "median_error_m": float(np.median(err[both])) if both.any() else float("nan"),
    }


def _time(fn, repeat: int = 1) -> float:
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat


def bench_renderers(config: BenchConfig | None = None) -> list[dict]:
    """Per gear and view, hypotheses per second of: Drake on the full image, Drake on the crop of
    the image where the gear can be, ours on every pixel of that crop that can see the gear, ours
    on the sparse pixels the search uses (SearchConfig.fine_pixels on the gear); and the depth
    agreement of ours with Drake (full images)."""
    config = config or BenchConfig()
    rng = np.random.default_rng(config.seed)
    rows = []
    for gear in config.gears:
        x, y = 0.42, -0.05
        scene = DrakeScene(SceneConfig(gears={gear: (x, y, 0.0)}))
        caster = RayCaster(gear_model(gear))
        n = config.hypotheses
        poses = np.column_stack(
            [x + rng.uniform(-0.01, 0.01, n), y + rng.uniform(-0.01, 0.01, n), rng.uniform(-np.pi, np.pi, n)]
        )
        for view, camera in _views(x, y).items():
            scene.render(camera, camera.X_PC)  # warm up the renderer
            drake = []

            def drake_full():
                drake.clear()
                for pose in poses:
                    scene.set_gear_pose(gear, tuple(pose))
                    drake.append(scene.render(camera, camera.X_PC))

            t_full = _time(drake_full)
            k = drake[0].intrinsics
            # The pixels whose rays can meet the gear anywhere in the pose box, and their crop.
            v, u = np.mgrid[0 : k.height, 0 : k.width]
            origin, dirs = drake[0].rays_W(u.ravel(), v.ravel())
            down = dirs[:, 2] < 0
            hit = origin[:2] + (-origin[2] / np.where(down, dirs[:, 2], -1.0))[:, None] * dirs[:, :2]
            reach = caster.model.tip_radius + 0.015 + 0.03
            roi = down & (np.hypot(hit[:, 0] - x, hit[:, 1] - y) < reach)
            rows_, cols_ = np.nonzero(roi.reshape(k.height, k.width))
            info = crop_info(camera.info(), cols_.min(), cols_.max() + 1, rows_.min(), rows_.max() + 1)

            def drake_crop():
                for pose in poses:
                    scene.set_gear_pose(gear, tuple(pose))
                    scene.render_info(info, camera.near, camera.far, camera.X_PC)

            t_crop = _time(drake_crop)
            light = -camera.X_PC.rotation().matrix()[:, 2]
            caster.render(origin, dirs[roi][:1], light, poses[:1])  # warm up: load the compiled loops
            out = None

            def ours_all():
                nonlocal out
                out = caster.render(origin, dirs[roi], light, poses)

            t_ours = _time(ours_all)
            footprint = int(np.count_nonzero(roi & (np.hypot(hit[:, 0] - x, hit[:, 1] - y) < caster.model.tip_radius)))
            m = max(1, round(footprint / SearchConfig().fine_pixels))
            sparse = np.nonzero(roi)[0][::m]
            t_sparse = _time(lambda: caster.render(origin, dirs[sparse], light, poses), repeat=3)
            agree = []
            idx = np.nonzero(roi)[0]
            for h, obs in enumerate(drake):
                depth = np.full(k.height * k.width, np.inf, np.float32)
                sel = out.hyp == h
                depth[idx[out.pix[sel]]] = out.depth[sel]
                agree.append(compare_depth(obs.depth, gear_mask(obs), depth.reshape(k.height, k.width)))
            rows.append(
                {
                    "gear": gear,
                    "view": view,
                    "hypotheses": n,
                    "drake_full_hypotheses_per_second": n / t_full,
                    "drake_crop_hypotheses_per_second": n / t_crop,
                    "drake_crop_pixels": int(info.width() * info.height()),
                    "ours_all_hypotheses_per_second": n / t_ours,
                    "ours_all_pixels": int(roi.sum()),
                    "ours_sparse_hypotheses_per_second": n / t_sparse,
                    "ours_sparse_pixels": int(len(sparse)),
                    "within_1mm_interior": float(np.mean([a["within_1mm_interior"] for a in agree])),
                    "within_1mm_all": float(np.mean([a["within_1mm_all"] for a in agree])),
                    "max_error_interior_m": float(np.max([a["max_error_interior_m"] for a in agree])),
                    "median_error_m": float(np.median([a["median_error_m"] for a in agree])),
                }
            )
    return rows


def bench_posteriors(config: BenchConfig | None = None) -> dict:
    """Whole close-view posteriors (search + grid) per gear: seconds each, hypotheses per second."""
    config = config or BenchConfig()
    rng = np.random.default_rng(config.seed + 1)
    seconds, hyps, rows = [], [], []
    for gear in config.gears:
        scene = DrakeScene(SceneConfig(gears={gear: (0.42, -0.05, 0.0)}))
        # Untimed: the compiled loops (numba; cached on disk after a machine's first run) and the
        # gear's height map are made once per process, not per posterior.
        camera = close_camera(0.42, -0.05)
        estimate_pose(scene.render(camera, camera.X_PC), gear, Prior(0.42, -0.05, 0.005))
        for _ in range(config.posteriors):
            truth = np.array(
                [0.42 + rng.uniform(-0.01, 0.01), -0.05 + rng.uniform(-0.01, 0.01), rng.uniform(-np.pi, np.pi)]
            )
            scene.set_gear_pose(gear, tuple(truth))
            camera = close_camera(truth[0] + rng.uniform(-0.02, 0.02), truth[1] + rng.uniform(-0.02, 0.02))
            obs = scene.render(camera, camera.X_PC)
            prior = Prior(truth[0] + rng.uniform(-0.01, 0.01), truth[1] + rng.uniform(-0.01, 0.01))
            t0 = time.perf_counter()
            post = estimate_pose(obs, gear, prior)
            dt = time.perf_counter() - t0
            seconds.append(dt)
            hyps.append(post.info["hypotheses"])
            rows.append(
                {
                    "gear": gear,
                    "seconds": dt,
                    "hypotheses": post.info["hypotheses"],
                    "xy_error_m": float(np.hypot(*(post.map_pose[:2] - truth[:2]))),
                }
            )
    return {
        "seconds_per_posterior": float(np.mean(seconds)),
        "hypotheses_per_second": float(np.sum(hyps) / np.sum(seconds)),
        "renderer": RAYCAST_NAME,
        "rows": rows,
    }


def bench_scenes(config: BenchConfig | None = None) -> dict:
    """The scene camera's whole first look, per random scene (seeds from 9000, never tuned on):
    global detection plus a far posterior for every gear found; seconds per scene (rendering
    excluded) and per stage."""
    config = config or BenchConfig()
    renderer = SceneRenderer()
    rows = []
    for scene in random_scenes(9000 + config.seed, config.posteriors):
        obs = renderer.render_view(scene, "scene", None, "clean", scene.rng("bench")).obs
        t0 = time.perf_counter()
        detections = detect_gears(obs)
        t1 = time.perf_counter()
        for gear, det in detections.items():
            if det.seen:
                estimate_pose(obs, gear_model(gear), det.prior)
        t2 = time.perf_counter()
        rows.append(
            {"detect_seconds": t1 - t0, "posteriors_seconds": t2 - t1, "seen": sum(d.seen for d in detections.values())}
        )
    return {
        "seconds_per_scene": float(np.mean([r["detect_seconds"] + r["posteriors_seconds"] for r in rows])),
        "detect_seconds": float(np.mean([r["detect_seconds"] for r in rows])),
        "rows": rows,
    }


def bench_perception(config: BenchConfig | None = None) -> dict:
    """What `goflow bench perception` reports: {"seconds_per_posterior", "hypotheses_per_second",
    "renderer"} for close-view posteriors with the renderer the pipeline uses, and
    "seconds_per_scene": detection plus the far posteriors of every gear, per scene-camera image
    (`posteriors` scenes)."""
    result = bench_posteriors(config)
    out = {k: result[k] for k in ("seconds_per_posterior", "hypotheses_per_second", "renderer")}
    out["seconds_per_scene"] = bench_scenes(config)["seconds_per_scene"]
    return out
