"""The perception channel of the diagnosis: a camera off its calibrated pose.

The simulated reality (`make_perception_log`) renders the station's scene camera from its TRUE
pose, the calibrated (nominal) pose moved by the catalogue's `camera_offset` (dx, dy, dz in the
camera's own frame), while the perception pipeline is handed the CALIBRATED pose: exactly what a
miscalibrated extrinsic does. The effect lives in the rendering (Drake's RenderEngineVtk renders
the offset camera); nothing is painted onto the results. The pipeline is the project's own first
look of the scene camera (perception.calibration / perception.speed): global detection
(`detect_gears`) and the far posterior of every gear found (`estimate_pose` within the detection's
prior). The log records, per scene and gear, the posterior's mean and std (x, y, yaw), whether the
gear was seen and whether its posterior is informative, and the true pose (what the robot measures
once it has picked and placed the gear: the reality's ground truth).

`perception_evidence` turns a log into the analysis' evidence: one residual channel "pose", one row
per scene, seven columns

    POSE_COLUMNS = ["x small", "y small", "x medium", "y medium", "x large", "y large", "yaw"]

(estimated minus true [m]; "yaw" is the mean over the scene's gears of the yaw error wrapped to each
gear's symmetry period [rad]). A gear that was not seen contributes zero residual and zero
prediction. Each column has a reference std, the RMS of its informative posteriors' own standard
deviations (of all its seen ones where none is informative); a row whose posterior is wider (an
uninformative one: the detection's box) is scaled, residual and prediction alike, by reference /
its std, which weights it by its own precision. The noise floor of each column is the reference
std (`Evidence.floor`: one row per scene has no time to estimate it from; the yaw column's: that
of a mean of three gears).

The candidate for `camera_offset` is linear in d = (dx, dy, dz) (camera frame), to first order,
through the pipeline's geometry. A point P seen by the true camera at camera-frame position p is
placed by the calibrated pose at X_WC_nominal p = P - R_WC d: the whole point cloud shifts rigidly
by s = -R_WC d. A gear at rest on the table is then either moved with the cloud ("rigid": the
depth dominates, Delta_xy = s_xy) or placed where the calibrated camera's ray through its shifted
top meets the height of a gear top ("ray": the silhouette dominates). The candidates are a grid
over alpha in ALPHAS, Delta = (1 - alpha) Delta_rigid + alpha Delta_ray, both Jacobians by central
finite differences of that geometry at each gear's true pose; the fit chooses alpha (the setting)
and d within the catalogue's bounds.

Cross-validation is over scenes: `perception_config` makes one block per scene with a gear seen
and leave-one-scene-out folds (blocks = folds = scenes) below 20 scenes, the default 20 blocks in
5 folds from 20 scenes on.

The option `depth_bias` of `make_perception_log` (a constant added to the rendered depth [m]) is
OUTSIDE the catalogue and only for tests. The pipeline reads the depth's scale off the table and
divides it out (perception.table_plane) before detection and search, so a constant bias is mostly
removed there: a 1 cm bias leaves no gap beyond the floor's uncertainty, and nothing of its size is
named (before that alignment the diagnosis called it unexplained).
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from goflow_common.errors import InputError
from sim2real.catalogue import CATALOGUE, effect
from sim2real.diagnosis import Diagnosis, DiagnosisConfig, Evidence, Progress, analyse
from sim2real.effects import Candidate

__all__ = [
    "POSE_COLUMNS",
    "PERCEPTION_EFFECTS",
    "ALPHAS",
    "make_perception_log",
    "perception_evidence",
    "perception_config",
    "diagnose_perception",
    "offset_jacobians",
]

Array = NDArray[np.float64]

POSE_COLUMNS = ["x small", "y small", "x medium", "y medium", "x large", "y large", "yaw"]
#: The catalogue's effects the perception channel can show.
PERCEPTION_EFFECTS: tuple[str, ...] = tuple(n for n, e in CATALOGUE.items() if e.place == "perception")
#: How far along the calibrated camera's ray a gear is placed (0: with the rigidly shifted cloud,
#: 1: where the ray through its shifted top meets the gear-top height).
ALPHAS: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)
CAMERAS = ("scene",)
_CHANNEL = "pose"
_FD_STEP = 1e-3  # [m] finite-difference step of the offset Jacobians


def _check_effects(effects: dict) -> dict[str, float]:
    """{"camera_offset": {"dx": .., "dy": .., "dz": ..}} -> the offset's (dx, dy, dz) by name;
    InputError naming an unknown effect, one that is not a perception effect, an unknown parameter
    or a value outside the catalogue's range."""
    if not isinstance(effects, dict):
        raise InputError(
            f"effects is {type(effects).__name__}; expected a dict such as "
            "{'camera_offset': {'dx': 0.01, 'dy': 0.0, 'dz': 0.0}}"
        )
    out = {"dx": 0.0, "dy": 0.0, "dz": 0.0}
    for name, params in effects.items():
        eff = effect(name)  # InputError for an unknown name
        if eff.place != "perception":
            raise InputError(
                f"effect {name!r} acts in {eff.place!r}; the perception log takes only "
                f"perception effects {list(PERCEPTION_EFFECTS)}"
            )
        if not isinstance(params, dict):
            raise InputError(f"effect {name!r}: parameters {params!r}; expected a dict {{param: value}}")
        for pname, value in params.items():
            spec = eff.param(pname)  # InputError for an unknown parameter
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise InputError(f"{name}.{pname} = {value!r}; expected a number [{spec.unit}]") from None
            if not (spec.low <= v <= spec.high):
                raise InputError(
                    f"{name}.{pname} = {v:g} {spec.unit}; expected a value in [{spec.low:g}, {spec.high:g}] {spec.unit}"
                )
            out[pname] = v
    return out


def make_perception_log(
    effects: dict, scenes: int = 8, seed: int = 0, camera: str = "scene", *, depth_bias: float = 0.0
) -> dict[str, Any]:
    """Run the scene camera's first look on `scenes` random scenes (perception.scenes.random_scenes
    from `seed`) in a reality with `effects` ({} or {"camera_offset": {"dx", "dy", "dz"} [m], camera
    frame, each in the catalogue's range}): the image is rendered from the offset (true) camera,
    the pipeline (detect_gears, then estimate_pose per gear seen) gets the calibrated pose.

    Returns plain arrays: "gears" (3,), "mean", "std", "truth" (S, 3, 3) per scene and gear
    (x, y [m], yaw [rad]; mean/std NaN where not seen), "seen", "informative" (S, 3), "period" (3,)
    the gears' yaw symmetry periods [rad], "top" (3,) their top heights [m], "X_WC" (4, 4) the
    calibrated camera pose, "offset" (3,) the true (dx, dy, dz), "seconds" (S,) per scene,
    "camera", "seed", "effects" (JSON text) and "depth_bias" [m].

    `depth_bias` (keyword only, default 0) adds a constant to the rendered depth: a sensing error
    OUTSIDE the catalogue, for tests. InputError for an unknown or non-perception effect, an
    unknown parameter, a value out of range, an unsupported camera or fewer than 1 scene."""
    d = _check_effects(effects)
    if camera not in CAMERAS:
        raise InputError(f"camera = {camera!r}; expected one of {list(CAMERAS)}")
    if isinstance(scenes, bool) or not isinstance(scenes, (int, np.integer)) or scenes < 1:
        raise InputError(f"scenes = {scenes!r}; expected an integer >= 1")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed = {seed!r}; expected an integer >= 0")
    if not np.isfinite(depth_bias) or abs(depth_bias) > 0.05:
        raise InputError(f"depth_bias = {depth_bias!r}; expected a value in [-0.05, 0.05] m")

    from pydrake.math import RigidTransform

    from assembly.gearset import GEAR_NAMES
    from perception.detection import detect_gears
    from perception.gear_model import gear_model
    from perception.observation import Observation
    from perception.posterior import wrap
    from perception.scenes import SceneRenderer, random_scenes
    from perception.search import estimate_pose

    renderer = SceneRenderer()
    nominal = renderer.scene_camera
    offset = np.array([d["dx"], d["dy"], d["dz"]])
    # The true camera: the calibrated one moved by d along its own axes.
    renderer.scene_camera = dataclasses.replace(nominal, X_PC=nominal.X_PC @ RigidTransform(offset))
    gears = tuple(GEAR_NAMES)
    models = {g: gear_model(g) for g in gears}
    S, G = int(scenes), len(gears)
    mean = np.full((S, G, 3), np.nan)
    std = np.full((S, G, 3), np.nan)
    truth = np.zeros((S, G, 3))
    seen = np.zeros((S, G), dtype=bool)
    informative = np.zeros((S, G), dtype=bool)
    seconds = np.zeros(S)
    for s, scene in enumerate(random_scenes(int(seed), S)):
        t0 = time.perf_counter()
        view = renderer.render_view(scene, camera, None, "clean", scene.rng(camera, "clean"))
        depth = view.obs.depth + np.float32(depth_bias) if depth_bias else view.obs.depth
        obs = Observation(view.obs.rgb, depth, view.obs.intrinsics, nominal.X_PC)  # the calibrated pose
        detections = detect_gears(obs, gears)
        for i, g in enumerate(gears):
            truth[s, i] = scene.poses[g]
            det = detections[g]
            if not det.seen:
                continue
            try:
                post = estimate_pose(obs, models[g], det.prior)
            except ValueError:  # the prior's region out of view: as not seen
                continue
            seen[s, i] = True
            informative[s, i] = bool(post.informative)
            m = post.mean()
            m[2] = truth[s, i, 2] + wrap(m[2] - truth[s, i, 2], post.period)  # the nearest symmetric yaw
            mean[s, i], std[s, i] = m, post.std()
        seconds[s] = time.perf_counter() - t0
    return {
        "gears": np.array(gears),
        "mean": mean,
        "std": std,
        "truth": truth,
        "seen": seen,
        "informative": informative,
        "period": np.array([models[g].period for g in gears], float),
        "top": np.array([models[g].height_map().top for g in gears], float),
        "X_WC": nominal.X_PC.GetAsMatrix4(),
        "offset": offset,
        "seconds": seconds,
        "camera": camera,
        "seed": int(seed),
        "effects": json.dumps(effects, sort_keys=True),
        "depth_bias": float(depth_bias),
    }


def _ray_shift(X_WC: Array, P: Array, d: Array) -> Array:
    """Where the pipeline puts a gear whose top centre is at P (world) when the camera truly sits
    at the calibrated pose moved by d (camera frame): the calibrated camera's ray through the
    shifted point P - R d met at the height of P. Returns the x-y shift (2,)."""
    R, c = X_WC[:3, :3], X_WC[:3, 3]
    q = P - R @ d
    t = (P[2] - c[2]) / (q[2] - c[2])
    return (c + t * (q - c))[:2] - P[:2]


def offset_jacobians(X_WC: Array, P: Array) -> tuple[Array, Array]:
    """(J_rigid, J_ray), each (2, 3): the x-y shift of the estimate of a gear whose top centre is at
    world P per metre of camera offset d (camera frame), under the rigid cloud shift -R d and under
    the ray re-projection (`_ray_shift`, central finite differences)."""
    R = X_WC[:3, :3]
    J_rigid = -R[:2, :]
    J_ray = np.zeros((2, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = _FD_STEP
        J_ray[:, k] = (_ray_shift(X_WC, P, e) - _ray_shift(X_WC, P, -e)) / (2 * _FD_STEP)
    return J_rigid, J_ray


def save_perception_log(log: dict[str, Any], path: str | os.PathLike[str]) -> Path:
    """Write a perception log (make_perception_log) as an .npz of plain arrays, atomically (the
    path checked first); text entries become 0-d unicode arrays."""
    from goflow_common.files import check_output_file, write_atomic

    _check_log(log)
    target = check_output_file(path, "perception log")
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in log.items()})
    return write_atomic(target, buf.getvalue())


def load_perception_log(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a perception log written by save_perception_log (np.load with allow_pickle=False);
    FileNotFoundError when absent, FileFormatError naming the file when it is not one."""
    from goflow_common.errors import FileFormatError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no perception log at {path}")
    if not zipfile.is_zipfile(path):  # np.load would take it for a pickle and suggest loading it unsafely
        raise FileFormatError(f"{path}: not a perception log (.npz of plain arrays): not a zip archive")
    try:
        with np.load(path, allow_pickle=False) as data:
            log = {k: (data[k].item() if data[k].ndim == 0 else data[k]) for k in data.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        why = "it holds pickled objects" if "pickle" in str(exc) else str(exc)[:120]
        raise FileFormatError(f"{path}: not a perception log (.npz of plain arrays): {why}") from None
    try:
        _check_log(log)
    except InputError as exc:
        raise FileFormatError(f"{path}: {exc}") from None
    return log


def _check_log(log: dict) -> None:
    need = ("gears", "mean", "std", "truth", "seen", "informative", "period", "top", "X_WC")
    missing = [k for k in need if k not in log]
    if missing:
        raise InputError(f"perception log lacks {missing}; expected a log from make_perception_log")
    if np.shape(log["mean"])[1:] != (3, 3) or list(log["gears"]) != ["small", "medium", "large"]:
        raise InputError(
            f"perception log: gears {list(log['gears'])}, mean {np.shape(log['mean'])}; "
            "expected gears small, medium, large and (scenes, 3, 3) poses"
        )


def perception_evidence(log: dict) -> Evidence:
    """The evidence of a perception log for sim2real.diagnosis.analyse: the residual channel
    "pose" (T = scenes rows, POSE_COLUMNS; estimated minus true for every gear seen, a row whose
    posterior is wider than its column's reference std scaled down with its prediction), scenes
    without a gear seen invalid, the noise floor the reference std per column, and the
    camera_offset candidates (one per alpha in ALPHAS, linear in dx, dy, dz within the catalogue's
    bounds)."""
    _check_log(log)
    mean, std, truth = (np.asarray(log[k], float) for k in ("mean", "std", "truth"))
    use = np.asarray(log["seen"], bool) & np.asarray(log["informative"], bool)
    period, top, X_WC = np.asarray(log["period"], float), np.asarray(log["top"], float), np.asarray(log["X_WC"])
    seen = np.asarray(log["seen"], bool)
    T = mean.shape[0]
    err = np.where(seen[..., None], mean - truth, 0.0)
    err[..., 2] = np.where(seen, (err[..., 2] + period / 2) % period - period / 2, 0.0)
    # per column the reference std: the RMS of the informative posteriors' std (of every seen one
    # where none is informative); a row whose posterior is wider is scaled down by ref / its std
    # (with its prediction), i.e. weighted by its own precision within the column's floor
    ref = np.full((3, 3), np.nan)
    for i in range(3):
        for k in range(3):
            for m in (use[:, i], seen[:, i]):
                v = std[m, i, k]
                v = v[np.isfinite(v)]
                if len(v):
                    ref[i, k] = max(float(np.sqrt(np.mean(v**2))), 1e-6)
                    break
    scale = np.where(seen[..., None], np.minimum(1.0, ref[None] / np.where(seen[..., None], std, 1.0)), 0.0)
    scale = np.nan_to_num(scale)
    err = err * scale
    residual = np.zeros((T, 7))
    residual[:, 0:6] = err[..., :2].reshape(T, 6)
    n_seen = seen.sum(axis=1)
    residual[:, 6] = np.where(n_seen > 0, err[..., 2].sum(axis=1) / np.maximum(n_seen, 1), 0.0)
    floor = np.full(7, 1e-5)
    floor[0:6] = np.nan_to_num(ref[:, :2].reshape(6), nan=1e-5)
    yaw_ref = ref[:, 2][np.isfinite(ref[:, 2])]
    if len(yaw_ref):
        floor[6] = max(float(np.sqrt(np.mean(yaw_ref**2) / 3)), 1e-5)
    # the camera_offset candidates
    J_rigid = np.zeros((T, 3, 2, 3))
    J_ray = np.zeros((T, 3, 2, 3))
    for t in range(T):
        for i in range(3):
            if seen[t, i]:
                P = np.array([truth[t, i, 0], truth[t, i, 1], top[i]])
                J_rigid[t, i], J_ray[t, i] = offset_jacobians(X_WC, P)
                J_rigid[t, i] *= scale[t, i, :2, None]
                J_ray[t, i] *= scale[t, i, :2, None]
    spec = effect("camera_offset")
    bounds = np.array([[spec.param(p).low, spec.param(p).high] for p in ("dx", "dy", "dz")], float)
    pool = []
    for a in ALPHAS:
        J = (1.0 - a) * J_rigid + a * J_ray  # (T, gear, xy, 3)
        feats = np.zeros((T, 7, 3))
        feats[:, 0:6, :] = J.reshape(T, 6, 3)
        pool.append(
            Candidate(
                "camera_offset",
                {"alpha": a},
                {_CHANNEL: feats},
                {},
                ["dx", "dy", "dz"],
                bounds,
                lambda coef: {"dx": float(coef[0]), "dy": float(coef[1]), "dz": float(coef[2])},
            )
        )
    valid = n_seen > 0
    mask = np.zeros((T, 7), dtype=bool)
    mask[:, 0:6] = np.repeat(use, 2, axis=1)
    mask[:, 6] = valid
    effects = json.loads(str(log.get("effects", "{}")))
    meta = {
        "source": "perception",
        "camera": str(log.get("camera", "scene")),
        "scenes": T,
        "seed": int(log.get("seed", 0)),
        "seen": int(np.asarray(log["seen"]).sum()),
        "informative": int(use.sum()),
        "truth": effects,
    }
    return Evidence(
        residual={_CHANNEL: residual},
        labels={_CHANNEL: list(POSE_COLUMNS)},
        valid=valid,
        phase=np.zeros(T, dtype=np.int64),
        regions={"informative posterior": mask},
        pool={"camera_offset": pool},
        audit=None,
        x=np.repeat(np.arange(T, dtype=float)[:, None], 7, 1),
        x_label="scene",
        time=np.arange(T, dtype=float),
        meta=meta,
        floor={_CHANNEL: floor},
        notes=[
            f"perception channel: {int(seen.sum())} gears seen of {3 * T} in {T} scenes, "
            f"{int(use.sum())} with an informative posterior; residual = posterior "
            "mean - true pose, a wider posterior's row scaled by its precision"
        ],
    )


def perception_config(log: dict, **changes: Any) -> DiagnosisConfig:
    """The DiagnosisConfig a perception log needs: one block per scene with a gear seen and
    leave-one-scene-out folds below 20 such scenes (blocks = folds = their number),
    20 blocks in 5 folds from 20 on; 200 bootstrap resamples; `changes` override. InputError with
    fewer than 5 such scenes (the noise floor's smoothing needs 5 rows)."""
    n = int(np.any(np.asarray(log["seen"], bool), axis=1).sum())
    if n < 5:
        raise InputError(f"the perception log has {n} scenes with a gear seen; expected at least 5")
    blocks, folds = (20, 5) if n >= 20 else (n, n)
    return DiagnosisConfig(**{"blocks": blocks, "folds": folds, "bootstrap": 200, **changes})


def diagnose_perception(
    log: dict, config: DiagnosisConfig | None = None, progress: Progress | None = None
) -> Diagnosis:
    """Where, which and how far for a perception log (sim2real.diagnosis.analyse on
    `perception_evidence(log)`; `config` defaults to `perception_config(log)`, and one whose
    blocks exceed the log's valid scenes raises InputError). The Diagnosis's channel is "pose"."""
    ev = perception_evidence(log)
    c = config or perception_config(log)
    if c.blocks > int(ev.valid.sum()):
        raise InputError(
            f"DiagnosisConfig.blocks = {c.blocks}; the log has {int(ev.valid.sum())} scenes "
            "with a gear seen (one block needs at least one)"
        )
    if c.effects is not None:
        ev.pool = {k: v for k, v in ev.pool.items() if k in c.effects}
    d = analyse(ev, c, progress)
    d.extra["perception"] = {
        "informative": ev.meta["informative"],
        "scenes": ev.meta["scenes"],
        "true_offset": np.asarray(log.get("offset", np.zeros(3)), float).tolist(),
    }
    return d
