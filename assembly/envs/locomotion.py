"""goflow/Hopper-v0, Walker2d-v0, HalfCheetah-v0 and Humanoid-v0: gymnasium's MuJoCo locomotion
tasks (v5 definitions) on Drake plants built from the same MJCF files, with per-episode physical
parameters xi as in the NFPDE paper's Table I.

Observations, rewards, termination, reset noise, frame skip and horizons (1000 steps) follow
gymnasium 1.x's Hopper-v5, Walker2d-v5, HalfCheetah-v5 and Humanoid-v5 with their default
arguments; actions are MuJoCo's `ctrl` (clamped to `ctrlrange` for the dynamics, unclamped in the
control cost, as there). The plant comes from `assembly.envs.mjcf`, which rebuilds what Drake's
parser drops. Observations are float32 (gymnasium's are float64), like every goflow env.

xi (docs/env_models.md#why-these-boxes gives the boxes' reasons):
- Hopper (6): torso, thigh, leg and foot masses [kg]; thigh and leg joint damping [N m s/rad].
- Walker2d (7): torso, thigh, leg and foot masses (each pair of legs' links together); hip and
  knee damping (both legs); floor friction (the foot-floor coefficient; other robot-floor pairs
  keep their ratio to it).
- HalfCheetah (14): the 7 body masses, the 6 joint dampings, floor friction.
- Humanoid (30): the 13 body masses and the 17 hinge joints' damping.
A mass changes the body's rotational inertia in proportion (a denser link); MuJoCo's usual
`body_mass` edit leaves the inertia alone.

render_mode "rgb_array": a side camera following the torso over a checkered floor (480 x 480, at
1 / control_dt fps), framed like gymnasium's default MuJoCo cameras.

References: Farama Gymnasium 1.x, gymnasium/envs/mujoco/{hopper,walker2d,half_cheetah,humanoid}_v5.py;
the NFPDE paper's Table I (parameter counts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import ParamEnv, SimulationError
from assembly.envs.drake_sim import HeldInput, SceneRendering, advance
from assembly.envs.mjcf import ContactSettings, MjcfPlant, build_plant, gymnasium_asset, pair_friction, read_mjcf
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from goflow_common.checks import check_choice, check_int, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError

__all__ = ["LocomotionConfig", "LocomotionEnv", "HopperEnv", "Walker2dEnv", "HalfCheetahEnv", "HumanoidEnv"]

# Box factors on the nominal value (docs/envs.md#locomotion).
MASS_BOX = (0.5, 2.0)
DAMPING_BOX = (0.25, 4.0)
FRICTION_BOX = (0.25, 2.0)


@dataclass(frozen=True)
class LocomotionConfig:
    """Simulation and task settings; None fields take the task's gymnasium v5 default."""

    time_step: float | None = None  # [s] Drake's plant step; None: the MJCF `option timestep`
    frame_skip: int | None = None  # plant steps per action; None: gymnasium's
    contact_approximation: str = "lagged"
    point_stiffness: float | None = None  # [N/m] None: from MuJoCo's contact time constant (mjcf.ContactSettings)
    dissipation: float | None = None  # [s/m] Hunt-Crossley; None: likewise
    horizon: int = 1000  # steps per episode (gymnasium.make keeps `max_episode_steps` for itself)
    terminate_when_unhealthy: bool = True
    reset_noise_scale: float | None = None
    success_threshold: float | None = None  # J_T; None: gymnasium's reward_threshold, else inf
    params: tuple[str, ...] | None = None  # the xi subset to randomize (others nominal); None: all
    xml_file: str | None = None  # an MJCF path or a gymnasium asset name; None: the task's file

    def __post_init__(self) -> None:
        if self.params is not None:
            if isinstance(self.params, str) or not all(isinstance(p, str) for p in self.params) or not self.params:
                raise InputError(
                    f"LocomotionConfig.params must be a non-empty list of parameter names, got {self.params!r}"
                )
            object.__setattr__(self, "params", tuple(self.params))
        for name in ("time_step", "point_stiffness", "dissipation"):
            if getattr(self, name) is not None:
                check_number(getattr(self, name), f"LocomotionConfig.{name}", 0.0, low_open=True)
        if self.frame_skip is not None:
            check_int(self.frame_skip, "LocomotionConfig.frame_skip", 1)
        check_int(self.horizon, "LocomotionConfig.horizon", 1)
        if self.reset_noise_scale is not None:
            check_number(self.reset_noise_scale, "LocomotionConfig.reset_noise_scale", 0.0)
        if self.success_threshold is not None:
            check_number(self.success_threshold, "LocomotionConfig.success_threshold")
        check_choice(self.terminate_when_unhealthy, (True, False), "LocomotionConfig.terminate_when_unhealthy")
        check_choice(
            self.contact_approximation, ("lagged", "similar", "sap", "tamsi"), "LocomotionConfig.contact_approximation"
        )


@dataclass(frozen=True)
class _Task:
    """One gymnasium v5 task: its file, defaults and parameters."""

    xml: str
    frame_skip: int
    reset_noise_scale: float
    ctrl_cost_weight: float
    forward_reward_weight: float
    healthy_reward: float
    reward_threshold: float | None
    # xi: (name, kind, targets, unit); kind mass (bodies), damping (joints) or friction
    params: tuple[tuple[str, str, tuple[str, ...], str], ...]


class LocomotionEnv(SceneRendering, ParamEnv):
    """A gymnasium v5 MuJoCo locomotion task on a Drake plant, xi drawn per episode."""

    task: ClassVar[_Task]
    # The render camera: target (world [m]; x, y follow the torso) and the eye's offset from it.
    view: ClassVar[tuple[tuple[float, float, float], tuple[float, float, float]]] = ((0.0, 0.0, 1.0), (0.0, -3.5, 1.0))

    def __init__(
        self,
        config: LocomotionConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = cfg = config_with_overrides(LocomotionConfig, config, overrides, type(self).__name__)
        task = self.task
        spec = read_mjcf(_model_file(cfg.xml_file or task.xml))
        time_step = cfg.time_step or spec.timestep
        self.frame_skip = cfg.frame_skip or task.frame_skip
        contact = ContactSettings(time_step, cfg.contact_approximation, cfg.point_stiffness, cfg.dissipation)
        self.model: MjcfPlant = build_plant(spec, contact)
        self._params = self._resolve_params(spec)
        if cfg.params is not None:
            known = [p.name for p, _, _ in self._params]
            unknown = [n for n in cfg.params if n not in known]
            if unknown:
                raise InputError(f"{type(self).__name__}: unknown parameter(s) {unknown}; expected some of {known}")
            self._fixed = [(p, kind, h) for p, kind, h in self._params if p.name not in cfg.params]
            self._params = [entry for entry in self._params if entry[0].name in cfg.params]
        else:
            self._fixed = []
        space = ParamSpace(tuple(p for p, _, _ in self._params))
        super().__init__(space, sampler)
        threshold = task.reward_threshold if cfg.success_threshold is None else cfg.success_threshold
        self._set_timing(
            time_step * self.frame_skip,
            time_step * self.frame_skip * cfg.horizon,
            math.inf if threshold is None else threshold,
        )
        self._init_render(render_mode)
        self.reset_noise_scale = task.reset_noise_scale if cfg.reset_noise_scale is None else cfg.reset_noise_scale

        from pydrake.systems.analysis import Simulator

        m = self.model
        self._simulator = Simulator(m.diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = m.plant.GetMyMutableContextFromRoot(self._context)
        self._sg_context = m.scene_graph.GetMyMutableContextFromRoot(self._context)
        self._nq, self._nv = m.plant.num_positions(), m.plant.num_velocities()
        self._u = np.zeros(m.plant.num_actuators())
        self._input = HeldInput(m.plant.get_actuation_input_port(), self._plant_context, self._u)
        self._qpos0, self._qvel0 = m.to_mujoco(m.plant.GetPositionsAndVelocities(self._plant_context))
        self._q_low, self._q_high = m.plant.GetPositionLowerLimits(), m.plant.GetPositionUpperLimits()
        self._k = 0
        low, high = m.ctrl_low, m.ctrl_high
        self.action_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        obs = self._observe(*self.mujoco_state())
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=obs.shape, dtype=np.float32)

    # -- parameters -----------------------------------------------------------------------------

    def _resolve_params(self, spec) -> list[tuple[Param, str, list[Any]]]:
        m = self.model
        out = []
        for name, kind, targets, unit in self.task.params:
            if kind == "mass":
                index = [spec.bodies.index(t) for t in targets]
                nominal, box = float(m.masses[index[0]]), MASS_BOX
                handles: list[Any] = index
            elif kind == "damping":
                handles = [m.joints[t] for t in targets]
                nominal, box = float(handles[0].default_damping()), DAMPING_BOX
            else:  # friction: the first target geom's pair value
                nominal, box, handles = pair_friction(spec, targets[0]), FRICTION_BOX, []
            out.append((Param(name, box[0] * nominal, box[1] * nominal, unit, nominal=nominal), kind, handles))
        return out

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        m = self.model
        masses = m.masses.copy()
        values = [*zip(xi, self._params), *((p.nominal, (p, kind, h)) for p, kind, h in self._fixed)]
        for value, (param, kind, handles) in values:
            if kind == "mass":
                masses[handles] *= value / param.nominal  # a pair of links keeps its ratio
            elif kind == "damping":
                for joint in handles:
                    joint.SetDamping(self._plant_context, float(value))
            else:
                m.set_pair_friction(self._sg_context, float(value) / param.nominal)
        m.set_masses(self._plant_context, masses)

    # -- state and stepping ---------------------------------------------------------------------

    def set_mujoco_state(self, qpos: ArrayLike, qvel: ArrayLike) -> None:
        """Put the plant in MuJoCo's state (qpos, qvel) (for replaying a MuJoCo run). Joint
        positions outside their range are clamped to it: MuJoCo's soft limit brings them back
        over ~0.02 s, Drake's near-rigid one in one step with a velocity kick (the Humanoid's
        knees start 2 degrees outside their range)."""
        x = self.model.from_mujoco(np.asarray(qpos, float), np.asarray(qvel, float))
        plant = self.model.plant
        x[: self._nq] = np.clip(x[: self._nq], self._q_low, self._q_high)
        plant.SetPositionsAndVelocities(self._plant_context, x)
        self._simulator.Initialize()

    @property
    def plant_state(self) -> NDArray[np.float64]:
        """The plant's state [q; v] in Drake's coordinates, a copy (what transition logs hold;
        `model.to_mujoco` converts it, normalizing the free joint's quaternion)."""
        return self.model.plant.GetPositionsAndVelocities(self._plant_context).copy()

    def mujoco_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The plant state as MuJoCo's (qpos, qvel)."""
        return self.model.to_mujoco(self.model.plant.GetPositionsAndVelocities(self._plant_context))

    def step_physics(self, action: ArrayLike) -> float:
        """One control step with `action` and its reward, outside the episode's bookkeeping (no
        termination or time limit): for comparing the physics with MuJoCo's. Needs a reset first."""
        if self._xi is None:
            raise RuntimeError(f"{type(self).__name__}.step_physics: call reset() first")
        self._done = True  # the gym episode, if any, is over
        return self._step_model(self._check_action(action))[1]

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        self._apply_xi(xi)
        self._context.SetTime(0.0)
        s = self.reset_noise_scale
        rng = self.np_random
        qpos = self._qpos0 + rng.uniform(-s, s, size=self._qpos0.size)
        qvel = self._qvel0 + self._velocity_noise(rng, s, self._qvel0.size)
        self._u[:] = 0.0
        self._input.set(self._u)
        self.set_mujoco_state(qpos, qvel)
        self._k = 0
        return self._observe(*self.mujoco_state())

    def _velocity_noise(self, rng: np.random.Generator, s: float, n: int) -> NDArray[np.float64]:
        return rng.uniform(-s, s, size=n)

    def _advance(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Hold gear x clamped ctrl for one control step; return MuJoCo's (qpos, qvel) after it."""
        m = self.model
        ctrl = np.clip(action, m.ctrl_low, m.ctrl_high)
        self._u[:] = m.gear * ctrl
        self._input.set(self._u)
        self._k += 1
        advance(self._simulator, self._k * self.control_dt, f"{type(self).__name__} (xi {self._xi.tolist()})")
        x = m.plant.GetPositionsAndVelocities(self._plant_context)
        if not np.all(np.isfinite(x)):
            raise SimulationError(f"{type(self).__name__}: non-finite state at t = {self._k * self.control_dt:g} s")
        return m.to_mujoco(x)

    # The per-step hooks take the state read once per step, in MuJoCo's coordinates.

    def _observe(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float32]:
        raise NotImplementedError

    def _forward_position(self, qpos: NDArray[np.float64]) -> float:
        return float(qpos[0])

    def _healthy(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> bool:
        return True

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        task = self.task
        x_before = self._forward_position(self.mujoco_state()[0])
        qpos, qvel = self._advance(action)
        x_after = self._forward_position(qpos)
        velocity = (x_after - x_before) / self.control_dt
        ctrl_cost = task.ctrl_cost_weight * float(np.sum(np.square(action)))
        healthy = self._healthy(qpos, qvel)
        forward = task.forward_reward_weight * velocity
        survive = task.healthy_reward * float(healthy)
        obs = self._observe(qpos, qvel)
        reward = forward + survive - ctrl_cost - self._extra_cost()
        terminated = (not healthy) and self.config.terminate_when_unhealthy
        info = {
            "x_position": x_after,
            "x_velocity": velocity,
            "reward_forward": forward,
            "reward_ctrl": -ctrl_cost,
            "reward_survive": survive,
        }
        return obs, float(reward), bool(terminated), info

    def _extra_cost(self) -> float:
        """A task's cost beyond control; called after `_observe` of the same step."""
        return 0.0

    # -- rendering ------------------------------------------------------------------------------

    def _make_renderer(self):
        """The class's `view`, following the torso over a checkered floor of 1 m squares."""
        from assembly.envs.rendering import CameraView, SceneRenderer

        m = self.model
        renderer = SceneRenderer(m.scene_graph, self._context, m.plant.get_source_id(), CameraView(*self.view))
        renderer.add_checker_floor(1.0, rgba=(0.45, 0.5, 0.45, 1.0))
        self._torso = m.plant.GetBodyByName("torso")
        return renderer

    def _render_track(self) -> NDArray[np.float64]:
        return self.model.plant.EvalBodyPoseInWorld(self._plant_context, self._torso).translation()


def _model_file(name: str) -> Path:
    """An MJCF path, or the name of one of gymnasium's MuJoCo assets; InputError if neither."""
    path = Path(name).expanduser()
    if path.is_file():
        return path
    if path.parent != Path(".") or path.suffix != ".xml":
        raise InputError(f"MJCF file {name!r} not found; expected a path to an .xml file or a gymnasium asset name")
    return gymnasium_asset(name)


def _planar_observation(qpos: NDArray[np.float64], qvel: NDArray[np.float64], clip: bool) -> NDArray[np.float32]:
    velocity = np.clip(qvel, -10.0, 10.0) if clip else qvel
    return np.concatenate([qpos[1:], velocity]).astype(np.float32)


class HopperEnv(LocomotionEnv):
    """Hopper-v5 on Drake; xi: 4 link masses, thigh and leg damping."""

    task = _Task(
        "hopper.xml",
        4,
        5e-3,
        1e-3,
        1.0,
        1.0,
        3800.0,
        (
            ("torso_mass", "mass", ("torso",), "kg"),
            ("thigh_mass", "mass", ("thigh",), "kg"),
            ("leg_mass", "mass", ("leg",), "kg"),
            ("foot_mass", "mass", ("foot",), "kg"),
            ("thigh_damping", "damping", ("thigh_joint",), "N m s/rad"),
            ("leg_damping", "damping", ("leg_joint",), "N m s/rad"),
        ),
    )

    def _observe(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float32]:
        return _planar_observation(qpos, qvel, clip=True)

    def _healthy(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> bool:
        state = np.concatenate([qpos, qvel])[2:]
        return bool(np.all((-100.0 < state) & (state < 100.0)) and qpos[1] > 0.7 and -0.2 < qpos[2] < 0.2)


class Walker2dEnv(LocomotionEnv):
    """Walker2d-v5 on Drake; xi: 4 link masses (legs in pairs), hip and knee damping, floor friction."""

    task = _Task(
        "walker2d_v5.xml",
        4,
        5e-3,
        1e-3,
        1.0,
        1.0,
        None,
        (
            ("torso_mass", "mass", ("torso",), "kg"),
            ("thigh_mass", "mass", ("thigh", "thigh_left"), "kg"),
            ("leg_mass", "mass", ("leg", "leg_left"), "kg"),
            ("foot_mass", "mass", ("foot", "foot_left"), "kg"),
            ("hip_damping", "damping", ("thigh_joint", "thigh_left_joint"), "N m s/rad"),
            ("knee_damping", "damping", ("leg_joint", "leg_left_joint"), "N m s/rad"),
            ("floor_friction", "friction", ("foot_geom",), "1"),
        ),
    )

    def _observe(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float32]:
        return _planar_observation(qpos, qvel, clip=True)

    def _healthy(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> bool:
        return bool(0.8 < qpos[1] < 2.0 and -1.0 < qpos[2] < 1.0)


class HalfCheetahEnv(LocomotionEnv):
    """HalfCheetah-v5 on Drake; xi: 7 body masses, 6 joint dampings, floor friction."""

    view = ((0.0, 0.0, 0.5), (0.0, -4.0, 1.0))

    _links = ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")
    task = _Task(
        "half_cheetah.xml",
        5,
        0.1,
        0.1,
        1.0,
        0.0,
        4800.0,
        (
            ("torso_mass", "mass", ("torso",), "kg"),
            *((f"{n}_mass", "mass", (n,), "kg") for n in _links),
            *((f"{n}_damping", "damping", (n,), "N m s/rad") for n in _links),
            ("floor_friction", "friction", ("bfoot",), "1"),
        ),
    )

    def _observe(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float32]:
        return _planar_observation(qpos, qvel, clip=False)

    def _velocity_noise(self, rng: np.random.Generator, s: float, n: int) -> NDArray[np.float64]:
        return s * rng.standard_normal(n)


class HumanoidEnv(LocomotionEnv):
    """Humanoid-v5 on Drake (348-dim observation with MuJoCo's com-based quantities); xi: 13
    body masses, 17 joint dampings."""

    view = ((0.0, 0.0, 1.0), (0.0, -4.5, 1.4))

    _bodies = (
        "torso",
        "lwaist",
        "pelvis",
        "right_thigh",
        "right_shin",
        "right_foot",
        "left_thigh",
        "left_shin",
        "left_foot",
        "right_upper_arm",
        "right_lower_arm",
        "left_upper_arm",
        "left_lower_arm",
    )
    _joints = (
        "abdomen_z",
        "abdomen_y",
        "abdomen_x",
        "right_hip_x",
        "right_hip_z",
        "right_hip_y",
        "right_knee",
        "left_hip_x",
        "left_hip_z",
        "left_hip_y",
        "left_knee",
        "right_shoulder1",
        "right_shoulder2",
        "right_elbow",
        "left_shoulder1",
        "left_shoulder2",
        "left_elbow",
    )
    task = _Task(
        "humanoid.xml",
        5,
        1e-2,
        0.1,
        1.25,
        5.0,
        None,
        (
            *((f"{n}_mass", "mass", (n,), "kg") for n in _bodies),
            *((f"{n}_damping", "damping", (n,), "N m s/rad") for n in _joints),
        ),
    )
    contact_cost_weight = 5e-7
    contact_cost_max = 10.0

    def _forward_position(self, qpos: NDArray[np.float64]) -> float:
        return float(self._com()[0])  # the centre of mass, as Humanoid-v5's mass_center

    def _com(self) -> NDArray[np.float64]:
        plant, ctx = self.model.plant, self._plant_context
        return plant.CalcCenterOfMassPositionInWorld(ctx, [plant.GetModelInstanceByName("humanoid")])

    def _healthy(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> bool:
        return bool(1.0 < qpos[2] < 2.0)

    def com_quantities(self) -> dict[str, NDArray[np.float64]]:
        """MuJoCo's cinert, cvel and cfrc_ext (rows for the 13 bodies, world excluded) and
        qfrc_actuator of the hinge joints, computed from the Drake plant (about the robot's
        centre of mass, world axes; the layouts of mjData's fields)."""
        m = self.model
        plant, ctx = m.plant, self._plant_context
        c = self._com()
        cinert = np.zeros((len(m.bodies), 10))
        cvel = np.zeros((len(m.bodies), 6))
        for i, body in enumerate(m.bodies):
            X = plant.EvalBodyPoseInWorld(ctx, body)
            M = body.CalcSpatialInertiaInBodyFrame(ctx).ReExpress(X.rotation())
            mass = M.get_mass()
            p_com = X.translation() + M.get_com()
            off = p_com - c
            Mc = M.Shift(c - X.translation()).CalcRotationalInertia().CopyToFullMatrix3()
            cinert[i] = [Mc[0, 0], Mc[1, 1], Mc[2, 2], Mc[0, 1], Mc[0, 2], Mc[1, 2], *(mass * off), mass]
            V = plant.EvalBodySpatialVelocityInWorld(ctx, body)
            w, v = V.rotational(), V.translational()
            cvel[i, :3], cvel[i, 3:] = w, v + np.cross(w, c - X.translation())
        cfrc = np.zeros((len(m.bodies), 6))
        row = {body.index(): i for i, body in enumerate(m.bodies)}
        results = plant.get_contact_results_output_port().Eval(ctx)
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            f, p = info.contact_force(), info.contact_point()
            for index, sign in ((info.bodyB_index(), 1.0), (info.bodyA_index(), -1.0)):
                if index in row:
                    cfrc[row[index], :3] += sign * np.cross(p - c, f)
                    cfrc[row[index], 3:] += sign * f
        return {"cinert": cinert, "cvel": cvel, "cfrc_ext": cfrc, "qfrc_actuator": self._u.copy()}

    def _observe(self, qpos: NDArray[np.float64], qvel: NDArray[np.float64]) -> NDArray[np.float32]:
        q = self._quantities = self.com_quantities()  # the contact cost of this step reads them
        return np.concatenate(
            [
                qpos[2:],
                qvel,
                q["cinert"].ravel(),
                q["cvel"].ravel(),
                q["qfrc_actuator"][self._hinge_order()],
                q["cfrc_ext"].ravel(),
            ]
        ).astype(np.float32)

    def _hinge_order(self) -> NDArray[np.int64]:
        """Actuator rows in qvel (hinge joint) order, for qfrc_actuator[6:]."""
        if not hasattr(self, "_hinge_rows"):
            acts = [a[1] for a in self.model.spec.actuators]
            self._hinge_rows = np.array([acts.index(j) for j in self.model.spec.joints[1:]], dtype=np.int64)
        return self._hinge_rows

    def _extra_cost(self) -> float:
        cost = self.contact_cost_weight * float(np.sum(np.square(self._quantities["cfrc_ext"])))
        return min(cost, self.contact_cost_max)
