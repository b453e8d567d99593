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
# Measured by `goflow bench calibration` on the held-out scenes of seed 12000 with the reshaped
# posteriors (`close_view_noise` of docs/results/perception_calibration_seed12000_rows.json.gz's rows).
CLOSE_VIEW: dict[str, dict[str, tuple[float, ...] | float]] = {
    "small": {"median": (2.1e-5, 2.0e-5, 2.3e-3), "p90": (3.0e-5, 2.8e-5, 3.5e-3), "informative": 1.0},
    "medium": {"median": (2.8e-5, 3.3e-5, 1.6e-3), "p90": (3.9e-5, 4.8e-5, 2.4e-3), "informative": 1.0},
    "large": {"median": (3.8e-5, 3.5e-5, 1.2e-3), "p90": (6.6e-5, 5.0e-5, 2.0e-3), "informative": 1.0},
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


def close_view_noise(rows: list[dict]) -> dict[str, dict[str, tuple[float, ...] | float]]:
    """`CLOSE_VIEW` measured on calibration rows (`goflow bench calibration`'s JSON "rows"): per
    gear, the median close-view std (x, y, yaw) over the informative clean views, its 90th
    percentile over the informative views of every group, and the informative share of the close
    views. ValueError if a gear has no informative clean close view."""
    out: dict[str, dict[str, tuple[float, ...] | float]] = {}
    for gear in dict.fromkeys(r["gear"] for r in rows if r["view"] == "inspect"):
        close = [r for r in rows if r["view"] == "inspect" and r["gear"] == gear]
        seen = [r for r in close if r.get("seen") and r.get("informative")]
        clean = np.array([r["std"] for r in seen if r["group"] == "clean"])
        if not len(clean):
            raise ValueError(f"no informative clean close view of the {gear} gear in the rows")
        every = np.array([r["std"] for r in seen])
        out[gear] = {
            "median": tuple(float(f"{v:.2g}") for v in np.median(clean, axis=0)),
            "p90": tuple(float(f"{v:.2g}") for v in np.percentile(every, 90, axis=0)),
            "informative": round(len(seen) / len(close), 3),
        }
    return out


def predict_inspection(gear: str, before: PosePosterior | np.ndarray) -> InspectPrediction:
    """The predicted effect of inspect(`gear`) on a belief with standard deviations `before`
    (a PosePosterior, or (x [m], y [m], yaw [rad]) stds; an uninformative posterior's are those
    of its uniform box). ValueError on an unknown gear or stds that are not 3 positive numbers."""
    spec = gear_spec(gear)
    std = before.std() if isinstance(before, PosePosterior) else np.asarray(before, float)
    if std.shape != (3,) or not np.all(np.isfinite(std)) or np.any(std <= 0):
        raise ValueError(
            f"before = {std}; expected 3 standard deviations > 0 (x [m], y [m], yaw [rad]) or a PosePosterior"
        )
    close = CLOSE_VIEW[spec.name]

    def fuse(sigma_close) -> np.ndarray:
        return 1.0 / np.sqrt(std**-2 + np.asarray(sigma_close, float) ** -2)

    return InspectPrediction(spec.name, std, fuse(close["median"]), fuse(close["p90"]), float(close["informative"]))


__all__ = ["CLOSE_VIEW", "InspectPrediction", "close_view_noise", "predict_inspection"]
