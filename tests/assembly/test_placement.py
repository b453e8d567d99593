"""The placement region and random gear start poses (assembly.world)."""

from __future__ import annotations

import numpy as np
import pytest

from assembly.cameras import default_scene_camera
from assembly.gearset import GEAR_NAMES, GEAR_THICKNESS, gear_spec
from assembly.world import (
    PLACEMENT_X,
    PLACEMENT_Y,
    REACH_RADIUS,
    WorldConfig,
    random_gear_poses,
    validate_gear_pose,
)


def test_random_poses_valid_in_region_and_deterministic():
    plate = WorldConfig().plate_pose
    for seed in range(20):
        poses = random_gear_poses(np.random.default_rng(seed))
        assert sorted(poses) == sorted(GEAR_NAMES)
        WorldConfig(gear_start_poses=poses)  # validates every gear against plate and others
        for name, (x, y, yaw) in poses.items():
            assert PLACEMENT_X[0] <= x <= PLACEMENT_X[1] and PLACEMENT_Y[0] <= y <= PLACEMENT_Y[1]
            assert -np.pi <= yaw < np.pi
            others = {k: v for k, v in poses.items() if k != name}
            validate_gear_pose(name, (x, y, yaw), plate, others)
        assert poses == random_gear_poses(np.random.default_rng(seed))
    assert random_gear_poses(np.random.default_rng(0)) != random_gear_poses(np.random.default_rng(1))
    assert list(random_gear_poses(np.random.default_rng(0), gears=("large",))) == ["large"]


def test_region_seen_by_scene_camera_and_reachable():
    """Every gear anywhere in the region projects fully inside the scene image with >= 10 px."""
    cam = default_scene_camera()
    info = cam.info()
    X_CW = cam.X_PC.inverse()
    th = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    for name in GEAR_NAMES:
        r = gear_spec(name).tip_radius
        for x in np.linspace(*PLACEMENT_X, 9):
            for y in np.linspace(*PLACEMENT_Y, 9):
                assert REACH_RADIUS[0] <= np.hypot(x, y) <= REACH_RADIUS[1]
                pts = np.concatenate(
                    [
                        np.stack([x + r * np.cos(th), y + r * np.sin(th), np.full_like(th, z)], 1)
                        for z in (0.0, GEAR_THICKNESS)
                    ]
                )
                p = pts @ X_CW.rotation().matrix().T + X_CW.translation()
                u = info.focal_x() * p[:, 0] / p[:, 2] + info.center_x()
                v = info.focal_y() * p[:, 1] / p[:, 2] + info.center_y()
                margin = min(u.min(), info.width() - u.max(), v.min(), info.height() - v.max())
                assert margin >= 10, (name, x, y, margin)


def test_bad_input():
    with pytest.raises(ValueError, match="numpy.random.Generator"):
        random_gear_poses(0)
    with pytest.raises(ValueError, match="unknown gear"):
        random_gear_poses(np.random.default_rng(0), gears=("tiny",))
    with pytest.raises(ValueError, match="max_tries"):
        random_gear_poses(np.random.default_rng(0), max_tries=0)
    # With one draw per gear, some seed's draw collides with the plate or another gear.
    with pytest.raises(RuntimeError, match="no valid pose"):
        for seed in range(50):
            random_gear_poses(np.random.default_rng(seed), max_tries=1)
