"""PosePosterior: a gridded posterior over a gear's planar pose (x, y, yaw).

The grid is a set of modes, one per repeat of the gear's appearance in yaw (every tooth pitch),
each a local (x, y, yaw-offset) grid around the same (x, y) cells; the cell masses are normalized
over all modes. Within a cell the density is taken as uniform.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

DIMS = ("x", "y", "yaw")


def wrap(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle, float) + np.pi) % (2 * np.pi) - np.pi


def _overlap(centres: np.ndarray, width: float, lo: float, hi: float) -> np.ndarray:
    """Fraction of each cell [c - w/2, c + w/2] inside [lo, hi]."""
    a = np.maximum(centres - width / 2, lo)
    b = np.minimum(centres + width / 2, hi)
    return np.clip(b - a, 0.0, None) / width


@dataclass
class PosePosterior:
    """Cell masses `log_mass` (modes, nx, ny, nyaw) over cells centred at (xs[i], ys[j],
    mode_yaws[k] + yaw_offsets[l]) of size (dx, dy, dyaw). `informative` is False when the image
    could not tell where the gear is; `reason` then says why and the posterior is the prior."""

    gear: str
    xs: np.ndarray
    ys: np.ndarray
    mode_yaws: np.ndarray
    yaw_offsets: np.ndarray
    log_mass: np.ndarray
    informative: bool = True
    reason: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        shape = (len(self.mode_yaws), len(self.xs), len(self.ys), len(self.yaw_offsets))
        if self.log_mass.shape != shape:
            raise ValueError(f"log_mass has shape {self.log_mass.shape}; expected {shape}")
        lm = self.log_mass - self.log_mass.max()
        self.log_mass = lm - np.log(np.exp(lm).sum())

    @property
    def dx(self) -> float:
        """Cell size in x [m]."""
        return float(self.xs[1] - self.xs[0]) if len(self.xs) > 1 else 0.0

    @property
    def dy(self) -> float:
        """Cell size in y [m]."""
        return float(self.ys[1] - self.ys[0]) if len(self.ys) > 1 else 0.0

    @property
    def dyaw(self) -> float:
        """Cell size in yaw [rad]."""
        return float(self.yaw_offsets[1] - self.yaw_offsets[0]) if len(self.yaw_offsets) > 1 else 0.0

    @property
    def mass(self) -> np.ndarray:
        """Cell probabilities, same shape as log_mass, summing to 1."""
        return np.exp(self.log_mass)

    def yaws(self) -> np.ndarray:
        """(modes, nyaw) yaw of each cell centre, wrapped to [-pi, pi)."""
        return wrap(self.mode_yaws[:, None] + self.yaw_offsets[None, :])

    @property
    def map_pose(self) -> np.ndarray:
        """(x, y, yaw) of the most probable cell."""
        k, i, j, l = np.unravel_index(np.argmax(self.log_mass), self.log_mass.shape)
        return np.array([self.xs[i], self.ys[j], self.yaws()[k, l]])

    def sample(self, n: int, seed: int | None = None) -> np.ndarray:
        """n poses (n, 3) drawn from the posterior (uniform within each drawn cell)."""
        if n < 0:
            raise ValueError(f"n = {n}; expected a non-negative number of samples")
        rng = np.random.default_rng(seed)
        flat = rng.choice(self.mass.size, size=n, p=self.mass.ravel())
        k, i, j, l = np.unravel_index(flat, self.log_mass.shape)
        jitter = rng.uniform(-0.5, 0.5, size=(n, 3)) * [self.dx, self.dy, self.dyaw]
        poses = np.column_stack([self.xs[i], self.ys[j], self.yaws()[k, l]]) + jitter
        poses[:, 2] = wrap(poses[:, 2])
        return poses

    def probability(self, x: tuple[float, float] | None = None, y: tuple[float, float] | None = None,
                    yaw: tuple[float, float] | None = None) -> float:
        """Probability that the pose lies in the box x in [x0, x1], y in [y0, y1] and yaw in the arc
        from yaw0 counter-clockwise to yaw1 [rad]; a dimension left as None is unconstrained."""
        fx = _overlap(self.xs, self.dx, *x) if x is not None else np.ones(len(self.xs))
        fy = _overlap(self.ys, self.dy, *y) if y is not None else np.ones(len(self.ys))
        if yaw is None:
            fyaw = np.ones((len(self.mode_yaws), len(self.yaw_offsets)))
        else:
            lo = float(wrap(yaw[0]))
            span = float((yaw[1] - yaw[0]) % (2 * np.pi)) or 2 * np.pi
            rel = (self.yaws() - lo) % (2 * np.pi)  # cell centres measured from the arc's start
            fyaw = sum(_overlap(rel + s, self.dyaw, 0.0, span) for s in (-2 * np.pi, 0.0, 2 * np.pi))
        w = fyaw[:, None, None, :] * fx[None, :, None, None] * fy[None, None, :, None]
        return float(np.clip((self.mass * w).sum(), 0.0, 1.0))

    def marginal(self, dim: str) -> tuple[np.ndarray, np.ndarray]:
        """(cell centres, probabilities) of the marginal of `dim` ('x', 'y' or 'yaw'); yaw cells of
        every mode, sorted by angle."""
        m = self.mass
        if dim == "x":
            return self.xs.copy(), m.sum(axis=(0, 2, 3))
        if dim == "y":
            return self.ys.copy(), m.sum(axis=(0, 1, 3))
        if dim == "yaw":
            values, probs = self.yaws().ravel(), m.sum(axis=(1, 2)).ravel()
            order = np.argsort(values)
            return values[order], probs[order]
        raise ValueError(f"unknown dimension {dim!r}; expected one of {DIMS}")

    def marginal_entropy(self, dim: str) -> float:
        """Differential entropy [nats] of the piecewise-constant marginal density of `dim`."""
        width = {"x": self.dx, "y": self.dy, "yaw": self.dyaw}[dim] if dim in DIMS else None
        _, p = self.marginal(dim)
        p = p[p > 0]
        return float(-(p * np.log(p / max(width, 1e-12))).sum())

    def std(self) -> np.ndarray:
        """Standard deviations of x and y [m] and the circular standard deviation of yaw [rad]."""
        out = []
        for dim in ("x", "y"):
            v, p = self.marginal(dim)
            mu = (v * p).sum()
            out.append(np.sqrt(max(((v - mu) ** 2 * p).sum(), 0.0)))
        v, p = self.marginal("yaw")
        r = abs((p * np.exp(1j * v)).sum())
        out.append(np.sqrt(-2 * np.log(max(r, 1e-12))))
        return np.array(out)

    def credible_mask(self, level: float = 0.9) -> np.ndarray:
        """Cells of the highest-probability region holding `level` of the mass."""
        if not 0 < level <= 1:
            raise ValueError(f"level = {level}; expected a probability in (0, 1]")
        flat = self.mass.ravel()
        order = np.argsort(flat)[::-1]
        keep = np.searchsorted(np.cumsum(flat[order]), level * (1 - 1e-12)) + 1
        mask = np.zeros(flat.size, bool)
        mask[order[:keep]] = True
        return mask.reshape(self.mass.shape)

    def cell_of(self, pose: np.ndarray) -> tuple[int, int, int, int] | None:
        """Index (mode, i, j, l) of the cell holding `pose`, or None outside the grid."""
        x, y, yaw = np.asarray(pose, float)
        i = int(np.round((x - self.xs[0]) / self.dx)) if self.dx else 0
        j = int(np.round((y - self.ys[0]) / self.dy)) if self.dy else 0
        if not (0 <= i < len(self.xs) and 0 <= j < len(self.ys)):
            return None
        off = wrap(yaw - self.mode_yaws)  # offset from each mode centre
        l = np.round((off - self.yaw_offsets[0]) / self.dyaw).astype(int) if self.dyaw else 0 * off
        ok = np.nonzero((l >= 0) & (l < len(self.yaw_offsets)))[0]
        if ok.size == 0:
            return None
        k = ok[np.argmin(np.abs(off[ok]))]
        return int(k), i, j, int(l[k])

    def contains(self, pose: np.ndarray, level: float = 0.9) -> bool:
        """Whether `pose` lies in the `level` highest-probability credible region."""
        cell = self.cell_of(pose)
        return cell is not None and bool(self.credible_mask(level)[cell])

    def summary(self) -> dict:
        """A JSON-ready summary: MAP, standard deviations, entropies, flags."""
        return {"gear": self.gear, "informative": self.informative, "reason": self.reason,
                "map": self.map_pose.tolist(), "std": self.std().tolist(),
                "entropy": {d: self.marginal_entropy(d) for d in DIMS},
                **{k: v for k, v in self.info.items() if isinstance(v, (int, float, str))}}

    def plot(self, path: str | Path | None = None, truth: np.ndarray | None = None):
        """The x-y map (summed over yaw) and the yaw marginal (the seed paper's Fig. 12); saved to
        `path` if given. Returns the matplotlib Figure."""
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 3.6))
        xy = self.mass.sum(axis=(0, 3))
        extent = [1e3 * (self.xs[0] - self.dx / 2), 1e3 * (self.xs[-1] + self.dx / 2),
                  1e3 * (self.ys[0] - self.dy / 2), 1e3 * (self.ys[-1] + self.dy / 2)]
        ax0.imshow(xy.T, origin="lower", extent=extent, cmap="viridis", aspect="equal")
        if truth is not None:
            ax0.plot(1e3 * truth[0], 1e3 * truth[1], "r+", ms=12, label="truth")
            ax0.legend(loc="upper right", fontsize=8)
        from matplotlib.ticker import MaxNLocator
        ax0.xaxis.set_major_locator(MaxNLocator(4))
        ax0.yaxis.set_major_locator(MaxNLocator(5))
        ax0.set_xlabel("x [mm]")
        ax0.set_ylabel("y [mm]")
        ax0.set_title(f"{self.gear} gear: p(x, y)" + ("" if self.informative else " (uninformative)"))
        v, p = self.marginal("yaw")
        ax1.plot(np.degrees(v), p / max(self.dyaw, 1e-12) * np.pi / 180, lw=0.8)
        if truth is not None:
            ax1.axvline(np.degrees(wrap(truth[2])), color="r", lw=0.8, label="truth")
            ax1.legend(loc="upper right", fontsize=8)
        ax1.set_xlim(-180, 180)
        ax1.set_xlabel("yaw [deg]")
        ax1.set_ylabel("p(yaw) [1/deg]")
        ax1.set_title("yaw marginal")
        fig.tight_layout()
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(path, dpi=120)
        return fig


def uniform_posterior(gear: str, centre: tuple[float, float], half_width: float, reason: str,
                      cells: int = 21, yaw_cells: int = 72, info: dict | None = None) -> PosePosterior:
    """The prior (uniform over the search box and every yaw), flagged uninformative."""
    xs = centre[0] + np.linspace(-half_width, half_width, cells)
    ys = centre[1] + np.linspace(-half_width, half_width, cells)
    offsets = -np.pi + (np.arange(yaw_cells) + 0.5) * 2 * np.pi / yaw_cells
    return PosePosterior(gear, xs, ys, np.zeros(1), offsets, np.zeros((1, cells, cells, yaw_cells)),
                         informative=False, reason=reason, info=dict(info or {}))
