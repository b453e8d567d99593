"""Global first stage: find every gear anywhere in the placement region in one scene-camera image,
and give each a small prior box for the fine pose search (`perception.search`).

Method (per gear, from colour, depth, the known table plane z = 0, the gears' colours and sizes):

1. Colour. Chromaticity rgb / (r + g + b) does not change with the light's intensity or the
   shading. A pixel blending two surfaces has a chromaticity on the line between theirs, so each
   gear gets a tube around the line from the table's chromaticity to its own: a pixel in the tube
   past the middle is the gear's colour, before the middle the table's. Too dark a pixel (a wall
   facing away from an oblique light) has no usable colour and is neither.
2. Height. Back-projected through its depth, a gear pixel lies at most `max_height` above the
   table and inside the placement region (plus a margin): a hand or a carried gear above is no
   gear on the table. Table-coloured pixels that are also low, and not in front of the gear
   pixel they border, are the background.
3. Pixels. Connected components (OpenCV) of the gear's pixels, closed over dropped-out depth
   pixels; the largest with those nearby (one gear can be cut in two by an occluder), holes
   (the bore) filled.
4. Outline fit. Every edge between a gear pixel and a background pixel is a ray that grazes the
   gear: between the heights of its top face and the table, its x-y path passes at the gear's
   outline radius from the axis (far side: it grazes the top rim; near side: the foot of the wall).
   A Gauss-Newton fit of the centre to those rays (Huber-weighted), with the radius known,
   needs no depth (noise- and dropout-proof) and only the part of the outline that is seen:
   edges against an occluder or a dark wall are not background edges and say nothing.
5. Checks. The fit's standard error must be small; at least `min_visible` of the fitted gear's
   predicted silhouette must be seen (its colour, or too dark but low: a wall in shadow; else it
   is hidden, or the fit is wrong), and the silhouette must explain its colour's pixels. The
   prior box's half-width grows with the fit's standard error and with the hidden part.

A gear that fails is reported `seen = False` with a one-line reason, never with a pose.
Measured accuracy and speed: docs/perception.md, "Global detection" (benchmarks/detection.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from assembly.gearset import GEAR_NAMES, GEAR_THICKNESS, gear_spec
from assembly.world import PLACEMENT_X, PLACEMENT_Y
from perception.likelihood import table_albedo
from perception.observation import Intrinsics, Observation
from perception.search import Prior
from perception.table_plane import aligned_to_table

__all__ = ["Detection", "DetectionConfig", "detect_gears"]


@dataclass
class DetectionConfig:
    """Settings of `detect_gears` (SI units).

    max_height: gear pixels lie at most this far above the table (tops at 20 mm; an occluder is
    higher); region_margin: how far beyond the placement region (plus the gear's radius) a gear
    pixel may be; min_brightness: r + g + b below which a pixel's colour is not judged; tube:
    chromaticity distance from the table-gear colour line; close_px: closing of the gear's mask
    over dropped-out pixels; min_pixels: fewer gear pixels -> not seen; radius_offset: the fitted
    outline's radius minus the gear's pitch radius (the silhouette of the teeth); min_edges: fewer
    background edges -> not seen; min_visible: seen part of the fitted gear's predicted silhouette;
    max_extra: share of the gear's pixels outside it; huber: residual scale of the fit [m];
    occluder_gap: a background pixel this much nearer than the gear pixel beside it is in front;
    half-width of the prior box: `base_half_width` + `sigma_scale` x the fit's standard error +
    `hidden_scale` x tip radius x hidden part of the outline, clipped to [min, max]."""

    max_height: float = 0.030
    region_margin: float = 0.02
    min_brightness: float = 0.10
    tube: float = 0.08
    close_px: int = 3
    min_pixels: int = 20
    radius_offset: float = 0.0005
    min_edges: int = 12
    min_visible: float = 0.25
    max_extra: float = 0.25
    huber: float = 0.001
    occluder_gap: float = 0.005
    base_half_width: float = 0.003
    sigma_scale: float = 6.0
    hidden_scale: float = 0.25
    min_half_width: float = 0.004
    max_half_width: float = 0.03
    fit_iterations: int = 20

    def __post_init__(self) -> None:
        for name in (
            "max_height",
            "region_margin",
            "tube",
            "huber",
            "occluder_gap",
            "base_half_width",
            "sigma_scale",
            "min_half_width",
            "max_half_width",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"DetectionConfig.{name} = {value}; expected a finite value > 0")
        if not self.min_half_width <= self.max_half_width <= 0.2:
            raise ValueError(
                f"DetectionConfig half-widths {self.min_half_width}, "
                f"{self.max_half_width}; expected min <= max <= 0.2 m (a Prior's limit)"
            )
        if not (np.isfinite(self.hidden_scale) and self.hidden_scale >= 0):
            raise ValueError(f"DetectionConfig.hidden_scale = {self.hidden_scale}; expected >= 0")
        for name in ("min_visible", "max_extra"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"DetectionConfig.{name} = {getattr(self, name)}; expected [0, 1]")
        for name in ("close_px", "min_pixels", "min_edges", "fit_iterations"):
            if getattr(self, name) < 1:
                raise ValueError(f"DetectionConfig.{name} = {getattr(self, name)}; expected >= 1")


@dataclass
class Detection:
    """One gear's detection. seen: found on the table; prior: a box around the fitted centre for
    the fine search (None when not seen); pixels: its colour's pixels attributed to it; score:
    confidence in [0, 1] (seen part of the predicted silhouette x share of its pixels explained);
    reason: why not seen (empty when seen); visible: seen fraction of the fitted gear's predicted
    silhouette; edges: outline edges against the background used by the fit; std: the fit's
    standard error along its worst direction [m]."""

    gear: str
    seen: bool
    prior: Prior | None = None
    pixels: int = 0
    score: float = 0.0
    reason: str = ""
    visible: float = 0.0
    edges: int = 0
    std: float = float("nan")


@dataclass
class _Image:
    """What every gear's detection shares, per pixel: chromaticity relative to the table's and its
    squared norm, brightness ok, and 'low' (valid depth, at most max_height above the table, x-y
    near the placement region)."""

    obs: Observation
    rel: np.ndarray  # (H, W, 3) chromaticity minus the table's
    rel2: np.ndarray  # (H, W) its squared norm
    bright: np.ndarray  # (H, W) r + g + b >= min_brightness
    low: np.ndarray  # (H, W)


def detect_gears(
    obs: Observation, gears: tuple[str, ...] = GEAR_NAMES, config: DetectionConfig | None = None
) -> dict[str, Detection]:
    """Detect each of `gears` lying flat on the table in the placement region from one RGB-D
    observation (the station's scene camera, or any camera that sees the table from above).
    ValueError on a non-Observation, an unknown gear or a camera that does not see the region."""
    if not isinstance(obs, Observation):
        raise ValueError(f"obs is {type(obs).__name__}; expected a perception.observation.Observation")
    if isinstance(gears, str):
        raise ValueError(f"gears = {gears!r}; expected a tuple of gear names, e.g. {GEAR_NAMES}")
    for g in gears:
        gear_spec(g)
    config = config or DetectionConfig()
    if not isinstance(config, DetectionConfig):
        raise ValueError(f"config is {type(config).__name__}; expected a DetectionConfig")
    _check_sees_region(obs, config)
    image = _prepare(aligned_to_table(obs), config)
    return {g: _detect(image, g, config) for g in gears}


def _region(margin: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The placement region grown by `margin` [m] on every side."""
    return ((PLACEMENT_X[0] - margin, PLACEMENT_X[1] + margin), (PLACEMENT_Y[0] - margin, PLACEMENT_Y[1] + margin))


def _check_sees_region(obs: Observation, config: DetectionConfig) -> None:
    """ValueError unless some pixel's ray reaches the table inside the placement region."""
    k = obs.intrinsics
    v, u = np.mgrid[0 : k.height : 8, 0 : k.width : 8]
    origin, dirs = obs.rays_W(u.ravel(), v.ravel())
    down = dirs[:, 2] < -1e-9
    t = -origin[2] / np.where(down, dirs[:, 2], -1.0)
    x, y = origin[0] + t * dirs[:, 0], origin[1] + t * dirs[:, 1]
    (x0, x1), (y0, y1) = _region(0.0)
    if origin[2] <= 0 or not np.any(down & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)):
        raise ValueError(
            f"the observation's camera at {np.round(origin, 3).tolist()} sees no part "
            f"of the placement region x {PLACEMENT_X}, y {PLACEMENT_Y} m on the table; "
            "expected a camera above the table looking at it"
        )


@lru_cache(maxsize=8)
def _camera_rays(k: Intrinsics) -> np.ndarray:
    """(H, W, 3) camera-frame ray directions (unit z) of every pixel of a camera."""
    v, u = np.mgrid[0 : k.height, 0 : k.width]
    return k.rays_C(u.ravel(), v.ravel()).reshape(k.height, k.width, 3).astype(np.float32)


def _prepare(obs: Observation, config: DetectionConfig) -> _Image:
    """The per-pixel data every gear's detection shares."""
    R = obs.X_WC.rotation().matrix().astype(np.float32)
    origin = obs.X_WC.translation()
    valid = obs.valid
    depth = np.where(valid, obs.depth, 0.0).astype(np.float32)
    dirs = _camera_rays(obs.intrinsics) @ R.T
    margin = config.region_margin + max(gear_spec(g).tip_radius for g in GEAR_NAMES)
    (x0, x1), (y0, y1) = _region(margin)
    x = origin[0] + depth * dirs[..., 0]
    y = origin[1] + depth * dirs[..., 1]
    z = origin[2] + depth * dirs[..., 2]
    low = valid & (z <= config.max_height) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    rgb = obs.rgb
    brightness = rgb[..., 0] + rgb[..., 1] + rgb[..., 2]
    rel = rgb / np.maximum(brightness, 1e-6)[..., None] - _chromaticity(table_albedo())
    rel2 = rel[..., 0] ** 2 + rel[..., 1] ** 2 + rel[..., 2] ** 2
    return _Image(obs, rel, rel2, brightness >= config.min_brightness, low)


def _chromaticity(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float32)
    return rgb / rgb.sum()


def _colour_classes(image: _Image, gear: str, config: DetectionConfig) -> tuple[np.ndarray, np.ndarray]:
    """(gear-coloured, table-coloured) masks: bright pixels within `tube` of the line from the
    table's chromaticity to the gear's, past its middle or before it."""
    line = _chromaticity(gear_spec(gear).rgba[:3]) - _chromaticity(table_albedo())
    t = image.rel @ (line / (line @ line))
    perp2 = image.rel2 - t * t * (line @ line)
    ok = (perp2 < config.tube**2) & image.bright
    return ok & (t > 0.5) & (t < 1.6), ok & (t <= 0.5) & (t > -0.6)


def _gear_mask(
    positive: np.ndarray, image: _Image, gear: str, config: DetectionConfig
) -> tuple[np.ndarray, tuple[slice, slice], int]:
    """The gear's filled mask in a window around it (the largest component of its pixels and the
    components within a gear's diameter of it, closed over dropped-out pixels, holes filled; the
    window pads it by half its size), the window, and the gear's pixels in it."""
    kernel = np.ones((config.close_px, config.close_px), np.uint8)
    closed = cv2.morphologyEx(positive.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(closed, connectivity=8)
    if n <= 1:
        return np.zeros((0, 0), bool), (slice(0, 0), slice(0, 0)), 0
    main = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    # The gear's diameter in pixels, from the distance of the main component's centre.
    cu, cv = (int(round(c)) for c in centroids[main])
    patch = image.obs.depth[max(cv - 2, 0) : cv + 3, max(cu - 2, 0) : cu + 3]
    depth = float(np.nanmedian(patch)) if np.isfinite(patch).any() else 1.0
    reach = 2.2 * gear_spec(gear).tip_radius * image.obs.intrinsics.fx / max(depth, 1e-3)
    near = 1 + np.nonzero(np.hypot(*(centroids[1:] - centroids[main]).T) <= reach)[0]
    u0, v0 = stats[near, cv2.CC_STAT_LEFT].min(), stats[near, cv2.CC_STAT_TOP].min()
    u1 = (stats[near, cv2.CC_STAT_LEFT] + stats[near, cv2.CC_STAT_WIDTH]).max()
    v1 = (stats[near, cv2.CC_STAT_TOP] + stats[near, cv2.CC_STAT_HEIGHT]).max()
    pad = max(8, int(0.5 * max(u1 - u0, v1 - v0)))
    h, w = positive.shape
    window = (slice(max(v0 - pad, 0), min(v1 + pad, h)), slice(max(u0 - pad, 0), min(u1 + pad, w)))
    mask = np.isin(labels[window], near).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(mask)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    filled = filled.astype(bool)
    return filled, window, int(np.count_nonzero(positive[window] & filled))


def _outline_edges(mask: np.ndarray, background: np.ndarray, depth: np.ndarray, gap: float) -> np.ndarray:
    """(n, 2) pixel coordinates (u, v) in the mask's array of the midpoints between a mask pixel
    and a 4-neighbouring background pixel that is not more than `gap` nearer to the camera (a
    nearer one, e.g. a shaft in front, hides the outline instead of bordering it; a mask pixel
    without depth is not compared)."""
    points = []
    h, w = mask.shape
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        outside = np.zeros_like(mask)
        src = (slice(max(-dv, 0), h - max(dv, 0)), slice(max(-du, 0), w - max(du, 0)))
        dst = (slice(max(dv, 0), h - max(-dv, 0)), slice(max(du, 0), w - max(-du, 0)))
        with np.errstate(invalid="ignore"):
            behind = ~(depth[dst] < depth[src] - gap)
        outside[src] = background[dst] & ~mask[dst] & behind
        vv, uu = np.nonzero(mask & outside)
        points.append(np.column_stack([uu + 0.5 * du, vv + 0.5 * dv]))
    return np.concatenate(points).astype(np.float64)


def _segments(obs: Observation, uv: np.ndarray, top: float) -> tuple[np.ndarray, np.ndarray]:
    """x-y endpoints (n, 2), (n, 2) of the rays through pixel coordinates `uv` at heights `top`
    and 0 (the table)."""
    origin, dirs = obs.rays_W(uv[:, 0], uv[:, 1])
    dz = np.minimum(dirs[:, 2], -1e-9)
    a = origin[:2] + ((top - origin[2]) / dz)[:, None] * dirs[:, :2]
    b = origin[:2] + ((0.0 - origin[2]) / dz)[:, None] * dirs[:, :2]
    return a, b


def _segment_distance(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances (n,) from point `c` to segments [a, b] and the closest points (n, 2)."""
    ab = b - a
    s = np.clip(((c - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0.0, 1.0)
    closest = a + s[:, None] * ab
    return np.linalg.norm(c - closest, axis=-1), closest


def _fit_centre(
    a: np.ndarray, b: np.ndarray, radius: float, start: np.ndarray, config: DetectionConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Centre whose distance to each segment is `radius` (Huber-weighted Gauss-Newton from
    `start`); returns the centre and its covariance (from the weighted residuals)."""
    c = np.asarray(start, float).copy()
    for _ in range(config.fit_iterations):
        dist, closest = _segment_distance(c, a, b)
        r = dist - radius
        J = (c - closest) / np.maximum(dist, 1e-9)[:, None]
        w = np.minimum(1.0, config.huber / np.maximum(np.abs(r), 1e-12))
        H = (J * w[:, None]).T @ J + 1e-12 * np.eye(2)
        step = -np.linalg.solve(H, (J * w[:, None]).T @ r)
        c += step
        if np.linalg.norm(step) < 1e-6:
            break
    dist, closest = _segment_distance(c, a, b)
    r = dist - radius
    J = (c - closest) / np.maximum(dist, 1e-9)[:, None]
    w = np.minimum(1.0, config.huber / np.maximum(np.abs(r), 1e-12))
    H = (J * w[:, None]).T @ J + 1e-12 * np.eye(2)
    sigma2 = float((w * r * r).sum() / max(w.sum() - 2, 1.0))
    return c, sigma2 * np.linalg.inv(H)


def _silhouette(obs: Observation, window: tuple[slice, slice], centre: np.ndarray, radius: float) -> np.ndarray:
    """The predicted silhouette in `window`: pixels whose ray passes within `radius` of the
    vertical axis at `centre` between the table and the gears' top."""
    v, u = np.mgrid[window]
    a, b = _segments(obs, np.column_stack([u.ravel(), v.ravel()]).astype(float), GEAR_THICKNESS)
    dist, _ = _segment_distance(centre, a, b)
    return (dist <= radius).reshape(u.shape)


def _detect(image: _Image, gear: str, config: DetectionConfig) -> Detection:
    """One gear's detection from the shared per-pixel data."""
    spec = gear_spec(gear)
    colour, table = _colour_classes(image, gear, config)
    positive = colour & image.low
    count = int(np.count_nonzero(positive))
    if count < config.min_pixels:
        return Detection(
            gear,
            False,
            pixels=count,
            reason=(
                f"{count} pixels of its colour at table height in the placement region (need "
                f"{config.min_pixels}): out of view, hidden or not on the table"
            ),
        )
    mask, window, pixels = _gear_mask(positive, image, gear, config)
    if pixels < config.min_pixels:
        return Detection(
            gear,
            False,
            pixels=pixels,
            reason=(
                f"its colour's pixels are scattered (largest group {pixels} px, need "
                f"{config.min_pixels}): mostly hidden, or not a gear"
            ),
        )
    offset = np.array([window[1].start, window[0].start], float)
    edges = (
        _outline_edges(mask, table[window] & image.low[window], image.obs.depth[window], config.occluder_gap) + offset
    )
    if len(edges) < config.min_edges:
        return Detection(
            gear,
            False,
            pixels=pixels,
            edges=len(edges),
            reason=(
                f"{len(edges)} outline edges against the table (need {config.min_edges}): too little "
                "of its outline is seen"
            ),
        )
    obs = image.obs
    a, b = _segments(obs, edges, GEAR_THICKNESS)
    vs, us = np.nonzero(mask)
    start, _ = _segments(obs, np.column_stack([us, vs]) + offset, GEAR_THICKNESS)
    radius = spec.pitch_radius + config.radius_offset
    centre, cov = _fit_centre(a, b, radius, start.mean(0), config)
    std = float(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))
    if not (np.all(np.isfinite(centre)) and config.sigma_scale * std <= config.max_half_width):
        return Detection(
            gear,
            False,
            pixels=pixels,
            edges=len(edges),
            std=std,
            reason=(
                f"the {len(edges)} outline edges seen do not fix its centre (standard error "
                f"{1e3 * std:.1f} mm): too little or too odd an outline"
            ),
        )
    predicted = _silhouette(obs, window, centre, radius)
    # Too dark to judge but low (a wall facing away from the light) is the gear, not an occluder.
    shown = mask | (~image.bright[window] & image.low[window])
    visible = float(np.count_nonzero(predicted & shown)) / max(np.count_nonzero(predicted), 1)
    extra = float(np.count_nonzero(mask & ~predicted)) / max(np.count_nonzero(mask), 1)
    score = float(np.clip(visible * (1.0 - extra), 0.0, 1.0))
    common = dict(pixels=pixels, score=score, visible=visible, edges=len(edges), std=std)
    if visible < config.min_visible:
        return Detection(
            gear,
            False,
            reason=(
                f"only {100 * visible:.1f} % of the fitted gear's silhouette is seen (need "
                f"{100 * config.min_visible:.1f} %): hidden, or its pixels are not this gear"
            ),
            **common,
        )
    if extra > config.max_extra:
        return Detection(
            gear,
            False,
            reason=(
                f"{100 * extra:.1f} % of its colour's pixels lie outside the fitted gear (allowed "
                f"{100 * config.max_extra:.1f} %): not a gear of this size"
            ),
            **common,
        )
    half = config.base_half_width + config.sigma_scale * std + config.hidden_scale * spec.tip_radius * (1.0 - visible)
    half = float(np.clip(half, config.min_half_width, config.max_half_width))
    return Detection(gear, True, Prior(float(centre[0]), float(centre[1]), half), **common)
