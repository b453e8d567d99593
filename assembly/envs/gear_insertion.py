"""goflow/GearInsertion-v0: insert a gear held with a grasp error onto its shaft.

xi = (x, y, yaw): the grasp error, the gear's offset in the hand from the nominal centred grasp,
along the tool's x and y axes [m] and about the gear's axis [rad]; default box x, y in +-5 cm,
yaw in +-0.393 rad (the GoFlow paper's, appendix A.1), much of it infeasible. The grasp is ideal
(the gear does not slip). Each episode starts with the tool where a centred gear would hover
`start_height` above its shaft's top. The policy never sees xi.

- action (4,) in [-1, 1]: pose offsets (dx, dy, dz, dyaw) scaled by `action_scale`, applied to
  the *measured* tool pose to make the impedance target, at `control_dt` (25 Hz by default). The
  target is kept within `workspace` of the seated tool pose.
- observation (80,): the last `history` (10) tool poses (x, y, z, yaw) relative to the seated
  tool pose and their finite-difference velocities, newest first (zeros before the first step);
  with `sensing="wrench"` (120,): each row also holds the Panda's estimated external wrench at
  the tool (Fx, Fy, Fz / 10 N, Mz / 1 N m; assembly.wrench_sensor, its errors `wrench_sensor`:
  "panda", from the real log, or "ideal"), the same law as the planner's insert skill.
- reward per step: 1 while the gear is seated (the assembly.station criterion: lateral < 2.5 mm,
  |height| < 1 mm), plus 0.1 (1 - tanh(d / 1 cm)) + 0.1 (1 - tanh(d / 5 cm)), plus the
  potential-based progress `progress_weight` (d_prev - d) (100 /m); d is the gear's distance to
  its seated pose.
- success: return >= J_T = 50 (100 steps in t_max = 4 s: seated for much of the episode).

Variants:
- "fast": assembly.insertion_model (tool on x-y-z-yaw joints under the same impedance law with
  the Panda's apparent inertia, shafts hydroelastic, plate point contact), 40 ms physics steps;
- "panda": the full station (assembly.station) with the gear held in the Panda's hand, 8 ms
  steps, the arm starting at an inverse-kinematics solution of the pre-insertion pose. For
  sim2real, it can hold the gear by friction-limited springs instead of welding it (`grasp_hold`,
  assembly.world.GraspHold) and change the gear/plate contact (`contact`, ContactOverrides).

render_mode "rgb_array": a fixed close view of the shaft from the front right (480 x 480, 25 fps);
variant "fast" draws the plate and shafts from their collision shapes (they have no visuals).

Why the reward has these terms and what J_T = 50 means: docs/env_models.md#reward-design; how far the
two variants' outcomes differ for the same xi and actions: docs/env_models.md#how-far-the-variants-differ.

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025, appendix A.1 (box, J_T); Tang et al., "IndustReal", RSS 2023 (actions relative
to the measured pose); Ng et al., "Policy invariance under reward transformations", ICML 1999.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import default_model_instance
from pydrake.systems.analysis import Simulator

from assembly.envs.base import ParamEnv, SimulationError
from goflow_common.checks import check_choice, check_finite_array, check_int, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from assembly.envs.drake_sim import SceneRendering, advance
from assembly.gearset import SHAFT_HEIGHT, gear_spec
from assembly.insertion_law import SENSING, InsertionLaw, PoseHistory
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from assembly.panda_ik import panda_jacobian_at
from assembly.wrench_sensor import WRENCH_MODELS, WrenchSensor, joint_torque_of
from assembly.world import (
    ContactOverrides,
    GraspHold,
    grasp_with_error,
    insertion_error,
    is_seated,
    nominal_grasp,
)

VARIANTS = ("fast", "panda")


@dataclass(frozen=True)
class GearInsertionConfig:
    """Task settings (SI units)."""

    gear: str = "medium"
    variant: str = "fast"
    grasp_xy: float = 0.05  # [m] half-width of the grasp-error box in x and y
    grasp_yaw: float = 0.393  # [rad] half-width of the grasp-error box in yaw
    control_dt: float = 0.04  # [s] policy period (25 Hz; IsaacLab Factory 15 Hz, IndustReal 60 Hz)
    t_max: float = 4.0  # [s]
    start_height: float = 0.005  # [m] centred gear's bottom above the shaft top at the start
    # Per step. The impedance target is the measured pose plus this, so the pushing force stays
    # below K times it (6 N down at K = 300 N/m) and free motion is at most K/D times it per second.
    # Seating needs a firm push (a steady 6 N seats a centred gear in 0.6 s, 1.5 N not within 4 s),
    # while a few millimetres of lateral drift already miss the chamfer: hence 2 cm down, 3 mm
    # sideways (docs/skills.md: with 1 cm sideways, PPO's exploration drifted off the shaft).
    action_scale: tuple[float, float, float, float] = (0.003, 0.003, 0.02, 0.05)
    workspace: tuple[float, float, float, float] = (0.06, 0.06, 0.06, 0.6)  # |target - seated|
    history: int = 10
    success_threshold: float = 50.0  # J_T
    shaping_weight: float = 0.1  # reward per step of each shaping term at d = 0
    shaping_near: float = 0.01  # [m] length scale of the fine shaping term
    shaping_far: float = 0.05  # [m] length scale of the coarse shaping term (the grasp-error box)
    progress_weight: float = 100.0  # [1/m] reward per metre the gear gets closer to its seat
    fast_time_step: float = 0.04  # [s] physics step of the fast variant (docs/envs.md)
    panda_time_step: float = 0.008  # [s] physics step of the panda variant (the station's)
    # Panda variant only (sim2real): the gear held by friction-limited springs instead of welded,
    # and gear/plate contact properties other than the model files' (assembly.world). None: nominal.
    grasp_hold: GraspHold | None = None
    contact: ContactOverrides | None = None
    # What the policy observes: "pose" (the tool poses; the blind skills) or "wrench" (also the
    # estimated external wrench, with the errors of assembly.wrench_sensor.WRENCH_MODELS[wrench_sensor]).
    sensing: str = "pose"
    wrench_sensor: str = "panda"

    def __post_init__(self) -> None:
        gear_spec(self.gear)
        check_choice(self.variant, VARIANTS, "GearInsertionConfig.variant")
        check_choice(self.sensing, SENSING, "GearInsertionConfig.sensing")
        check_choice(self.wrench_sensor, WRENCH_MODELS, "GearInsertionConfig.wrench_sensor")
        for name in ("grasp_hold", "contact"):
            if getattr(self, name) is not None and self.variant != "panda":
                raise InputError(
                    f"GearInsertionConfig.{name} = {getattr(self, name)!r}; expected None "
                    f"for variant {self.variant!r} (only the panda variant models it)"
                )
        for name in (
            "grasp_xy",
            "grasp_yaw",
            "control_dt",
            "t_max",
            "start_height",
            "shaping_near",
            "shaping_far",
            "fast_time_step",
            "panda_time_step",
        ):
            check_number(getattr(self, name), f"GearInsertionConfig.{name}", 0.0, low_open=True)
        for name in ("success_threshold", "shaping_weight", "progress_weight"):
            check_number(getattr(self, name), f"GearInsertionConfig.{name}")
        for name in ("action_scale", "workspace"):  # per action: x, y, z [m], yaw [rad]
            value = getattr(self, name)
            if not np.all(check_finite_array(value, f"GearInsertionConfig.{name}", (4,)) > 0):
                raise InputError(
                    f"GearInsertionConfig.{name} = {value!r}; expected 4 numbers > 0 (x, y, z [m], yaw [rad])"
                )
        for name in ("fast_time_step", "panda_time_step"):
            dt = getattr(self, name)
            steps = self.control_dt / dt
            if abs(steps - round(steps)) >= 1e-9:
                raise InputError(
                    f"GearInsertionConfig.{name} = {dt!r}; expected a step that divides "
                    f"control_dt = {self.control_dt} into whole physics steps"
                )
        check_int(self.history, "GearInsertionConfig.history", 2)


def _yaw(R: RotationMatrix) -> float:
    """Yaw of a tool frame pointing down (its x axis's heading in the world)."""
    m = R.matrix()
    return float(np.arctan2(m[1, 0], m[0, 0]))


def tool_down_pose(p: np.ndarray, yaw: float) -> RigidTransform:
    """The tool pose at position p [m] with its z axis down, turned by yaw [rad] about the world z."""
    return RigidTransform(RotationMatrix.MakeZRotation(yaw) @ RotationMatrix.MakeXRotation(np.pi), p)


def grasp_error_space(c: GearInsertionConfig) -> ParamSpace:
    """xi: the grasp error (x, y [m] along the tool's axes, yaw [rad]) over the config's box."""
    return ParamSpace(
        (
            Param("x", -c.grasp_xy, c.grasp_xy, "m"),
            Param("y", -c.grasp_xy, c.grasp_xy, "m"),
            Param("yaw", -c.grasp_yaw, c.grasp_yaw, "rad"),
        )
    )


def observation_space(c: GearInsertionConfig) -> spaces.Box:
    """The history's bounds: poses within 1 m / pi of the seated pose, velocities within 10 m/s /
    100 rad/s, wrenches within 1 kN / 100 N m (far beyond what the impedance allows; a simulation
    that leaves them has failed)."""
    row = [1.0, 1.0, 1.0, np.pi, 10.0, 10.0, 10.0, 100.0] + ([100.0] * 4 if c.sensing == "wrench" else [])
    bound = np.tile(row, c.history).astype(np.float32)
    return spaces.Box(-bound, bound, dtype=np.float32)


def seated_and_start(c: GearInsertionConfig, X_WS: RigidTransform) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tool poses (x, y, z, yaw): seated (where a centred gear sits on the shaft at X_WS) and the
    episode's start above it."""
    X_WT_seated = X_WS @ nominal_grasp(c.gear).inverse()
    seated = np.array([*X_WT_seated.translation(), _yaw(X_WT_seated.rotation())])
    return seated, seated + [0.0, 0.0, SHAFT_HEIGHT + c.start_height, 0.0]


def insertion_reward(c: GearInsertionConfig, seated: bool, d: float, d_before: float) -> float:
    """The step reward: 1 when seated, two tanh shaping terms in the distance d [m] to the seat, and
    progress (d_before - d)."""
    return (
        float(seated)
        + c.shaping_weight * (1.0 - math.tanh(d / c.shaping_near))
        + c.shaping_weight * (1.0 - math.tanh(d / c.shaping_far))
        + c.progress_weight * (d_before - d)
    )


class GearInsertionEnv(SceneRendering, ParamEnv):
    """Insert a gear held with grasp error xi = (x, y, yaw) onto its shaft."""

    def __init__(
        self,
        config: GearInsertionConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = c = config_with_overrides(GearInsertionConfig, config, overrides, "GearInsertionEnv")
        super().__init__(grasp_error_space(c), sampler)
        self._set_timing(c.control_dt, c.t_max, c.success_threshold)
        self._init_render(render_mode)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.observation_space = observation_space(c)
        self._sim = _FastSim(c) if c.variant == "fast" else _PandaSim(c)
        self._X_SW = self._sim.X_WS.inverse()
        self._seated, self._start = seated_and_start(c, self._sim.X_WS)
        self._sim.prepare(tool_down_pose(self._start[:3], self._start[3]))
        self.law = InsertionLaw(tuple(self._seated), c.action_scale, c.workspace, c.history, c.control_dt, c.sensing)
        self._history = PoseHistory(self.law)
        self._wrench = WrenchSensor(WRENCH_MODELS[c.wrench_sensor], c.control_dt) if c.sensing == "wrench" else None

    @property
    def sim(self) -> _FastSim | _PandaSim:
        """The simulation behind the env (variant "panda": `station`, `context`, `simulator`,
        `advance(target, duration)` and the per-physics-step hook `on_step`), for tools that log
        or replay episodes (sim2real.station_logs). Driving it bypasses the env's bookkeeping."""
        return self._sim

    # -- task quantities -------------------------------------------------------------------

    def insertion_error(self) -> tuple[float, float]:
        """(lateral, signed height) of the gear frame from its seated pose on the shaft [m]."""
        return insertion_error(self._X_SW, self._sim.gear_pose())

    def tool_pose(self) -> np.ndarray:
        """Measured tool pose (x, y, z, yaw) in the world."""
        return self._sim.tool_pose()

    def wrench(self) -> NDArray[np.float64] | None:
        """The estimated external wrench at the tool now (Fx, Fy, Fz [N], Mz [N m]; a fresh noise
        draw), or None without wrench sensing."""
        if self._wrench is None:
            return None
        return self._wrench.measure(*self._sim.wrench_inputs(), self.np_random)

    def _observation(self) -> NDArray[np.float32]:
        """The policy's observation (assembly.insertion_law.PoseHistory), checked against its
        bounds."""
        obs = self._history.observation()
        if not np.all(np.abs(obs) <= self.observation_space.high):
            raise SimulationError(f"observation left its bounds: tool pose {self._history.poses[0]}")
        return obs

    def bare_rollout(self, xi: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Run the same control law through the bare simulator, without the gym wrapper
        (no observation, reward or validation); return the final tool pose. For measuring the
        wrapper's overhead: env.reset + env.step over `actions` ends in the same pose."""
        self._sim.reset(grasp_with_error(self.config.gear, *xi))
        for a in np.asarray(actions, dtype=float):
            self._sim.advance(self._target(a), self.control_dt)
        return self._sim.tool_pose()

    def _target(self, action: np.ndarray) -> np.ndarray:
        """Impedance target: the measured tool pose plus the scaled action, kept in the workspace."""
        return self.law.target(action, self._sim.tool_pose())

    # -- rendering -------------------------------------------------------------------------

    def _make_renderer(self):
        """A camera 0.4 m from the shaft, from the front right and above (the side the station's
        scene camera sees the plate from)."""
        from assembly.envs.rendering import CameraView, SceneRenderer

        model = self._sim.model if isinstance(self._sim, _FastSim) else self._sim.station
        target = self._sim.X_WS.translation() + [0.0, 0.0, 0.03]
        view = CameraView(tuple(target), (0.25, -0.3, 0.15), near=0.01, far=5.0)
        r = SceneRenderer(model.scene_graph, self._sim.context, model.plant.get_source_id(), view)
        if isinstance(self._sim, _FastSim):  # plate and shafts from their collision shapes; a table under them
            from pydrake.geometry import Box

            r.show_collision_geometry((0.75, 0.75, 0.78, 1.0), {"plate": (0.35, 0.4, 0.5, 1.0)})
            table = RigidTransform([target[0], target[1], -0.01])
            r.add_visual(
                model.scene_graph.world_frame_id(), Box(1.0, 1.0, 0.02), table, (0.55, 0.4, 0.25, 1.0), "table"
            )
        return r

    # -- ParamEnv hooks --------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        self._sim.reset(grasp_with_error(self.config.gear, *xi))
        if self._wrench is not None:
            self._wrench.reset(self.np_random)
        self._history.reset(self._sim.tool_pose(), self.wrench())
        self._d = math.hypot(*self.insertion_error())
        return self._observation()

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        self._sim.advance(self._target(action), self.control_dt)
        pose = self._sim.tool_pose()
        if not np.all(np.isfinite(pose)):
            raise SimulationError(f"non-finite tool pose {pose} after the step")
        self._history.push(pose, self.wrench())
        lateral, height = self.insertion_error()
        seated = is_seated(lateral, height)
        d = math.hypot(lateral, height)
        reward = insertion_reward(self.config, seated, d, self._d)
        self._d = d
        return self._observation(), reward, False, {"seated": seated, "lateral_error": lateral, "height_error": height}


class _FastSim:
    """The reduced model behind variant "fast"."""

    def __init__(self, c: GearInsertionConfig) -> None:
        from assembly.insertion_model import (
            FastInsertionConfig,
            build_fast_insertion,
            gravity_feedforward,
        )

        self.model = build_fast_insertion(FastInsertionConfig(gear=c.gear, time_step=c.fast_time_step))
        self.X_WS = self.model.X_WS(c.gear)
        self._gear = c.gear
        self.context = self.model.diagram.CreateDefaultContext()
        self._pc = self.model.plant.GetMyMutableContextFromRoot(self.context)
        self._desired = self.model.diagram.GetInputPort("desired_state")
        self.model.diagram.GetInputPort("feedforward").FixValue(self.context, gravity_feedforward(self.model))
        self.simulator = Simulator(self.model.diagram, self.context)
        self._body = self.model.plant.get_body(self.model.plant.GetBodyIndices(self.model.held.instance)[0])
        self._contact = self.model.plant.get_generalized_contact_forces_output_port(default_model_instance())

    def prepare(self, X_WT_start: RigidTransform) -> None:
        self._q_start = self.model.joint_positions_for(X_WT_start)
        self._J = None  # the Panda's Jacobian at the start pose, made when first needed

    def wrench_inputs(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(tau_ext (7,), J (6, 7)): the joint torques a Panda at the episode's start pose would
        feel from the contact wrench on this tool (its x, y, z forces and yaw torque), and its
        Jacobian there."""
        if self._J is None:
            self._J = panda_jacobian_at(self.model.tool_pose_of(self._q_start))
        return joint_torque_of(self._J, self._contact.Eval(self._pc)), self._J

    def reset(self, X_TG: RigidTransform) -> None:
        self.context.SetTime(0.0)
        self.model.plant.SetPositions(self._pc, self._q_start)
        self.model.plant.SetVelocities(self._pc, np.zeros(4))
        self.model.held.grasp_frame.SetPoseInParentFrame(self._pc, X_TG)
        self._desired.FixValue(self.context, np.concatenate([self._q_start, np.zeros(4)]))
        self.simulator.Initialize()

    def advance(self, target: np.ndarray, duration: float) -> None:
        self._desired.FixValue(self.context, np.concatenate([target, np.zeros(4)]))
        advance(self.simulator, self.context.get_time() + duration, "GearInsertion")

    def tool_pose(self) -> np.ndarray:
        return self.model.plant.GetPositions(self._pc).copy()

    def gear_pose(self) -> RigidTransform:
        return self._body.EvalPoseInWorld(self._pc)


class _PandaSim:
    """The full station behind variant "panda"."""

    def __init__(self, c: GearInsertionConfig) -> None:
        from assembly.cameras import CamerasConfig
        from assembly.station import StationConfig, build_station
        from assembly.world import WorldConfig

        self.station = build_station(
            StationConfig(
                world=WorldConfig(gears=(), held_gear=c.gear, grasp_hold=c.grasp_hold, contact=c.contact),
                time_step=c.panda_time_step,
                cameras=CamerasConfig(scene=None, wrist=None),
            )
        )
        self.X_WS = self.station.models.X_WS(c.gear)
        self._gear = c.gear
        self.context = self.station.diagram.CreateDefaultContext()
        self._pc = self.station.plant.GetMyMutableContextFromRoot(self.context)
        self._target = self.station.diagram.GetInputPort("X_WT_desired")
        width = 2 * gear_spec(c.gear).tip_radius
        self.station.diagram.GetInputPort("gripper_width").FixValue(self.context, [width])
        self._hand_q = np.array([width / 2, width / 2])
        self.simulator = Simulator(self.station.diagram, self.context)
        self.time_step = c.panda_time_step
        # Called before every physics step when set (the target for the step is already held).
        self.on_step: Callable[[], None] | None = None

    def prepare(self, X_WT_start: RigidTransform) -> None:
        from assembly.panda_ik import solve_tool_ik

        self._q_start = solve_tool_ik(X_WT_start)
        self._X_start = X_WT_start

    def reset(self, X_TG: RigidTransform) -> None:
        plant, models = self.station.plant, self.station.models
        self.context.SetTime(0.0)
        plant.SetPositions(self._pc, models.arm, self._q_start)
        plant.SetVelocities(self._pc, models.arm, np.zeros(7))
        plant.SetPositions(self._pc, models.hand, self._hand_q)
        plant.SetVelocities(self._pc, models.hand, np.zeros(2))
        self.station.set_grasp(self.context, X_TG)
        self._target.FixValue(self.context, self._X_start)
        self.simulator.Initialize()

    def advance(self, target: np.ndarray, duration: float) -> None:
        self._target.FixValue(self.context, tool_down_pose(target[:3], target[3]))
        t0 = self.context.get_time()
        if self.on_step is None:
            advance(self.simulator, t0 + duration, "GearInsertion")
            return
        for k in range(1, round(duration / self.time_step) + 1):
            self.on_step()
            advance(self.simulator, t0 + k * self.time_step, "GearInsertion")

    def tool_pose(self) -> np.ndarray:
        X = self.station.tool_pose(self.context)
        return np.array([*X.translation(), _yaw(X.rotation())])

    def wrench_inputs(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(tau_ext (7,), J (6, 7)): the joint torques contact puts on the arm and the tool's Jacobian."""
        d = self.station.diagram
        return d.GetOutputPort("tau_contact").Eval(self.context), d.GetOutputPort("tool_jacobian").Eval(
            self.context
        ).reshape(6, 7)

    def gear_pose(self) -> RigidTransform:
        return self.station.gear_pose(self.context, self._gear)
