"""Is a released gear seated on its shaft? A check from one depth image.

A seated gear's top face lies flush with its shaft's top, GEAR_THICKNESS above the plate, flat.
The check back-projects the depth pixels that fall inside the face's ring around the shaft axis
(between the bore, plus a margin, and the tooth root, minus one) away from the side facing the
camera, and compares their heights with that face: a gear left cocked on the shaft or
beside it shows up as a face above it, or as points scattered off it. Points far above the face (the open fingers, the hand) are occluders and are
ignored; too few points left means the view cannot tell ("unseen"), never a guess.

The ring's sector facing the camera (within 60 degrees of its direction) is left out because
there the gear's outer wall faces the camera: a real camera's calibration error (a millimetre at
the wrist camera's range) moves the wall's points, 20 mm deep, inside the tooth root, where they
would read as a face far too low. Elsewhere the outer wall faces away or is seen edge-on, and the
bore's wall lies inside the ring's inner edge. A camera above the axis (within
`overhead_radius`) sees no wall and uses the whole ring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform

from assembly.gearset import (
    GEAR_BORE_CHAMFER,
    GEAR_BORE_RADIUS,
    GEAR_THICKNESS,
    SHAFT_CHAMFER,
    SHAFT_HEIGHT,
    SHAFT_RADIUS,
    gear_spec,
)
from perception.observation import Observation

VERDICTS = ("seated", "unseated", "unseen")


@dataclass(frozen=True)
class SeatCheckConfig:
    """Seated: the ring's median height is within `tolerance` [m] of a seated face and at least
    `inliers` of its points within twice that (a flat face: a gear tilted by a degree or two on
    its shaft still passes, one cocked beside it does not). margin: the ring keeps this far from
    the bore's chamfer and the tooth root [m]; occluder_height: points this far above the face
    are something in front of it [m]; min_points: fewer ring points than this gives "unseen";
    reference_offset: the shaft's top (flush with a seated face) seen within this of its nominal
    height [m] is the reference the face is measured from, so that a real camera's depth scale
    and mounting error cancel (a view that does not see the shaft's top, or sees it farther off,
    measures from the nominal height); overhead_radius: a camera whose position is within this of
    the shaft's axis [m] uses the whole ring; one farther out drops the ring's points within
    `wall_sector` [rad] of its direction, where the gear's outer wall faces it."""

    tolerance: float = 0.0005
    inliers: float = 0.8
    margin: float = 0.001
    occluder_height: float = 0.010
    min_points: int = 60
    reference_offset: float = 0.003
    overhead_radius: float = 0.005
    wall_sector: float = np.pi / 3

    def __post_init__(self) -> None:
        if not (
            self.tolerance > 0
            and 0 < self.inliers <= 1
            and self.margin >= 0
            and self.occluder_height > 2 * self.tolerance
            and self.min_points >= 10
            and self.reference_offset >= 0
            and self.overhead_radius >= 0
            and 0 <= self.wall_sector <= np.pi / 2
        ):
            raise ValueError(
                f"{self}: expected tolerance > 0, 0 < inliers <= 1, margin >= 0, "
                "occluder_height > 2 tolerance, min_points >= 10, reference_offset >= 0, "
                "overhead_radius >= 0 and 0 <= wall_sector <= pi/2"
            )


@dataclass(frozen=True)
class SeatCheck:
    """verdict: seated | unseated | unseen; height_m: median height of the ring's points above a
    seated face [m] (nan if unseen); inliers: the fraction of them within twice the tolerance of
    it; points: how many were used; reason: one line for the log."""

    verdict: str
    height_m: float
    inliers: float
    points: int
    reason: str


def check_seat(obs: Observation, gear: str, X_WS: RigidTransform, config: SeatCheckConfig | None = None) -> SeatCheck:
    """Whether `gear` sits seated on its shaft (frame X_WS: on the shaft axis at the plate top,
    z up) as seen in `obs` (any calibrated RGB-D view of the shaft: the wrist camera after the
    release). ValueError for an unknown gear."""
    c = config or SeatCheckConfig()
    spec = gear_spec(gear)
    v, u = np.nonzero(obs.valid)
    origin, dirs = obs.rays_W(u, v)
    p_S = X_WS.inverse().multiply((origin + dirs * obs.depth[v, u][:, None]).T).T
    r = np.hypot(p_S[:, 0], p_S[:, 1])
    ring = (r > GEAR_BORE_RADIUS + GEAR_BORE_CHAMFER + c.margin) & (r < spec.root_radius - c.margin)
    camera_xy = X_WS.inverse().multiply(obs.X_WC.translation())[:2]
    if np.hypot(*camera_xy) > c.overhead_radius:  # drop the side where the outer wall faces the camera
        ring &= p_S[:, :2] @ camera_xy <= np.cos(c.wall_sector) * r * np.hypot(*camera_xy)
    dz = p_S[ring, 2] - GEAR_THICKNESS
    dz = dz[dz < c.occluder_height]  # the fingers and the hand are in front of the face
    top = p_S[r < SHAFT_RADIUS - SHAFT_CHAMFER - c.margin, 2] - SHAFT_HEIGHT
    top = top[np.abs(top) < c.reference_offset]
    reference = float(np.median(top)) if top.size >= c.min_points // 4 else 0.0
    dz = dz - reference
    if dz.size < c.min_points:
        return SeatCheck(
            "unseen",
            float("nan"),
            float("nan"),
            int(dz.size),
            f"{gear}: {dz.size} points on its seated face's ring, fewer than {c.min_points}",
        )
    height = float(np.median(dz))
    inliers = float(np.mean(np.abs(dz) <= 2 * c.tolerance))
    what = "seated" if abs(height) <= c.tolerance and inliers >= c.inliers else "unseated"
    return SeatCheck(
        what,
        height,
        inliers,
        int(dz.size),
        f"{gear}: face {1e3 * height:+.2f} mm from seated, {100 * inliers:.0f} % of {dz.size} "
        f"points within {2e3 * c.tolerance:.1f} mm: {what}",
    )


__all__ = ["SeatCheck", "SeatCheckConfig", "VERDICTS", "check_seat"]
