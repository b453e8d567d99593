"""From an observation to a PosePosterior: staged grids (coarse to fine) to the MAP over
(x, y, yaw) with the gear flat on the table, then a grid posterior centred at the MAP.

1. Coarse: a grid over the prior box and over one period of the model's appearance in yaw (the
   whole turn for a marked gear: the model itself then has no symmetry), scored on sparse pixels;
   the best few go on.
2. Refine: 5 x 5 x 5 grids around the best, halving the steps, on denser pixels, down to the
   posterior's resolution.
3. Posterior: a local grid around the MAP whose steps adapt until the mass fits inside it and is
   spread over several cells, cut to the prior box (a hard support). A plain gear's yaw is a class
   modulo the tooth pitch, so its posterior is that one grid; for a marked gear the same yaw slice
   is scored at every tooth-pitch repeat of the MAP yaw, and each repeat gets the local grid's
   shape weighted by its own evidence.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import logsumexp

from assembly.gearset import gear_spec
from perception.gear_model import GearModel, gear_model
from perception.likelihood import LikelihoodConfig
from perception.observation import Observation
from perception.posterior import PosePosterior, cell_overlap, uniform_posterior, wrap
from perception.renderer import RayCasterConfig
from perception.scoring import ImageScorer
from perception.table_plane import aligned_to_table


@dataclass
class Prior:
    """Where the gear may be: a square of half-width `half_width` [m] around (x, y); any yaw."""

    x: float
    y: float
    half_width: float = 0.03

    def __post_init__(self) -> None:
        if not (np.isfinite(self.x) and np.isfinite(self.y)):
            raise ValueError(f"prior centre ({self.x}, {self.y}) is not finite; expected metres")
        if not (np.isfinite(self.half_width) and 0 < self.half_width <= 0.2):
            raise ValueError(f"prior half_width = {self.half_width}; expected (0, 0.2] m")

    @property
    def box(self) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1): the hard support of every posterior searched within this prior."""
        h = self.half_width
        return self.x - h, self.x + h, self.y - h, self.y + h

    def clip(self, poses: np.ndarray) -> np.ndarray:
        """`poses` (N, 3) with x and y moved into the box."""
        out = np.array(poses, float)
        out[:, 0] = np.clip(out[:, 0], self.x - self.half_width, self.x + self.half_width)
        out[:, 1] = np.clip(out[:, 1], self.y - self.half_width, self.y + self.half_width)
        return out


@dataclass
class SearchConfig:
    """Settings of the search and of the posterior grid (SI units, radians)."""

    likelihood: LikelihoodConfig = field(default_factory=LikelihoodConfig)
    raycaster: RayCasterConfig = field(default_factory=RayCasterConfig)
    coarse_pixels: int = 80  # sampled pixels on a gear in the coarse stage
    fine_pixels: int = 600  # ... in the refining stages and the posterior
    coarse_step: float = 0.35  # coarse x-y step, as a fraction of the tip radius
    coarse_yaw_cells: int = 4  # coarse yaw steps per appearance period ...
    coarse_yaw_cells_turn: int = 24  # ... or per turn for a model without symmetry (marked)
    beam: int = 2  # coarse hypotheses refined (distinct basins)
    sweep_yaw_cells: int = 16  # yaw sweep over one appearance period around the refined x-y
    sweep_xy: float = 1.5e-3  # ... within this x-y distance [m] (3 x 3 points)
    min_step: float = 2.5e-4  # finest x-y step [m] of the refinement
    min_yaw_step: float = np.radians(0.25)
    grid: int = 7  # posterior grid points per dimension (odd)
    adapt: int = 4  # posterior grids scored at most (refitted to the mass)
    max_cell_mass: float = 0.5  # refit the grid while an axis puts more than this in one cell
    max_edge_mass: float = 0.01  # ... or more than this in its two edge cells
    grid_step_std: float = 1.2  # refitted grid step, in standard deviations of the mass
    upsample: int = 2  # posterior cells per scored grid step (cubic spline between)
    min_pixels: int = 25  # fewer gear pixels (at the fine stride) -> uninformative
    min_inlier_fraction: float = 0.5
    fit_light: bool = True  # estimate the light's direction from the gear's shading
    light_rounds: int = 2  # ... and search again under it at most this many times

    def __post_init__(self) -> None:
        if self.light_rounds < 0:
            raise ValueError(f"light_rounds = {self.light_rounds}; expected >= 0")
        if isinstance(self.upsample, bool) or not isinstance(self.upsample, int) or self.upsample < 1:
            raise ValueError(f"upsample = {self.upsample!r}; expected a whole number >= 1")
        if isinstance(self.adapt, bool) or not isinstance(self.adapt, int) or self.adapt < 1:
            raise ValueError(f"adapt = {self.adapt!r}; expected a whole number >= 1")
        if not (
            0 < self.max_edge_mass < 0.5
            and 0 < self.max_cell_mass <= 1
            and np.isfinite(self.grid_step_std)
            and self.grid_step_std > 0
        ):
            raise ValueError(
                f"max_edge_mass = {self.max_edge_mass}, max_cell_mass = "
                f"{self.max_cell_mass}, grid_step_std = {self.grid_step_std}; expected "
                "0 < max_edge_mass < 0.5, 0 < max_cell_mass <= 1, grid_step_std > 0"
            )
        if self.grid < 3 or self.grid % 2 == 0:
            raise ValueError(f"grid = {self.grid}; expected an odd number >= 3")
        if self.beam < 1 or self.coarse_pixels < 10 or self.fine_pixels < self.coarse_pixels:
            raise ValueError(
                f"beam = {self.beam}, coarse_pixels = {self.coarse_pixels}, "
                f"fine_pixels = {self.fine_pixels}; expected beam >= 1 and "
                "10 <= coarse_pixels <= fine_pixels"
            )
        if self.coarse_yaw_cells < 1 or self.coarse_yaw_cells_turn < 4 or self.sweep_yaw_cells < 2:
            raise ValueError(
                f"coarse_yaw_cells = {self.coarse_yaw_cells}, coarse_yaw_cells_turn = "
                f"{self.coarse_yaw_cells_turn}, sweep_yaw_cells = "
                f"{self.sweep_yaw_cells}; expected >= 1, >= 4 and >= 2"
            )


def _grid(centre: np.ndarray, steps: np.ndarray, n: int) -> np.ndarray:
    """(n^3, 3) poses on a grid of n points per dimension around `centre`."""
    r = np.arange(n) - (n - 1) / 2
    g = np.meshgrid(*(centre[d] + r * steps[d] for d in range(3)), indexing="ij")
    return np.stack([a.ravel() for a in g], axis=1)


def _refine(
    centres: np.ndarray, steps: np.ndarray, score, stride: int, config: SearchConfig, prior: Prior, wide_stages: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Each centre refined on its own by grids of halving steps (5^3 for the first `wide_stages`
    stages, then 3^3) down to the finest steps; returns the refined poses and their scores."""
    st = np.asarray(steps, float).copy()
    floor = np.array([config.min_step, config.min_step, config.min_yaw_step])
    last = score(centres, stride).loglik
    stage = 0
    while np.any(st > floor):
        st = np.maximum(st / 2, floor)
        n = 5 if stage < wide_stages else 3
        cand = prior.clip(np.vstack([_grid(c, st, n) for c in centres]))
        sc = score(cand, stride).loglik.reshape(len(centres), n**3)
        centres = cand.reshape(len(centres), n**3, 3)[np.arange(len(centres)), sc.argmax(1)]
        last = sc.max(1)
        stage += 1
    return centres, last


def _distinct_best(poses: np.ndarray, loglik: np.ndarray, k: int, steps: np.ndarray, period: float) -> np.ndarray:
    """Up to k best poses, each at least one grid step (x-y) or one yaw step (modulo `period`) away
    from every better one kept: the beam covers distinct basins."""
    kept: list[np.ndarray] = []
    for i in np.argsort(loglik)[::-1]:
        p = poses[i]
        if all(
            np.hypot(*(p[:2] - q[:2])) > 0.99 * steps[0] or abs(wrap(p[2] - q[2], period)) > 0.99 * steps[2]
            for q in kept
        ):
            kept.append(p)
            if len(kept) == k:
                break
    return np.array(kept)


def _model(gear: str | GearModel) -> GearModel:
    return gear if isinstance(gear, GearModel) else gear_model(gear)


def estimate_pose(
    obs: Observation, gear: str | GearModel, prior: Prior, config: SearchConfig | None = None
) -> PosePosterior:
    """The posterior over `gear`'s pose (x, y, yaw) given `obs`, searched within `prior`.

    ValueError if the camera does not see the prior's region at all; a posterior flagged
    uninformative (the prior itself) if the gear cannot be found in the image."""
    config = config or SearchConfig()
    t0 = time.perf_counter()
    model = _model(gear)
    obs = aligned_to_table(obs)
    scorer = ImageScorer(
        obs, model, (prior.x, prior.y), prior.half_width * np.sqrt(2), config.likelihood, config.raycaster
    )
    info = {"hypotheses": 0}
    if scorer.footprint < config.min_pixels:
        raise ValueError(
            f"the camera does not see the {model.name} gear's search region around "
            f"({prior.x:.3f}, {prior.y:.3f}) m: {scorer.footprint} pixels of a gear "
            f"there would be in view; expected at least {config.min_pixels}"
        )

    def score(poses, stride):
        info["hypotheses"] += len(poses)
        return scorer.score(poses, stride)

    coarse = scorer.stride_for(config.coarse_pixels)
    fine = scorer.stride_for(config.fine_pixels)
    best = _search_map(model, prior, score, coarse, fine, config)
    # The light: if the gear's shading at the MAP says the light comes from elsewhere than the
    # assumed headlight (walls lit differently), search again under the fitted light; the fit at a
    # wrong pose is itself off, so refit at the new MAP (at most `light_rounds` times).
    for _ in range(config.light_rounds if config.fit_light else 0):
        if not scorer.fit_light(best, fine):
            break
        info["light"] = scorer.light.tolist()
        best = _search_map(model, prior, score, coarse, fine, config)
    # Sanity: does the best pose show enough of the gear, and explain what it shows?
    check = score(best[None], fine)
    pixels, inliers = int(check.pixels[0]), float(check.inliers[0])
    info.update(
        pixels=pixels,
        inlier_fraction=inliers / max(pixels, 1),
        stride=fine,
        search_hypotheses=info["hypotheses"],
        gsd=scorer.gsd,
        tempering=scorer.tempering,
        depth_noise=scorer.conditions.depth_noise,
        brightness=scorer.brightness,
        pixel_noise=scorer.conditions.pixel_noise,
        valid_fraction=scorer.valid_fraction,
    )
    reason = ""
    if pixels < config.min_pixels:
        reason = (
            f"only {pixels} pixels of the {model.name} gear at its best pose are in view "
            f"(expected >= {config.min_pixels}): occluded or out of view"
        )
    elif inliers / pixels < config.min_inlier_fraction:
        reason = (
            f"the best pose explains only {inliers / pixels:.0%} of its gear pixels "
            f"(expected >= {config.min_inlier_fraction:.0%}): the gear is not where the "
            "prior says, or something hides it"
        )
    if reason:
        info["seconds"] = time.perf_counter() - t0
        return uniform_posterior(
            model.name, (prior.x, prior.y), prior.half_width, reason, period=model.period, info=info
        )
    # 3. Posterior grid around the MAP, its evidence weighed by what the view and the MAP say.
    factor = config.likelihood.evidence_factor(
        scorer.gsd, inliers / pixels, scorer.conditions.pixel_noise, "light" in info
    )
    info.update(evidence_factor=factor, tempering=scorer.tempering * factor)

    def weighed(poses, stride):
        scores = score(poses, stride)
        return replace(scores, loglik=factor * scores.loglik)

    # 4. The reshaping, on the fixed cells: calibrates the posterior without moving its grid.
    reshaping = config.likelihood.reshaping_for(scorer.gsd, model.name, pixels, scorer.brightness)
    post = _posterior_grid(model, best, weighed, fine, config, prior).reshaped(*reshaping)
    info.update(posterior_factor=reshaping[0], shape=reshaping[1])
    info["seconds"] = time.perf_counter() - t0
    post.info.update(info)
    return post


def _search_map(model: GearModel, prior: Prior, score, coarse: int, fine: int, config: SearchConfig) -> np.ndarray:
    """The MAP pose within `prior`: a coarse grid, the beam refined, then the yaw sweep."""
    # 1. Coarse grid over the box and one appearance period.
    step = min(config.coarse_step * model.tip_radius, prior.half_width)
    nxy = int(np.ceil(prior.half_width / step)) * 2 + 1
    axis = np.linspace(-prior.half_width, prior.half_width, nxy)
    n_yaw = config.coarse_yaw_cells if model.symmetry > 1 else config.coarse_yaw_cells_turn
    yaw_step = model.period / n_yaw
    yaws = np.arange(n_yaw) * yaw_step - (np.pi if model.symmetry == 1 else 0.0)
    g = np.meshgrid(prior.x + axis, prior.y + axis, yaws, indexing="ij")
    poses = np.stack([a.ravel() for a in g], axis=1)
    s = score(poses, coarse)
    dxy = axis[1] - axis[0] if nxy > 1 else step
    steps = np.array([dxy, dxy, yaw_step])
    centres = _distinct_best(poses, s.loglik, config.beam, steps, model.period)
    # 2. Refine each of the beam's hypotheses on its own with shrinking grids (5^3 for the first
    #    stage, then 3^3), so that a yaw alias (e.g. half a tooth pitch off) cannot crowd out the
    #    true basin; the best refined one is the MAP so far.
    centres, last = _refine(centres, steps, score, fine, config, prior, wide_stages=1)
    best, best_ll = centres[int(np.argmax(last))], float(last.max())
    # 3. Yaw sweep at the refined position: the silhouette fixes x-y long before the teeth fix
    #    yaw, and a tooth pattern half a pitch off is a strong local optimum.
    return _yaw_sweep(best, best_ll, model, score, fine, config, prior)[0]


def _yaw_sweep(
    best: np.ndarray, best_ll: float, model: GearModel, score, stride: int, config: SearchConfig, prior: Prior
) -> tuple[np.ndarray, float]:
    """Sweep the whole appearance period finely in yaw at 3 x 3 positions around `best`'s x-y,
    refine the best two sweep hypotheses, and return the better of them and `best`."""
    sweep_step = model.period / config.sweep_yaw_cells
    if model.period <= 8 * config.min_yaw_step:
        return best, best_ll
    r = config.sweep_xy * np.linspace(-1.0, 1.0, 3)
    g = np.meshgrid(
        best[0] + r, best[1] + r, best[2] + sweep_step * np.arange(1, config.sweep_yaw_cells), indexing="ij"
    )
    sweep = prior.clip(np.stack([a.ravel() for a in g], axis=1))
    sweep_ll = score(sweep, stride).loglik
    steps = np.array([r[1] - r[0], r[1] - r[0], sweep_step])
    starts = _distinct_best(sweep, sweep_ll, 2, steps, model.period)
    alt, alt_ll = _refine(starts, steps, score, stride, config, prior)
    if alt_ll.max() > best_ll:
        return alt[int(np.argmax(alt_ll))], float(alt_ll.max())
    return best, best_ll


def _posterior_grid(
    model: GearModel, map_pose: np.ndarray, score, stride: int, config: SearchConfig, prior: Prior
) -> PosePosterior:
    """Local grid around the MAP with adapted steps, cut to the prior box; for a marked gear,
    replicated over the tooth-pitch repeats."""
    n = config.grid
    half = (n - 1) // 2
    teeth = gear_spec(model.name).teeth
    pitch = 2 * np.pi / teeth
    window = min(pitch, model.period)  # one mode's yaw window: a tooth pitch at most
    max_xy = 2 * prior.half_width / (n - 1)  # a grid never needs to be wider than the box
    centre = map_pose.copy()
    steps = _probe_steps(centre, score, stride, config, half, window)
    steps[:2] = np.minimum(steps[:2], max_xy)
    x0, x1, y0, y1 = prior.box
    cap = np.array([max_xy, max_xy, window / n])  # a mode's yaw window stays inside one pitch
    unit = np.arange(n) - half  # grid points in steps from the centre
    for attempt in range(config.adapt):
        poses = _grid(centre, steps, n)
        with np.errstate(divide="ignore"):
            cut = np.log(cell_overlap(poses[:, 0], steps[0], x0, x1)) + np.log(
                cell_overlap(poses[:, 1], steps[1], y0, y1)
            )
        ll = score(poses, stride).loglik.reshape(n, n, n)  # the support cut is the posterior's own
        cut_ll = ll + cut.reshape(n, n, n)
        p = np.exp(cut_ll - logsumexp(cut_ll))
        marginals = [p.sum(axis=tuple(a for a in range(3) if a != d)) for d in range(3)]
        edge = np.array([m[0] + m[-1] for m in marginals])
        top = np.array([m.max() for m in marginals])
        truncated = (edge > config.max_edge_mass) & (steps < cap)
        if attempt == config.adapt - 1 or not (truncated.any() or (top > config.max_cell_mass).any()):
            break
        # Moment-matched next grid: centred on the marginal means, steps of grid_step_std standard
        # deviations (a third of a step at least: mass in one cell has no measured spread); at
        # least doubled where the mass ran off an edge (its std is then underestimated).
        mean = np.array([m @ unit for m in marginals])
        var = np.array([m @ unit**2 for m in marginals]) - mean**2
        centre = centre + mean * steps
        centre[:2] = prior.clip(centre[None])[0, :2]
        fitted = config.grid_step_std * np.sqrt(np.maximum(var, 1.0 / 12.0)) * steps
        steps = np.minimum(np.where(truncated, np.maximum(fitted, 2 * steps), fitted), cap)
    edge_mass = float(edge.max())
    offsets = unit * steps[2]
    xs = centre[0] + unit * steps[0]
    ys = centre[1] + unit * steps[1]
    if model.symmetry > 1:  # yaw is a class modulo the period: one mode
        post = PosePosterior(
            model.name, xs, ys, centre[2:3], offsets, ll[None], period=model.period, support=prior.box
        ).upsampled(config.upsample)
        post.info["edge_mass"] = edge_mass
        return post
    # A marked gear: every tooth-pitch repeat of the MAP yaw, its yaw slice through the MAP (x, y).
    repeats = wrap(centre[2] + pitch * np.arange(teeth))
    slice_poses = np.array([[centre[0], centre[1], r + o] for r in repeats for o in offsets])
    slice_ll = score(slice_poses, stride).loglik.reshape(teeth, n)
    evidence = logsumexp(slice_ll, axis=1)
    log_mass = ll[None] + (evidence - evidence[0])[:, None, None, None]
    post = PosePosterior(model.name, xs, ys, repeats, offsets, log_mass, support=prior.box).upsampled(config.upsample)
    post.info["repeat_log_evidence"] = (evidence - evidence.max()).tolist()
    post.info["edge_mass"] = edge_mass
    return post


def _probe_steps(centre: np.ndarray, score, stride: int, config: SearchConfig, half: int, window: float) -> np.ndarray:
    """Posterior grid steps from 1-D probes: along each axis, how far from the MAP the tempered
    log-likelihood falls by 4 (about 2.8 standard deviations for a Gaussian); the grid reaches
    1.25 times that far."""
    dist = np.array([config.min_step, config.min_step, config.min_yaw_step]) * 2.0 ** np.arange(7)[:, None]
    poses = []
    for d in range(3):
        for sign in (-1, 1):
            p = np.repeat(centre[None], len(dist), axis=0)
            p[:, d] += sign * dist[:, d]
            poses.append(p)
    ll = score(np.vstack([centre[None]] + poses), stride).loglik
    drop = ll[0] - ll[1:].reshape(3, 2, len(dist))
    steps = np.empty(3)
    for d in range(3):
        far = np.nonzero(drop[d].min(axis=0) > 4.0)[0]
        reach = dist[far[0], d] if far.size else dist[-1, d]
        steps[d] = 1.25 * reach / half
    steps[:2] = np.maximum(steps[:2], config.min_step / 2)
    steps[2] = min(max(steps[2], config.min_yaw_step / 2), window / (2 * half + 1))
    return steps
