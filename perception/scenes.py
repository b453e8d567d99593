"""Random scenes and perturbations for calibrating perception.

A scene is the station's table with the gear plate at its WorldConfig pose and all three gears at
`assembly.world.random_gear_poses` (the placement region). A view renders it with Drake's
RenderEngineVtk from

* "scene": the station's fixed scene camera (`assembly.cameras.default_scene_camera`), or
* "inspect": the wrist camera where `inspect(gear)` puts it: 0.17 m above the gear's top looking
  straight down, aimed at a believed position up to 1 cm off the truth, with the wrist camera's
  intrinsics; the hand that carries the camera is in the picture (its fingers are, as in the
  station).

under one `Perturbation` of the catalogue `PERTURBATIONS`: lighting is rendered by Drake itself (one
VTK renderer per lighting setup, all in one SceneGraph); depth noise and dropout are applied to the
rendered depth image, as a sensor would; an occluder (the committed Panda hand model, or a copy of
another gear as if carried) is a free body placed between the camera and the target gear so that it
hides a given fraction of the gear's pixels (measured on label images).

    renderer = SceneRenderer()
    for scene in random_scenes(seed=0, count=10):
        view = renderer.render_view(scene, "scene", None, "dim", scene.rng("scene", "dim"))
        view.obs, view.poses, view.hidden_fraction
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import LightParameter
from pydrake.math import RigidTransform, RotationMatrix

from assembly.cameras import CameraConfig, default_scene_camera, default_wrist_camera
from assembly.gearset import GEAR_NAMES, GEAR_THICKNESS
from assembly.inspection import X_HT, inspect_tool_pose
from assembly.rgbd_sensor import IDEAL, RgbdSensorModel, sensor_model
from assembly.world import WorldConfig, random_gear_poses
from perception.drake_scene import DEFAULT_LIGHTING, HAND_OCCLUDER, DrakeScene, SceneConfig
from perception.observation import Observation

__all__ = [
    "DEPTH_NOISE_REFERENCE",
    "INSPECT_OFFSET",
    "Lighting",
    "PERTURBATIONS",
    "Perturbation",
    "RandomScene",
    "SceneRenderer",
    "VIEWS",
    "View",
    "apply_depth_noise",
    "apply_dropout",
    "random_scenes",
]

VIEWS = ("scene", "inspect")
# Structured-light depth noise grows with the square of the depth; its sigma is given at this depth.
DEPTH_NOISE_REFERENCE = 0.5  # [m]
# The inspect view aims at a believed gear position up to this far from the truth [m].
INSPECT_OFFSET = 0.01
# Occluder kinds of a Perturbation: the Panda hand, or another gear of the set (as if carried).
OCCLUDER_KINDS = ("hand", "gear")
# Occluder body names in the scene: "hand" hovers, "wrist_hand" carries the inspect camera.
_WRIST_HAND = "wrist_hand"
# The hand frame's origin is its flange; the bulk of the palm is about this far along its z [m],
# and its fingertips this far beyond the palm's bulk [m] (TCP at 0.1034 m, pads end ~1 cm lower).
_PALM_CENTRE = 0.03
_HAND_DROP = 0.085
# An occluder's lowest point stays this far above the gears' tops [m], its bulk at most this high.
_OCCLUDER_CLEARANCE = 0.015
_OCCLUDER_MAX_HEIGHT = 0.20


@dataclass(frozen=True)
class Lighting:
    """A lighting setup: one white directional light of `intensity`; `elevation_deg` None is
    Drake's camera headlight (along the optical axis, as with no lights given), otherwise the
    light arrives from that elevation above the table and the world azimuth `azimuth_deg`
    (measured from +x towards +y)."""

    intensity: float = 1.0
    elevation_deg: float | None = None
    azimuth_deg: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.intensity) and self.intensity > 0):
            raise ValueError(f"Lighting.intensity = {self.intensity}; expected a finite value > 0")
        if self.elevation_deg is not None and not 0 < self.elevation_deg <= 90:
            raise ValueError(
                f"Lighting.elevation_deg = {self.elevation_deg}; expected (0, 90] "
                "degrees or None (the camera headlight)"
            )

    @property
    def is_default(self) -> bool:
        """Whether this is exactly what Drake renders with no lights given."""
        return self.elevation_deg is None and self.intensity == 1.0

    def lights(self) -> tuple[LightParameter, ...]:
        """The Drake LightParameters of this setup."""
        if self.elevation_deg is None:
            return (
                LightParameter(type="directional", frame="camera", intensity=self.intensity, direction=[0.0, 0.0, 1.0]),
            )
        el, az = np.radians(self.elevation_deg), np.radians(self.azimuth_deg)
        towards = -np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        return (LightParameter(type="directional", frame="world", intensity=self.intensity, direction=towards),)


@dataclass(frozen=True)
class Perturbation:
    """One way a view can differ from the clean render.

    lighting: how Drake lights the scene; depth_noise: Gaussian depth noise sigma [m] at
    DEPTH_NOISE_REFERENCE, growing with depth squared (nothing clipped); dropout: fraction of depth
    pixels set to NaN, each pixel independently; occluder: None, "hand" or "gear", hovering between
    the camera and the target gear so that it hides a fraction in `hidden` of the gear's pixels;
    sensors: the real camera of the scene view and of the inspect view (names of
    assembly.rgbd_sensor.SENSOR_MODELS, None: ideal): its noise on the render, its depth scale and
    its true mounting off the calibrated one drawn once per scene and view (`RandomScene.rng("mount",
    view)`), the observation keeping the calibrated pose."""

    name: str
    description: str = ""
    lighting: Lighting = field(default_factory=Lighting)
    depth_noise: float = 0.0
    dropout: float = 0.0
    occluder: str | None = None
    hidden: tuple[float, float] = (0.15, 0.40)
    sensors: tuple[str | None, str | None] = (None, None)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.depth_noise) and self.depth_noise >= 0):
            raise ValueError(f"{self.name}: depth_noise = {self.depth_noise}; expected >= 0 m")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"{self.name}: dropout = {self.dropout}; expected a fraction in [0, 1)")
        if self.occluder is not None and self.occluder not in OCCLUDER_KINDS:
            raise ValueError(f"{self.name}: occluder = {self.occluder!r}; expected None or one of {OCCLUDER_KINDS}")
        if not 0 < self.hidden[0] < self.hidden[1] < 1:
            raise ValueError(f"{self.name}: hidden = {self.hidden}; expected 0 < low < high < 1")
        if len(self.sensors) != 2:
            raise ValueError(f"{self.name}: sensors = {self.sensors}; expected (scene view's, inspect view's) models")
        for name in self.sensors:
            if name is not None:
                sensor_model(name)

    def sensor(self, view: str) -> RgbdSensorModel:
        """The real camera of `view` ("scene" or "inspect")."""
        name = self.sensors[VIEWS.index(view)]
        return IDEAL if name is None else sensor_model(name)


# The scene camera looks from azimuth -52 deg (from the table centre towards (0.78, -0.42)); the
# oblique light comes from the side of that view, 90 deg further round.
_SIDE_AZIMUTH = 38.0

PERTURBATIONS: dict[str, Perturbation] = {
    p.name: p
    for p in (
        Perturbation("clean", "Drake's default headlight, perfect depth"),
        Perturbation(
            "depth_noise", "Gaussian depth noise, sigma 1 mm at 0.5 m growing with depth^2", depth_noise=0.001
        ),
        Perturbation("dropout_3", "3 % of depth pixels NaN (independent pixels)", dropout=0.03),
        Perturbation("dropout_10", "10 % of depth pixels NaN (independent pixels)", dropout=0.10),
        Perturbation("dim", "headlight at half intensity", lighting=Lighting(intensity=0.5)),
        Perturbation("bright", "headlight at 1.6 x intensity, colours saturate at 1", lighting=Lighting(intensity=1.6)),
        Perturbation(
            "oblique",
            "one directional light from 45 deg elevation off the side instead of the headlight",
            lighting=Lighting(elevation_deg=45.0, azimuth_deg=_SIDE_AZIMUTH),
        ),
        Perturbation("occluded_hand", "a Panda hand between camera and gear hides 15-40 % of it", occluder="hand"),
        Perturbation(
            "occluded_gear", "another gear, as if carried, between camera and gear hides 15-40 % of it", occluder="gear"
        ),
        Perturbation(
            "realsense",
            "a RealSense D415 scene and D405 wrist camera (depth noise, unit, scale and shadows; colour noise; "
            "extrinsics off by their calibration std) under a lamp from 60 deg elevation",
            lighting=Lighting(elevation_deg=60.0, azimuth_deg=_SIDE_AZIMUTH + 90.0),
            sensors=("d415", "d405"),
        ),
    )
}


def _perturbation(perturbation: str | Perturbation) -> Perturbation:
    if isinstance(perturbation, Perturbation):
        return perturbation
    if perturbation not in PERTURBATIONS:
        raise ValueError(
            f"unknown perturbation {perturbation!r}; expected one of {list(PERTURBATIONS)} or a Perturbation"
        )
    return PERTURBATIONS[perturbation]


def apply_depth_noise(depth: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """`depth` plus Gaussian noise of sigma `sigma` * (depth / DEPTH_NOISE_REFERENCE)^2 on its
    finite pixels (a new array; nothing clipped)."""
    finite = np.isfinite(depth)
    scale = sigma * (np.where(finite, depth, 0.0) / DEPTH_NOISE_REFERENCE) ** 2
    return np.where(finite, depth + rng.standard_normal(depth.shape) * scale, depth).astype(depth.dtype)


def apply_dropout(depth: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """`depth` with each pixel set to NaN independently with probability `fraction` (a new array)."""
    return np.where(rng.random(depth.shape) < fraction, np.nan, depth).astype(depth.dtype)


@dataclass(frozen=True)
class RandomScene:
    """Scene `index` of the stream seeded `seed`: the gears' true poses (x, y, yaw)."""

    seed: int
    index: int
    poses: dict[str, tuple[float, float, float]]

    def rng(self, *tags: str) -> np.random.Generator:
        """A generator for this scene and `tags` (e.g. view and perturbation): the same tags give
        the same stream, different tags independent ones."""
        key = [zlib.crc32(t.encode()) for t in tags]
        return np.random.default_rng([self.seed, self.index, 1, *key])


def random_scenes(
    seed: int,
    count: int | None = None,
    plate_pose: tuple[float, float, float] = WorldConfig().plate_pose,
    gears: tuple[str, ...] = GEAR_NAMES,
) -> Iterator[RandomScene]:
    """Fresh random scenes from `seed` (scene k depends only on seed and k): `count` of them, or
    endlessly when None."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed = {seed!r}; expected an integer >= 0")
    k = 0
    while count is None or k < count:
        rng = np.random.default_rng([seed, k, 0])
        yield RandomScene(int(seed), k, random_gear_poses(rng, plate_pose, gears))
        k += 1


@dataclass
class View:
    """One rendered view: the observation and what is true about it.

    gear: the view's target (the inspected or occluded gear; None for a plain scene view);
    believed_xy: where the inspect view aimed; hidden_fraction: the fraction of the target gear's
    pixels the occluder hides (None without an occluder); occluder: the occluder body's kind and
    world pose; visible: per gear, the fraction of its pixels (in this view without the occluder)
    that the occluder leaves visible (1 for every gear without an occluder; a gear out of the
    view is absent); extrinsic_std: the std (translation [m], rotation [rad]) of the camera's true
    mounting about the calibrated pose `obs.X_WC` (0: the true pose)."""

    obs: Observation
    view: str
    gear: str | None
    perturbation: str
    poses: dict[str, tuple[float, float, float]]
    camera: CameraConfig
    believed_xy: tuple[float, float] | None = None
    hidden_fraction: float | None = None
    occluder: tuple[str, RigidTransform] | None = None
    visible: dict[str, float] = field(default_factory=dict)
    extrinsic_std: tuple[float, float] = (0.0, 0.0)


class SceneRenderer:
    """One Drake scene (table, plate, the three gears, occluder bodies, a renderer per lighting
    setup of `perturbations`) reused for every random scene: a view costs a few renders, not a
    rebuild."""

    def __init__(
        self,
        plate_pose: tuple[float, float, float] = WorldConfig().plate_pose,
        perturbations: dict[str, Perturbation] | None = None,
    ) -> None:
        self.plate_pose = tuple(plate_pose)
        self.perturbations = dict(perturbations or PERTURBATIONS)
        self._lighting_names: dict[Lighting, str] = {}
        lightings = {}
        for p in self.perturbations.values():
            if p.lighting.is_default:
                self._lighting_names[p.lighting] = DEFAULT_LIGHTING
            elif p.lighting not in self._lighting_names:
                name = f"light{len(lightings)}"
                self._lighting_names[p.lighting] = name
                lightings[name] = p.lighting.lights()
        occluders = {HAND_OCCLUDER: HAND_OCCLUDER, _WRIST_HAND: HAND_OCCLUDER}
        occluders.update({f"carried_{g}": g for g in GEAR_NAMES})
        self.scene = DrakeScene(
            SceneConfig(
                gears={g: (0.40, 0.0, 0.0) for g in GEAR_NAMES},
                plate_pose=self.plate_pose,
                lightings=lightings,
                occluders=occluders,
            )
        )
        self.scene_camera = default_scene_camera()
        self.wrist_camera = default_wrist_camera()

    def render_view(
        self,
        scene: RandomScene,
        view: str,
        gear: str | None,
        perturbation: str | Perturbation,
        rng: np.random.Generator,
        believed_xy: tuple[float, float] | None = None,
    ) -> View:
        """Render `view` ("scene" or "inspect") of `scene` under `perturbation`; `gear` is the
        inspected gear (required for "inspect") and the one an occluder hides (for "scene" with an
        occluder and no gear, one drawn from `rng`). Everything random (believed position,
        occluder, noise, dropout) comes from `rng`; `believed_xy` aims the inspect view there
        instead of at a random point near the truth (e.g. at a far posterior's estimate)."""
        p = _perturbation(perturbation)
        if p.lighting not in self._lighting_names:
            raise ValueError(
                f"perturbation {p.name!r} has a lighting this renderer was not built "
                f"with; build SceneRenderer(perturbations=...) with it"
            )
        if view not in VIEWS:
            raise ValueError(f"view = {view!r}; expected one of {VIEWS}")
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng is {type(rng).__name__}; expected a numpy.random.Generator")
        if gear is not None and gear not in scene.poses:
            raise ValueError(f"gear {gear!r} is not in the scene; it has {sorted(scene.poses)}")
        if view == "inspect" and gear is None:
            raise ValueError("the inspect view needs a gear to inspect; got gear=None")
        self._set_scene(scene)
        believed = None
        if view == "inspect":
            believed, camera, X_WC = self._inspect_camera(scene.poses[gear], rng, believed_xy)
        else:
            camera, X_WC = self.scene_camera, self.scene_camera.X_PC
        sensor = p.sensor(view)
        X_WC_believed, scale = X_WC, 1.0
        if not sensor.is_ideal:  # the camera as it really is; the observation keeps the calibrated pose
            mount = scene.rng("mount", view)
            X_WC, scale = X_WC @ sensor.draw_extrinsic_error(mount), sensor.draw_scale(mount)
        hidden = occluder = None
        info = camera.info()
        labels = self.scene.render_labels(info, camera.near, camera.far, X_WC)
        counts = {g: int(np.count_nonzero(labels == self.scene.label(g))) for g in scene.poses}
        visible = {g: 1.0 for g, n in counts.items() if n > 0}
        if p.occluder is not None:
            if gear is None:
                names = sorted(scene.poses)
                gear = names[int(rng.integers(len(names)))]
            occluder, hidden = self._place_occluder(p, scene, gear, camera, X_WC, labels, rng)
            labels = self.scene.render_labels(info, camera.near, camera.far, X_WC)
            visible = {g: int(np.count_nonzero(labels == self.scene.label(g))) / counts[g] for g in visible}
        obs = self.scene.render(camera, X_WC, self._lighting_names[p.lighting])
        rgb, depth = obs.rgb, obs.depth
        if not sensor.is_ideal:
            rgb, depth = sensor.corrupt(rgb, depth, obs.intrinsics.fy, rng, scale)
        if p.depth_noise > 0:
            depth = apply_depth_noise(depth, p.depth_noise, rng)
        if p.dropout > 0:
            depth = apply_dropout(depth, p.dropout, rng)
        obs = Observation(rgb, depth, obs.intrinsics, X_WC_believed)
        return View(
            obs,
            view,
            gear,
            p.name,
            dict(scene.poses),
            camera,
            believed,
            hidden,
            occluder,
            visible,
            sensor.extrinsic_std,
        )

    def _set_scene(self, scene: RandomScene) -> None:
        """Gears of `scene` at their poses, the others and every occluder parked."""
        for g in GEAR_NAMES:
            self.scene.set_gear_pose(g, scene.poses.get(g))
        for name in self.scene.occluder_bodies:
            self.scene.set_occluder_pose(name, None)

    def _inspect_camera(
        self, pose: tuple[float, float, float], rng: np.random.Generator, believed_xy: tuple[float, float] | None = None
    ) -> tuple[tuple[float, float], CameraConfig, RigidTransform]:
        """The believed position (uniform in a disc of radius INSPECT_OFFSET around the truth),
        the wrist camera and its world pose at inspect_tool_pose(believed); places the hand that
        carries the camera."""
        r, a = INSPECT_OFFSET * np.sqrt(rng.random()), rng.uniform(-np.pi, np.pi)
        believed = (pose[0] + r * np.cos(a), pose[1] + r * np.sin(a))
        if believed_xy is not None:
            believed = (float(believed_xy[0]), float(believed_xy[1]))
        X_WH = inspect_tool_pose(believed, self.wrist_camera) @ X_HT.inverse()
        self.scene.set_occluder_pose(_WRIST_HAND, X_WH)
        return believed, self.wrist_camera, X_WH @ self.wrist_camera.X_PC

    def _place_occluder(
        self,
        p: Perturbation,
        scene: RandomScene,
        gear: str,
        camera: CameraConfig,
        X_WC: RigidTransform,
        labels: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[tuple[str, RigidTransform], float]:
        """Put an occluder of kind `p.occluder` between the camera and `gear` so that it hides a
        fraction in `p.hidden` of the gear's pixels: drawn height along the line of sight,
        direction across it and yaw, then the offset across the line found by bisection on the
        hidden fraction (label images; `labels` is the view's without the occluder)."""
        if p.occluder == "hand":
            name, kind = HAND_OCCLUDER, HAND_OCCLUDER
        else:
            others = [g for g in GEAR_NAMES if g != gear]
            kind = others[int(rng.integers(len(others)))]
            name = f"carried_{kind}"
        info = camera.info()
        target = self.scene.label(gear)
        v, u = np.nonzero(labels == target)
        if len(u) == 0:
            raise ValueError(f"the {gear} gear is not in the {camera.name} camera's view; nothing to occlude")
        seen = len(u)

        def hidden_at(X_WO: RigidTransform) -> float:
            self.scene.set_occluder_pose(name, X_WO)
            return (
                1.0
                - float(np.count_nonzero(self.scene.render_labels(info, camera.near, camera.far, X_WC) == target))
                / seen
            )

        x, y, _ = scene.poses[gear]
        p_gear = np.array([x, y, GEAR_THICKNESS])
        p_cam = X_WC.translation()
        sight = (p_cam - p_gear) / np.linalg.norm(p_cam - p_gear)
        across_1 = np.cross(sight, [0.0, 0.0, 1.0])
        if np.linalg.norm(across_1) < 1e-6:
            across_1 = np.array([1.0, 0.0, 0.0])
        across_1 /= np.linalg.norm(across_1)
        across_2 = np.cross(sight, across_1)
        lo, hi = p.hidden
        # The occluder's bulk (palm centre, gear centre) hangs `drop` above its lowest point, which
        # stays above the gears' tops; its height above the target's top is drawn in [h0, h1].
        if kind == HAND_OCCLUDER:  # pointing down: the fingertips are the lowest point
            centre, drop = np.array([0.0, 0.0, _PALM_CENTRE]), _HAND_DROP
        else:  # a gear held flat
            centre, drop = np.array([0.0, 0.0, GEAR_THICKNESS / 2]), GEAR_THICKNESS / 2
        h0 = drop + 2 * _OCCLUDER_CLEARANCE  # room to move across the line of sight
        h1 = max(h0, min(_OCCLUDER_MAX_HEIGHT, 0.8 * (p_cam[2] - p_gear[2])))
        for _ in range(30):
            goal = rng.uniform(lo + 0.02, hi - 0.02)
            s = rng.uniform(h0, h1) / sight[2]
            phi = rng.uniform(-np.pi, np.pi)
            across = np.cos(phi) * across_1 + np.sin(phi) * across_2
            R = RotationMatrix.MakeZRotation(rng.uniform(-np.pi, np.pi))
            if kind == HAND_OCCLUDER:
                R = R @ RotationMatrix.MakeXRotation(np.pi)

            def pose(k: float) -> RigidTransform:
                return RigidTransform(R, p_gear + s * sight + k * across - R @ centre)

            near, far, found = 0.0, 0.25, None
            if hidden_at(pose(near)) < lo:
                continue
            for _ in range(14):
                k = 0.5 * (near + far)
                h = hidden_at(pose(k))
                if lo <= h <= hi:
                    found = (k, h)
                    if abs(h - goal) < 0.02:
                        break
                if h > goal:
                    near = k
                else:
                    far = k
            if found is None or (p_gear + s * sight + found[0] * across)[2] - drop < (
                GEAR_THICKNESS + _OCCLUDER_CLEARANCE
            ):
                continue
            X_WO = pose(found[0])
            self.scene.set_occluder_pose(name, X_WO)
            return (kind, X_WO), found[1]
        raise RuntimeError(f"could not place a {kind} occluder hiding {lo:.0%}-{hi:.0%} of the {gear} gear in 30 tries")
