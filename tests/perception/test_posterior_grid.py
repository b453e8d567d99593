"""The posterior grid around the search's MAP follows the mass: when the likelihood's peak lies off
the MAP the search handed over (a far view's yaw refined on 0.25 deg steps, say), the grid moves
and widens until none of its mass sits at its edges, instead of truncating the posterior there
(the truth then read as outside every credible region)."""

import numpy as np
import pytest

from perception.gear_model import gear_model
from perception.posterior import wrap
from perception.scoring import Scores
from perception.search import Prior, SearchConfig, _posterior_grid

SIGMA = np.array([4e-5, 5e-5, 1.2e-3])  # a far view's posterior std (x, y [m], yaw [rad])


def _gaussian_score(peak: np.ndarray):
    def score(poses, stride):
        z = (np.atleast_2d(poses) - peak) / SIGMA
        n = len(z)
        return Scores(-0.5 * (z**2).sum(axis=1), np.full(n, 600), np.full(n, 600))

    return score


def test_grid_is_refitted_to_a_peak_off_the_map():
    model = gear_model("large")
    map_pose = np.array([0.42, 0.19, 0.15])
    peak = map_pose + np.array([-1.5, 1.0, 6.0]) * SIGMA  # the yaw peak 6 std off the MAP
    prior = Prior(0.42, 0.19, 0.004)
    post = _posterior_grid(model, map_pose, _gaussian_score(peak), 1, SearchConfig(), prior)
    assert post.info["edge_mass"] < 0.01
    assert post.credible_level(peak) < 0.05
    np.testing.assert_allclose(post.std(), SIGMA, rtol=0.1)
    off = post.mean() - peak
    off[2] = wrap(off[2], model.period)  # yaw is a symmetry class
    assert np.all(np.abs(off) < 0.1 * SIGMA), off / SIGMA
    # the grid the 1-D probes from the MAP set, not refitted: 3-6 std a step, 25-35 % too wide
    probed = _posterior_grid(model, map_pose, _gaussian_score(peak), 1, SearchConfig(adapt=1), prior)
    assert np.all(probed.std() > 1.2 * SIGMA)


@pytest.mark.parametrize("bad", [{"adapt": 0}, {"max_edge_mass": 0.0}, {"grid_step_std": -1.0}, {"max_cell_mass": 1.5}])
def test_bad_grid_settings_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        SearchConfig(**bad)
