"""planning.PlannerPerception: what the belief-space planner sees, as a Drake system of its own.

The planner (planning.system) asks on its `request` output port for one look (a `LookRequest`):
the scene camera's far view of the gears still to insert, a wrist-camera close view of one gear
(its prior box from the gear's belief), or the wrist camera's check that an inserted gear sits on
its shaft. This system answers on its `percept` output port (a `Percept`: the beliefs it saw, or
why it saw none) from the camera images and the measured tool pose (which places the wrist
camera). The port is evaluated only when the planner reads it, so each look is computed once, at
the planner's update that needs it (the pattern of the manipulation course's perception systems
feeding its Planner).

    scene camera -> detect_gears -> a far posterior per gear -> Gaussian beliefs (+ the scene
    camera's extrinsic uncertainty) | wrist camera -> a close posterior -> a belief | wrist camera
    -> check_seat
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np
from numpy.typing import NDArray
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, LeafSystem

from assembly.cameras import CamerasConfig, with_extrinsic_std
from assembly.gearset import GEAR_NAMES
from assembly.inspection import X_HT
from perception.detection import detect_gears
from perception.observation import Observation
from perception.search import Prior, estimate_pose
from perception.seat_check import SeatCheck, SeatCheckConfig, check_seat
from perception.station_views import observation_from_images
from planning.domain import GearBelief, table_belief

#: The camera images the perception reads: input port name -> (camera, image kind).
IMAGE_PORTS: dict[str, tuple[str, str]] = {
    "scene_rgb": ("scene", "rgb"),
    "scene_depth": ("scene", "depth"),
    "wrist_rgb": ("wrist", "rgb"),
    "wrist_depth": ("wrist", "depth"),
}


class Look(Enum):
    """What the planner asks its perception for."""

    NOTHING = "nothing"  # no look: the percept is empty
    SCENE = "scene"  # the scene camera's far belief of each gear of `LookRequest.gears`
    CLOSE = "close"  # a wrist-camera close view of `LookRequest.gear`, its prior from `belief`
    SEAT = "seat"  # the wrist camera's check that `LookRequest.gear` sits on its shaft


@dataclass(frozen=True)
class LookRequest:
    """One look: `look`, the gears of a SCENE look, the gear of a CLOSE or SEAT look and (CLOSE)
    its belief now. ValueError when a field the look needs is missing."""

    look: Look = Look.NOTHING
    gears: tuple[str, ...] = ()
    gear: str | None = None
    belief: GearBelief | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.look, Look):
            raise ValueError(f"look = {self.look!r}; expected one of {[k.name for k in Look]}")
        if self.look is Look.SCENE and not self.gears:
            raise ValueError("a SCENE look with no gears; expected the gears to perceive")
        if self.look in (Look.CLOSE, Look.SEAT) and self.gear is None:
            raise ValueError(f"a {self.look.name} look with no gear; expected the gear to look at")
        if self.look is Look.CLOSE and self.belief is None:
            raise ValueError("a CLOSE look with no belief; expected the gear's belief (its prior box)")


@dataclass(frozen=True)
class Percept:
    """What a look saw. SCENE: `beliefs` holds a far belief per requested gear, or is empty and
    `reason` says which gear the scene camera did not find; CLOSE: `beliefs` holds the gear's
    close belief (a posterior's mean and std), or is empty and `reason` says why the view was
    uninformative; SEAT: `seat` is the check. `seconds`: the look's wall time."""

    request: LookRequest
    beliefs: Mapping[str, GearBelief] = field(default_factory=dict)
    reason: str = ""
    seat: SeatCheck | None = None
    seconds: float = 0.0


class PlannerPerception(LeafSystem):
    """The planner's perception (see the module docstring). `cameras`: the station's
    CamerasConfig as calibrated (what the robot is given); `gears`: the gears the scene camera
    searches for; `X_WS`: each shaft's pose (the seat check's reference); `close_prior`,
    `scene_extrinsic_std`, `seat_check`, `wrist_extrinsic_std`: as in planning.system.PlannerSystemConfig (a SEAT look
    with `seat_check` None checks with SeatCheckConfig's defaults).

    Inputs: scene_rgb, scene_depth, wrist_rgb, wrist_depth (the cameras' images), X_WT (the
    measured tool pose), request (a LookRequest). Output: percept (a Percept of that request)."""

    def __init__(
        self,
        cameras: CamerasConfig,
        gears: tuple[str, ...],
        X_WS: Mapping[str, RigidTransform],
        close_prior: tuple[float, float, float] = (4.0, 0.005, 0.03),
        scene_extrinsic_std: tuple[float, float] = (0.0, 0.0),
        seat_check: SeatCheckConfig | None = None,
        wrist_extrinsic_std: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__()
        self.set_name("planner_perception")
        unknown = [g for g in gears if g not in GEAR_NAMES]
        if unknown:
            raise ValueError(f"gears {unknown}; expected names among {list(GEAR_NAMES)}")
        self.cameras, self.X_WS = cameras, dict(X_WS)
        self.search = tuple(g for g in GEAR_NAMES if g in gears)
        self.close_prior, self.scene_extrinsic_std = close_prior, scene_extrinsic_std
        self.wrist_extrinsic_std = wrist_extrinsic_std
        self.seat_check = seat_check
        for name, (_, kind) in IMAGE_PORTS.items():
            self.DeclareAbstractInputPort(name, AbstractValue.Make(image_value(kind)))
        self.DeclareAbstractInputPort("X_WT", AbstractValue.Make(RigidTransform()))
        self.DeclareAbstractInputPort("request", AbstractValue.Make(LookRequest()))
        self.DeclareAbstractOutputPort(
            "percept", lambda: AbstractValue.Make(Percept(LookRequest())), self._calc_percept
        )

    def _calc_percept(self, context: Context, output: AbstractValue) -> None:
        request = self.GetInputPort("request").Eval(context)
        t0 = time.perf_counter()
        if request.look is Look.SCENE:
            percept = self._scene(context, request)
        elif request.look is Look.CLOSE:
            percept = self._close(context, request)
        elif request.look is Look.SEAT:
            check = check_seat(self.observe(context, "wrist"), request.gear, self.X_WS[request.gear], self.seat_check)
            percept = Percept(request, reason=check.reason, seat=check)
        else:
            percept = Percept(request)
        output.set_value(replace(percept, seconds=time.perf_counter() - t0))

    def observe(self, context: Context, camera: str) -> Observation:
        """The `camera` ("scene" | "wrist") image in `context` as an Observation; the wrist camera
        rides on the hand, placed by the measured tool pose (X_WC = X_WT X_TH X_HC)."""
        config = self.cameras.scene if camera == "scene" else self.cameras.wrist
        if camera == "scene":
            X_WC = config.X_PC
        else:
            X_WC = self.GetInputPort("X_WT").Eval(context) @ X_HT.inverse() @ config.X_PC
        return observation_from_images(
            self.GetInputPort(f"{camera}_rgb").Eval(context),
            self.GetInputPort(f"{camera}_depth").Eval(context),
            config,
            X_WC,
        )

    def _scene(self, context: Context, request: LookRequest) -> Percept:
        obs = self.observe(context, "scene")
        found = detect_gears(obs, self.search)
        beliefs = {}
        for gear in request.gears:
            det = found.get(gear)
            if det is None or not det.seen:
                return Percept(
                    request, reason=f"{gear} gear not seen by the scene camera: {det.reason if det else 'not searched'}"
                )
            post = estimate_pose(obs, gear, det.prior)
            if not post.informative:
                beliefs[gear] = table_belief((det.prior.x, det.prior.y, 0.0), (det.prior.half_width,) * 2 + (np.pi,))
            else:
                beliefs[gear] = table_belief(post.mean(), self.far_std(obs, post.mean(), post.std()))
        return Percept(request, beliefs)

    def far_std(self, obs: Observation, mean: NDArray[np.float64], std: NDArray[np.float64]) -> NDArray[np.float64]:
        """A far posterior's std (x, y, yaw) with the scene camera's extrinsic uncertainty added
        (its x-y shift on the table at the gear's `mean`, its rotation in yaw)."""
        return with_extrinsic_std(obs.X_WC, mean, std, self.scene_extrinsic_std)

    def _close(self, context: Context, request: LookRequest) -> Percept:
        b = request.belief
        k, lo, hi = self.close_prior
        prior = Prior(b.mean[0], b.mean[1], float(np.clip(k * max(b.std[:2]), lo, hi)))
        obs = self.observe(context, "wrist")
        post = estimate_pose(obs, request.gear, prior)
        if not post.informative:
            return Percept(request, reason=post.reason)
        std = with_extrinsic_std(obs.X_WC, post.mean(), post.std(), self.wrist_extrinsic_std)
        return Percept(request, {request.gear: GearBelief("table", tuple(post.mean()), tuple(std))})


def image_value(kind: str):
    """An empty Drake image of `kind` ("rgb": ImageRgba8U, "depth": ImageDepth32F): the model
    value of a camera image port."""
    from pydrake.systems.sensors import ImageDepth32F, ImageRgba8U

    if kind not in ("rgb", "depth"):
        raise ValueError(f"image kind {kind!r}; expected 'rgb' or 'depth'")
    return ImageRgba8U() if kind == "rgb" else ImageDepth32F()


__all__ = ["IMAGE_PORTS", "Look", "LookRequest", "Percept", "PlannerPerception", "image_value"]
