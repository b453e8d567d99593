"""Shared scenes for the perception tests (Drake renders, headless)."""

from __future__ import annotations

import numpy as np
import pytest

from perception.speed import close_camera
from perception.drake_scene import DrakeScene, SceneConfig

POSES = {"large": (0.40, -0.15, 0.1), "medium": (0.41, -0.03, 0.7), "small": (0.40, 0.07, 0.3)}
PLATE = (0.55, 0.0, np.pi / 2)


@pytest.fixture(scope="session")
def plain_scene() -> DrakeScene:
    """All three gears (no markers) and the gear plate on the table."""
    return DrakeScene(SceneConfig(gears=dict(POSES), plate_pose=PLATE))


@pytest.fixture(scope="session")
def marked_scene() -> DrakeScene:
    """The same scene with every gear marked (a white bar on its top face along tooth 0)."""
    return DrakeScene(SceneConfig(gears=dict(POSES), marked=tuple(POSES), plate_pose=PLATE))


@pytest.fixture(scope="session")
def poses() -> dict:
    """The gears' true poses (x, y, yaw) in the shared scenes."""
    return dict(POSES)


def _close_view(scene: DrakeScene, gear: str, height: float = 0.15):
    x, y, _ = POSES[gear]
    cam = close_camera(x, y, height)
    return scene.render(cam, cam.X_PC)


@pytest.fixture(scope="session")
def close_view():
    """close_view(scene, gear, height=0.15): a wrist-like view from `height` above the table
    over `gear` in a shared scene."""
    return _close_view
