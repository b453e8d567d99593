"""The depth image aligned to the known table plane: a real camera's depth carries a scale error of
up to about 2 % (the RealSense D400 datasheet's accuracy bound) and a calibrated pose a millimetre or
so off, so the table reads centimetres nearer or farther than the plane z = 0 the perception models.
The table fills most of every view and lies below everything else on it, so the deepest strong peak
of the depths' ratio to the plane's is the camera's depth scale there; dividing it out puts the
table back on its plane (what a robot's "tare" against a known surface does, per image).

    obs = aligned_to_table(obs)          # detect_gears and estimate_pose call it
"""

from __future__ import annotations

import numpy as np

from perception.likelihood import table_depth
from perception.observation import Observation

__all__ = ["aligned_to_table", "deepest_peak", "depth_scale"]

# A scale this close to 1 is left alone (0.1 mm at 0.5 m): an ideal or already aligned image is
# returned as it is.
SCALE_TOLERANCE = 2e-4
# The scale's search range, +-6 % (three times the datasheet's bound), and its histogram's bin.
SCALE_REACH = 0.06
SCALE_BIN = 0.001
# Fewer table pixels than this (every 4th pixel each way) and no scale is read.
MIN_PIXELS = 500


def deepest_peak(values: np.ndarray, min_count: int, reach: float, bin_width: float) -> float | None:
    """The centre of the deepest (largest-valued) strong peak of `values`' histogram within
    +-`reach` (bins of `bin_width`; strong: >= 20 % of the highest, smoothed over 5 bins), refined
    as the median of the values within 3 bins of it; None when fewer than `min_count` values are
    within reach. The table lies below everything on it, so among depth residuals about the table
    plane (or their ratio to it) the deepest strong peak is the table's."""
    r = values[np.abs(values) < reach]
    if len(r) < min_count:
        return None
    counts, edges = np.histogram(r, np.linspace(-reach, reach, int(round(2 * reach / bin_width)) + 1))
    smooth = np.convolve(counts, np.ones(5), "same")
    strong = np.flatnonzero(smooth >= 0.2 * smooth.max())
    start = strong[-1]  # the deepest run of strong bins
    while start - 1 in strong:
        start -= 1
    peak = start + int(np.argmax(smooth[start : strong[-1] + 1]))
    centre = 0.5 * (edges[peak] + edges[peak + 1])
    return float(np.median(r[np.abs(r - centre) < 3 * bin_width]))


def depth_scale(obs: Observation, stride: int = 4) -> float | None:
    """The image's depth scale against the table plane z = 0 (observed depth / the plane's along
    the same ray, at the table's pixels; every `stride`-th pixel each way), or None when too few
    pixels see the table within +-6 %."""
    k = obs.intrinsics
    v, u = np.mgrid[0 : k.height : stride, 0 : k.width : stride]
    u, v = u.ravel(), v.ravel()
    origin, dirs = obs.rays_W(u, v)
    plane = table_depth(origin, dirs).astype(np.float64)
    d = obs.depth[v, u].astype(np.float64)
    ok = np.isfinite(plane) & np.isfinite(d) & (d > 0)
    peak = deepest_peak(d[ok] / plane[ok] - 1.0, MIN_PIXELS, SCALE_REACH, SCALE_BIN)
    return None if peak is None else 1.0 + peak


def aligned_to_table(obs: Observation) -> Observation:
    """`obs` with its depth divided by its `depth_scale` (the same object when the scale is
    unknown or within SCALE_TOLERANCE of 1)."""
    scale = depth_scale(obs)
    if scale is None or abs(scale - 1.0) <= SCALE_TOLERANCE:
        return obs
    return Observation(obs.rgb, obs.depth / np.float32(scale), obs.intrinsics, obs.X_WC)
