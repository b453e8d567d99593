"""Our batched renderer: many pose hypotheses of one gear, ray cast through the gear's height map.

For every (hypothesis, pixel) pair whose ray passes within the gear's tip radius, the ray is
marched through the slab 0 <= z <= top of the gear (in the gear frame, where hypotheses differ
only by a planar rotation and shift) until it first enters the solid; the entry is then refined,
exactly for flat faces and by bisection for walls and chamfers. The pairs are marched by one
compiled loop (numba), no Python per pair or per step. Colour follows Drake's
RenderEngineVtk default lighting: one directional light along the camera's optical axis, Lambert
shading of the diffuse colour (albedo * max(0, n . -z_C)), no ambient term.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from perception.gear_model import GearModel, HeightMap

NAME = "raycast-heightmap"


@dataclass
class RenderedPairs:
    """The gear's hits, one row per (hypothesis, pixel) pair whose ray meets the gear: hypothesis
    index `hyp`, pixel index `pix` (into the rays given), `depth` [m] and shaded `rgb` in [0, 1]."""

    hyp: np.ndarray
    pix: np.ndarray
    depth: np.ndarray
    rgb: np.ndarray
    normal: np.ndarray | None = None  # (n, 3) world-frame surface normals, when asked for
    albedo: np.ndarray | None = None  # (n, 3) unshaded colours, when asked for


@dataclass
class RayCasterConfig:
    """march_step: horizontal distance between samples along a ray [m] (below the narrowest tooth
    tip); refine_steps: bisection steps for wall and chamfer hits."""

    march_step: float = 3e-4
    refine_steps: int = 8

    def __post_init__(self) -> None:
        if not 0 < self.march_step <= 1e-3:
            raise ValueError(f"march_step = {self.march_step}; expected (0, 1e-3] m")
        if self.refine_steps < 1:
            raise ValueError(f"refine_steps = {self.refine_steps}; expected >= 1")


class RayCaster:
    """Renders a GearModel resting flat on the table (z = 0) at planar poses (x, y, yaw)."""

    name = NAME

    def __init__(self, model: GearModel, config: RayCasterConfig | None = None) -> None:
        self.model = model
        self.config = config or RayCasterConfig()
        self.map: HeightMap = model.height_map()
        self._h = self.map.height.ravel()
        self._n = self.map.normal.reshape(-1, 3)
        self._albedo = self.map.albedo.reshape(-1, 3)
        self._wall = self.map.wall_normal.reshape(-1, 2)
        self._top = self.map.top + 1e-6
        flat = self.map.normal[:, :, 2] > 0.999
        # Heights of the flat faces, highest first: a ray is tested there before marching, so
        # that rays grazing a face's edge hit it even between two march samples.
        self._levels = np.ascontiguousarray(np.unique(self.map.height[flat])[::-1][:4])

    def render(
        self, origin: np.ndarray, dirs: np.ndarray, light: np.ndarray, poses: np.ndarray, surface: bool = False
    ) -> RenderedPairs:
        """Hits of rays origin + t * dirs (t = depth) for each pose (N, 3) in `poses`; `light` is
        the direction towards the light in the world (minus the camera's optical axis for Drake's
        headlight), its length the intensity. `surface`: also return each hit's world normal and
        albedo."""
        poses = np.atleast_2d(np.asarray(poses, float))
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise ValueError(f"poses have shape {poses.shape}; expected (N, 3) rows (x, y, yaw)")
        if self.model.symmetry > 1:
            # The model repeats every period: render the representative yaw in [0, period), so
            # that poses one period apart give identical images (the texel grid is not symmetric).
            poses = poses.copy()
            poses[:, 2] = np.mod(poses[:, 2], self.model.period)
        origin = np.asarray(origin, float)
        dirs = np.asarray(dirs, float)
        if origin[2] <= self._top:
            raise ValueError(
                f"camera height {origin[2]:.4f} m is not above the gear top "
                f"{self._top:.4f} m; the ray caster looks down at the table"
            )
        down = dirs[:, 2] < -1e-9
        t_top = np.where(down, (self._top - origin[2]) / np.where(down, dirs[:, 2], -1.0), np.inf)
        t_bot = np.where(down, -origin[2] / np.where(down, dirs[:, 2], -1.0), np.inf)
        a = origin[:2] + t_top[:, None] * dirs[:, :2]  # where each ray enters the slab (xy)
        b = origin[:2] + np.where(down, t_bot, t_top)[:, None] * dirs[:, :2]
        hyp, pix = self._candidates(a, b, down, poses[:, :2])
        m = self.map
        count, *out = _march_pairs(
            hyp,
            pix,
            a,
            b,
            t_top,
            t_bot,
            poses,
            np.cos(poses[:, 2]),
            np.sin(poses[:, 2]),
            np.asarray(light, float),
            self.config.march_step,
            self._h,
            self._n,
            self._wall,
            self._albedo,
            self._levels,
            float(m.x0),
            1.0 / m.texel,
            m.size,
            float(self._top),
            (self.model.tip_radius + 2 * m.texel) ** 2,
            self.config.refine_steps,
            surface,
        )
        hyp, pix, depth, rgb, normal, albedo = (o[:count] for o in out)
        return RenderedPairs(hyp, pix, depth, rgb, normal if surface else None, albedo if surface else None)

    def _candidates(
        self, a: np.ndarray, b: np.ndarray, down: np.ndarray, centres: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hypothesis, pixel) pairs whose slab chord a-b passes within the tip radius of the
        hypothesis' centre; computed once per distinct centre (hypotheses that differ only in yaw
        share their pixels)."""
        uniq, inverse = np.unique(centres, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        ax, ay = a[down, 0], a[down, 1]
        abx, aby = b[down, 0] - ax, b[down, 1] - ay
        inv_ab2 = 1.0 / np.maximum(abx * abx + aby * aby, 1e-18)
        pix_down = np.nonzero(down)[0]
        r2 = (self.model.tip_radius + 2 * self.map.texel) ** 2
        ms, ps = [], []
        step = max(1, 2_000_000 // max(len(ax), 1))
        for s in range(0, len(uniq), step):
            cx, cy = uniq[s : s + step, 0:1], uniq[s : s + step, 1:2]
            acx, acy = cx - ax, cy - ay
            u = np.clip((acx * abx + acy * aby) * inv_ab2, 0.0, 1.0)
            ex, ey = acx - u * abx, acy - u * aby
            m, p = np.nonzero(ex * ex + ey * ey <= r2)
            ms.append(m + s)
            ps.append(pix_down[p])
        m = np.concatenate(ms) if ms else np.zeros(0, np.int64)
        p = np.concatenate(ps) if ps else np.zeros(0, np.int64)
        # Expand each (centre, pixel) pair to every hypothesis with that centre.
        order = np.argsort(inverse, kind="stable")
        counts = np.bincount(inverse, minlength=len(uniq))
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        reps = counts[m]
        pair_p = np.repeat(p, reps)
        first = np.repeat(starts[m], reps)
        within = np.arange(len(pair_p)) - np.repeat(np.cumsum(reps) - reps, reps)
        return order[first + within], pair_p


def render_image(
    caster: RayCaster, origin: np.ndarray, dirs: np.ndarray, light: np.ndarray, pose: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Dense (depth, rgb) images of one pose for rays given in row-major pixel order; depth is
    +inf and rgb 0 where the gear is not hit."""
    out = caster.render(origin, dirs, light, np.asarray(pose, float)[None])
    depth = np.full(shape[0] * shape[1], np.inf, np.float32)
    rgb = np.zeros((shape[0] * shape[1], 3), np.float32)
    depth[out.pix] = out.depth
    rgb[out.pix] = out.rgb
    return depth.reshape(shape), rgb.reshape(*shape, 3)


@numba.njit(cache=True, inline="always")
def _texel(x, y, x0, inv_texel, n):
    """Flat index of the texel of the height map (n x n texels from (x0, x0), 1 / inv_texel wide)
    under the gear-frame point (x, y); off the map: texel 0, which is always empty (the map has a
    one-texel empty border)."""
    j = np.int64(np.floor((x - x0) * inv_texel))
    i = np.int64(np.floor((y - x0) * inv_texel))
    if i < 0 or i >= n or j < 0 or j >= n:
        return 0
    return i * n + j


@numba.njit(cache=True)
def _march_pairs(
    hyp,
    pix,
    a,
    b,
    t_top,
    t_bot,
    poses,
    cos_yaw,
    sin_yaw,
    light,
    march_step,
    h,
    normal,
    wall_normal,
    albedo,
    levels,
    x0,
    inv_texel,
    n,
    top,
    r2,
    refine_steps,
    surface,
):
    """The hits of the (hypothesis, pixel) pairs (hyp[q], pix[q]), in pair order: the ray's slab
    chord runs from a[pix] (top of the slab, ray parameter t_top) to b[pix] (the table, t_bot); in
    the gear frame of pose poses[hyp] it is (x + s dx, y + s dy), s in [0, 1], marched through the
    height map `h` (flat, float32; `normal`, `wall_normal` and `albedo` per texel). Returns the
    number of hits and, in its first rows, each hit's hypothesis, pixel, depth, shaded colour and
    (when `surface`) world normal and albedo, as RenderedPairs holds them.

    Per chord: first the flat faces' heights `levels` (so that a ray grazing a face's edge hits it
    even between two march samples), then samples every `march_step` (horizontally) along the part
    of the chord inside the tip cylinder (radius^2 `r2`: the solid lies within it); the entry is
    then exact for a flat face (the ray reaches the texel's height within the last step) or
    bisected `refine_steps` times, and a wall hit takes the wall normal of the texel just outside
    it. The arithmetic and its float32 steps are those of the array version this replaced, so the
    images are the same to the bit."""
    m = hyp.size
    one32 = np.float32(1.0)
    top32 = np.float32(top)
    flat32 = np.float32(0.999)
    wall32 = np.float32(1e-4)
    count = 0
    out_hyp = np.empty(m, np.int64)
    out_pix = np.empty(m, np.int64)
    out_depth = np.empty(m, np.float32)
    out_rgb = np.empty((m, 3), np.float32)
    k_extra = m if surface else 0
    out_normal = np.empty((k_extra, 3), np.float32)
    out_albedo = np.empty((k_extra, 3), np.float32)
    for q in range(m):
        i, p = hyp[q], pix[q]
        c, s = cos_yaw[i], sin_yaw[i]
        # The chord in the gear frame: rotated by -yaw about the gear's axis.
        rx, ry = a[p, 0] - poses[i, 0], a[p, 1] - poses[i, 1]
        x, y = c * rx + s * ry, -s * rx + c * ry
        dx, dy = b[p, 0] - a[p, 0], b[p, 1] - a[p, 1]
        ddx, ddy = c * dx + s * dy, -s * dx + c * dy
        ds = min(1.0, march_step / max(np.hypot(dx, dy), 1e-12))
        hit = False
        lo = hi = 0.0
        for level in levels:
            sv32 = one32 - level / top32
            if top32 * (one32 - sv32) <= h[_texel(x + sv32 * ddx, y + sv32 * ddy, x0, inv_texel, n)]:
                hit = True
                lo = hi = np.float64(sv32)
                break
        if not hit:
            # March only the part of the chord inside the tip cylinder (the solid lies within it).
            qa = ddx * ddx + ddy * ddy
            qb = x * ddx + y * ddy
            qc = x * x + y * y - r2
            disc = qb * qb - qa * qc
            root = np.sqrt(max(disc, 0.0))
            if qa < 1e-24:
                s_in = 0.0 if qc <= 0 else 1.0
                s_end = 1.0 if qc <= 0 else 0.0
            else:
                s_in = (-qb - root) / qa
                s_end = (-qb + root) / qa
            s_in = 1.0 if disc < 0 else max(s_in, 0.0)
            s_end = 0.0 if disc < 0 else min(s_end, 1.0)
            step = 1
            while s_in < s_end:
                sv = min(s_end, s_in + step * ds)
                if top * (1.0 - sv) <= h[_texel(x + sv * ddx, y + sv * ddy, x0, inv_texel, n)]:
                    hit = True
                    hi = sv
                    lo = max(sv - ds, s_in)
                    break
                if not sv < s_end:
                    break
                step += 1
            if not hit:
                continue
        # A flat face is hit where the ray reaches the texel's height (one lookup); other hits
        # (walls, chamfers) are bisected.
        k = _texel(x + hi * ddx, y + hi * ddy, x0, inv_texel, n)
        z_face = h[k]
        s_face = one32 - z_face / top32
        face = False
        if s_face >= lo - 1e-9 and s_face <= hi + 1e-9 and normal[k, 2] > flat32:
            face = h[_texel(x + s_face * ddx, y + s_face * ddy, x0, inv_texel, n)] == z_face
        if face:
            s32 = s_wall32 = s_face
        else:
            for _ in range(refine_steps):
                mid = 0.5 * (lo + hi)
                if top * (1.0 - mid) <= h[_texel(x + mid * ddx, y + mid * ddy, x0, inv_texel, n)]:
                    hi = mid
                else:
                    lo = mid
            s32 = np.float32(hi)
            s_wall32 = np.float32(lo)  # just outside the wall
        # The normal (a wall hit takes the wall normal of the texel just outside it), Lambert
        # shading with the light turned into the gear frame, the depth.
        k = _texel(x + s32 * ddx, y + s32 * ddy, x0, inv_texel, n)
        nx, ny, nz = np.float64(normal[k, 0]), np.float64(normal[k, 1]), np.float64(normal[k, 2])
        if h[k] - top32 * (one32 - s32) > wall32:
            k_out = _texel(x + s_wall32 * ddx, y + s_wall32 * ddy, x0, inv_texel, n)
            nx, ny, nz = np.float64(wall_normal[k_out, 0]), np.float64(wall_normal[k_out, 1]), 0.0
        lx, ly = c * light[0] + s * light[1], -s * light[0] + c * light[1]
        shade = max(0.0, nx * lx + ny * ly + nz * light[2])
        out_hyp[count] = i
        out_pix[count] = p
        out_depth[count] = np.float32(t_top[p] + s32 * (t_bot[p] - t_top[p]))
        for j in range(3):
            out_rgb[count, j] = np.float32(albedo[k, j] * shade)
        if surface:
            out_normal[count, 0] = np.float32(c * nx - s * ny)
            out_normal[count, 1] = np.float32(s * nx + c * ny)
            out_normal[count, 2] = np.float32(nz)
            for j in range(3):
                out_albedo[count, j] = albedo[k, j]
        count += 1
    return count, out_hyp, out_pix, out_depth, out_rgb, out_normal, out_albedo
