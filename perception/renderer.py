"""Our batched renderer: many pose hypotheses of one gear, ray cast through the gear's height map.

For every (hypothesis, pixel) pair whose ray passes within the gear's tip radius, the ray is
marched through the slab 0 <= z <= top of the gear (in the gear frame, where hypotheses differ
only by a planar rotation and shift) until it first enters the solid; the entry is then refined,
exactly for flat faces and by bisection for walls and chamfers. Colour follows Drake's
RenderEngineVtk default lighting: one directional light along the camera's optical axis, Lambert
shading of the diffuse colour (albedo * max(0, n . -z_C)), no ambient term.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    tip); refine_steps: bisection steps for wall and chamfer hits; chunk: pairs per batch."""

    march_step: float = 3e-4
    refine_steps: int = 8
    chunk: int = 400_000

    def __post_init__(self) -> None:
        if not 0 < self.march_step <= 1e-3:
            raise ValueError(f"march_step = {self.march_step}; expected (0, 1e-3] m")
        if self.refine_steps < 1 or self.chunk < 1000:
            raise ValueError(f"refine_steps = {self.refine_steps}, chunk = {self.chunk}; expected "
                             ">= 1 and >= 1000")


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
        self._levels = np.unique(self.map.height[flat])[::-1][:4]

    def render(self, origin: np.ndarray, dirs: np.ndarray, light: np.ndarray,
               poses: np.ndarray, surface: bool = False) -> RenderedPairs:
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
            raise ValueError(f"camera height {origin[2]:.4f} m is not above the gear top "
                             f"{self._top:.4f} m; the ray caster looks down at the table")
        down = dirs[:, 2] < -1e-9
        t_top = np.where(down, (self._top - origin[2]) / np.where(down, dirs[:, 2], -1.0), np.inf)
        t_bot = np.where(down, -origin[2] / np.where(down, dirs[:, 2], -1.0), np.inf)
        a = origin[:2] + t_top[:, None] * dirs[:, :2]  # where each ray enters the slab (xy)
        b = origin[:2] + np.where(down, t_bot, t_top)[:, None] * dirs[:, :2]
        pairs_h, pairs_p = self._candidates(a, b, down, poses[:, :2])
        out = []
        for s in range(0, len(pairs_h), self.config.chunk):
            h, p = pairs_h[s:s + self.config.chunk], pairs_p[s:s + self.config.chunk]
            out.append(self._march(origin, a[p], b[p], t_top[p], t_bot[p], poses[h], light, h, p,
                                   surface))
        if not out:
            empty = np.zeros(0, np.int64)
            none3 = np.zeros((0, 3), np.float32)
            return RenderedPairs(empty, empty, np.zeros(0, np.float32), none3,
                                 none3 if surface else None, none3 if surface else None)
        parts = [np.concatenate([o[k] for o in out]) for k in range(6 if surface else 4)]
        return RenderedPairs(*parts)

    def _candidates(self, a: np.ndarray, b: np.ndarray, down: np.ndarray,
                    centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
            cx, cy = uniq[s:s + step, 0:1], uniq[s:s + step, 1:2]
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

    def _cylinder_span(self, x0, y0, dx, dy) -> tuple[np.ndarray, np.ndarray]:
        """Chord parameters [s_in, s_out] within [0, 1] where (x0 + s dx, y0 + s dy) lies inside
        the tip radius (s_in >= s_out: never)."""
        r2 = (self.model.tip_radius + 2 * self.map.texel) ** 2
        A = dx * dx + dy * dy
        B = x0 * dx + y0 * dy
        C = x0 * x0 + y0 * y0 - r2
        disc = B * B - A * C
        root = np.sqrt(np.maximum(disc, 0.0))
        safe = np.maximum(A, 1e-30)
        vertical = A < 1e-24
        s_in = np.where(vertical, np.where(C <= 0, 0.0, 1.0), (-B - root) / safe)
        s_out = np.where(vertical, np.where(C <= 0, 1.0, 0.0), (-B + root) / safe)
        s_in = np.where(disc < 0, 1.0, np.maximum(s_in, 0.0))
        s_out = np.where(disc < 0, 0.0, np.minimum(s_out, 1.0))
        return s_in, s_out

    def _lookup(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        return self.map.index(gx, gy)

    def _march(self, origin, a, b, t_top, t_bot, pose, light, hyp, pix, surface=False):
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        # Slab entry point and chord in the gear frame: rotate by -yaw about the gear's axis.
        rx, ry = a[:, 0] - pose[:, 0], a[:, 1] - pose[:, 1]
        gx0, gy0 = c * rx + s * ry, -s * rx + c * ry
        dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        gdx, gdy = c * dx + s * dy, -s * dx + c * dy
        length = np.hypot(dx, dy)
        ds = np.minimum(1.0, self.config.march_step / np.maximum(length, 1e-12))
        top = self._top

        def inside(idx_rows, sv):
            k = self._lookup(gx0[idx_rows] + sv * gdx[idx_rows], gy0[idx_rows] + sv * gdy[idx_rows])
            return top * (1.0 - sv) <= self._h[k], k

        n = len(a)
        s_hit = np.full(n, np.nan)
        active = np.arange(n)
        s_prev = np.zeros(n)
        for level in self._levels:
            sv = np.full(active.size, 1.0 - level / top)
            hit, _ = inside(active, sv)
            s_hit[active[hit]] = s_prev[active[hit]] = sv[hit]
            active = active[~hit]
        # March only the part of the chord inside the tip cylinder (the solid lies within it).
        s_in, s_out = self._cylinder_span(gx0[active], gy0[active], gdx[active], gdy[active])
        keep = s_in < s_out
        active, s_in, s_out = active[keep], s_in[keep], s_out[keep]
        k_step = 1
        while active.size:
            sv = np.minimum(s_out, s_in + k_step * ds[active])
            hit, _ = inside(active, sv)
            s_hit[active[hit]] = sv[hit]
            s_prev[active[hit]] = np.maximum(sv[hit] - ds[active[hit]], s_in[hit])
            go = ~hit & (sv < s_out)
            active, s_in, s_out = active[go], s_in[go], s_out[go]
            k_step += 1
        rows = np.nonzero(np.isfinite(s_hit))[0]
        lo = s_prev[rows]
        hi = s_hit[rows]
        # Flat top faces: the hit is where the ray reaches the texel's height (one lookup).
        _, k_hi = inside(rows, hi)
        z_face = self._h[k_hi]
        s_face = 1.0 - z_face / top
        ok_face = (s_face >= lo - 1e-9) & (s_face <= hi + 1e-9) & (self._n[k_hi, 2] > 0.999)
        if np.any(ok_face):
            _, k_face = inside(rows[ok_face], s_face[ok_face])
            ok_face[ok_face] = self._h[k_face] == z_face[ok_face]
        rest = ~ok_face
        r_rows, r_lo, r_hi = rows[rest], lo[rest], hi[rest]
        for _ in range(self.config.refine_steps):
            mid = 0.5 * (r_lo + r_hi)
            inn, _ = inside(r_rows, mid)
            r_hi = np.where(inn, mid, r_hi)
            r_lo = np.where(inn, r_lo, mid)
        s_final = np.where(ok_face, s_face, 0.0)
        s_final[rest] = r_hi
        _, k_in = inside(rows, s_final)
        z = top * (1.0 - s_final)
        wall = self._h[k_in] - z > 1e-4
        normal = self._n[k_in].astype(np.float64)
        if np.any(wall):
            s_out = s_final.copy()
            s_out[rest] = r_lo  # just outside the wall, where its footprint gradient lives
            _, k_out = inside(rows[wall], s_out[wall])
            normal[wall, :2] = self._wall[k_out]
            normal[wall, 2] = 0.0
        # Light direction in the gear frame.
        cr, sr = c[rows], s[rows]
        lx, ly = cr * light[0] + sr * light[1], -sr * light[0] + cr * light[1]
        shade = np.maximum(0.0, normal[:, 0] * lx + normal[:, 1] * ly + normal[:, 2] * light[2])
        albedo = self._albedo[k_in]
        rgb = (albedo * shade[:, None]).astype(np.float32)
        depth = (t_top[rows] + s_final * (t_bot[rows] - t_top[rows])).astype(np.float32)
        if not surface:
            return hyp[rows], pix[rows], depth, rgb, None, None
        world = np.column_stack([cr * normal[:, 0] - sr * normal[:, 1],
                                 sr * normal[:, 0] + cr * normal[:, 1], normal[:, 2]])
        return hyp[rows], pix[rows], depth, rgb, world.astype(np.float32), albedo


def render_image(caster: RayCaster, origin: np.ndarray, dirs: np.ndarray, light: np.ndarray,
                 pose: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Dense (depth, rgb) images of one pose for rays given in row-major pixel order; depth is
    +inf and rgb 0 where the gear is not hit."""
    out = caster.render(origin, dirs, light, np.asarray(pose, float)[None])
    depth = np.full(shape[0] * shape[1], np.inf, np.float32)
    rgb = np.zeros((shape[0] * shape[1], 3), np.float32)
    depth[out.pix] = out.depth
    rgb[out.pix] = out.rgb
    return depth.reshape(shape), rgb.reshape(*shape, 3)
