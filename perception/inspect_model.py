"""What an inspection does to a gear's pose belief, for planning: predict the close view's
posterior width from the belief before it, without rendering anything.

Measured (`goflow bench calibration`, docs/perception.md "Inspect model"): the close view's
standard deviations barely depend on the far belief as long as the gear lies in the close view's
prior box; they depend on the gear (its outline) and the view's ground sampling distance. So an
inspection is modelled as one more independent measurement of known noise, fused with the belief:

    sigma_after = (sigma_before^-2 + sigma_close^-2)^-1/2   per axis (x, y, yaw),

with sigma_close the median close-view std measured per gear (clean views; the 90th percentile
over all perturbation groups is `sigma_close_p90`, for a cautious planner), and the probability
that the close view is informative at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from assembly.gearset import gear_spec
from perception.posterior import PosePosterior

# Per gear: close-view std (x [m], y [m], yaw [rad]) median over clean views, the same at the 90th
# percentile over every perturbation group, and the fraction of close views that were informative.
# Measured by `goflow bench calibration` on the held-out scenes of seed 9000 with the upsampled grid
# (docs/results/perception_calibration_seed9000.json).
CLOSE_VIEW: dict[str, dict[str, tuple[float, ...] | float]] = {
    "small": {"median": (2.5e-5, 2.4e-5, 2.4e-3), "p90": (3.2e-5, 3.1e-5, 3.6e-3), "informative": 1.0},
    "medium": {"median": (3.1e-5, 3.7e-5, 1.6e-3), "p90": (4.2e-5, 4.9e-5, 2.3e-3), "informative": 1.0},
    "large": {"median": (4.2e-5, 3.7e-5, 1.1e-3), "p90": (5.9e-5, 5.1e-5, 1.9e-3), "informative": 1.0},
}


@dataclass(frozen=True)
class InspectPrediction:
    """The predicted belief after inspect(gear): std (x [m], y [m], yaw [rad]) at the median and at
    the cautious 90th percentile of the close view's noise, and the probability that the close
    view is informative (else the belief stays as it was)."""

    gear: str
    std_before: np.ndarray
    std_after: np.ndarray
    std_after_cautious: np.ndarray
    p_informative: float

    @property
    def entropy_drop(self) -> float:
        """Expected drop of the Gaussian entropy [nats] over (x, y, yaw)."""
        gain = float(np.log(self.std_before / self.std_after).sum())
        return self.p_informative * gain


def predict_inspection(gear: str, before: PosePosterior | np.ndarray) -> InspectPrediction:
    """The predicted effect of inspect(`gear`) on a belief with standard deviations `before`
    (a PosePosterior, or (x [m], y [m], yaw [rad]) stds; an uninformative posterior's are those
    of its uniform box). ValueError on an unknown gear or stds that are not 3 positive numbers."""
    spec = gear_spec(gear)
    std = before.std() if isinstance(before, PosePosterior) else np.asarray(before, float)
    if std.shape != (3,) or not np.all(np.isfinite(std)) or np.any(std <= 0):
        raise ValueError(f"before = {std}; expected 3 standard deviations > 0 (x [m], y [m], "
                         "yaw [rad]) or a PosePosterior")
    close = CLOSE_VIEW[spec.name]

    def fuse(sigma_close) -> np.ndarray:
        return 1.0 / np.sqrt(std ** -2 + np.asarray(sigma_close, float) ** -2)

    return InspectPrediction(spec.name, std, fuse(close["median"]), fuse(close["p90"]),
                             float(close["informative"]))


__all__ = ["CLOSE_VIEW", "InspectPrediction", "predict_inspection"]
