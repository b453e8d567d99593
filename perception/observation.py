"""One RGB-D observation: colour, depth, pinhole intrinsics and the camera's world pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform
from pydrake.systems.sensors import CameraInfo

# Drake 1.51's RenderEngineVtk draws pixel (u, v) along the documented CameraInfo ray of
# (u + 0.5, v + 0.5) (drake PR #10190, still open): back-project through this offset.
VTK_PIXEL_OFFSET = 0.5


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera: image size [px], focal lengths and principal point [px]."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(f"intrinsics {name} = {value!r}; expected a positive number of pixels")
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value) or (name in ("fx", "fy") and value <= 0):
                raise ValueError(
                    f"intrinsics {name} = {value}; expected a finite "
                    + ("focal length > 0 [px]" if name in ("fx", "fy") else "principal point [px]")
                )

    @staticmethod
    def from_camera_info(info: CameraInfo) -> "Intrinsics":
        """The intrinsics of a Drake CameraInfo."""
        return Intrinsics(
            int(info.width()),
            int(info.height()),
            float(info.focal_x()),
            float(info.focal_y()),
            float(info.center_x()),
            float(info.center_y()),
        )

    def rays_C(self, u: np.ndarray, v: np.ndarray, offset: float = VTK_PIXEL_OFFSET) -> np.ndarray:
        """Camera-frame ray directions (unit z component) through pixels (u, v), shape (n, 3)."""
        u = np.asarray(u, float) + offset
        v = np.asarray(v, float) + offset
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], -1)


@dataclass
class Observation:
    """An RGB-D image with what is needed to back-project it.

    rgb: (H, W, 3) float in [0, 1] (uint8 and an alpha channel are accepted and converted);
    depth: (H, W) metres along the optical axis; non-finite or non-positive values are invalid;
    X_WC: the camera's pose in the world (z along the optical axis, y down the image rows).
    """

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    X_WC: RigidTransform

    def __post_init__(self) -> None:
        k = self.intrinsics
        if self.depth is None:
            raise ValueError("observation has no depth image; expected a (H, W) depth image in metres")
        rgb = np.asarray(self.rgb)
        depth = np.asarray(self.depth)
        if depth.ndim == 3 and depth.shape[2] == 1:
            depth = depth[:, :, 0]
        if rgb.ndim != 3 or rgb.shape[2] not in (3, 4) or rgb.shape[:2] != (k.height, k.width):
            raise ValueError(
                f"rgb image has shape {rgb.shape}; expected ({k.height}, {k.width}, 3) "
                "or with an alpha channel (the camera's height x width)"
            )
        if depth.shape != (k.height, k.width):
            raise ValueError(
                f"depth image has shape {depth.shape}; expected ({k.height}, {k.width}) (the camera's height x width)"
            )
        if rgb.dtype == np.uint8:
            rgb = rgb.astype(np.float32) / 255.0
        rgb = np.asarray(rgb[:, :, :3], dtype=np.float32)
        if not np.all(np.isfinite(rgb)) or rgb.min() < 0.0 or rgb.max() > 1.0:
            raise ValueError("rgb values must be finite and in [0, 1] (float) or 0..255 (uint8)")
        depth = np.asarray(depth, dtype=np.float32)
        if not np.any(np.isfinite(depth) & (depth > 0)):
            raise ValueError("depth image has no valid pixel (all non-finite or <= 0); expected depths in metres")
        if not isinstance(self.X_WC, RigidTransform):
            raise ValueError(f"X_WC is {type(self.X_WC).__name__}; expected a pydrake RigidTransform")
        self.rgb, self.depth = rgb, depth

    @property
    def valid(self) -> np.ndarray:
        """(H, W) mask of pixels with a usable depth."""
        return np.isfinite(self.depth) & (self.depth > 0)

    def rays_W(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame origin (3,) and directions (n, 3) (camera-z component 1, so that the ray
        parameter of a hit is its depth) of the rays through pixels (u, v)."""
        d_C = self.intrinsics.rays_C(u, v)
        return self.X_WC.translation().copy(), d_C @ self.X_WC.rotation().matrix().T
