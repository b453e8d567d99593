"""Our ray caster against Drake's RenderEngineVtk: same depth (within 1 mm) where both see the
gear away from depth edges; the gear model's height map is the mesh's top surface."""

import numpy as np
import pytest

from assembly.cameras import default_scene_camera
from assembly.gearset import GEAR_BORE_CHAMFER, GEAR_BORE_RADIUS, GEAR_THICKNESS, GEARS
from perception.speed import close_camera, compare_depth, gear_mask
from perception.drake_scene import DrakeScene, SceneConfig
from perception.gear_model import MARKER_HEIGHT, gear_model
from perception.renderer import RayCaster, RayCasterConfig, render_image


@pytest.mark.parametrize("gear", ["small", "large"])
def test_height_map_is_the_top_surface(gear):
    hm = gear_model(gear).height_map()
    assert hm.top == pytest.approx(GEAR_THICKNESS, abs=1e-7)
    c = hm.size // 2
    r_px = int((GEAR_BORE_RADIUS - 1e-4) / hm.texel)
    assert hm.height[c, c - r_px + 2] < 0  # the bore is empty
    ring = int((GEAR_BORE_RADIUS + GEAR_BORE_CHAMFER + 1e-3) / hm.texel)
    assert hm.height[c, c + ring] == pytest.approx(GEAR_THICKNESS, abs=1e-6)
    tip = int((GEARS[gear].tip_radius + 1e-4) / hm.texel)
    assert hm.height[c, c + tip] < 0  # outside the tips
    assert gear_model(gear, marked=True).height_map().top == pytest.approx(GEAR_THICKNESS + MARKER_HEIGHT, abs=1e-7)
    assert gear_model(gear, marked=True).symmetry == 1
    assert gear_model(gear).symmetry == GEARS[gear].teeth


@pytest.mark.parametrize("gear,view", [("medium", "close"), ("large", "scene"), ("small", "close")])
def test_depth_agrees_with_drake(gear, view):
    pose = (0.42, -0.05, 0.37)
    scene = DrakeScene(SceneConfig(gears={gear: pose}, marked=(gear,) if gear == "small" else ()))
    camera = close_camera(0.42, -0.05) if view == "close" else default_scene_camera()
    obs = scene.render(camera, camera.X_PC)
    k = obs.intrinsics
    v, u = np.mgrid[0 : k.height, 0 : k.width]
    origin, dirs = obs.rays_W(u.ravel(), v.ravel())
    caster = RayCaster(gear_model(gear, marked=gear == "small"))
    light = -camera.X_PC.rotation().matrix()[:, 2]
    depth, rgb = render_image(caster, origin, dirs, light, np.array(pose), (k.height, k.width))
    drake_gear = gear_mask(obs)
    agree = compare_depth(obs.depth, drake_gear, depth)
    assert agree["pixels_interior"] > 300
    assert agree["within_1mm_interior"] >= 0.99, agree
    assert agree["within_1mm_all"] >= 0.98, agree
    # silhouettes agree: pixels seen as gear by one renderer only are a thin rim
    ours = np.isfinite(depth)
    assert np.count_nonzero(ours ^ drake_gear) < 0.05 * np.count_nonzero(drake_gear)
    # shading follows Drake's headlight: the median colour error on the gear is small
    both = ours & drake_gear
    assert np.median(np.abs(obs.rgb - rgb).sum(-1)[both]) < 0.05


def test_caster_rejects_bad_arguments():
    caster = RayCaster(gear_model("small"))
    with pytest.raises(ValueError, match="poses have shape"):
        caster.render(np.array([0, 0, 0.5]), np.array([[0, 0, -1.0]]), np.array([0, 0, 1.0]), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="not above the gear top"):
        caster.render(np.array([0, 0, 0.01]), np.array([[0, 0, -1.0]]), np.array([0, 0, 1.0]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="march_step"):
        RayCasterConfig(march_step=0.01)
