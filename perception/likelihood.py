"""The per-pixel RGB-D likelihood (the GoFlow paper's appendix A.3.1, Bayes3D family).

Per valid pixel, an outlier density (uniform over colour and depth) mixed with a Laplace inlier
density centred on the rendered hypothesis:

    p(c, d | c_hat, d_hat) = p_out / (1 * depth_range)
                             + (1 - p_out) exp(-|c - c_hat|_1 / b_rgb - |d - d_hat| / b_d)
                               / ((2 b_rgb)^3 (2 b_d)),

the product over pixels raised to a tempering exponent. Every m-th pixel of the region is used; each
stands for m pixels, so its log term is weighted by m and the tempering exponent is that of the
full-resolution product.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from assembly.gear_meshes import gearset_model_paths


@dataclass
class LikelihoodConfig:
    """p_out: outlier probability; b_rgb: colour scale (L1 over r, g, b in [0, 1]); b_d: depth
    scale [m]; depth_range: support of the outlier depth density [m]; tempering: exponent on the
    full-resolution product of pixel likelihoods (accounts for correlated pixels)."""

    p_out: float = 0.1
    b_rgb: float = 0.15
    b_d: float = 0.004
    depth_range: float = 2.0
    tempering: float = 0.002

    def __post_init__(self) -> None:
        if not 0.0 < self.p_out < 1.0:
            raise ValueError(f"p_out = {self.p_out}; expected a probability in (0, 1)")
        for name in ("b_rgb", "b_d", "depth_range", "tempering"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"LikelihoodConfig.{name} = {value}; expected a finite value > 0")

    def _log_terms(self, rgb, depth, rgb_hat, depth_hat) -> tuple[np.ndarray, float]:
        colour = np.abs(rgb - rgb_hat).sum(-1) / self.b_rgb
        dist = np.abs(depth - depth_hat) / self.b_d
        log_in = (np.log1p(-self.p_out) - colour - dist - 3 * np.log(2 * self.b_rgb)
                  - np.log(2 * self.b_d))
        return log_in, float(np.log(self.p_out) - np.log(self.depth_range))

    def pixel_loglik(self, rgb: np.ndarray, depth: np.ndarray, rgb_hat: np.ndarray,
                     depth_hat: np.ndarray) -> np.ndarray:
        """Log-likelihood of observed pixels (rgb (..., 3), depth (...)) given rendered ones."""
        log_in, log_out = self._log_terms(rgb, depth, rgb_hat, depth_hat)
        return np.logaddexp(log_in, log_out)

    def is_inlier(self, rgb: np.ndarray, depth: np.ndarray, rgb_hat: np.ndarray,
                  depth_hat: np.ndarray, scales: float = 3.0) -> np.ndarray:
        """Whether each pixel matches its rendering within `scales` times b_rgb (colour, L1) and
        b_d (depth): what "the hypothesis explains this pixel" means in the sanity checks."""
        colour = np.abs(rgb - rgb_hat).sum(-1) / self.b_rgb
        dist = np.abs(depth - depth_hat) / self.b_d
        return (colour < scales) & (dist < scales)


@lru_cache(maxsize=None)
def table_albedo() -> np.ndarray:
    """The table's diffuse colour, read from its model file (assembly/models/gearset/table.sdf)."""
    text = gearset_model_paths()["table"].read_text()
    match = re.search(r"<diffuse>\s*([\d.eE+-]+)\s+([\d.eE+-]+)\s+([\d.eE+-]+)", text)
    if match is None:
        raise ValueError("table.sdf has no <diffuse> colour; perception needs the table's colour")
    return np.array([float(g) for g in match.groups()], np.float32)


def table_prediction(origin: np.ndarray, dirs: np.ndarray, light: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """What each ray sees if no gear is in its way: the table plane z = 0 (depth, shaded colour);
    depth is +inf for rays that never reach it."""
    down = dirs[:, 2] < -1e-9
    depth = np.where(down, -origin[2] / np.where(down, dirs[:, 2], -1.0), np.inf)
    shade = max(0.0, float(light[2]))
    rgb = np.broadcast_to(table_albedo() * shade, (len(dirs), 3)).astype(np.float32)
    return depth.astype(np.float32), rgb
