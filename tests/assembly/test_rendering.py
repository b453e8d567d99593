"""What the station's RGB-D cameras see (assembly/station.py, assembly/cameras.py): the scene
camera's colour, depth and label images agree with the world's geometry through the pinhole model,
and the wrist camera renders the table below the hand at the home pose.

The station is rendered once, at t = 0 without simulating: the gears rest at
`WorldConfig().gear_start_poses` with their bottom faces on the table (z = 0), so each gear's top
face is the plane z = GEAR_THICKNESS.

Pixel convention: the documented CameraInfo one (the centre of pixel (u, v) lies at image
coordinates (u, v); principal point (center_x, center_y)). Drake 1.51's VTK renderer draws the
image half a pixel off that convention (the ray through pixel (u, v) is the documented ray of
(u + 0.5, v + 0.5); drake PR #10190 "camera_info: Fix a half pixel misalignment" is still open).
For the scene camera that costs at most ~1.3 mm of depth on the oblique table and well under
1 mm on the gears, inside the 2 mm tolerance used here.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.geometry import Role
from pydrake.math import RigidTransform

from assembly import gearset
from assembly.panda_model import Q_HOME
from assembly.station import StationConfig, build_station
from assembly.world import gear_body

GEARS = ("small", "medium", "large")
TOP_Z = gearset.GEAR_THICKNESS  # the gears' top faces, in W [m]
FLAT_TOP = gearset.GEAR_BORE_RADIUS + gearset.GEAR_BORE_CHAMFER  # inner edge of the flat top annulus
DEPTH_TOL = 0.002  # [m]


class Rendered:
    """One station, one context, the images of both cameras at t = 0."""

    def __init__(self, config: StationConfig | None = None) -> None:
        self.config = config or StationConfig()
        self.station = build_station(self.config)
        diagram = self.station.diagram
        self.context = diagram.CreateDefaultContext()
        diagram.GetInputPort("X_WT_desired").FixValue(
            self.context, AbstractValue.Make(self.station.controller.tool_pose(Q_HOME))
        )
        diagram.GetInputPort("gripper_width").FixValue(self.context, [0.08])
        self.images = {}
        for cam in ("scene", "wrist"):
            self.images[cam] = {
                "rgb": diagram.GetOutputPort(f"{cam}_rgb").Eval(self.context).data.copy(),
                "depth": diagram.GetOutputPort(f"{cam}_depth").Eval(self.context).data[:, :, 0].copy(),
                "label": diagram.GetOutputPort(f"{cam}_label").Eval(self.context).data[:, :, 0].copy(),
            }

    def body_label(self, body) -> int:
        """The render label registered on `body`'s perception geometries (one label per body)."""
        plant, inspector = self.station.plant, self.station.scene_graph.model_inspector()
        ids = inspector.GetGeometries(plant.GetBodyFrameIdOrThrow(body.index()), Role.kPerception)
        assert ids, f"body {body.name()} has no perception geometry"
        labels = {int(inspector.GetPerceptionProperties(g).GetProperty("label", "id")) for g in ids}
        assert len(labels) == 1, f"body {body.name()} carries several render labels {labels}"
        return labels.pop()

    def gear_label(self, gear: str) -> int:
        return self.body_label(gear_body(self.station.plant, self.station.models.gears[gear]))


class Pinhole:
    """The pinhole model of a camera at pose X_WC with CameraInfo `info`."""

    def __init__(self, X_WC: RigidTransform, info) -> None:
        self.X_WC, self.info = X_WC, info
        self.K = np.array(
            [[info.focal_x(), 0.0, info.center_x()], [0.0, info.focal_y(), info.center_y()], [0.0, 0.0, 1.0]]
        )

    def pixel(self, p_W: np.ndarray) -> tuple[int, int] | None:
        """The (column u, row v) of the pixel that images world point p_W; None out of view."""
        p_C = self.X_WC.inverse() @ np.asarray(p_W, float)
        if p_C[2] <= 0:
            return None
        uvw = self.K @ p_C
        u, v = int(round(uvw[0] / uvw[2])), int(round(uvw[1] / uvw[2]))
        if 0 <= u < self.info.width() and 0 <= v < self.info.height():
            return u, v
        return None

    def project(self, p_W: np.ndarray) -> tuple[int, int]:
        """Like pixel(), but the point must be in view."""
        uv = self.pixel(p_W)
        assert uv is not None, f"point {np.round(p_W, 3)} is outside the camera's view"
        return uv

    def ray_on_plane(self, u: float, v: float, z: float) -> tuple[np.ndarray, float]:
        """Where the ray through pixel (u, v) meets the world plane at height z, and the depth of
        that point (its camera-frame z)."""
        d_C = np.linalg.solve(self.K, [u, v, 1.0])  # camera-frame direction with unit z
        d_W = self.X_WC.rotation() @ d_C
        o_W = self.X_WC.translation()
        s = (z - o_W[2]) / d_W[2]
        assert s > 0, f"pixel ({u}, {v}) looks away from the plane z = {z}"
        return o_W + s * d_W, float(s)  # d_C has z = 1: the depth is s


@pytest.fixture(scope="module")
def rendered() -> Rendered:
    return Rendered()


@pytest.fixture(scope="module")
def scene_camera(rendered) -> Pinhole:
    cam = rendered.config.cameras.scene
    return Pinhole(cam.X_PC, cam.info())  # the scene camera's parent is the world


def _chromaticity(rgb) -> np.ndarray:
    rgb = np.asarray(rgb, float)[:3]
    return rgb / max(rgb.sum(), 1e-9)


def _gear_xy(rendered: Rendered, gear: str) -> np.ndarray:
    """The gear's axis (x, y) in W: its start pose (nothing has moved at t = 0)."""
    x, y, _ = rendered.config.world.gear_start_poses[gear]
    return np.array([x, y])


def test_scene_images_have_configured_size_and_types(rendered):
    cam = rendered.config.cameras.scene
    img = rendered.images["scene"]
    assert img["rgb"].shape == (cam.height, cam.width, 4)
    assert img["rgb"].dtype == np.uint8
    assert img["depth"].shape == (cam.height, cam.width)
    assert img["depth"].dtype == np.float32
    assert img["label"].shape == (cam.height, cam.width)


def test_gears_rest_at_their_start_poses(rendered):
    """What the rendering tests assume: at t = 0 each gear frame sits at its start pose on the table."""
    for gear in GEARS:
        p = rendered.station.gear_pose(rendered.context, gear).translation()
        np.testing.assert_allclose(p, np.append(_gear_xy(rendered, gear), 0.0), atol=1e-9)


def test_gear_labels_are_distinct(rendered):
    labels = {g: rendered.gear_label(g) for g in GEARS}
    assert len(set(labels.values())) == len(GEARS), labels
    # MultibodyPlant's default: a visual geometry's render label is its body's index.
    for g in GEARS:
        body = gear_body(rendered.station.plant, rendered.station.models.gears[g])
        assert labels[g] == int(body.index())


@pytest.mark.parametrize("gear", GEARS)
def test_gear_top_face_colour_and_label(rendered, scene_camera, gear):
    """The pixel imaging a point on the gear's top face shows the gear's colour and label."""
    spec = gearset.GEARS[gear]
    centre = _gear_xy(rendered, gear)
    toward = scene_camera.X_WC.translation()[:2] - centre  # in the table plane, toward the camera
    r = 0.5 * (gearset.GEAR_BORE_RADIUS + spec.tip_radius)
    p_W = np.append(centre + r * toward / np.linalg.norm(toward), TOP_Z)
    u, v = scene_camera.project(p_W)
    img = rendered.images["scene"]

    assert img["label"][v, u] == rendered.gear_label(gear), (
        f"{gear} gear: label {img['label'][v, u]} at pixel ({u}, {v}); expected "
        f"{rendered.gear_label(gear)} (the gear body's render label)"
    )

    # Shading scales the colour (a lit top face renders at ~0.6-0.8 of the diffuse colour), so
    # compare chromaticities (r, g, b) / (r + g + b) and bound the brightness separately.
    seen = img["rgb"][v, u, :3].astype(float)
    chroma = _chromaticity(seen)
    dist = {g: float(np.linalg.norm(chroma - _chromaticity(gearset.GEARS[g].rgba))) for g in GEARS}
    assert dist[gear] < 0.05, f"{gear} gear at pixel ({u}, {v}) is RGB {seen}; chroma distances {dist}"
    assert all(dist[g] > 2 * dist[gear] for g in GEARS if g != gear), dist
    want = 255.0 * np.array(spec.rgba[:3])
    assert np.argmax(seen) == np.argmax(want)
    assert 0.4 < seen.sum() / want.sum() < 1.2, f"{gear} gear: RGB {seen} vs diffuse {want}"


@pytest.mark.parametrize("gear", GEARS)
def test_gear_top_face_depth(rendered, scene_camera, gear):
    """Depth on the top face equals the camera-frame z of the ray's hit on the plane z = 0.020."""
    spec = gearset.GEARS[gear]
    centre = _gear_xy(rendered, gear)
    # Flat, solid annulus between the bore chamfer and the tooth roots; sample its midline.
    r_mid = 0.5 * (FLAT_TOP + spec.root_radius)
    img = rendered.images["scene"]
    errors = []
    for angle in np.linspace(0.0, 2 * np.pi, 8, endpoint=False):
        p_W = np.append(centre + r_mid * np.array([np.cos(angle), np.sin(angle)]), TOP_Z)
        u, v = scene_camera.project(p_W)
        hit, expected = scene_camera.ray_on_plane(u, v, TOP_Z)
        r_hit = np.linalg.norm(hit[:2] - centre)
        assert FLAT_TOP < r_hit < spec.root_radius, "test set-up: the pixel misses the flat annulus"
        assert img["label"][v, u] == rendered.gear_label(gear)
        errors.append(float(img["depth"][v, u]) - expected)
    assert np.max(np.abs(errors)) < DEPTH_TOL, (
        f"{gear} gear top-face depth errors [mm]: {np.round(1e3 * np.array(errors), 2)}"
    )


def test_bare_table_depth(rendered, scene_camera):
    """Pixels whose rays hit the bare table read the depth of the plane z = 0."""
    table_label = rendered.body_label(rendered.station.plant.GetBodyByName("table"))
    img = rendered.images["scene"]
    # Away from the gears (x = 0.40), the plate (around (0.55, 0)) and the robot (at the origin);
    # those in view are checked, and most must be.
    candidates = (
        [0.60, -0.35, 0.0],
        [0.50, 0.20, 0.0],
        [0.30, -0.30, 0.0],
        [0.45, -0.42, 0.0],
        [0.65, 0.15, 0.0],
        [0.55, -0.25, 0.0],
    )
    in_view = [(p, scene_camera.pixel(p)) for p in candidates if scene_camera.pixel(p) is not None]
    assert len(in_view) >= 4, f"only {len(in_view)} of the bare-table points are in view"
    for p_W, (u, v) in in_view:
        _, expected = scene_camera.ray_on_plane(u, v, 0.0)
        assert img["label"][v, u] == table_label, f"pixel ({u}, {v}) for {p_W} is not the table"
        assert abs(float(img["depth"][v, u]) - expected) < DEPTH_TOL, (
            f"table at pixel ({u}, {v}): depth {img['depth'][v, u]:.4f} m, expected {expected:.4f} m"
        )


def test_scene_camera_sees_plate_and_all_gears(rendered):
    """The scene camera frames the work area: every gear and the plate are in view, with some
    pixels of each (a coarse check of the camera's aim)."""
    label = rendered.images["scene"]["label"]
    plant = rendered.station.plant
    for gear in GEARS:
        assert np.count_nonzero(label == rendered.gear_label(gear)) > 50, gear
    plate = rendered.body_label(plant.GetBodyByName("gear_plate"))
    assert np.count_nonzero(label == plate) > 500


def test_wrist_camera_sees_table_below_hand(rendered):
    """The wrist camera has its configured size; at the home pose it looks down at the table: its
    finite depths lie in the clipping range and the table pixels read the depth of the plane z = 0
    seen from the hand's pose (parent frame = panda_hand)."""
    cam = rendered.config.cameras.wrist
    img = rendered.images["wrist"]
    assert img["rgb"].shape == (cam.height, cam.width, 4)
    assert img["depth"].shape == (cam.height, cam.width)
    depth = img["depth"]
    finite = np.isfinite(depth) & (depth > 0)
    assert finite.mean() > 0.5, f"only {finite.mean():.0%} of the wrist depth image is finite"
    assert cam.near <= depth[finite].min() and depth[finite].max() <= cam.far

    plant = rendered.station.plant
    hand = plant.GetBodyByName("panda_hand")
    X_WH = plant.EvalBodyPoseInWorld(rendered.station.plant_context(rendered.context), hand)
    pinhole = Pinhole(X_WH @ cam.X_PC, cam.info())
    table = rendered.body_label(plant.GetBodyByName("table"))
    rows, cols = np.nonzero(img["label"] == table)
    assert rows.size > 0.3 * depth.size, "the wrist camera should see mostly table"
    pick = np.linspace(0, rows.size - 1, 25).astype(int)
    for v, u in zip(rows[pick], cols[pick]):
        _, expected = pinhole.ray_on_plane(u, v, 0.0)
        assert abs(float(depth[v, u]) - expected) < DEPTH_TOL, (
            f"wrist table pixel ({u}, {v}): depth {depth[v, u]:.4f} m, expected {expected:.4f} m"
        )
