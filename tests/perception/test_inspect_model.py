"""The inspect model the planner calls: an inspection narrows a wide belief to about the close
view's measured width, barely changes a belief already narrower, and rejects bad input."""

from pathlib import Path

import numpy as np
import pytest

from perception.calibration import load_result
from perception.inspect_model import CLOSE_VIEW, close_view_noise, predict_inspection
from perception.posterior import uniform_posterior


def test_wide_belief_narrows_to_the_close_view():
    wide = uniform_posterior("large", (0.45, -0.1), 0.02, "detection only")
    pred = predict_inspection("large", wide)
    np.testing.assert_allclose(pred.std_after, CLOSE_VIEW["large"]["median"], rtol=0.05)
    assert np.all(pred.std_after_cautious >= pred.std_after)
    assert pred.entropy_drop > 5.0


def test_narrow_belief_hardly_changes():
    narrow = np.array([5e-6, 5e-6, 1e-4])  # a fifth of the small gear's close-view std or less
    pred = predict_inspection("small", narrow)
    np.testing.assert_allclose(pred.std_after, narrow, rtol=0.05)
    assert pred.entropy_drop < 0.1


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="unknown gear 'huge'"):
        predict_inspection("huge", [1e-3, 1e-3, 0.1])
    with pytest.raises(ValueError, match="3 standard deviations"):
        predict_inspection("small", [1e-3, -1.0, 0.1])


def test_close_view_is_what_the_committed_benchmark_measured():
    """CLOSE_VIEW is `close_view_noise` of the held-out benchmark run it cites, so the planner's
    inspect model follows the posteriors as they are shipped."""
    path = Path(__file__).resolve().parents[2] / "docs" / "results" / "perception_calibration_seed12000_rows.json.gz"
    assert close_view_noise(load_result(path)["rows"]) == CLOSE_VIEW


def test_close_view_noise_needs_a_clean_close_view():
    rows = [
        {
            "view": "inspect",
            "gear": "small",
            "group": "dim",
            "seen": True,
            "informative": True,
            "std": [2e-5, 2e-5, 2e-3],
        }
    ]
    with pytest.raises(ValueError, match="no informative clean close view of the small gear"):
        close_view_noise(rows)
