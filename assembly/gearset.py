"""The gear set: IndustReal's gear plate, shafts and three spur gears, as dimensions and frames.

Dimensions are measured from IndustReal's public gear assets (Tang et al., RSS 2023; isaac-sim/
IsaacGymEnvs assets/industreal/; sources per number: docs/models.md#sources).
Frames:
  * plate frame P: origin at the centre of the plate's bottom face, z up, shafts along +x.
  * shaft frame S_g: origin on shaft g's axis at the plate's top face, z up (axes parallel to P).
  * gear frame G: origin on the bore axis at the gear's bottom face, z up.
A gear is seated when G coincides with S_g up to a rotation about z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GEAR_NAMES: tuple[str, ...] = ("small", "medium", "large")

# Plate (IndustReal gear base: 150 x 75 x 5 mm).
PLATE_SIZE = (0.150, 0.075, 0.005)
# Shafts (IndustReal: diameter 9 mm, 20 mm tall above the plate, 1 mm chamfer at the top).
SHAFT_RADIUS = 0.0045
SHAFT_HEIGHT = 0.020
SHAFT_CHAMFER = 0.001
# Gears (IndustReal: bore diameter 10 mm, i.e. 0.5 mm radial clearance; thickness 20 mm).
GEAR_BORE_RADIUS = 0.005
GEAR_THICKNESS = 0.020
GEAR_BORE_CHAMFER = 0.001
# Module 1 mm: tip radii 11/21/31 mm give pitch radii 10/20/30 mm and 20/40/60 teeth. The shaft
# spacing (50.5 and 30.5 mm) is 0.5 mm wider than the pitch-circle sums: that is the backlash.
GEAR_MODULE = 0.001
# Seated criterion (IsaacLab Factory, FactoryEnv._get_curr_successes): a gear is inserted when its
# frame is within 2.5 mm laterally and 1 mm in height of its seated pose on the shaft.
SEATED_LATERAL_TOL = 0.0025
SEATED_HEIGHT_TOL = 0.001
# Gear material: 3D-printed PLA, density 1240 kg/m^3 (typical datasheet value).
GEAR_DENSITY = 1240.0


@dataclass(frozen=True)
class GearSpec:
    """One spur gear and the shaft it goes on."""

    name: str
    teeth: int
    tip_radius: float
    shaft_x: float  # shaft position along the plate's x axis [m]
    rgba: tuple[float, float, float, float]

    @property
    def pitch_radius(self) -> float:
        return 0.5 * GEAR_MODULE * self.teeth

    @property
    def root_radius(self) -> float:
        return self.pitch_radius - 1.25 * GEAR_MODULE

    @property
    def tooth_pitch_angle(self) -> float:
        """Yaw between two consecutive teeth [rad]: the gear looks the same after this rotation."""
        return 2.0 * np.pi / self.teeth


GEARS: dict[str, GearSpec] = {
    # IndustReal gear base: shaft x positions large -30.25 mm, medium +20.25 mm, small +50.75 mm;
    # tip radii 11 / 21 / 31 mm. Colours: small blue, medium pink, large yellow.
    "small": GearSpec("small", 20, 0.011, 0.05075, (0.15, 0.35, 0.85, 1.0)),
    "medium": GearSpec("medium", 40, 0.021, 0.02025, (0.92, 0.40, 0.62, 1.0)),
    "large": GearSpec("large", 60, 0.031, -0.03025, (0.95, 0.78, 0.15, 1.0)),
}


def gear_spec(name: str) -> GearSpec:
    """The GearSpec for `name`; ValueError naming the valid names otherwise."""
    try:
        return GEARS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown gear {name!r}; expected one of {list(GEAR_NAMES)}") from None


def shaft_position_in_plate(name: str) -> np.ndarray:
    """Origin of shaft frame S_name in the plate frame P [m]."""
    return np.array([gear_spec(name).shaft_x, 0.0, PLATE_SIZE[2]])
