"""Scores pose hypotheses of one gear against one observation.

The region of interest is every pixel whose ray passes through the vertical cylinder the gear can
occupy anywhere in the search region; every m-th of them (a lattice fixed by the geometry, so that
dropped depth pixels remove samples instead of reshuffling them) is scored, a pixel without depth
on its colour alone. Before scoring, the image's conditions are read off the bare table around the
gear: a colour gain per channel (the light's intensity and direction scale the table and the gear's
top face alike; the colour scale follows the brightness) and the depth noise (which widens the
depth scale). A hypothesis predicts its rendered gear where its
rays hit the gear and the bare table elsewhere, so its log-likelihood over the region is the
no-gear log-likelihood (the same for all hypotheses) plus the sum, over the pixels its gear
covers, of (gear term - table term): only those pixels are rendered and summed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from perception.gear_model import GearModel
from perception.table_plane import deepest_peak
from perception.likelihood import LikelihoodConfig, pixel_terms, table_colour, table_depth, table_prediction
from perception.observation import VTK_PIXEL_OFFSET, Observation
from perception.renderer import RayCaster, RayCasterConfig


@dataclass
class Scores:
    """Per hypothesis: tempered log-likelihood relative to the no-gear image (`loglik`), how many
    sampled pixels its gear covers (`pixels`) and how many of those are inliers (`inliers`)."""

    loglik: np.ndarray
    pixels: np.ndarray
    inliers: np.ndarray


@dataclass
class ImageConditions:
    """What the bare table in the region says about the image: `gain` multiplies every predicted
    colour (r, g, b); `depth_noise` [m] is the robust standard deviation of the table's depth
    about its plane (noise, a bias and a ramp alike: how far the depth model is off; it widens the
    depth residual); `table_pixels` how many pixels they were read from (0: defaults kept);
    `pixel_noise` [m] the independent per-pixel depth noise alone (what the evidence factor
    discounts; a bias or a ramp leaves it at 0)."""

    gain: np.ndarray
    depth_noise: float
    table_pixels: int
    pixel_noise: float = 0.0


@dataclass
class _PixelSet:
    origin: np.ndarray
    dirs: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    delta_bg: np.ndarray  # table term of each pixel
    weight: float


class ImageScorer:
    """Hypotheses of `model` near (cx, cy) (within `radius` [m]) against `obs`."""

    def __init__(
        self,
        obs: Observation,
        model: GearModel,
        centre: tuple[float, float],
        radius: float,
        likelihood: LikelihoodConfig | None = None,
        raycaster: RayCasterConfig | None = None,
    ) -> None:
        self.obs, self.model = obs, model
        self.likelihood = likelihood or LikelihoodConfig()
        self.caster = RayCaster(model, raycaster)
        self.light = -obs.X_WC.rotation().matrix()[:, 2]
        top = model.height_map().top
        centre = np.asarray(centre, float)
        u0, u1, v0, v1 = _image_box(obs, centre, radius + model.tip_radius, top)
        v, u = np.mgrid[v0:v1, u0:u1]
        self._u, self._v = u.ravel(), v.ravel()
        origin, dirs = obs.rays_W(self._u, self._v)
        self.origin = origin
        # Distance of each ray's chord through the slab 0 <= z <= top to the search centre.
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (top - origin[2]) / dirs[:, 2]
            t1 = -origin[2] / dirs[:, 2]
        down = dirs[:, 2] < -1e-9
        a = origin[:2] + np.where(down, t0, 0.0)[:, None] * dirs[:, :2]
        b = origin[:2] + np.where(down, t1, 0.0)[:, None] * dirs[:, :2]
        ab = b - a
        w = np.clip(((centre - a) * ab).sum(1) / np.maximum((ab**2).sum(1), 1e-18), 0.0, 1.0)
        dist = np.linalg.norm(a + w[:, None] * ab - centre, axis=1)
        valid = obs.valid[self._v, self._u]
        self.roi = down & (dist <= radius + model.tip_radius)
        self.footprint = int(np.count_nonzero(down & (dist <= model.tip_radius)))
        self.roi_pixels = int(np.count_nonzero(self.roi))
        self.valid_fraction = float(valid[self.roi].mean()) if self.roi_pixels else 0.0
        self._dirs = dirs
        table = self.roi & valid
        self._table = _read_table(obs, self._u[table], self._v[table], dirs[table], origin)
        # Ground sampling distance at the search centre: metres of table per pixel.
        p_C = obs.X_WC.inverse().multiply(np.array([centre[0], centre[1], top]))
        self.gsd = float(max(p_C[2], 1e-3) / obs.intrinsics.fx)
        self._set_light(self.light)
        self.tempering = self.likelihood.tempering_for(model.name, self.gsd)

    def _set_light(self, light: np.ndarray) -> None:
        """Assume the light arrives from direction `light` (world, unit): read the image's
        conditions off the bare table under it and set the pixel model (colour differences grow
        with the light's brightness, a little slower than it: part of them, quantization and
        antialiased edges, does not scale, `LikelihoodConfig.colour_scale_for`; depth residuals
        widen with the noise)."""
        self.light = np.asarray(light, float)
        self.conditions = self._table.conditions(self.light)
        self.brightness = float(np.mean(self.conditions.gain))  # the light's colour gain, mean of r, g, b
        self.pixels_model = replace(
            self.likelihood,
            b_rgb=self.likelihood.colour_scale_for(self.brightness, self.gsd),
            b_d=float(np.hypot(self.likelihood.b_d, self.conditions.depth_noise)),
        )
        self._sets = {}

    def fit_light(self, pose: np.ndarray, stride: int, min_walls: int = 30, min_gain: float = 0.3) -> bool:
        """Estimate the light's direction from the gear's shading at `pose` (x, y, yaw) and use it
        if it explains the gear's colours clearly better than the current one; returns whether the
        light changed.

        Under a directional white light L, a pixel of albedo a and normal n shows a * max(0, n . L);
        the bare table (n = z) fixes L_z times the light's colour, so with k = table colour / table
        albedo, y = rgb / (a k) = max(0, n . (L / L_z)): in the two unknowns L_x / L_z and
        L_y / L_z, fitted (Huber-weighted Gauss-Newton, from the current light and from lights all
        round) on the unsaturated pixels whose depth the pose explains, the walls in their own
        shade included (left out, the fit cannot tell which side the light is on: the scene
        view sees the walls facing the camera only). Only the gear's walls and chamfers (normals
        off vertical) carry the horizontal part; with fewer than `min_walls` of them, or a fit
        that lowers the robust colour residual by less than `min_gain` of the current light's,
        the light is kept."""
        if self.conditions.table_pixels == 0 or self.light[2] <= 0:
            return False
        ps = self.pixels(stride)
        hits = self.caster.render(ps.origin, ps.dirs, self.light, np.asarray(pose, float)[None], surface=True)
        k = self.conditions.gain * self.light[2]  # table colour / table albedo, per channel
        depth = ps.depth[hits.pix]
        near = np.isfinite(depth) & (np.abs(depth - hits.depth) < 3 * self.pixels_model.b_d)
        denom = (hits.albedo * k).sum(1)
        y = ps.rgb[hits.pix].sum(1) / np.maximum(denom, 1e-6)
        # Dark pixels stay in: a wall in its own shade (y ~ 0) says the light is on its other side.
        seen = near & (denom > 0.05) & (ps.rgb[hits.pix].max(1) < 0.99)
        n, y = hits.normal[seen].astype(float), y[seen]
        walls = np.hypot(n[:, 0], n[:, 1]) > 0.5
        if np.count_nonzero(walls) < min_walls:
            return False
        m0 = self.light[:2] / self.light[2]

        def loss(mm):  # on the walls: the top faces fit any light alike
            pred = np.maximum(0.0, n[walls, :2] @ mm + n[walls, 2])
            return float(np.median(np.abs(y[walls] - pred)))

        # The hinge has local optima (a wall predicted dark never pulls): start from the current
        # light and from lights all round at a few elevations, keep the best fit.
        starts = [m0] + [
            np.array([np.cos(az), np.sin(az)]) / np.tan(el)
            for el in np.radians([30.0, 50.0, 70.0])
            for az in np.radians(np.arange(0.0, 360.0, 45.0))
        ]
        m = min((_fit_hinge(n, y, start) for start in starts), key=loss)
        if loss(m) > (1.0 - min_gain) * loss(m0):
            return False
        light = np.append(m, 1.0)
        self._set_light(light / np.linalg.norm(light))
        return True

    def stride_for(self, target: int) -> int:
        """The subsampling factor m at which a gear at the centre covers about `target` of the
        sampled pixels (every m-th pixel of the region in raster order is used)."""
        return max(1, int(round(self.footprint / max(target, 1))))

    def pixels(self, stride: int) -> _PixelSet:
        """Every `stride`-th pixel of the region in raster order (cached); pixels without depth
        carry NaN depth and are scored on colour."""
        if stride not in self._sets:
            idx = np.nonzero(self.roi)[0][::stride]
            dirs = self._dirs[idx]
            rgb = self.obs.rgb[self._v[idx], self._u[idx]]
            depth = self.obs.depth[self._v[idx], self._u[idx]].astype(np.float32)
            depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
            bg_depth, bg_rgb = table_prediction(self.origin, dirs, self.light)
            bg = self.pixels_model.pixel_loglik(rgb, depth, self._lit(bg_rgb), bg_depth)
            weight = self.tempering * stride
            self._sets[stride] = _PixelSet(self.origin, dirs, rgb, depth, bg, weight)
        return self._sets[stride]

    def _lit(self, rgb: np.ndarray) -> np.ndarray:
        """Predicted colours under the image's measured gain, saturating at 1 like a camera."""
        return np.minimum(rgb * self.conditions.gain, 1.0).astype(np.float32)

    def score(self, poses: np.ndarray, stride: int) -> Scores:
        """Scores of hypotheses `poses` (N, 3) using the region's pixels on `stride`."""
        poses = np.atleast_2d(np.asarray(poses, float))
        ps = self.pixels(stride)
        hits = self.caster.render(ps.origin, ps.dirs, self.light, poses)
        total, pixels, inliers = _score_hits(
            hits.hyp,
            hits.pix,
            hits.rgb,
            hits.depth,
            ps.rgb,
            ps.depth,
            ps.delta_bg,
            self.conditions.gain.astype(np.float32),
            self.pixels_model.pixel_constants(),
            len(poses),
        )
        return Scores(ps.weight * total, pixels, inliers)


@numba.njit(cache=True)
def _score_hits(hyp, pix, rgb_hit, depth_hit, rgb, depth, delta_bg, gain, constants, n):
    """Per hypothesis: the sum over its hits of the pixel's log-likelihood minus its table term,
    the number of hits and of inliers. A hit's colour is lit by the image's `gain` and saturates
    at 1 like a camera (ImageScorer._lit)."""
    total = np.zeros(n)
    pixels = np.zeros(n, np.int64)
    inliers = np.zeros(n)
    one = np.float32(1.0)
    for q in range(hyp.size):
        i, p = hyp[q], pix[q]
        loglik, inlier = pixel_terms(
            rgb[p, 0],
            rgb[p, 1],
            rgb[p, 2],
            depth[p],
            min(rgb_hit[q, 0] * gain[0], one),
            min(rgb_hit[q, 1] * gain[1], one),
            min(rgb_hit[q, 2] * gain[2], one),
            depth_hit[q],
            constants,
        )
        total[i] += loglik - delta_bg[p]
        pixels[i] += 1
        inliers[i] += 1.0 if inlier else 0.0
    return total, pixels, inliers


def _fit_hinge(n: np.ndarray, y: np.ndarray, m: np.ndarray, iterations: int = 12) -> np.ndarray:
    """The light's horizontal part m = L_xy / L_z fitting y = max(0, n . (m, 1)) to shading `y` of
    normals `n` (N, 3): Huber-weighted Gauss-Newton from `m`."""
    m = np.asarray(m, float).copy()
    for _ in range(iterations):
        on = n[:, :2] @ m + n[:, 2] > 0
        r = y - np.where(on, n[:, :2] @ m + n[:, 2], 0.0)
        scale = max(1.4826 * np.median(np.abs(r)), 1e-3)
        w = np.minimum(1.0, 1.345 * scale / np.maximum(np.abs(r), 1e-12)) * on
        J = n[:, :2] * w[:, None]
        m = m + np.linalg.lstsq(J.T @ n[:, :2] + 1e-6 * np.eye(2), J.T @ r, rcond=None)[0]
    return m


@dataclass
class _TableReading:
    """What the bare table in the region says whatever the light: the median colour of its pixels
    (None: too few of them), the depth spread about its plane, how many pixels, the per-pixel
    depth noise."""

    colour: np.ndarray | None
    spread: float
    pixels: int
    pixel_noise: float

    def conditions(self, light: np.ndarray) -> ImageConditions:
        """The image's conditions if the light arrives from `light` (world, unit): the colour gain
        is the table's colour over its albedo shaded by that light (1 when unknown)."""
        shaded = table_colour(light)
        if self.colour is None or shaded.max() <= 0:
            return ImageConditions(np.ones(3, np.float32), self.spread, 0, self.pixel_noise)
        gain = np.clip(self.colour / np.maximum(shaded, 1e-3), 0.1, 10.0)
        return ImageConditions(gain.astype(np.float32), self.spread, self.pixels, self.pixel_noise)


def _read_table(
    obs: Observation, u: np.ndarray, v: np.ndarray, dirs: np.ndarray, origin: np.ndarray, min_pixels: int = 200
) -> _TableReading:
    """The bare table's reading from the pixels (u, v): those with depth within 2 robust standard
    deviations (at least 2 mm) of the table plane's. The pixel noise is read apart, from second
    differences along rows over the pixels within 1 cm of the region's own depth offset, so that a
    bias or a ramp (a camera off its pose) does not count as noise."""
    resid = obs.depth[v, u] - table_depth(origin, dirs)
    offset = deepest_peak(resid, min_pixels, 0.06, 0.001)
    pixel_noise = 0.0
    if offset is not None:
        level = np.abs(resid - offset) < 0.01
        pixel_noise = _row_noise(obs.depth, u[level], v[level])
    near = np.abs(resid) < 0.01
    if np.count_nonzero(near) < min_pixels:
        return _TableReading(None, 0.0, 0, pixel_noise)
    centred = resid[near] - np.median(resid[near])
    spread = float(1.4826 * np.median(np.abs(centred)))
    table = near & (np.abs(resid) < max(0.002, 2 * spread))
    if np.count_nonzero(table) < min_pixels:
        return _TableReading(None, spread, 0, pixel_noise)
    colour = np.median(obs.rgb[v[table], u[table]], axis=0)
    return _TableReading(colour, spread, int(np.count_nonzero(table)), pixel_noise)


def _row_noise(depth: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """Robust standard deviation [m] of independent per-pixel depth noise at the pixels (u, v), from
    the second difference d[u-1] - 2 d[u] + d[u+1] along each row over triples that are all in the
    set (its std is sqrt(6) sigma; a plane's curvature over two pixels is far below a micrometre)."""
    if len(u) == 0:
        return 0.0
    u0, v0 = int(u.min()), int(v.min())
    mask = np.zeros((int(v.max()) - v0 + 1, int(u.max()) - u0 + 3), bool)
    mask[v - v0, u - u0 + 1] = True
    inner = mask[:, 1:-1] & mask[:, :-2] & mask[:, 2:]
    rows, cols = np.nonzero(inner)
    if len(rows) < 20:
        return 0.0
    rows, cols = rows + v0, cols + u0
    d = depth.astype(np.float64)
    d2 = d[rows, cols - 1] - 2.0 * d[rows, cols] + d[rows, cols + 1]
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def _image_box(obs: Observation, centre: np.ndarray, radius: float, top: float) -> tuple[int, int, int, int]:
    """Pixel bounds (u0, u1, v0, v1), end-exclusive and clipped to the image, of the vertical
    cylinder of `radius` around `centre` between z = 0 and `top` (empty if it is behind the
    camera or out of view)."""
    k = obs.intrinsics
    angles = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)]) * radius + centre
    pts = np.vstack([np.column_stack([ring, np.full(len(ring), z)]) for z in (0.0, top)])
    p_C = obs.X_WC.inverse().multiply(pts.T).T
    front = p_C[:, 2] > 1e-6
    if not front.any():
        return 0, 0, 0, 0
    if not front.all():  # the cylinder straddles the camera plane: take the whole image
        return 0, k.width, 0, k.height
    u = k.fx * p_C[:, 0] / p_C[:, 2] + k.cx - VTK_PIXEL_OFFSET
    v = k.fy * p_C[:, 1] / p_C[:, 2] + k.cy - VTK_PIXEL_OFFSET
    u0, u1 = int(np.clip(np.floor(u.min()) - 1, 0, k.width)), int(np.clip(np.ceil(u.max()) + 2, 0, k.width))
    v0, v1 = int(np.clip(np.floor(v.min()) - 1, 0, k.height)), int(np.clip(np.ceil(v.max()) + 2, 0, k.height))
    return u0, max(u0, u1), v0, max(v0, v1)
