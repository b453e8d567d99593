"""goflow/Quadrotor-v0: fly a quadrotor of randomized mass to a random goal.

A Drake MultibodyPlant free body (discrete, SAP "lagged" contact) driven by Drake's `Propeller`
system (a C++ LeafSystem: no Python in the simulation loop) above a ground box; one Simulator and
one Context are reused for every episode. Task and reward are the GoFlow seed's (its Isaac Lab
quadcopter env); the airframe is Drake's quadrotor example's.

- xi: mass [0.01, 20] kg. The rotors are sized for the nominal 0.775 kg (thrust-to-weight 1.9), so
  above 1.47 kg the drone cannot hover: the infeasible region a learned sampler should find.
- Reset: at (0, 0, 0.5) m, level, at rest; goal uniform in x, y in [-2, 2] m, z in [0.5, 1.5] m.
- Action (4,): normalized rotor thrusts in [-1, 1] (clipped), thrust_i = T_max (a_i + 1) / 2 with
  T_max = 3.61 N.
- Observation (12,): body-frame linear and angular velocity, gravity direction and goal position
  in the body frame.
- Reward per step: dt (-0.05 |v_b|^2 - 0.01 |w_b|^2 + 15 (1 - tanh(d / 0.8))), d the distance to
  the goal; 100 steps of 0.02 s; success: return >= J_T = 15.
- render_mode "rgb_array": a fixed view of the goal box, the goal a green ball (480 x 480, 50 fps).

Derivation (the seed's task as read from the authors' code, our airframe and thrust model, the
rotational damping, why J_T stays 15): docs/env_models.md#quadrotor.

References: Curtis et al., ICML 2025, appendix A.1 (box, J_T); github.com/aidan-curtis/goflow at
294d0ee (goflow/environments/quadcopter/quadcopter_env.py); pydrake.examples.QuadrotorPlant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from assembly.envs.base import SimulationError, clipped_float32
from goflow_common.checks import check_finite_array, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from assembly.envs.drake_sim import HeldInput, PlantEnv, point_contact_properties
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler

__all__ = ["QuadrotorConfig", "QuadrotorEnv", "QUADROTOR_SPACE"]

#: GoFlow paper appendix A.1 DR box; the nominal point is the box centre (NoDR's default).
QUADROTOR_SPACE = ParamSpace((Param("mass", 0.01, 20.0, "kg"),))

GRAVITY = 9.81  # [m/s^2] Drake's default gravity magnitude


@dataclass(frozen=True)
class QuadrotorConfig:
    """Task, airframe and reward settings (SI units); defaults: the seed (docs/env_models.md#quadrotor)."""

    t_max: float = 2.0  # [s] episode length
    control_dt: float = 0.02  # [s] policy period (seed: sim dt 1/100, decimation 2)
    sim_dt: float = 0.01  # [s] discrete plant step; control_dt must be a multiple of it
    nominal_mass: float = 0.775  # [kg] mass the rotors are sized for (Drake QuadrotorPlant default)
    thrust_to_weight: float = 1.9  # all rotors at full thrust / nominal weight (seed)
    arm_length: float = 0.15  # [m] rotor distance from the centre
    inertia: tuple[float, float, float] = (0.0015, 0.0025, 0.0035)  # [kg m^2] at nominal_mass
    moment_ratio: float = 0.0245  # [m] rotor drag moment per unit thrust
    collision_radius: float = 0.05  # [m] sphere used for ground contact
    # [N m s] rotational damping torque per body angular velocity: limits |w| to ~55 rad/s at the
    # largest rotor-thrust difference; 0.25 s time constant at the nominal inertia.
    angular_damping: float = 0.01
    # [rad/s] a body rate beyond this is a diverged physics step (SimulationError: the episode ends
    # truncated with info["sim_error"]). Bang-bang thrusts at 0.01-0.03 kg reach at most ~1,100 rad/s
    # in 450 episodes that stay finite; a diverging step grows without bound (1e13 rad/s at 0.03 kg in
    # one of them; a GoFlow training run logged an episode return of -4e10).
    max_angular_rate: float = 5000.0
    start_position: tuple[float, float, float] = (0.0, 0.0, 0.5)  # [m]
    goal_xy_range: float = 2.0  # [m] goal x, y uniform in +-this
    goal_z_range: tuple[float, float] = (0.5, 1.5)  # [m] goal z uniform in this interval
    rew_lin_vel: float = -0.05  # times |v_b|^2 dt
    rew_ang_vel: float = -0.01  # times |w_b|^2 dt
    rew_distance: float = 15.0  # times (1 - tanh(d / distance_scale)) dt
    distance_scale: float = 0.8  # [m]
    success_threshold: float = 15.0  # J_T (paper appendix A.1)

    def __post_init__(self) -> None:
        for name in (
            "t_max",
            "control_dt",
            "sim_dt",
            "nominal_mass",
            "thrust_to_weight",
            "arm_length",
            "collision_radius",
            "distance_scale",
            "angular_damping",
            "max_angular_rate",
        ):
            check_number(getattr(self, name), f"QuadrotorConfig.{name}", 0.0, low_open=True)
        for name in ("moment_ratio", "goal_xy_range"):
            check_number(getattr(self, name), f"QuadrotorConfig.{name}", 0.0)
        for name in ("rew_lin_vel", "rew_ang_vel", "rew_distance", "success_threshold"):
            check_number(getattr(self, name), f"QuadrotorConfig.{name}")
        ratio = self.control_dt / self.sim_dt
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise InputError(
                f"Quadrotor: control_dt ({self.control_dt:g} s) must be a positive integer multiple "
                f"of sim_dt ({self.sim_dt:g} s)"
            )
        if not np.all(check_finite_array(self.inertia, "QuadrotorConfig.inertia", (3,)) > 0):
            raise InputError(f"QuadrotorConfig.inertia = {self.inertia!r}; expected three moments > 0 [kg m^2]")
        check_finite_array(self.start_position, "QuadrotorConfig.start_position", (3,))
        lo, hi = check_finite_array(self.goal_z_range, "QuadrotorConfig.goal_z_range", (2,))
        if not lo <= hi:
            raise InputError(
                f"QuadrotorConfig.goal_z_range = {self.goal_z_range!r}; expected (low, high) with low <= high [m]"
            )

    @property
    def max_rotor_thrust(self) -> float:
        """T_max [N]: one rotor's thrust at action +1."""
        return self.thrust_to_weight * self.nominal_mass * GRAVITY / 4.0

    @property
    def max_hover_mass(self) -> float:
        """[kg] the heaviest drone all four rotors at full thrust can hold up."""
        return self.thrust_to_weight * self.nominal_mass


def rotor_layout(cfg: QuadrotorConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rotor positions in the body frame [m] (4, 3), "+" layout, and each rotor's spin sign (4,):
    rotor i's drag moment about body z is sign_i * moment_ratio * thrust_i."""
    L = cfg.arm_length
    positions = np.array([[L, 0, 0], [0, L, 0], [-L, 0, 0], [0, -L, 0]], dtype=np.float64)
    return positions, np.array([1.0, -1.0, 1.0, -1.0])


def _contact():
    return point_contact_properties(1e5, 20.0, 1.0)


def add_quadrotor(plant, cfg: QuadrotorConfig, instance=None):
    """Add one airframe (a free body with rotor damping and a collision sphere) to an unfinalized
    plant in model instance `instance` (default: the plant's default instance); return its body.
    Also sets the plant's contact approximation (SAP "lagged")."""
    from pydrake.math import RigidTransform
    from pydrake.geometry import Sphere
    from pydrake.multibody.plant import DiscreteContactApproximation
    from pydrake.multibody.tree import QuaternionFloatingJoint, SpatialInertia, UnitInertia, default_model_instance

    instance = default_model_instance() if instance is None else instance
    unit = UnitInertia(*(np.asarray(cfg.inertia) / cfg.nominal_mass))
    body = plant.AddRigidBody("body", instance, SpatialInertia(cfg.nominal_mass, np.zeros(3), unit))
    # Rotor aerodynamic damping of the body rotation, applied implicitly by the discrete solver. Without
    # it a light drone under bang-bang thrusts spins up without bound and the explicit gyroscopic
    # term diverges (NaN within 0.2 s at 0.05 kg); PhysX (the seed) damps and caps angular velocity.
    plant.AddJoint(
        QuaternionFloatingJoint(
            "body_free",
            plant.world_frame(),
            body.body_frame(),
            angular_damping=cfg.angular_damping,
            translational_damping=0.0,
        )
    )
    plant.RegisterCollisionGeometry(body, RigidTransform(), Sphere(cfg.collision_radius), "body", _contact())
    # SAP "lagged" (Drake's default, explicit here): TAMSI is ~3.5x faster while the drone rests on
    # the ground but failed (NaN) in 31 of 90 bang-bang episodes across the mass box; lagged in none.
    plant.set_discrete_contact_approximation(DiscreteContactApproximation.kLagged)
    return body


def add_ground(plant):
    """The ground box (top at z = 0) every airframe lands on; returns its GeometryId."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform

    return plant.RegisterCollisionGeometry(
        plant.world_body(), RigidTransform([0.0, 0.0, -0.5]), Box(200.0, 200.0, 1.0), "ground", _contact()
    )


def add_propellers(builder, plant, cfg: QuadrotorConfig, bodies):
    """One Drake Propeller system (named "propellers") driving four rotors on each body, its
    command input ordered body by body; connected to the finalized plant's spatial force input."""
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import Propeller, PropellerInfo

    positions, spins = rotor_layout(cfg)
    infos = [
        PropellerInfo(body.index(), RigidTransform(p), 1.0, s * cfg.moment_ratio)
        for body in bodies
        for p, s in zip(positions, spins)
    ]
    propellers = builder.AddSystem(Propeller(infos))
    propellers.set_name("propellers")
    builder.Connect(propellers.get_spatial_forces_output_port(), plant.get_applied_spatial_force_input_port())
    builder.Connect(plant.get_body_poses_output_port(), propellers.get_body_poses_input_port())
    return propellers


class QuadrotorEnv(PlantEnv):
    """Fly to a random goal in 2 s; xi = (mass,); actions are four normalized rotor thrusts."""

    _owner = "Quadrotor"

    def __init__(
        self,
        config: QuadrotorConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = config_with_overrides(QuadrotorConfig, config, overrides, "QuadrotorEnv")
        super().__init__(QUADROTOR_SPACE, sampler)
        cfg = self.config
        self._set_timing(cfg.control_dt, cfg.t_max, cfg.success_threshold)
        self._init_render(render_mode)
        # Finite bounds (observations are clipped to them): speeds far beyond what 2 s of flight reach
        # at the lowest mass, the unit gravity direction, and the farthest goal after such a flight.
        self._obs_high = (200.0,) * 3 + (500.0,) * 3 + (1.0,) * 3 + (500.0,) * 3
        high = np.array(self._obs_high, dtype=np.float32)
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._build()

    # -- Drake model ---------------------------------------------------------------------------

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        cfg = self.config
        builder = DiagramBuilder()
        plant, _ = AddMultibodyPlantSceneGraph(builder, time_step=cfg.sim_dt)
        body = add_quadrotor(plant, cfg)
        add_ground(plant)
        plant.Finalize()
        self._rotor_positions, self._rotor_spin = rotor_layout(cfg)
        add_propellers(builder, plant, cfg, [body])
        self._diagram = builder.Build()
        self._plant, self._body = plant, body
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        propellers = self._diagram.GetSubsystemByName("propellers")
        self._prop_context = propellers.GetMyMutableContextFromRoot(self._context)
        self._input_zero = np.zeros(4)
        self._input = HeldInput(propellers.get_command_input_port(), self._prop_context, self._input_zero)
        self._initial_state: NDArray[np.float64] | None = None
        self._goal = np.array([0.0, 0.0, 1.0])
        self._goal_xyz = (0.0, 0.0, 1.0)
        self._k = 0

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        self._body.SetMass(self._plant_context, float(xi[0]))

    def thrusts(self, action: ArrayLike) -> NDArray[np.float64]:
        """Rotor thrusts [N] for normalized actions (..., 4): T_max (clip(a, -1, 1) + 1) / 2."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return 0.5 * self.config.max_rotor_thrust * (a + 1.0)

    # -- observation and reward ----------------------------------------------------------------
    # Drake's free-body state: q = (qw, qx, qy, qz, x, y, z), v = (w_WB in world, v_WB in world).

    def _observe_and_reward(self, state: list[float]) -> tuple[NDArray[np.float32], float]:
        """Observation (v_B, w_B, gravity direction in B, goal offset in B) and the step reward, in
        Python floats (the same maths as R_WB^T applied with `base.quaternion_rotation`)."""
        cfg = self.config
        qw, qx, qy, qz, px, py, pz, wx, wy, wz, vx, vy, vz = state
        n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        w, x, y, z = qw * n, qx * n, qy * n, qz * n
        # R_WB^T (rows a, b, c) applied to world vectors.
        a0, a1, a2 = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)
        b0, b1, b2 = 2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)
        c0, c1, c2 = 2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)
        v_b = (a0 * vx + a1 * vy + a2 * vz, b0 * vx + b1 * vy + b2 * vz, c0 * vx + c1 * vy + c2 * vz)
        w_b = (a0 * wx + a1 * wy + a2 * wz, b0 * wx + b1 * wy + b2 * wz, c0 * wx + c1 * wy + c2 * wz)
        g_b = (-a2, -b2, -c2)  # R^T (0, 0, -1)
        gx, gy, gz = self._goal_xyz
        ex, ey, ez = gx - px, gy - py, gz - pz
        goal_b = (a0 * ex + a1 * ey + a2 * ez, b0 * ex + b1 * ey + b2 * ez, c0 * ex + c1 * ey + c2 * ez)
        obs = clipped_float32(v_b + w_b + g_b + goal_b, self._obs_high)
        d = math.sqrt(goal_b[0] ** 2 + goal_b[1] ** 2 + goal_b[2] ** 2)
        reward = self.control_dt * (
            cfg.rew_lin_vel * (v_b[0] ** 2 + v_b[1] ** 2 + v_b[2] ** 2)
            + cfg.rew_ang_vel * (w_b[0] ** 2 + w_b[1] ** 2 + w_b[2] ** 2)
            + cfg.rew_distance * (1.0 - math.tanh(d / cfg.distance_scale))
        )
        return obs, reward

    # -- ParamEnv ------------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        cfg = self.config
        r = cfg.goal_xy_range
        gx, gy = self.np_random.uniform(-r, r, size=2)
        gz = self.np_random.uniform(*cfg.goal_z_range)
        self._goal = np.array([gx, gy, gz], dtype=np.float64)
        self._goal_xyz = (float(gx), float(gy), float(gz))
        state = self._default_state(xi)
        self._initial_state = state.copy()
        self._start(xi, state)
        return self._observe_and_reward(state.tolist())[0]

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        half = 0.5 * self.config.max_rotor_thrust  # `thrusts`, on floats (the per-step path)
        state = self._advance(np.array([half * (min(1.0, max(-1.0, a)) + 1.0) for a in action.tolist()]))
        limit = self.config.max_angular_rate
        if not (-limit <= state[7] <= limit and -limit <= state[8] <= limit and -limit <= state[9] <= limit):
            raise SimulationError(
                f"Quadrotor (mass {float(self._xi[0]):g} kg): body rate ({state[7]:.3g}, {state[8]:.3g}, {state[9]:.3g}) "
                f"rad/s at t = {self._k * self.control_dt:.2f} s is beyond max_angular_rate = {limit:g} rad/s: "
                "the discrete step diverged"
            )
        obs, reward = self._observe_and_reward(state)
        return obs, reward, False, {}

    # -- rendering -----------------------------------------------------------------------------

    _GOAL_RADIUS = 0.06  # [m] the goal marker's radius (image only)

    def _make_renderer(self):
        """A fixed camera on the goal box from -y, above a checkered floor; the airframe (arms, hub,
        rotors: the front one, +x, red) and the goal are image-only shapes (the model's only
        geometry is a collision sphere and the ground)."""
        from pydrake.geometry import Box, Cylinder, Sphere
        from pydrake.math import RigidTransform, RotationMatrix

        from assembly.envs.rendering import CameraView, SceneRenderer, scene_graph_of

        cfg, plant = self.config, self._plant
        scene_graph = scene_graph_of(self._diagram)
        view = CameraView(target=(0.0, 0.0, 0.8), eye_offset=(0.0, -4.5, 1.8))
        r = SceneRenderer(scene_graph, self._context, plant.get_source_id(), view)
        r.show_collision_geometry((0.8, 0.8, 0.8, 1.0))  # the ground
        r.add_checker_floor(0.5, cells=16, rgba=(0.6, 0.6, 0.6, 1.0))
        body = plant.GetBodyFrameIdOrThrow(self._body.index())
        span, dark = 2.0 * cfg.arm_length + 0.02, (0.15, 0.15, 0.15, 1.0)
        r.add_visual(body, Box(span, 0.02, 0.015), RigidTransform(), dark, "arm_x")
        r.add_visual(body, Box(0.02, span, 0.015), RigidTransform(), dark, "arm_y")
        r.add_visual(body, Box(0.07, 0.07, 0.04), RigidTransform(), (0.2, 0.4, 0.8, 1.0), "hub")
        for i, p in enumerate(self._rotor_positions):
            color = (0.85, 0.1, 0.1, 1.0) if i == 0 else (0.3, 0.3, 0.3, 1.0)
            X = RigidTransform(RotationMatrix(), p + [0.0, 0.0, 0.015])
            r.add_visual(body, Cylinder(0.06, 0.006), X, color, f"rotor_{i}")
        world = scene_graph.world_frame_id()
        self._goal_marker = r.add_visual(
            world, Sphere(self._GOAL_RADIUS), RigidTransform(), (0.1, 0.8, 0.2, 1.0), "goal"
        )
        self._goal_drawn: tuple[float, float, float] | None = None
        return r

    def _render_frame(self) -> NDArray[np.uint8]:
        from pydrake.geometry import Sphere
        from pydrake.math import RigidTransform

        r = self._scene_renderer()
        if self._goal_drawn != self._goal_xyz:
            r.move_visual(self._goal_marker, Sphere(self._GOAL_RADIUS), RigidTransform(self._goal_xyz))
            self._goal_drawn = self._goal_xyz
        return r.render()

    # -- tools ---------------------------------------------------------------------------------

    @property
    def goal(self) -> NDArray[np.float64]:
        """The episode's goal position in the world [m]."""
        return self._goal.copy()

    @property
    def rotor_positions(self) -> NDArray[np.float64]:
        """Rotor positions in the body frame [m], shape (4, 3)."""
        return self._rotor_positions.copy()

    @property
    def rotor_spin(self) -> NDArray[np.float64]:
        """Sign of each rotor's drag moment about body z per unit thrust (times moment_ratio), shape (4,)."""
        return self._rotor_spin.copy()

    def _default_state(self, xi: NDArray[np.float64]) -> NDArray[np.float64]:
        """At rest at the start position, level: (qw, qx, qy, qz, x, y, z, w_WB, v_WB)."""
        state = np.zeros(13)
        state[0] = 1.0
        state[4:7] = self.config.start_position
        return state

    def _inputs(self, actions: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.thrusts(actions)
