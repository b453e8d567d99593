"""PosePosterior: a gridded posterior over a gear's planar pose (x, y, yaw).

Yaw is over the gear's symmetry class: a plain gear looks the same after every tooth pitch, so its
yaw is only defined modulo `period` (the pitch) and the posterior holds one mode; a marked gear has
period 2 pi and one mode per tooth-pitch repeat. Each mode is a local (x, y, yaw-offset) grid around
the same (x, y) cells; the cell masses are normalized over all modes. Within a cell the density is
uniform, and cells are cut to the hard `support` box (the prior's): no mass lies outside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

DIMS = ("x", "y", "yaw")
TURN = 2 * np.pi


def wrap(angle: np.ndarray | float, period: float = TURN) -> np.ndarray:
    """Angles wrapped to [-period/2, period/2) ([-pi, pi) by default)."""
    return (np.asarray(angle, float) + period / 2) % period - period / 2


def cell_overlap(centres: np.ndarray, width: float, lo: float, hi: float) -> np.ndarray:
    """Fraction of each cell [c - w/2, c + w/2] inside [lo, hi] (a point cell: 1 or 0)."""
    if width <= 0:
        return ((centres >= lo) & (centres <= hi)).astype(float)
    a = np.maximum(centres - width / 2, lo)
    b = np.minimum(centres + width / 2, hi)
    return np.clip(b - a, 0.0, None) / width


@dataclass
class PosePosterior:
    """Cell masses `log_mass` (modes, nx, ny, nyaw) over cells centred at (xs[i], ys[j],
    mode_yaws[k] + yaw_offsets[l]) of size (dx, dy, dyaw). `period` is the yaw after which the gear
    looks the same (yaw is a class modulo it); `support` = (x0, x1, y0, y1) is a hard box outside
    which there is no mass (cells straddling it keep the fraction inside). `informative` is False
    when the image could not tell where the gear is; `reason` then says why and the posterior is
    the prior."""

    gear: str
    xs: np.ndarray
    ys: np.ndarray
    mode_yaws: np.ndarray
    yaw_offsets: np.ndarray
    log_mass: np.ndarray
    informative: bool = True
    reason: str = ""
    info: dict = field(default_factory=dict)
    period: float = TURN
    support: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        self.xs, self.ys = np.asarray(self.xs, float), np.asarray(self.ys, float)
        self.mode_yaws = np.asarray(self.mode_yaws, float)
        self.yaw_offsets = np.asarray(self.yaw_offsets, float)
        shape = (len(self.mode_yaws), len(self.xs), len(self.ys), len(self.yaw_offsets))
        if self.log_mass.shape != shape:
            raise ValueError(f"log_mass has shape {self.log_mass.shape}; expected {shape}")
        if not (0 < self.period <= TURN and np.isclose(TURN / self.period, round(TURN / self.period))):
            raise ValueError(f"period = {self.period}; expected 2 pi / k for a whole k >= 1")
        lm = np.asarray(self.log_mass, float)
        if self.support is not None:
            x0, x1, y0, y1 = self.support
            if not (x0 < x1 and y0 < y1):
                raise ValueError(f"support {self.support}; expected (x0, x1, y0, y1) with x0 < x1 and y0 < y1")
            lm = lm + self._support_cut()
        if not np.isfinite(lm.max()):
            raise ValueError("the posterior has no mass (every cell is -inf or outside its support)")
        lm = lm - lm.max()
        self.log_mass = lm - np.log(np.exp(lm).sum())

    def _support_cut(self) -> np.ndarray:
        """(1, nx, ny, 1) log of each cell's fraction inside the support box (-inf outside)."""
        x0, x1, y0, y1 = self.support
        with np.errstate(divide="ignore"):
            return (
                np.log(cell_overlap(self.xs, self.dx, x0, x1))[None, :, None, None]
                + np.log(cell_overlap(self.ys, self.dy, y0, y1))[None, None, :, None]
            )

    def _evidence(self) -> np.ndarray:
        """The log-masses without the support cut (-inf outside the support): what the image says,
        up to a constant. The cut is geometry, not evidence: `tempered` and `upsampled` keep it
        out of what they rescale or interpolate, and the constructor applies it again."""
        if self.support is None:
            return np.asarray(self.log_mass, float)
        cut = self._support_cut()
        inside = np.isfinite(cut)
        return np.where(inside, self.log_mass - np.where(inside, cut, 0.0), -np.inf)

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
        """(modes, nyaw) yaw of each cell centre (a representative of its class), in [-pi, pi)."""
        return wrap(self.mode_yaws[:, None] + self.yaw_offsets[None, :])

    @property
    def map_pose(self) -> np.ndarray:
        """(x, y, yaw) of the most probable cell."""
        k, i, j, l = np.unravel_index(np.argmax(self.log_mass), self.log_mass.shape)
        return np.array([self.xs[i], self.ys[j], self.yaws()[k, l]])

    def sample(self, n: int, seed: int | None = None) -> np.ndarray:
        """n poses (n, 3) drawn from the posterior (uniform within each drawn cell, inside the
        support); yaw is the representative near the drawn cell's mode."""
        if n < 0:
            raise ValueError(f"n = {n}; expected a non-negative number of samples")
        rng = np.random.default_rng(seed)
        flat = rng.choice(self.mass.size, size=n, p=self.mass.ravel())
        k, i, j, l = np.unravel_index(flat, self.log_mass.shape)
        jitter = rng.uniform(-0.5, 0.5, size=(n, 3)) * [self.dx, self.dy, self.dyaw]
        poses = np.column_stack([self.xs[i], self.ys[j], self.yaws()[k, l]]) + jitter
        if self.support is not None:
            poses[:, 0] = np.clip(poses[:, 0], *self.support[:2])
            poses[:, 1] = np.clip(poses[:, 1], *self.support[2:])
        poses[:, 2] = wrap(poses[:, 2])
        return poses

    def _yaw_overlap(self, lo: float, span: float) -> np.ndarray:
        """(modes, nyaw) fraction of each yaw cell inside the arc [lo, lo + span], modulo period."""
        if span >= self.period:
            return np.ones((len(self.mode_yaws), len(self.yaw_offsets)))
        rel = (self.yaws() - lo) % self.period  # cell centres measured from the arc's start
        return sum(cell_overlap(rel + s, self.dyaw, 0.0, span) for s in (-self.period, 0.0, self.period))

    def probability(
        self,
        x: tuple[float, float] | None = None,
        y: tuple[float, float] | None = None,
        yaw: tuple[float, float] | None = None,
    ) -> float:
        """Probability that the pose lies in the box x in [x0, x1], y in [y0, y1] and yaw in the arc
        from yaw0 counter-clockwise to yaw1 [rad] (for a symmetric gear: that some yaw of its class
        does); a dimension left as None is unconstrained."""
        fx = cell_overlap(self.xs, self.dx, *x) if x is not None else np.ones(len(self.xs))
        fy = cell_overlap(self.ys, self.dy, *y) if y is not None else np.ones(len(self.ys))
        if yaw is None:
            fyaw = np.ones((len(self.mode_yaws), len(self.yaw_offsets)))
        else:
            span = float((yaw[1] - yaw[0]) % TURN) or TURN
            fyaw = np.clip(self._yaw_overlap(float(yaw[0]), span), 0.0, 1.0)
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
        """Differential entropy [nats] of the piecewise-constant marginal density of `dim` (yaw:
        over the symmetry class)."""
        _, p = self.marginal(dim)
        width = {"x": self.dx, "y": self.dy, "yaw": self.dyaw}[dim]
        p = p[p > 0]
        return float(-(p * np.log(p / max(width, 1e-12))).sum())

    def mean(self) -> np.ndarray:
        """Posterior mean of x and y [m] and the circular mean of yaw over its class [rad]."""
        out = [(v * p).sum() for v, p in (self.marginal("x"), self.marginal("y"))]
        v, p = self.marginal("yaw")
        scale = TURN / self.period
        out.append(wrap(np.angle((p * np.exp(1j * scale * v)).sum()) / scale))
        return np.array(out)

    def std(self) -> np.ndarray:
        """Standard deviations of x and y [m] and the circular standard deviation of yaw over its
        symmetry class [rad], each including the spread within a cell (width^2 / 12)."""
        out = []
        for dim, width in (("x", self.dx), ("y", self.dy)):
            v, p = self.marginal(dim)
            mu = (v * p).sum()
            out.append(np.sqrt(max(((v - mu) ** 2 * p).sum(), 0.0) + width**2 / 12))
        v, p = self.marginal("yaw")
        scale = TURN / self.period
        r = abs((p * np.exp(1j * scale * v)).sum())
        sigma = np.sqrt(-2 * np.log(np.clip(r, 1e-12, 1.0))) / scale
        out.append(np.sqrt(sigma**2 + self.dyaw**2 / 12))
        return np.array(out)

    def _levels(self) -> np.ndarray:
        """Per cell, the credible level at which it enters the highest-probability region: the
        mass of every denser cell plus half the mass of cells as dense as it."""
        flat = self.mass.ravel()
        order = np.argsort(-flat, kind="stable")
        sorted_mass = flat[order]
        before = np.cumsum(sorted_mass) - sorted_mass
        # cells of equal mass (ties) share the level of their group's middle
        _, first, counts = np.unique(-sorted_mass, return_index=True, return_counts=True)
        group_mid = before[first] + 0.5 * sorted_mass[first] * counts
        levels = np.empty(flat.size)
        levels[order] = np.repeat(group_mid, counts)
        return levels.reshape(self.mass.shape)

    def tempered(self, factor: float) -> "PosePosterior":
        """The posterior with its tempering exponent multiplied by `factor` (> 0), on the same
        cells: log-masses scaled by `factor` and renormalized. A factor below 1 widens it, above 1
        sharpens it; used to fit the tempering (docs/perception.md), exact when the cells cover
        the rescaled posterior."""
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"factor = {factor}; expected a finite tempering factor > 0")
        return self._with_evidence(factor * self._evidence())

    def shaped(self, exponent: float) -> "PosePosterior":
        """The posterior whose log-evidence deficit from its peak, D = max - log-evidence [nats],
        is raised to `exponent` (> 0), on the same cells: log-evidence max - D^exponent. Above 1
        the tails fall faster and the core (D < 1) flattens; 1 returns the posterior itself. A
        robust pixel likelihood's deficit grows linearly, not quadratically, far from the peak, so
        its tails are heavier than the pose errors' (docs/perception.md, Tempering)."""
        return self.reshaped(1.0, exponent)

    def reshaped(self, factor: float, exponent: float) -> "PosePosterior":
        """The posterior whose log-evidence deficit from its peak D becomes (factor D)^exponent,
        on the same cells (both > 0): `tempered(factor)`, then `shaped(exponent)`; the cells and
        the order of their densities stay, so the MAP does not move. (1, 1) returns the posterior
        itself, and `reshaped(f ** -g, 1 / g)` undoes `reshaped(f, g)`."""
        for name, value in (("factor", factor), ("exponent", exponent)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value}; expected a finite reshaping {name} > 0")
        if factor == 1 and exponent == 1:
            return self
        raw = self._evidence()
        with np.errstate(invalid="ignore"):
            deficit = factor * (raw.max() - raw)
            reshaped = np.where(np.isfinite(raw), -(deficit**exponent), -np.inf)
        return self._with_evidence(reshaped)

    def _with_evidence(self, log_evidence: np.ndarray) -> "PosePosterior":
        """This posterior with another log-evidence on the same cells (the support cut applied
        again by the constructor)."""
        return PosePosterior(
            self.gear,
            self.xs,
            self.ys,
            self.mode_yaws,
            self.yaw_offsets,
            log_evidence,
            self.informative,
            self.reason,
            dict(self.info),
            self.period,
            self.support,
        )

    def upsampled(self, factor: int, order: int = 3) -> "PosePosterior":
        """The posterior on cells `factor` times finer in x, y and yaw over the same cell centres'
        span: the log-evidence between the scored cell centres by a spline of `order` (capped at
        its largest scored value, so no peak is invented), the support cut recomputed per fine
        cell. The scored centres keep their values; factor 1 returns the posterior itself."""
        from scipy.ndimage import zoom

        if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
            raise ValueError(f"factor = {factor!r}; expected a whole number >= 1")
        if factor == 1:
            return self
        raw = self._evidence()
        finite = np.isfinite(raw)
        raw = np.where(finite, raw, raw[finite].min())  # cells outside the support: their floor

        def fine_axis(v: np.ndarray) -> np.ndarray:
            return np.linspace(v[0], v[-1], (len(v) - 1) * factor + 1) if len(v) > 1 else v

        xs, ys, offsets = fine_axis(self.xs), fine_axis(self.ys), fine_axis(self.yaw_offsets)
        shape = (len(xs), len(ys), len(offsets))
        scale = [m / k for m, k in zip(shape, raw.shape[1:])]
        fine = (
            np.stack([zoom(r, scale, order=order, mode="nearest", grid_mode=False) for r in raw])
            if raw.shape[1:] != shape
            else raw
        )
        fine = np.minimum(fine, raw.max())
        return PosePosterior(
            self.gear,
            xs,
            ys,
            self.mode_yaws,
            offsets,
            fine,
            self.informative,
            self.reason,
            dict(self.info),
            self.period,
            self.support,
        )

    def credible_mask(self, level: float = 0.9) -> np.ndarray:
        """Cells of the highest-probability region holding `level` of the mass (a cell is in when
        its own credible level, see `credible_level`, is below `level`)."""
        if not 0 < level <= 1:
            raise ValueError(f"level = {level}; expected a probability in (0, 1]")
        return self._levels() < level

    def cell_of(self, pose: np.ndarray) -> tuple[int, int, int, int] | None:
        """Index (mode, i, j, l) of the cell holding `pose` (its yaw taken modulo the period), or
        None outside the grid or the support."""
        x, y, yaw = np.asarray(pose, float)
        if self.support is not None:
            x0, x1, y0, y1 = self.support
            if not (x0 <= x <= x1 and y0 <= y <= y1):
                return None
        i = int(np.round((x - self.xs[0]) / self.dx)) if self.dx else 0
        j = int(np.round((y - self.ys[0]) / self.dy)) if self.dy else 0
        if not (0 <= i < len(self.xs) and 0 <= j < len(self.ys)):
            return None
        off = wrap(yaw - self.mode_yaws, self.period)  # offset from each mode centre
        l = np.round((off - self.yaw_offsets[0]) / self.dyaw).astype(int) if self.dyaw else 0 * off
        ok = np.nonzero((l >= 0) & (l < len(self.yaw_offsets)))[0]
        if ok.size == 0:
            return None
        k = ok[np.argmin(np.abs(off[ok]))]
        return int(k), i, j, int(l[k])

    def credible_level(self, pose: np.ndarray) -> float:
        """The smallest credible level whose highest-probability region holds `pose` (1.0 outside
        the grid): uniform on (0, 1) over the truths of a calibrated posterior."""
        cell = self.cell_of(pose)
        return 1.0 if cell is None else float(self._levels()[cell])

    def contains(self, pose: np.ndarray, level: float = 0.9) -> bool:
        """Whether `pose` lies in the `level` highest-probability credible region."""
        if not 0 < level <= 1:
            raise ValueError(f"level = {level}; expected a probability in (0, 1]")
        return self.credible_level(pose) < level

    def summary(self) -> dict:
        """A JSON-ready summary: MAP, standard deviations, entropies, flags."""
        return {
            "gear": self.gear,
            "informative": self.informative,
            "reason": self.reason,
            "map": self.map_pose.tolist(),
            "std": self.std().tolist(),
            "entropy": {d: self.marginal_entropy(d) for d in DIMS},
            **{k: v for k, v in self.info.items() if isinstance(v, (int, float, str))},
        }

    def plot(self, path: str | Path | None = None, truth: np.ndarray | None = None):
        """The x-y map (summed over yaw) and the yaw marginal (the seed paper's Fig. 12); saved to
        `path` if given. Returns the matplotlib Figure (made without pyplot: no backend is chosen
        or switched; a notebook shows it as a cell's value, or with IPython's display)."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(9, 3.6))
        ax0, ax1 = fig.subplots(1, 2)
        xy = self.mass.sum(axis=(0, 3))
        extent = [
            1e3 * (self.xs[0] - self.dx / 2),
            1e3 * (self.xs[-1] + self.dx / 2),
            1e3 * (self.ys[0] - self.dy / 2),
            1e3 * (self.ys[-1] + self.dy / 2),
        ]
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


def uniform_posterior(
    gear: str,
    centre: tuple[float, float],
    half_width: float,
    reason: str,
    period: float = TURN,
    cells: int = 21,
    yaw_cells: int = 72,
    info: dict | None = None,
) -> PosePosterior:
    """The prior, flagged uninformative: uniform over the square box of `half_width` around
    `centre` (its support) and over every yaw of the symmetry class (`period`)."""
    edges = (np.arange(cells) + 0.5) * 2 * half_width / cells - half_width
    offsets = -period / 2 + (np.arange(yaw_cells) + 0.5) * period / yaw_cells
    support = (centre[0] - half_width, centre[0] + half_width, centre[1] - half_width, centre[1] + half_width)
    return PosePosterior(
        gear,
        centre[0] + edges,
        centre[1] + edges,
        np.zeros(1),
        offsets,
        np.zeros((1, cells, cells, yaw_cells)),
        informative=False,
        reason=reason,
        info=dict(info or {}),
        period=period,
        support=support,
    )
