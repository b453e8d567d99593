"""The inspect model the planner calls: an inspection narrows a wide belief to about the close
view's measured width, barely changes a belief already narrower, and rejects bad input."""

import numpy as np
import pytest

from perception.inspect_model import CLOSE_VIEW, predict_inspection
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
