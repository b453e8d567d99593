"""Scores pose hypotheses of one gear against one observation.

The region of interest is every valid pixel whose ray passes through the vertical cylinder the
gear can occupy anywhere in the search region. A hypothesis predicts its rendered gear where its
rays hit the gear and the bare table elsewhere, so its log-likelihood over the region is the
no-gear log-likelihood (the same for all hypotheses) plus the sum, over the pixels its gear
covers, of (gear term - table term): only those pixels are rendered and summed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perception.gear_model import GearModel
from perception.likelihood import LikelihoodConfig, table_prediction
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
class _PixelSet:
    origin: np.ndarray
    dirs: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    delta_bg: np.ndarray  # table term of each pixel
    weight: float


class ImageScorer:
    """Hypotheses of `model` near (cx, cy) (within `radius` [m]) against `obs`."""

    def __init__(self, obs: Observation, model: GearModel, centre: tuple[float, float],
                 radius: float, likelihood: LikelihoodConfig | None = None,
                 raycaster: RayCasterConfig | None = None) -> None:
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
        w = np.clip(((centre - a) * ab).sum(1) / np.maximum((ab ** 2).sum(1), 1e-18), 0.0, 1.0)
        dist = np.linalg.norm(a + w[:, None] * ab - centre, axis=1)
        valid = obs.valid[self._v, self._u]
        self.roi = down & valid & (dist <= radius + model.tip_radius)
        self.footprint = int(np.count_nonzero(down & valid & (dist <= model.tip_radius)))
        self.roi_pixels = int(np.count_nonzero(self.roi))
        self._dirs = dirs
        self._sets: dict[int, _PixelSet] = {}

    def stride_for(self, target: int) -> int:
        """The subsampling factor m at which a gear at the centre covers about `target` of the
        sampled pixels (every m-th pixel of the region in raster order is used)."""
        return max(1, int(round(self.footprint / max(target, 1))))

    def pixels(self, stride: int) -> _PixelSet:
        """Every `stride`-th pixel of the region in raster order (cached)."""
        if stride not in self._sets:
            idx = np.nonzero(self.roi)[0][::stride]
            dirs = self._dirs[idx]
            rgb = self.obs.rgb[self._v[idx], self._u[idx]]
            depth = self.obs.depth[self._v[idx], self._u[idx]]
            bg_depth, bg_rgb = table_prediction(self.origin, dirs, self.light)
            bg = self.likelihood.pixel_loglik(rgb, depth, bg_rgb, bg_depth)
            weight = self.likelihood.tempering * stride
            self._sets[stride] = _PixelSet(self.origin, dirs, rgb, depth, bg, weight)
        return self._sets[stride]

    def score(self, poses: np.ndarray, stride: int) -> Scores:
        """Scores of hypotheses `poses` (N, 3) using the region's pixels on `stride`."""
        poses = np.atleast_2d(np.asarray(poses, float))
        ps = self.pixels(stride)
        hits = self.caster.render(ps.origin, ps.dirs, self.light, poses)
        lik = self.likelihood
        ll = lik.pixel_loglik(ps.rgb[hits.pix], ps.depth[hits.pix], hits.rgb, hits.depth)
        inl = lik.is_inlier(ps.rgb[hits.pix], ps.depth[hits.pix], hits.rgb, hits.depth)
        n = len(poses)
        total = np.bincount(hits.hyp, weights=ll - ps.delta_bg[hits.pix], minlength=n)
        return Scores(ps.weight * total, np.bincount(hits.hyp, minlength=n),
                      np.bincount(hits.hyp, weights=inl.astype(float), minlength=n))


def _image_box(obs: Observation, centre: np.ndarray, radius: float, top: float
               ) -> tuple[int, int, int, int]:
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
