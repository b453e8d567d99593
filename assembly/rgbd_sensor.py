"""What a real RGB-D camera does to the ideal render: an active-stereo depth imager's noise, its
quantisation, its depth-scale error and occlusion shadows, the colour imager's noise, and the error
of the camera's calibrated extrinsics.

The depth model follows the Intel RealSense D400 family (docs/perception.md, Realistic cameras, for
the sources):

* depth from disparity, z = f B / d, so a disparity error of `subpixel` pixels RMS gives a depth RMS
  of z^2 subpixel / (f B) (Grunnet-Jepsen et al., "Tuning depth cameras for best performance",
  Intel, rev. 2.0), f the depth imager's focal length at its native resolution [px], B the baseline;
* depth reported in steps of the depth unit (1 mm by default on the D400 family);
* an absolute depth error of up to 2 % of the distance (the D400 datasheet's accuracy bound, within
  80 % of the field of view): drawn once per camera as a scale factor on every depth;
* no depth where the right imager cannot see what the left (reference) imager sees: the occlusion
  shadow beside a near edge, and outside the imager's depth range;
* colour: 8-bit counts with Gaussian read and shot noise (an assumption, not a datasheet value).

    model = D415
    rgb, depth = model.corrupt(rgb, depth, focal_px, rng, scale)
    scale = model.draw_scale(rng)                         # once per camera
    X_CE = model.draw_extrinsic_error(rng)                # once per mounting
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem
from pydrake.systems.sensors import ImageDepth32F, ImageRgba8U

from assembly.cameras import extrinsic_error
from goflow_common.checks import check_number

__all__ = [
    "CameraSensor",
    "D405",
    "D415",
    "IDEAL",
    "SENSOR_MODELS",
    "RgbdSensorModel",
    "RgbdSensorNoise",
    "sensor_model",
]


@dataclass(frozen=True)
class RgbdSensorModel:
    """An RGB-D camera's departures from the ideal render.

    baseline [m]: the stereo baseline (0: ideal depth, nothing else of the depth applies);
    focal_px: the depth imager's focal length at its native resolution [px]; subpixel: the RMS
    disparity error [px]; depth_unit [m]: the reported depth's step (0: none); depth_range [m]:
    (min, max) depths reported; scale_std: std of the per-camera depth scale error (a fraction);
    colour_read_noise, colour_shot_noise: the colour noise std in 8-bit counts is
    sqrt(read^2 + shot^2 * counts / 255); extrinsic_std: (translation [m], rotation [rad]) std
    of the calibrated extrinsics' error about the true ones (assembly.cameras.extrinsic_error)."""

    name: str
    baseline: float = 0.0
    focal_px: float = 1.0
    subpixel: float = 0.0
    depth_unit: float = 0.0
    depth_range: tuple[float, float] = (0.0, np.inf)
    scale_std: float = 0.0
    colour_read_noise: float = 0.0
    colour_shot_noise: float = 0.0
    extrinsic_std: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("baseline", "subpixel", "depth_unit", "scale_std", "colour_read_noise", "colour_shot_noise"):
            check_number(getattr(self, name), f"{self.name}: {name}", 0.0)
        check_number(self.focal_px, f"{self.name}: focal_px", 0.0, low_open=True)
        lo, hi = self.depth_range
        if not (np.isfinite(lo) and lo >= 0 and hi > lo):
            raise ValueError(f"{self.name}: depth_range = {self.depth_range}; expected 0 <= min < max [m]")
        if len(self.extrinsic_std) != 2 or not all(np.isfinite(v) and v >= 0 for v in self.extrinsic_std):
            raise ValueError(
                f"{self.name}: extrinsic_std = {self.extrinsic_std}; expected (translation [m], rotation [rad]) >= 0"
            )

    @property
    def is_ideal(self) -> bool:
        """Whether this model changes nothing."""
        return self == RgbdSensorModel(self.name)

    def depth_rms(self, z: np.ndarray | float) -> np.ndarray:
        """The depth noise's RMS [m] at depth `z` [m]: z^2 subpixel / (f B)."""
        if self.baseline == 0:
            return np.zeros_like(np.asarray(z, float))
        return np.asarray(z, float) ** 2 * self.subpixel / (self.focal_px * self.baseline)

    def draw_scale(self, rng: np.random.Generator) -> float:
        """A camera's depth scale factor, 1 + N(0, scale_std), clipped to 1 +- 3 scale_std."""
        return float(1.0 + np.clip(rng.normal(0.0, self.scale_std), -3 * self.scale_std, 3 * self.scale_std))

    def draw_extrinsic_error(self, rng: np.random.Generator):
        """A RigidTransform X_CE: the camera's true pose is X_PC @ X_CE when the robot believes X_PC."""
        return extrinsic_error(*self.extrinsic_std, rng)

    def corrupt(
        self, rgb: np.ndarray, depth: np.ndarray, render_focal_px: float, rng: np.random.Generator, scale: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """The (rgb (H, W, 3) uint8 or floats in [0, 1], as given; depth float32 (H, W) [m]) the camera reports for the ideal
        render (`rgb`, `depth`) of a pinhole of focal length `render_focal_px` [px] (for the
        occlusion shadow's width in the render's pixels), with the camera's depth `scale`: `colour`
        then `depth`, drawn from `rng` in that order. New arrays; non-finite depth stays missing."""
        rgb, depth = np.asarray(rgb), np.asarray(depth, np.float32)
        if rgb.ndim != 3 or rgb.shape[:2] != depth.shape:
            raise ValueError(f"rgb {rgb.shape} and depth {depth.shape}; expected (H, W, 3) and (H, W)")
        return self.colour(rgb, rng), self.depth(depth, render_focal_px, rng, scale)

    def depth(
        self, depth: np.ndarray, render_focal_px: float, rng: np.random.Generator, scale: float = 1.0
    ) -> np.ndarray:
        """The depth image (float32 (H, W) [m]) the camera reports for the ideal render `depth`, as
        in `corrupt`. A new array; non-finite depth stays missing."""
        depth = np.asarray(depth, np.float32)
        if self.baseline == 0:
            return depth.copy()
        z = depth.astype(np.float64)
        finite = np.isfinite(z)
        z_safe = np.where(finite, z, 0.0)
        shadow = occlusion_shadow(z_safe, finite, render_focal_px * self.baseline)
        noisy = scale * z_safe + self.depth_rms(z_safe) * rng.standard_normal(z.shape)
        if self.depth_unit > 0:
            noisy = np.round(noisy / self.depth_unit) * self.depth_unit
        lo, hi = self.depth_range
        valid = finite & ~shadow & (noisy >= lo) & (noisy <= hi)
        return np.where(valid, noisy, np.nan).astype(np.float32)

    def colour(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The colour image the camera reports for the ideal render `rgb` (uint8 counts, or floats
        in [0, 1]): the colour noise in 8-bit counts, in `rgb`'s own dtype. A new array."""
        if self.colour_read_noise == 0 and self.colour_shot_noise == 0:
            return rgb.copy()
        counts = rgb.astype(np.float64) * (1.0 if rgb.dtype == np.uint8 else 255.0)
        std = np.sqrt(self.colour_read_noise**2 + self.colour_shot_noise**2 * counts / 255.0)
        noisy = np.clip(np.round(counts + std * rng.standard_normal(counts.shape)), 0, 255)
        return noisy.astype(np.uint8) if rgb.dtype == np.uint8 else (noisy / 255.0).astype(rgb.dtype)


def occlusion_shadow(z: np.ndarray, finite: np.ndarray, f_b: float) -> np.ndarray:
    """(H, W) bool: pixels of the left (reference) imager that the right imager, `f_b` = focal
    length [px] x baseline [m] to the right of it along the image rows, cannot see, because a
    nearer surface further right along the row covers them there (a pixel u is seen at u - f_b /
    z in the right image; it is hidden when some pixel right of it lands at or left of that)."""
    if f_b <= 0:
        return np.zeros(z.shape, bool)
    u = np.arange(z.shape[1], dtype=np.float64)
    right = np.where(finite, u - f_b / np.where(finite, z, 1.0), np.inf)
    # the smallest right-image column of the pixels strictly right of each pixel
    after = np.minimum.accumulate(right[:, ::-1], axis=1)[:, ::-1]
    after = np.concatenate([after[:, 1:], np.full((z.shape[0], 1), np.inf)], axis=1)
    return finite & (after < right - 0.5)


# The perfect camera (today's render).
IDEAL = RgbdSensorModel("ideal")
# Intel RealSense D415 (the scene camera): baseline 55 mm, depth imager 1280 px wide over a 65 deg
# horizontal field of view (f = 640 / tan(32.5 deg) = 1005 px), subpixel 0.08 px RMS (the tuning
# paper's typical value), 1 mm depth unit, depth range 0.16-10 m (the datasheet's min-Z at reduced
# resolution; the station's scene distances 0.45-0.75 m are inside it at any resolution), scale
# error std 1 % (the +-2 % accuracy bound as two std), colour noise 2 counts read + 3 counts shot
# at full scale (assumed); extrinsics known to 1 mm and 0.1 deg (a calibration target).
D415 = RgbdSensorModel(
    "d415",
    baseline=0.055,
    focal_px=640.0 / np.tan(np.radians(32.5)),
    subpixel=0.08,
    depth_unit=0.001,
    depth_range=(0.16, 10.0),
    scale_std=0.01,
    colour_read_noise=2.0,
    colour_shot_noise=3.0,
    extrinsic_std=(0.001, np.radians(0.1)),
)
# Intel RealSense D405 (the wrist camera, the family's short-range model for 7-50 cm): baseline
# 18 mm, 1280 px over 87 deg (f = 640 / tan(43.5 deg) = 674 px), subpixel 0.08 px RMS, 0.1 mm depth
# unit (its default depth scale), depth range 0.07-0.5 m, scale error std 1 % (+-2 % at 50 cm as two
# std), the same colour noise; hand-eye extrinsics known to 0.5 mm and 0.1 deg (an eye-in-hand
# calibration with a target, assumed).
D405 = RgbdSensorModel(
    "d405",
    baseline=0.018,
    focal_px=640.0 / np.tan(np.radians(43.5)),
    subpixel=0.08,
    depth_unit=0.0001,
    depth_range=(0.07, 0.5),
    scale_std=0.01,
    colour_read_noise=2.0,
    colour_shot_noise=3.0,
    extrinsic_std=(0.0005, np.radians(0.1)),
)
SENSOR_MODELS = {m.name: m for m in (IDEAL, D415, D405)}


def sensor_model(name: str | RgbdSensorModel) -> RgbdSensorModel:
    """The model named `name` (one of SENSOR_MODELS), or `name` itself when it is a model."""
    if isinstance(name, RgbdSensorModel):
        return name
    if name not in SENSOR_MODELS:
        raise ValueError(f"camera model {name!r}; expected one of {list(SENSOR_MODELS)}")
    return SENSOR_MODELS[name]


@dataclass(frozen=True)
class CameraSensor:
    """One station camera's real sensor: its `model`, its depth `scale` (drawn once per camera:
    `model.draw_scale`) and the `seed` of its per-frame noise."""

    model: RgbdSensorModel = IDEAL
    scale: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_number(self.scale, "CameraSensor.scale", 0.5, 1.5)


class RgbdSensorNoise(LeafSystem):
    """A camera's images as the real camera reports them: inputs `rgb` (ImageRgba8U) and `depth`
    (ImageDepth32F) from an ideal RgbdSensor, outputs the same kinds through `model.colour` and `model.depth` with
    the camera's depth `scale`, each port computing only its own image. The noise of an image is
    drawn from (seed, the camera's name, the context's time in microseconds, the port): the same
    time gives the same image, as a frame would."""

    def __init__(self, name: str, model: RgbdSensorModel, render_focal_px: float, scale: float, seed: int) -> None:
        super().__init__()
        self.set_name(f"{name}_noise")
        self.model, self.render_focal_px, self.scale = model, float(render_focal_px), float(scale)
        self._key = [int(seed), zlib.crc32(name.encode())]
        self.DeclareAbstractInputPort("rgb", AbstractValue.Make(ImageRgba8U()))
        self.DeclareAbstractInputPort("depth", AbstractValue.Make(ImageDepth32F()))
        self.DeclareAbstractOutputPort("rgb", lambda: AbstractValue.Make(ImageRgba8U()), self._calc_rgb)
        self.DeclareAbstractOutputPort("depth", lambda: AbstractValue.Make(ImageDepth32F()), self._calc_depth)

    def _rng(self, context: Context, port: int) -> np.random.Generator:
        return np.random.default_rng([*self._key, int(round(context.get_time() * 1e6)), port])

    def _calc_rgb(self, context: Context, output: AbstractValue) -> None:
        rgba = self.get_input_port(0).Eval(context).data
        image = ImageRgba8U(rgba.shape[1], rgba.shape[0])
        image.mutable_data[:, :, :3] = self.model.colour(rgba[:, :, :3], self._rng(context, 0))
        image.mutable_data[:, :, 3] = rgba[:, :, 3]
        output.set_value(image)

    def _calc_depth(self, context: Context, output: AbstractValue) -> None:
        depth = self.get_input_port(1).Eval(context).data[:, :, 0]
        d = self.model.depth(depth, self.render_focal_px, self._rng(context, 1), self.scale)
        image = ImageDepth32F(d.shape[1], d.shape[0])
        image.mutable_data[:, :, 0] = d
        output.set_value(image)
