"""Known feasible sets on the unit box and how a sampler's density measures against them.

A `Layout` is a reward oracle on [0, 1]^d whose feasible set F is known exactly: a 0/1 layout has
reward 1 on F and 0 elsewhere; a graded layout has a plateau at 1 on a core region, 0 far away, a
smooth ramp between, and F = {reward >= 0.5}. `LAYOUTS` is the suite of issue 21 (disks of very
different sizes, a ring, a thin rotated strip, a set on the box's edges and corners, a 5 % and a
0.3 % disk, 3-D and 6-D ellipsoids, the authors' 48 % half-plane anchor, 1-D intervals, graded 1-D
and 2-D rewards).

The measures are pure functions of a log-density callable (parameter units, -inf outside the
support) and points, so they serve any sampler on the protocol (assembly.samplers) and, later,
trained skills whose feasible set is a labelled grid of points:

- `mass_on`: the share of a sampler's draws in F;
- `coverage`: the share of F (points uniform on F) where the density exceeds `level` times the
  uniform-on-F density 1 / (share * volume);
- `kl_to_optimum`: KL(q || p*) by Monte Carlo on q's draws, with p* the optimum of an objective:
  ("entropy", alpha): p* proportional to exp(r / alpha) on the box (max E_q[r] + alpha H(q));
  ("constrained", delta): p* = (1 - delta) U_F + delta U_{box \\ F} (max H(q) s.t. E_q[1_F] >= 1 - delta).

Example:
    >>> import numpy as np
    >>> layout = LAYOUTS["small"]
    >>> round(layout.share, 4)
    0.05
    >>> uniform = lambda xi: np.zeros(len(xi))  # log density of the uniform unit box
    >>> inside = layout.sample_inside(1000, np.random.default_rng(0))
    >>> coverage(uniform, inside, layout.share, 0.1), coverage(uniform, inside, layout.share, 0.01)
    (0.0, 1.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from assembly.params import Param, ParamSpace
from goflow_common.checks import check_choice, check_finite_array, check_int, check_number
from goflow_common.errors import InputError

__all__ = [
    "Layout",
    "LAYOUTS",
    "OBJECTIVES",
    "unit_space",
    "mass_on",
    "coverage",
    "report_on",
    "optimum_log_prob",
    "optimum_mass",
    "kl_to_optimum",
    "describe",
]

#: Points of the fixed-seed uniform Monte Carlo behind shares and normalizing constants.
MC_POINTS = 1_000_000
MC_SEED = 20_250_021
_CHUNK = 100_000

#: (n, d) points -> (n,) values: a log density, a margin.
LogDensity = Callable[[NDArray[np.float64]], NDArray[np.float64]]
PointFunction = LogDensity


def unit_space(dim: int) -> ParamSpace:
    """The unit box [0, 1]^dim as a ParamSpace with parameters p0..p{dim-1}, unit "1"."""
    check_int(dim, "dim", 1)
    return ParamSpace(tuple(Param(f"p{i}", 0.0, 1.0, "1") for i in range(dim)))


# -- the layouts ----------------------------------------------------------------------------------


def _smoothstep(t: NDArray[np.float64]) -> NDArray[np.float64]:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class Layout:
    """A reward oracle on the unit box [0, 1]^dim with a known feasible set F.

    Arguments:
        name: the suite's key.
        dim: the number of parameters d.
        description: one line for tables and figures.
        margin: (n, d) -> (n,), positive inside F, negative outside, zero on its boundary; a signed
            distance in box units where the shape allows (disks, intervals, half-planes), a scaled
            one elsewhere (ellipsoids, strips: exact sign, approximate magnitude).
        ramp: 0 for a 0/1 reward; > 0 for a graded one: reward = smoothstep((margin + ramp/2) /
            ramp), so 1 where margin >= ramp/2, 0 where margin <= -ramp/2, exactly 0.5 on F's boundary.
        exact_share: F's share of the box when known in closed form (None: Monte Carlo).

    F = {margin >= 0} = {reward >= 0.5} (for a 0/1 layout, {reward == 1}).
    """

    name: str
    dim: int
    description: str
    margin: Callable[[NDArray[np.float64]], NDArray[np.float64]] = field(repr=False)
    ramp: float = 0.0
    exact_share: float | None = None

    def __post_init__(self) -> None:
        check_int(self.dim, f"Layout {self.name!r}: dim", 1)
        check_number(self.ramp, f"Layout {self.name!r}: ramp", 0.0)
        if self.exact_share is not None:
            check_number(
                self.exact_share, f"Layout {self.name!r}: exact_share", 0.0, 1.0, low_open=True, high_open=True
            )

    @property
    def graded(self) -> bool:
        """Whether the reward has a ramp (else it is 0/1)."""
        return self.ramp > 0.0

    @property
    def space(self) -> ParamSpace:
        """The unit box as a ParamSpace (`unit_space(dim)`)."""
        return unit_space(self.dim)

    @property
    def volume(self) -> float:
        """The box's volume: 1."""
        return 1.0

    def _points(self, xi: ArrayLike) -> NDArray[np.float64]:
        return check_finite_array(xi, "xi", (None, self.dim))

    def reward(self, xi: ArrayLike) -> NDArray[np.float64]:
        """The reward in [0, 1] at (n, d) points, shape (n,)."""
        m = self.margin(self._points(xi))
        if not self.graded:
            return (m >= 0.0).astype(np.float64)
        return _smoothstep((m + 0.5 * self.ramp) / self.ramp)

    def contains(self, xi: ArrayLike) -> NDArray[np.bool_]:
        """Whether each of the (n, d) points lies in F, shape (n,)."""
        return self.margin(self._points(xi)) >= 0.0

    def monte_carlo_share(self, n: int = MC_POINTS, seed: int = MC_SEED) -> float:
        """F's share of the box from n uniform points drawn with `seed` (in chunks)."""
        check_int(n, "n", 1)
        rng = np.random.default_rng(seed)
        hits = 0
        for start in range(0, n, _CHUNK):
            hits += int(self.contains(rng.random((min(_CHUNK, n - start), self.dim))).sum())
        return hits / n

    @cached_property
    def share(self) -> float:
        """F's share of the box: `exact_share`, else the fixed-seed 10^6-point Monte Carlo (cached)."""
        return self.exact_share if self.exact_share is not None else self.monte_carlo_share()

    @cached_property
    def uniform_rewards(self) -> NDArray[np.float64]:
        """Rewards at the fixed-seed 10^6 uniform points (cached; behind graded normalizers)."""
        rng = np.random.default_rng(MC_SEED)
        return np.concatenate(
            [self.reward(rng.random((min(_CHUNK, MC_POINTS - s), self.dim))) for s in range(0, MC_POINTS, _CHUNK)]
        )

    def sample_inside(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n points uniform on F, shape (n, d) (rejection from the uniform box)."""
        n = check_int(n, "n", 0)
        out: list[NDArray[np.float64]] = []
        have = 0
        per_draw = max(self.share, 1e-4)
        while have < n:
            batch = int(min(4 * _CHUNK, max(1024, 1.2 * (n - have) / per_draw)))
            x = rng.random((batch, self.dim))
            x = x[self.contains(x)]
            out.append(x)
            have += len(x)
        return np.concatenate(out)[:n] if out else np.zeros((0, self.dim))


def _rotation(dim: int, planes: tuple[tuple[int, int, float], ...]) -> NDArray[np.float64]:
    """The product of Givens rotations (i, j, angle in degrees), applied in order."""
    rot = np.eye(dim)
    for i, j, degrees in planes:
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        g = np.eye(dim)
        g[i, i], g[i, j], g[j, i], g[j, j] = c, -s, s, c
        rot = g @ rot
    return rot


def _disk(centre: tuple[float, ...], radius: float) -> PointFunction:
    c = np.asarray(centre)
    return lambda x: radius - np.linalg.norm(x - c, axis=1)


def _union(*margins: PointFunction) -> PointFunction:
    return lambda x: np.max(np.stack([m(x) for m in margins]), axis=0)


def _annulus(centre: tuple[float, float], inner: float, outer: float) -> PointFunction:
    c = np.asarray(centre)

    def margin(x: NDArray[np.float64]) -> NDArray[np.float64]:
        r = np.linalg.norm(x - c, axis=1)
        return np.minimum(r - inner, outer - r)

    return margin


def _strip(centre: tuple[float, float], length: float, width: float, degrees: float) -> PointFunction:
    """A rectangle length x width, its long side at `degrees` from the p0 axis."""
    c, rot = np.asarray(centre), _rotation(2, ((0, 1, degrees),))

    def margin(x: NDArray[np.float64]) -> NDArray[np.float64]:
        local = (x - c) @ rot  # coordinates along the rectangle's axes
        return np.minimum(0.5 * length - np.abs(local[:, 0]), 0.5 * width - np.abs(local[:, 1]))

    return margin


def _ellipsoid(
    centre: tuple[float, ...], axes: tuple[float, ...], planes: tuple[tuple[int, int, float], ...]
) -> PointFunction:
    """A rotated ellipsoid; margin = min(axes) * (1 - |scaled local coordinates|)."""
    c, a, rot = np.asarray(centre), np.asarray(axes), _rotation(len(centre), planes)
    return lambda x: float(a.min()) * (1.0 - np.linalg.norm(((x - c) @ rot) / a, axis=1))


def _halfplane(normal: tuple[float, ...], offset: float) -> PointFunction:
    """{x: normal . x <= offset}, margin the signed distance to its boundary."""
    n = np.asarray(normal)
    norm = float(np.linalg.norm(n))
    return lambda x: (offset - x @ n) / norm


def _band(axis: int, start: float) -> PointFunction:
    """{x: x[axis] >= start}."""
    return lambda x: x[:, axis] - start


_R_SMALL = math.sqrt(0.05 / math.pi)  # a disk of 5 % of the box
_R_TINY = math.sqrt(0.003 / math.pi)  # a disk of 0.3 % (the gears' capture range)


def _suite() -> dict[str, Layout]:
    layouts = [
        Layout(
            "disks",
            2,
            "three disjoint disks, radii 0.2, 0.08, 0.04",
            _union(_disk((0.3, 0.65), 0.2), _disk((0.72, 0.3), 0.08), _disk((0.8, 0.75), 0.04)),
            exact_share=math.pi * (0.2**2 + 0.08**2 + 0.04**2),
        ),
        Layout(
            "ring",
            2,
            "an off-centre annulus, radii 0.2 to 0.32",
            _annulus((0.45, 0.55), 0.2, 0.32),
            exact_share=math.pi * (0.32**2 - 0.2**2),
        ),
        Layout(
            "strip",
            2,
            "a thin strip 0.9 x 0.04 rotated by 30 degrees",
            _strip((0.5, 0.5), 0.9, 0.04, 30.0),
            exact_share=0.9 * 0.04,
        ),
        Layout(
            "edges",
            2,
            "a quarter disk (radius 0.35) in a corner and a band along the opposite edge",
            _union(_disk((0.0, 0.0), 0.35), _band(0, 0.9)),
            exact_share=math.pi * 0.35**2 / 4 + 0.1,
        ),
        Layout("small", 2, "an off-centre disk of 5 % of the box", _disk((0.7, 0.3), _R_SMALL), exact_share=0.05),
        Layout("tiny", 2, "an off-centre disk of 0.3 % of the box", _disk((0.3, 0.7), _R_TINY), exact_share=0.003),
        Layout(
            "halfplane",
            2,
            "the anchor: the half-plane p0 + 0.3 p1 <= 0.63, 48 % of the box",
            _halfplane((1.0, 0.3), 0.63),
            exact_share=0.48,
        ),
        Layout(
            "intervals",
            1,
            "two intervals, [0.15, 0.25] and [0.55, 0.85]",
            _union(_disk((0.2,), 0.05), _disk((0.7,), 0.15)),
            exact_share=0.4,
        ),
        Layout(
            "ellipsoid3d",
            3,
            "an off-centre rotated ellipsoid, semi-axes 0.38, 0.25, 0.15",
            _ellipsoid((0.55, 0.45, 0.5), (0.38, 0.25, 0.15), ((0, 1, 30.0), (1, 2, 40.0), (0, 2, 20.0))),
            exact_share=4.0 / 3.0 * math.pi * 0.38 * 0.25 * 0.15,
        ),
        Layout(
            "ellipsoid6d",
            6,
            "an off-centre rotated ellipsoid cut by the box, about 11 % of it",
            _ellipsoid(
                (0.45, 0.55, 0.5, 0.4, 0.6, 0.5),
                (0.75, 0.6, 0.55, 0.5, 0.45, 0.4),
                ((0, 1, 30.0), (2, 3, 45.0), (4, 5, 20.0), (1, 4, 35.0), (0, 5, 25.0)),
            ),
        ),
        Layout(
            "graded1d",
            1,
            "graded: plateau on [0.55, 0.65], ramp 0.2, F = [0.45, 0.75]",
            _disk((0.6,), 0.15),
            ramp=0.2,
            exact_share=0.3,
        ),
        Layout(
            "graded2d",
            2,
            "graded: two disks (radii 0.18, 0.12), ramp 0.1",
            _union(_disk((0.3, 0.35), 0.18), _disk((0.72, 0.7), 0.12)),
            ramp=0.1,
            exact_share=math.pi * (0.18**2 + 0.12**2),
        ),
    ]
    return {layout.name: layout for layout in layouts}


#: The suite of issue 21, by name.
LAYOUTS: dict[str, Layout] = _suite()

# -- the measures ---------------------------------------------------------------------------------

#: The objectives whose optimum p* is known: ("entropy", alpha) and ("constrained", delta).
OBJECTIVES: tuple[str, ...] = ("entropy", "constrained")


def _check_objective(objective: tuple[str, float]) -> tuple[str, float]:
    if not isinstance(objective, (tuple, list)) or len(objective) != 2:
        raise InputError(f'objective = {objective!r}; expected ("entropy", alpha) or ("constrained", delta)')
    kind = check_choice(objective[0], OBJECTIVES, "objective kind")
    if kind == "entropy":
        return kind, check_number(objective[1], "objective alpha", 0.0, low_open=True)
    return kind, check_number(objective[1], "objective delta", 0.0, 1.0, low_open=True, high_open=True)


def _finite_log(values: NDArray[np.float64], what: str) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if np.isnan(arr).any():
        raise InputError(f"{what}: the log density returned NaN at {int(np.isnan(arr).sum())} points")
    return arr


def mass_on(samples: ArrayLike, contains: Callable[[NDArray[np.float64]], NDArray[np.bool_]]) -> float:
    """The share of `samples` (n, d), n >= 1, for which `contains` is true: a sampler's mass on F
    when they are its draws (standard error sqrt(m (1 - m) / n))."""
    x = check_finite_array(samples, "samples", (None, None))
    if len(x) == 0:
        raise InputError("samples has 0 rows; expected at least one draw")
    return float(np.mean(np.asarray(contains(x), dtype=bool)))


def coverage(log_prob: LogDensity, inside_points: ArrayLike, share: float, level: float, volume: float = 1.0) -> float:
    """The share of F where a density exceeds `level` x the uniform-on-F density.

    Arguments:
        log_prob: the sampler's log density, (n, d) -> (n,), in the box's units (-inf outside).
        inside_points: (n, d) points uniform on F (e.g. `Layout.sample_inside`, or the feasible
            points of a uniform grid).
        share: F's share of the box, in (0, 1].
        level: the fraction of the uniform-on-F density 1 / (share * volume), e.g. 0.1 or 0.01.
        volume: the box's volume in its units (1 for the unit box).

    Returns: the fraction of `inside_points` where log_prob > log(level / (share * volume)):
    1 for a density uniform on F (level < 1); for the uniform box 1 when level < share and 0
    otherwise (at level 0.1 the uniform box covers none of a 5 % set); small for a density that
    misses part of F.
    """
    x = check_finite_array(inside_points, "inside_points", (None, None))
    if len(x) == 0:
        raise InputError("inside_points has 0 rows; expected points uniform on the feasible set")
    share = check_number(share, "share", 0.0, 1.0, low_open=True)
    level = check_number(level, "level", 0.0, low_open=True)
    volume = check_number(volume, "volume", 0.0, low_open=True)
    lp = _finite_log(log_prob(x), "coverage")
    return float(np.mean(lp > math.log(level) - math.log(share * volume)))


def report_on(
    sampler: Any,
    contains: Callable[[NDArray[np.float64]], NDArray[np.bool_]],
    space: ParamSpace,
    rng: np.random.Generator,
    draws: int = 20_000,
    box_points: int = 200_000,
) -> dict[str, float]:
    """A sampler (`sample`, `log_prob`) against a feasible set given by `contains` over the box of
    `space`: the set's share of the box (`box_points` uniform draws), the sampler's mass on it
    (`draws` of its draws, after the box's from the same `rng`), and its coverage at 10 % and 1 %
    of the uniform-on-set density (0 when no box draw falls in the set)."""
    box = space.low + (space.high - space.low) * rng.random((box_points, space.dim))
    inside = box[np.asarray(contains(box), bool)]
    share, volume = len(inside) / len(box), float(np.prod(space.high - space.low))
    report = {"share": share, "mass_on": mass_on(sampler.sample(draws, rng), contains)}
    for level, key in ((0.1, "coverage10"), (0.01, "coverage1")):
        report[key] = coverage(sampler.log_prob, inside, share, level, volume) if len(inside) else 0.0
    return report


def optimum_log_prob(layout: Layout, objective: tuple[str, float]) -> LogDensity:
    """The log density (box units) of the optimum p* of `objective` on `layout`.

    ("entropy", alpha): log p*(x) = r(x) / alpha - log Z, Z = integral of exp(r / alpha) over the
    box; for a 0/1 reward Z = V (s e^{1/alpha} + 1 - s) exactly (s = share, V = volume); for a
    graded one Z is the mean of exp(r / alpha) over the layout's fixed-seed 10^6 uniform points
    times V (relative error below 1e-3 for alpha >= 0.1 on the suite).
    ("constrained", delta): log p* = log((1 - delta) / (s V)) on F, log(delta / ((1 - s) V)) off it.
    """
    kind, value = _check_objective(objective)
    s, log_v = layout.share, math.log(layout.volume)
    if kind == "constrained":
        on, off = math.log((1.0 - value) / s) - log_v, math.log(value / (1.0 - s)) - log_v
        return lambda x: np.where(layout.contains(x), on, off)
    alpha = value
    if layout.graded:
        scaled = layout.uniform_rewards / alpha
        top = float(scaled.max())
        log_z = top + math.log(float(np.mean(np.exp(scaled - top)))) + log_v
    else:  # log(s e^{1/a} + 1 - s), stable for small alpha
        log_z = 1.0 / alpha + math.log(s + (1.0 - s) * math.exp(-1.0 / alpha)) + log_v
    return lambda x: layout.reward(x) / alpha - log_z


def optimum_mass(layout: Layout, objective: tuple[str, float]) -> float:
    """The mass p* puts on F: 1 - delta for ("constrained", delta); for ("entropy", alpha)
    s e^{1/alpha} / (s e^{1/alpha} + 1 - s) with a 0/1 reward, and from the layout's uniform Monte
    Carlo points with a graded one (where F = {r >= 0.5} and r varies inside it)."""
    kind, value = _check_objective(objective)
    if kind == "constrained":
        return 1.0 - value
    s = layout.share
    if not layout.graded:
        return s / (s + (1.0 - s) * math.exp(-1.0 / value))
    r = layout.uniform_rewards
    w = np.exp((r - r.max()) / value)
    return float(np.sum(w[r >= 0.5]) / np.sum(w))


def kl_to_optimum(
    sampler_draws: ArrayLike, log_prob: LogDensity, layout: Layout, objective: tuple[str, float]
) -> float:
    """KL(q || p*) in nats, by Monte Carlo on draws of q.

    Arguments:
        sampler_draws: (n, d) independent draws of q (the distribution `log_prob` describes).
        log_prob: q's normalized log density in the box's units.
        layout: the reward oracle and its feasible set.
        objective: ("entropy", alpha) or ("constrained", delta); p* as in `optimum_log_prob`.

    Returns: mean_i [log q(x_i) - log p*(x_i)], the plain Monte Carlo estimate: unbiased when q is
    normalized, with standard error std(log q - log p*) / sqrt(n) (about 0.01-0.05 nats at n = 4096
    for the flows of the benchmark). It needs an exact log q: a density known only up to a constant,
    or one with atoms (ADR's boundary draws), biases it. +inf where q has a point mass (log q = +inf).
    Estimator choices: draws of q rather than importance sampling from the box (p* and q may be
    concentrated on a 0.3 % set; q's own draws cover where the integrand lives); log Z of p* exact
    for 0/1 rewards, from 10^6 fixed uniform points for graded ones (one number per layout and alpha,
    the same for every sampler and round, so it cancels in comparisons).
    """
    x = check_finite_array(sampler_draws, "sampler_draws", (None, layout.dim))
    if len(x) == 0:
        raise InputError("sampler_draws has 0 rows; expected draws of the sampler")
    lq = _finite_log(log_prob(x), "kl_to_optimum")
    if np.isposinf(lq).any():
        return math.inf
    if np.isneginf(lq).any():
        raise InputError(
            f"kl_to_optimum: log_prob is -inf at {int(np.isneginf(lq).sum())} of its own draws; "
            "expected draws of the distribution log_prob describes"
        )
    return float(np.mean(lq - optimum_log_prob(layout, objective)(x)))


def describe(layout: Layout) -> dict[str, Any]:
    """The layout as JSON data: name, dim, description, graded, share."""
    return {
        "name": layout.name,
        "dim": layout.dim,
        "description": layout.description,
        "graded": layout.graded,
        "share": layout.share,
    }
