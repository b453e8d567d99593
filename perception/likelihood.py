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
from dataclasses import dataclass, field
from functools import lru_cache

import numba
import numpy as np

from assembly.gear_meshes import gearset_model_paths
from assembly.gearset import GEAR_MODULE, gear_spec


# Per gear, the factor A (gsd / g0)^B on the shared tempering law, as (A, B): fitted on tuning
# scenes by benchmarks/perception_tempering.py (docs/perception.md, Tempering).
GEAR_TEMPERING = {"small": (1.516, 0.3), "medium": (1.320, 0.3), "large": (1.0, 0.45)}
# The posterior's reshaping once its cells are fixed, (unresolved, resolved teeth): fitted by
# benchmarks/perception_tempering.py (`fit_reshaping`, on rows with shaped levels), on the tuning
# scenes of seeds 600 and 700, again on seed 5000's with COLOUR_SCALE_FACTOR (the resolved factor
# and the unresolved exponent moved); both pairs refitted with FAR_RESHAPING and CLOSE_RESHAPING on
# seed 6500's rows and the fresh sets 19000-25000 (benchmarks/perception_reshaping.py; Tempering,
# item 11).
POSTERIOR_FACTOR = (0.7608, 1.0)
SHAPE_EXPONENT = (1.25, 1.25)
# b_rgb's factor, (unresolved, resolved teeth): chosen on tuning scenes (docs/perception.md,
# Tempering, item 8).
COLOUR_SCALE_FACTOR = (1.0, 2.0)
# Per gear, (a, b) of the far view's reshaping factor (a (n / FAR_REFERENCE_PIXELS)^b)^(1 - w), n the
# gear's sampled pixels at the MAP, w = `teeth_resolved`: where the teeth are not resolved the
# sampled pixels err about independently, so a far view's evidence grows with their number, which
# the tempering law (outline-bound evidence) and the stride's weighting leave out (docs/perception.md,
# Tempering, item 9); fitted by benchmarks/perception_far_view.py. The gears not named keep 1.
FAR_RESHAPING = {"small": (1.4641, 1.1), "medium": (1.0353, 0.8), "large": (1.0353, 0.9)}
FAR_REFERENCE_PIXELS = 600.0  # sampled pixels at which a alone applies (SearchConfig.fine_pixels)
# Per gear, (a, c_dim, c_bright) of the close view's reshaping factor (a g^c)^w, g the light's
# colour gain read off the table (c_dim below 1, c_bright above), w = `teeth_resolved`: the gears'
# colours answer the light differently, which one colour scale exponent for every gear leaves out
# (docs/perception.md, Tempering, item 10); fitted by benchmarks/perception_close_view.py. The
# gears not named keep 1.
GAIN_RANGE = (0.25, 4.0)  # the colour gains the light laws (colour scale, close_reshaping) follow
CLOSE_RESHAPING = {"small": (1.0, 0.05, 0.1), "medium": (1.0718, 0.25, -0.05), "large": (1.0534, -0.05, 0.25)}


@dataclass
class LikelihoodConfig:
    """p_out: outlier probability; b_rgb: colour scale (L1 over r, g, b in [0, 1]); b_d: depth
    scale [m]; depth_range: support of the outlier depth density [m]; tempering: exponent on the
    full-resolution product of pixel likelihoods (accounts for correlated pixels); its default
    comes from the view and the gear: correlation_length, gsd_exponent, reference_gsd and
    gear_tempering, per gear (A, B) of a factor A (gsd / g0)^B on the shared law (tempering_for)."""

    p_out: float = 0.1
    b_rgb: float = 0.15
    b_d: float = 0.004
    depth_range: float = 2.0
    tempering: float | None = None  # None: from the view and the gear (see tempering_for)
    correlation_length: float = 1.0e-3  # [m] along the gear's outline (calibrated, docs)
    gsd_exponent: float = 1.77  # how the tempering grows with the pixel size (calibrated)
    reference_gsd: float = 4.1e-4  # [m/pixel] where the exponent is anchored (the close view)
    gear_tempering: dict[str, tuple[float, float]] = field(default_factory=lambda: dict(GEAR_TEMPERING))
    occlusion_exponent: float = 0.5  # evidence of a partly hidden gear, resolved teeth (calibrated)
    noise_exponent: float = 1.0  # evidence under depth noise (calibrated)
    lamp_discount: float = 0.8  # evidence under a light fitted from the gear's shading (calibrated)
    brightness_exponent: float = 0.75  # how the colour scale follows a dimmer light (calibrated)
    # how it follows a brighter one, (unresolved, resolved teeth) blended by `teeth_resolved`: the
    # scene view's colour residuals grow faster with it than the close view's (calibrated, docs)
    bright_exponent: tuple[float, float] = (1.0, 0.75)
    # b_rgb's factor by view, (unresolved, resolved teeth) blended geometrically by
    # `teeth_resolved`: where the teeth are resolved, the gear's pose is carried by its depth
    # edges as much as by its colour, and a colour scale that ignores this lets a change of light
    # (which moves the colour contrast, not the pose's error) move the posterior's width
    colour_scale_factor: tuple[float, float] = COLOUR_SCALE_FACTOR
    # The reshaping, applied to the posterior once its cells are fixed (so it moves no cell): its
    # log-evidence deficit D from the peak becomes (factor D)^exponent, (unresolved, resolved
    # teeth) each; (1, 1) = off. Fitted on tuning scenes (docs/perception.md, Tempering, item 7).
    posterior_factor: tuple[float, float] = POSTERIOR_FACTOR
    shape_exponent: tuple[float, float] = SHAPE_EXPONENT
    # per gear, (a, b) of a further factor on the reshaping where the teeth are not resolved,
    # following the gear's sampled pixel count (reshaping_for; docs/perception.md, Tempering, item 9)
    far_reshaping: dict[str, tuple[float, float]] = field(default_factory=lambda: dict(FAR_RESHAPING))
    far_reference_pixels: float = FAR_REFERENCE_PIXELS
    # per gear, (a, c_dim, c_bright) of a further factor on the reshaping where the teeth are
    # resolved, following the light's brightness (reshaping_for; Tempering, item 10)
    close_reshaping: dict[str, tuple[float, float, float]] = field(default_factory=lambda: dict(CLOSE_RESHAPING))

    def __post_init__(self) -> None:
        if not 0.0 < self.p_out < 1.0:
            raise ValueError(f"p_out = {self.p_out}; expected a probability in (0, 1)")
        for name in (
            "b_rgb",
            "b_d",
            "depth_range",
            "tempering",
            "correlation_length",
            "gsd_exponent",
            "reference_gsd",
            "far_reference_pixels",
        ):
            value = getattr(self, name)
            if name == "tempering" and value is None:
                continue
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"LikelihoodConfig.{name} = {value}; expected a finite value > 0")
        if not (np.isfinite(self.lamp_discount) and 0 < self.lamp_discount <= 1):
            raise ValueError(f"LikelihoodConfig.lamp_discount = {self.lamp_discount}; expected a factor in (0, 1]")
        for name in ("occlusion_exponent", "noise_exponent", "brightness_exponent"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"LikelihoodConfig.{name} = {value}; expected a finite value >= 0")
        if not (len(self.bright_exponent) == 2 and all(np.isfinite(e) and e >= 0 for e in self.bright_exponent)):
            raise ValueError(
                f"LikelihoodConfig.bright_exponent = {self.bright_exponent}; expected "
                "(unresolved, resolved) values >= 0"
            )
        for name in ("posterior_factor", "shape_exponent", "colour_scale_factor"):
            pair = getattr(self, name)
            if not (len(pair) == 2 and all(np.isfinite(e) and 0 < e <= 4 for e in pair)):
                raise ValueError(f"LikelihoodConfig.{name} = {pair}; expected (unresolved, resolved) values in (0, 4]")
        for gear, pair in self.far_reshaping.items():
            gear_spec(gear)  # a known gear, or ValueError naming the valid ones
            if not (
                len(pair) == 2
                and np.isfinite(pair[0])
                and 0 < pair[0] <= 4
                and np.isfinite(pair[1])
                and abs(pair[1]) <= 8
            ):
                raise ValueError(
                    f"LikelihoodConfig.far_reshaping[{gear!r}] = {pair}; expected (a in (0, 4], "
                    "b in [-8, 8]) of the far view's factor (a (pixels / far_reference_pixels)^b)^(1 - w)"
                )
        for gear, triple in self.close_reshaping.items():
            gear_spec(gear)  # a known gear, or ValueError naming the valid ones
            if not (
                len(triple) == 3
                and np.isfinite(triple[0])
                and 0 < triple[0] <= 4
                and all(np.isfinite(c) and abs(c) <= 8 for c in triple[1:])
            ):
                raise ValueError(
                    f"LikelihoodConfig.close_reshaping[{gear!r}] = {triple}; expected (a in (0, 4], "
                    "c_dim and c_bright in [-8, 8]) of the close view's factor (a brightness^c)^w"
                )
        for gear, factor in self.gear_tempering.items():
            gear_spec(gear)  # a known gear, or ValueError naming the valid ones
            if not (len(factor) == 2 and np.isfinite(factor[0]) and factor[0] > 0 and np.isfinite(factor[1])):
                raise ValueError(
                    f"LikelihoodConfig.gear_tempering[{gear!r}] = {factor}; expected "
                    "(A > 0, B) of the factor A (gsd / reference_gsd)^B"
                )

    def tempering_for(self, gear: str, gsd: float) -> float:
        """The tempering exponent for `gear` seen at ground sampling distance `gsd` [m of table per
        pixel]: the fixed `tempering` if set, else

            min(1, A (gsd / g0)^B g0^2 (gsd / g0)^k / (correlation_length * tip radius)),
            g0 = reference_gsd, k = gsd_exponent, (A, B) = gear_tempering[gear] ((1, 0) if absent).

        The evidence about a gear's pose lies along its outline (silhouette and teeth), where
        neighbouring pixels err together over about `correlation_length`: a pixel of area gsd^2
        is worth that fraction of one independent look at a piece of outline (k = 2), and the
        outline grows with the radius. Measured, the exponent is a little below 2: the coarser,
        oblique scene view needs relatively less weight than the close view; and the gears'
        tooth patterns differ in how much their pixels err together (the per-gear factor; docs)."""
        if self.tempering is not None:
            return float(self.tempering)
        if not (np.isfinite(gsd) and gsd > 0):
            raise ValueError(f"gsd = {gsd}; expected a ground sampling distance > 0 [m/pixel]")
        g0 = self.reference_gsd
        a, b = self.gear_tempering.get(gear, (1.0, 0.0))
        pixel = a * g0**2 * (gsd / g0) ** (self.gsd_exponent + b)
        return float(min(1.0, pixel / (self.correlation_length * gear_spec(gear).tip_radius)))

    def evidence_factor(self, gsd: float, visible: float, depth_noise: float, fitted_light: bool = False) -> float:
        """What the tempering is multiplied by once the best pose is known, from the view
        (`gsd` [m/pixel]), the share of the gear's predicted pixels that pose explains (`visible`,
        in (0, 1]), the per-pixel depth noise read off the table (`depth_noise` [m]; the
        scorer's `pixel_noise`, which a depth bias or a camera off its pose leaves at 0) and
        whether the light was fitted from the gear's own shading (`fitted_light`):

            visible^(-occlusion_exponent * w) * (b_d / hypot(b_d, depth_noise))^noise_exponent
            * lamp_discount^(1 - w) if fitted_light,

        w = clip((tooth pitch / gsd - 2) / 4, 0, 1) how well the view resolves the teeth (none
        below 2 pixels a tooth, fully from 6). Where the teeth are resolved, the pose's error is
        dominated by what every tooth shares (the model's small mismatch), so hiding part of the
        gear costs less evidence than its share of pixels; noisy depth costs more than the widened
        depth scale says; a lamp read off walls the view does not resolve is itself ~10 deg off,
        and the shading it predicts with it. All three are fitted on tuning scenes
        (docs/perception.md)."""
        if not (np.isfinite(gsd) and gsd > 0):
            raise ValueError(f"gsd = {gsd}; expected a ground sampling distance > 0 [m/pixel]")
        if not (np.isfinite(visible) and 0 < visible <= 1):
            raise ValueError(f"visible = {visible}; expected a share in (0, 1]")
        if not (np.isfinite(depth_noise) and depth_noise >= 0):
            raise ValueError(f"depth_noise = {depth_noise}; expected a standard deviation >= 0 [m]")
        resolved = teeth_resolved(gsd)
        occlusion = max(visible, 0.25) ** (-self.occlusion_exponent * resolved)
        noise = (self.b_d / np.hypot(self.b_d, depth_noise)) ** self.noise_exponent
        lamp = self.lamp_discount ** (1.0 - resolved) if fitted_light else 1.0
        return float(occlusion * noise * lamp)

    def colour_scale_for(self, brightness: float, gsd: float) -> float:
        """b_rgb under a light of `brightness` (the mean colour gain read off the table; clipped by
        `light_gain`) in a view of ground sampling distance `gsd` [m/pixel]: f b_rgb brightness^e, e =
        `brightness_exponent` for a dimmer light and `bright_exponent` blended by how well the
        view resolves the teeth (`teeth_resolved`) for a brighter one, f = `colour_scale_factor`
        blended geometrically by the same. Part of a colour residual (8-bit steps, antialiased
        edges) does not scale with the light, so e < 1."""
        if not np.isfinite(brightness):
            raise ValueError(f"brightness = {brightness}; expected a finite colour gain")
        g = light_gain(brightness)
        w = teeth_resolved(gsd)
        e = self.brightness_exponent if g <= 1.0 else by_view(self.bright_exponent, w)
        return float(by_view(self.colour_scale_factor, w, geometric=True) * self.b_rgb * g**e)

    def reshaping_for(
        self, gsd: float, gear: str | None = None, pixels: float | None = None, brightness: float = 1.0
    ) -> tuple[float, float]:
        """(factor, exponent) of the posterior's reshaping for `gear` in a view of ground sampling
        distance `gsd` [m/pixel] (PosePosterior.reshaped): posterior_factor's and shape_exponent's
        two values blended by how well the view resolves the teeth (`teeth_resolved`; the factor
        geometrically), the factor times `far_factor_for(gsd, gear, pixels)` and
        `close_factor_for(gsd, gear, brightness)`."""
        factor, exponent = blend_reshaping(self.posterior_factor, self.shape_exponent, teeth_resolved(gsd))
        factor *= self.far_factor_for(gsd, gear, pixels) * self.close_factor_for(gsd, gear, brightness)
        return float(factor), float(exponent)

    def close_factor_for(self, gsd: float, gear: str | None, brightness: float = 1.0) -> float:
        """The close view's factor on `gear`'s reshaping at `gsd` [m/pixel] under a light of
        `brightness` (the colour gain read off the table): `close_factor` with
        close_reshaping[gear]; 1 for a gear it does not name and for gear None. ValueError if it
        names the gear and `brightness` is not a finite gain > 0."""
        if gear is None or gear not in self.close_reshaping:
            return 1.0
        if not (np.isfinite(brightness) and brightness > 0):
            raise ValueError(
                f"brightness = {brightness}; expected the light's colour gain (> 0) "
                f"for the {gear} gear's close-view reshaping"
            )
        return close_factor(gsd, brightness, *self.close_reshaping[gear])

    def far_factor_for(self, gsd: float, gear: str | None, pixels: float | None = None) -> float:
        """The far view's factor on `gear`'s reshaping at `gsd` [m/pixel] with `pixels` of the gear
        sampled at its MAP: `far_factor` with (a, b) = far_reshaping[gear]; 1 for a gear it does
        not name and for gear None. ValueError if it names the gear and `pixels` is not a count > 0."""
        if gear is None or gear not in self.far_reshaping:
            return 1.0
        if pixels is None or not (np.isfinite(pixels) and pixels > 0):
            raise ValueError(
                f"pixels = {pixels}; expected the {gear} gear's sampled pixel count (> 0) for its far-view reshaping"
            )
        a, b = self.far_reshaping[gear]
        return far_factor(gsd, pixels, a, b, self.far_reference_pixels)

    def pixel_constants(self, scales: float = 3.0) -> tuple:
        """The constants `pixel_terms` takes: the scales in float32 (the images' precision) and
        the density's log normalizers; `scales` sets the inlier test."""
        return (
            np.float32(self.b_rgb),
            np.float32(self.b_d),
            float(np.log1p(-self.p_out)),
            float(3 * np.log(2 * self.b_rgb)),
            float(np.log(2 * self.b_d)),
            float(np.log(self.p_out)),
            float(np.log(self.depth_range)),
            np.float32(scales),
        )

    def pixel_loglik(
        self, rgb: np.ndarray, depth: np.ndarray, rgb_hat: np.ndarray, depth_hat: np.ndarray
    ) -> np.ndarray:
        """Log-likelihood of observed pixels (rgb (..., 3), depth (...)) given rendered ones,
        computed in float32 like the images; a pixel without a valid depth (NaN, <= 0) is scored
        on its colour alone (its depth density marginalized out)."""
        return self._per_pixel(rgb, depth, rgb_hat, depth_hat, 3.0)[0]

    def is_inlier(
        self, rgb: np.ndarray, depth: np.ndarray, rgb_hat: np.ndarray, depth_hat: np.ndarray, scales: float = 3.0
    ) -> np.ndarray:
        """Whether each pixel matches its rendering within `scales` times b_rgb (colour, L1) and
        b_d (depth; a pixel without depth on colour alone): what "the hypothesis explains this
        pixel" means in the sanity checks."""
        return self._per_pixel(rgb, depth, rgb_hat, depth_hat, scales)[1]

    def _per_pixel(self, rgb, depth, rgb_hat, depth_hat, scales):
        rgb, depth, rgb_hat, depth_hat = (np.asarray(x, np.float32) for x in (rgb, depth, rgb_hat, depth_hat))
        shape = np.broadcast_shapes(rgb.shape[:-1], rgb_hat.shape[:-1], depth.shape, depth_hat.shape)
        flat = [
            np.ascontiguousarray(np.broadcast_to(x, shape + tail).reshape((-1,) + tail))
            for x, tail in ((rgb, (3,)), (depth, ()), (rgb_hat, (3,)), (depth_hat, ()))
        ]
        loglik, inlier = _pixels(*flat, self.pixel_constants(scales))
        return loglik.reshape(shape), inlier.reshape(shape)


def teeth_resolved(gsd: float) -> float:
    """How well a view of ground sampling distance `gsd` [m/pixel] resolves the teeth, in [0, 1]:
    none below 2 pixels a tooth pitch, fully from 6."""
    if not (np.isfinite(gsd) and gsd > 0):
        raise ValueError(f"gsd = {gsd}; expected a ground sampling distance > 0 [m/pixel]")
    return float(np.clip((np.pi * GEAR_MODULE / gsd - 2.0) / 4.0, 0.0, 1.0))


def by_view(pair: tuple[float, float], resolved: float | np.ndarray, geometric: bool = False):
    """An (unresolved, resolved teeth) pair's value at teeth-resolution `resolved` in [0, 1] (a
    number or an array, `teeth_resolved`): blended geometrically (factors) or linearly
    (exponents)."""
    a, b = pair
    if geometric:
        return a ** (1.0 - resolved) * b**resolved
    return (1.0 - resolved) * a + resolved * b


def far_factor(gsd: float, pixels: float, a: float, b: float, reference: float = FAR_REFERENCE_PIXELS) -> float:
    """(a (pixels / reference)^b)^(1 - w), w = `teeth_resolved(gsd)`: a factor following a gear's
    sampled pixel count in the far view, 1 where the teeth are resolved (LikelihoodConfig.far_reshaping)."""
    return float(by_view((a * (pixels / reference) ** b, 1.0), teeth_resolved(gsd), geometric=True))


def close_factor(gsd: float, brightness: float, a: float, c_dim: float, c_bright: float) -> float:
    """(a g^c)^w, g = `light_gain(brightness)` as for the colour scale, c = c_dim below 1
    and c_bright above, w = `teeth_resolved(gsd)`: a factor following the light in the close view,
    1 where the teeth are not resolved (LikelihoodConfig.close_reshaping)."""
    g = light_gain(brightness)
    return float(by_view((1.0, a * g ** (c_dim if g < 1.0 else c_bright)), teeth_resolved(gsd), geometric=True))


def light_gain(brightness: float) -> float:
    """The colour gain the light laws use: `brightness` (the mean gain read off the table) clipped
    to GAIN_RANGE, so a saturated or nearly black table cannot drive them without bound."""
    return float(np.clip(brightness, *GAIN_RANGE))


def blend_reshaping(
    posterior_factor: tuple[float, float], shape_exponent: tuple[float, float], resolved: float | np.ndarray
) -> tuple:
    """(factor, exponent) of the reshaping at teeth-resolution `resolved` in [0, 1] (a number or
    an array, `teeth_resolved`): the (unresolved, resolved) factors blended geometrically, the
    exponents linearly."""
    return by_view(posterior_factor, resolved, geometric=True), by_view(shape_exponent, resolved)


@numba.njit(cache=True, inline="always")
def pixel_terms(r, g, b, depth, r_hat, g_hat, b_hat, depth_hat, constants):
    """(log-likelihood, inlier) of one pixel given its rendering (colours and depths float32;
    `constants` from LikelihoodConfig.pixel_constants): the density of the module docstring, and
    whether colour (L1) and depth (when valid) lie within `scales` of their scales. Its float32
    and float64 steps are those numpy takes on float32 images."""
    b_rgb, b_d, log_in0, log_rgb, log_2bd, log_out0, log_range, scales = constants
    colour = ((abs(r - r_hat) + abs(g - g_hat)) + abs(b - b_hat)) / b_rgb
    has_depth = np.isfinite(depth) and depth > 0
    dist = abs(depth - depth_hat) / b_d  # NaN without depth
    log_in = (log_in0 - np.float64(colour)) - log_rgb
    log_out = log_out0
    if has_depth:
        log_in -= np.float64(dist) + log_2bd
        log_out -= log_range
    # log(exp(log_in) + exp(log_out)) as numpy's logaddexp takes it.
    if log_in == log_out:
        loglik = log_in + np.log(2.0)
    elif log_in - log_out > 0:
        loglik = log_in + np.log1p(np.exp(-(log_in - log_out)))
    else:
        loglik = log_out + np.log1p(np.exp(log_in - log_out))
    return loglik, colour < scales and (dist < scales or not has_depth)


@numba.njit(cache=True)
def _pixels(rgb, depth, rgb_hat, depth_hat, constants):
    n = depth.size
    loglik = np.empty(n)
    inlier = np.empty(n, np.bool_)
    for i in range(n):
        loglik[i], inlier[i] = pixel_terms(
            rgb[i, 0],
            rgb[i, 1],
            rgb[i, 2],
            depth[i],
            rgb_hat[i, 0],
            rgb_hat[i, 1],
            rgb_hat[i, 2],
            depth_hat[i],
            constants,
        )
    return loglik, inlier


@lru_cache(maxsize=None)
def table_albedo() -> np.ndarray:
    """The table's diffuse colour, read from its model file (assembly/models/gearset/table.sdf)."""
    text = gearset_model_paths()["table"].read_text()
    match = re.search(r"<diffuse>\s*([\d.eE+-]+)\s+([\d.eE+-]+)\s+([\d.eE+-]+)", text)
    if match is None:
        raise ValueError("table.sdf has no <diffuse> colour; perception needs the table's colour")
    return np.array([float(g) for g in match.groups()], np.float32)


def table_colour(light: np.ndarray) -> np.ndarray:
    """The bare table's colour (r, g, b) under a white directional light from `light` (world)."""
    return table_albedo() * max(0.0, float(light[2]))


def table_depth(origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Depth of the table plane z = 0 along each ray (+inf for rays that never reach it)."""
    down = dirs[:, 2] < -1e-9
    return np.where(down, -origin[2] / np.where(down, dirs[:, 2], -1.0), np.inf).astype(np.float32)


def table_prediction(origin: np.ndarray, dirs: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What each ray sees if no gear is in its way: the table plane z = 0 (depth, shaded colour);
    depth is +inf for rays that never reach it."""
    rgb = np.broadcast_to(table_colour(light), (len(dirs), 3)).astype(np.float32)
    return table_depth(origin, dirs), rgb
