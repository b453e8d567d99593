"""Global gear detection in the scene camera's image (perception.detection)."""

from __future__ import annotations

import pytest
from pydrake.math import RigidTransform

from assembly.gearset import GEAR_NAMES
from perception.detection import Detection, DetectionConfig, detect_gears
from perception.observation import Observation
from perception.scenes import RandomScene, SceneRenderer, random_scenes

SEED = 31  # not used while tuning


@pytest.fixture(scope="module")
def renderer() -> SceneRenderer:
    return SceneRenderer()


def _view(renderer, scene, perturbation="clean"):
    return renderer.render_view(scene, "scene", None, perturbation, scene.rng("det", perturbation))


def _in_box(det: Detection, pose) -> bool:
    return max(abs(det.prior.x - pose[0]), abs(det.prior.y - pose[1])) <= det.prior.half_width


@pytest.mark.parametrize("perturbation", ["clean", "dim", "oblique", "depth_noise", "dropout_10"])
def test_every_gear_found_with_truth_in_box(renderer, perturbation):
    for scene in random_scenes(SEED, 4):
        found = detect_gears(_view(renderer, scene, perturbation).obs)
        assert sorted(found) == sorted(GEAR_NAMES)
        for gear, det in found.items():
            assert det.seen, (scene.index, gear, det.reason)
            assert det.reason == "" and 0.8 < det.score <= 1 and det.pixels > 20
            assert _in_box(det, scene.poses[gear]), (scene.index, gear, det)
            assert 0.004 <= det.prior.half_width <= 0.01


def test_occluded_gear_found_or_reported(renderer):
    for scene in random_scenes(SEED + 1, 3):
        for perturbation in ("occluded_hand", "occluded_gear"):
            view = _view(renderer, scene, perturbation)
            found = detect_gears(view.obs)
            assert found[view.gear].seen and _in_box(found[view.gear], scene.poses[view.gear])
            for gear, det in found.items():
                if det.seen:  # never a made-up pose
                    assert _in_box(det, scene.poses[gear])
                else:
                    assert det.prior is None and det.reason
                    assert view.visible.get(gear, 0.0) < 0.5, (gear, det.reason)


def test_missing_gear_not_seen(renderer):
    scene = next(random_scenes(SEED + 2, 1))
    poses = dict(scene.poses)
    gone = poses.pop("medium")
    for name, others in (("removed", poses), ("off the region", {**poses, "medium": (0.0, -0.4, 0.0)})):
        found = detect_gears(_view(renderer, RandomScene(SEED, 0, others)).obs)
        assert not found["medium"].seen and found["medium"].prior is None, name
        assert "pixels of its colour" in found["medium"].reason
        for gear in poses:
            assert found[gear].seen and _in_box(found[gear], poses[gear])
    assert gone  # the medium gear was in the scene before
    # Only the gears asked for.
    only = detect_gears(_view(renderer, scene).obs, gears=("small",))
    assert list(only) == ["small"] and only["small"].seen


def test_bad_input(renderer):
    obs = _view(renderer, next(random_scenes(SEED, 1))).obs
    with pytest.raises(ValueError, match="expected a perception.observation.Observation"):
        detect_gears(obs.rgb)
    with pytest.raises(ValueError, match="unknown gear"):
        detect_gears(obs, gears=("tiny",))
    with pytest.raises(ValueError, match="tuple of gear names"):
        detect_gears(obs, gears="small")
    with pytest.raises(ValueError, match="DetectionConfig"):
        detect_gears(obs, config={"tube": 0.1})
    with pytest.raises(ValueError, match="tube"):
        DetectionConfig(tube=-1.0)
    up = RigidTransform([0.45, 0.0, 0.5])  # optical axis along world +z: the sky
    with pytest.raises(ValueError, match="sees no part of the placement region"):
        detect_gears(Observation(obs.rgb, obs.depth, obs.intrinsics, up))
