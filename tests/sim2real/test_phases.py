"""Phases segmented from an unlabelled log's own signals."""

from __future__ import annotations

import numpy as np

from sim2real.log import PHASES, RobotLog
from sim2real.phases import segment_phases


def _log(wrench=None, z=None, phase=None, T=3000, dt=0.002):
    t = np.arange(T) * dt
    pose = None
    if z is not None:
        pose = np.tile(np.eye(4), (T, 1, 1))
        pose[:, 2, 3] = z
    return RobotLog(
        time=t,
        q=np.zeros((T, 7)),
        dq=np.zeros((T, 7)),
        tau=np.zeros((T, 7)),
        wrench=wrench,
        tool_pose=pose,
        phase=phase,
    )


def test_contact_and_insertion_from_force_and_descent():
    rng = np.random.default_rng(0)
    T = 3000
    force = 0.2 * rng.standard_normal((T, 6))
    force[1500:, 2] += 8.0  # touching from sample 1500 on
    z = np.where(np.arange(T) < 2000, 0.10, 0.10 - 0.01 * (np.arange(T) - 2000) * 0.002)  # descends after 2000
    phase = segment_phases(_log(force, z))
    names = np.array(PHASES)[phase]
    assert np.all(names[:900] == "free")
    assert np.all(names[1100:1490] == "approach")  # the second before the first contact
    assert np.mean(names[1510:1950] == "contact") > 0.95
    assert np.mean(names[2100:] == "insertion") > 0.95


def test_a_log_without_force_is_free_motion_and_labels_win():
    assert np.all(segment_phases(_log()) == 0)
    labels = np.full(3000, 2)
    assert np.all(segment_phases(_log(phase=labels)) == 2)
