"""goflow/Cartpole-v0: balance a pole on a cart, with randomized pole mass, cart mass and slider friction.

A Drake MultibodyPlant built in code (discrete, SAP "lagged" contact), simulated with one Simulator
and one Context reused for every episode; the per-episode parameters xi are written into that
Context. Task, reward and box are the GoFlow seed's (its Isaac Lab cartpole balance task).

- xi: pole mass [0.01, 20] kg, cart mass [0.01, 20] kg, slider Coulomb friction coefficient [0, 1]
  (the cart rides on a frictional contact: Drake joints have no Coulomb friction).
- Reset: cart at 0 m, at rest, pole angle uniform in +-pi/4 rad from upright.
- Observation (5,): cart position [m], cart velocity [m/s], cos theta, sin theta, pole angular
  velocity [rad/s]; theta = 0 upright, positive leaning toward +x.
- Action (1,): normalized slider force in [-1, 1] (clipped), times max_force = 100 N.
- Reward per step: 1 - theta^2 - 0.01 |cart velocity| - 0.005 |pole angular velocity|; 120 steps
  of 1/60 s, no early termination; success: return >= J_T = 54.
- render_mode "rgb_array": a fixed side view of the rail (480 x 480, 60 fps).

Derivation (the seed's task as read from the authors' code, our model of friction and masses,
J_T = 54 from the seed's 50): docs/env_models.md#cartpole.

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025, appendix A.1 (box, J_T); github.com/aidan-curtis/goflow at 294d0ee
(goflow/environments/cartpole/).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs.base import clipped_float32
from goflow_common.checks import check_finite_array, check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from assembly.envs.drake_sim import HeldInput, PlantEnv, point_contact_properties
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler

__all__ = ["CartpoleConfig", "CartpoleEnv", "CARTPOLE_SPACE"]

#: GoFlow paper appendix A.1 DR box; the nominal point is the box centre (NoDR's default).
CARTPOLE_SPACE = ParamSpace(
    (
        Param("pole_mass", 0.01, 20.0, "kg"),
        Param("cart_mass", 0.01, 20.0, "kg"),
        Param("slider_friction", 0.0, 1.0, "1"),  # Coulomb coefficient of the cart on its rail
    )
)


@dataclass(frozen=True)
class CartpoleConfig:
    """Task, model and reward settings (SI units); defaults follow the seed (docs/env_models.md#cartpole)."""

    t_max: float = 2.0  # [s] episode length
    control_dt: float = 1.0 / 60.0  # [s] policy period (seed: sim dt 1/120, decimation 2)
    sim_dt: float = 1.0 / 120.0  # [s] discrete plant step; control_dt must be a multiple of it
    max_force: float = 100.0  # [N] slider force at action 1 (seed action_scale)
    slider_damping: float = 10.0  # [N s/m] viscous damping of the slider (seed cart actuator damping)
    slider_limit: float = 4.0  # [m] cart position limits +-slider_limit
    initial_pole_angle: float = 0.25 * math.pi  # [rad] pole angle drawn uniformly in +-this at reset
    pole_length: float = 1.0  # [m] pole box length (0.04 x 0.06 x pole_length)
    pole_com: float = 0.47  # [m] pole centre of mass above the pivot
    cart_size: tuple[float, float, float] = (0.2, 0.25, 0.2)  # [m] cart box (sets its unit inertia)
    wheel_radius: float = 0.05  # [m] contact sphere under the cart
    contact_stiffness: float = 1e6  # [N/m] point-contact stiffness of the wheel on the ground
    contact_dissipation: float = 20.0  # [s/m] Hunt-Crossley dissipation of the wheel contacts
    rew_alive: float = 1.0
    rew_pole_angle: float = -1.0  # times theta^2 [rad^2]
    rew_cart_vel: float = -0.01  # times |cart velocity| [m/s]
    rew_pole_vel: float = -0.005  # times |pole angular velocity| [rad/s]
    success_threshold: float = 54.0  # J_T from the seed's 50 (docs/env_models.md#horizon-and-j_t)

    def __post_init__(self) -> None:
        for name in (
            "t_max",
            "control_dt",
            "sim_dt",
            "max_force",
            "slider_limit",
            "pole_length",
            "wheel_radius",
            "contact_stiffness",
            "contact_dissipation",
        ):
            check_number(getattr(self, name), f"CartpoleConfig.{name}", 0.0, low_open=True)
        for name in ("slider_damping", "initial_pole_angle"):
            check_number(getattr(self, name), f"CartpoleConfig.{name}", 0.0)
        for name in ("rew_alive", "rew_pole_angle", "rew_cart_vel", "rew_pole_vel", "success_threshold"):
            check_number(getattr(self, name), f"CartpoleConfig.{name}")
        ratio = self.control_dt / self.sim_dt
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise InputError(
                f"Cartpole: control_dt ({self.control_dt:g} s) must be a positive integer multiple "
                f"of sim_dt ({self.sim_dt:g} s)"
            )
        check_number(self.pole_com, "CartpoleConfig.pole_com", 0.0, self.pole_length, low_open=True)
        if not np.all(check_finite_array(self.cart_size, "CartpoleConfig.cart_size", (3,)) > 0):
            raise InputError(f"CartpoleConfig.cart_size = {self.cart_size!r}; expected three lengths > 0 [m]")


def wheel_contact(mu: float, cfg: CartpoleConfig):
    """ProximityProperties of the wheel and its ground: the config's point contact, Coulomb mu."""
    return point_contact_properties(cfg.contact_stiffness, cfg.contact_dissipation, mu)


def cart_height(cfg: CartpoleConfig) -> float:
    """[m] height of the cart origin when its wheel touches the ground top (z = 0)."""
    return 0.5 * cfg.cart_size[2] + cfg.wheel_radius


@dataclass(frozen=True)
class CartpoleCopy:
    """One cartpole added to a plant: its bodies, joints, actuator and contact geometries."""

    cart: Any  # RigidBody
    pole: Any  # RigidBody
    joints: tuple[Any, Any, Any]  # slider (x), cart vertical (z), pole hinge (theta)
    actuator: Any  # JointActuator on the slider
    geometries: tuple[Any, Any]  # GeometryIds: wheel, ground


def add_cartpole(plant, cfg: CartpoleConfig, instance=None, y: float = 0.0) -> CartpoleCopy:
    """Add one cartpole (bodies, joints, the slider actuator, the wheel and its ground) to an
    unfinalized plant, in model instance `instance` (default: the plant's default instance), its
    rail along x at lateral offset y [m] (the joint coordinates do not depend on y)."""
    from pydrake.geometry import Box, Sphere
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import (
        FixedOffsetFrame,
        PrismaticJoint,
        RevoluteJoint,
        SpatialInertia,
        UnitInertia,
        default_model_instance,
    )

    instance = default_model_instance() if instance is None else instance
    # Massless carriage between the x slider and the vertical joint; the cart and pole above it
    # give both joints positive inertia.
    carriage = plant.AddRigidBody("carriage", instance, SpatialInertia(0.0, np.zeros(3), UnitInertia(0.0, 0.0, 0.0)))
    cart = plant.AddRigidBody("cart", instance, SpatialInertia(1.0, np.zeros(3), UnitInertia.SolidBox(*cfg.cart_size)))
    g_pole = UnitInertia.SolidBox(0.04, 0.06, cfg.pole_length).ShiftFromCenterOfMass([0.0, 0.0, -cfg.pole_com])
    pole = plant.AddRigidBody("pole", instance, SpatialInertia(1.0, [0.0, 0.0, cfg.pole_com], g_pole))
    rail = plant.world_frame()
    if y != 0.0:
        rail = plant.AddFrame(FixedOffsetFrame("rail", plant.world_frame(), RigidTransform([0.0, y, 0.0]), instance))
    slider = plant.AddJoint(
        PrismaticJoint(
            "slider_to_cart",
            rail,
            carriage.body_frame(),
            [1.0, 0.0, 0.0],
            -cfg.slider_limit,
            cfg.slider_limit,
            cfg.slider_damping,
        )
    )
    vertical = plant.AddJoint(
        PrismaticJoint("cart_vertical", carriage.body_frame(), cart.body_frame(), [0.0, 0.0, 1.0])
    )
    hinge = plant.AddJoint(RevoluteJoint("cart_to_pole", cart.body_frame(), pole.body_frame(), [0.0, 1.0, 0.0]))
    actuator = plant.AddJointActuator("slider_force", slider)
    wheel = plant.RegisterCollisionGeometry(
        cart,
        RigidTransform([0.0, 0.0, -0.5 * cfg.cart_size[2]]),
        Sphere(cfg.wheel_radius),
        "wheel",
        wheel_contact(0.0, cfg),
    )
    # A box, not a HalfSpace (which makes Drake warn about deformable contact).
    name = "ground" if instance == default_model_instance() else f"ground_{plant.GetModelInstanceName(instance)}"
    ground = plant.RegisterCollisionGeometry(
        plant.world_body(),
        RigidTransform([0.0, y, -0.5]),
        Box(4.0 * cfg.slider_limit + 2.0, 2.0, 1.0),
        name,
        wheel_contact(0.0, cfg),
    )
    # SAP with its default "lagged" approximation: it enforces the slider limits, and stays stable
    # for 0.02 kg carts hitting them; TAMSI (~4x faster) ignores joint limits and diverges on stiff
    # end stops, and SAP's "sap"/"similar" approximations make a sliding cart float (normal
    # velocity ~ mu * slip speed).
    return CartpoleCopy(cart, pole, (slider, vertical, hinge), actuator, (wheel, ground))


class CartpoleEnv(PlantEnv):
    """Balance a pole on a force-driven cart; xi = (pole mass, cart mass, slider Coulomb friction)."""

    _owner = "Cartpole"

    def __init__(
        self,
        config: CartpoleConfig | None = None,
        *,
        sampler: Sampler | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.config = config_with_overrides(CartpoleConfig, config, overrides, "CartpoleEnv")
        super().__init__(CARTPOLE_SPACE, sampler)
        cfg = self.config
        self._set_timing(cfg.control_dt, cfg.t_max, cfg.success_threshold)
        self._init_render(render_mode)
        # Finite bounds (observations are clipped to them): the slider limits (+1 m of slack), cos/sin,
        # and speeds far above what the 100 N force against the 10 N s/m damper reaches.
        self._obs_high = (cfg.slider_limit + 1.0, 100.0, 1.0, 1.0, 200.0)
        high = np.array(self._obs_high, dtype=np.float32)
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self._build()

    # -- Drake model ---------------------------------------------------------------------------

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=self.config.sim_dt)
        copy = add_cartpole(plant, self.config)
        plant.Finalize()
        self._diagram = builder.Build()
        self._plant, self._scene_graph = plant, scene_graph
        self._cart, self._pole = copy.cart, copy.pole
        self._geometries = copy.geometries
        self._cart_height = cart_height(self.config)
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._sg_context = scene_graph.GetMyMutableContextFromRoot(self._context)
        self._input_zero = 0.0
        self._input = HeldInput(plant.get_actuation_input_port(), self._plant_context, [0.0])
        self._initial_state: NDArray[np.float64] | None = None
        self._friction_set: float | None = None
        self._k = 0  # control steps since reset (simulated time = k * control_dt)

    def _apply_xi(self, xi: NDArray[np.float64]) -> None:
        """Write xi into the Context: body masses and the wheel/ground Coulomb coefficient."""
        from pydrake.geometry import RoleAssign

        pole_mass, cart_mass, mu = (float(v) for v in xi)
        self._pole.SetMass(self._plant_context, pole_mass)
        self._cart.SetMass(self._plant_context, cart_mass)
        if mu != self._friction_set:
            source = self._plant.get_source_id()
            for gid in self._geometries:  # equal coefficients combine to the same mu
                self._scene_graph.AssignRole(
                    self._sg_context, source, gid, wheel_contact(mu, self.config), RoleAssign.kReplace
                )
            self._friction_set = mu

    def _initial_plant_state(self, xi: NDArray[np.float64], theta0: float = 0.0) -> NDArray[np.float64]:
        """(x, z, theta, xdot, zdot, thetadot) at rest, the wheel pressed to its static penetration."""
        penetration = (xi[0] + xi[1]) * 9.81 / self.config.contact_stiffness
        return np.array([0.0, self._cart_height - penetration, theta0, 0.0, 0.0, 0.0])

    # -- observation and reward ----------------------------------------------------------------

    @staticmethod
    def _wrap(theta: float) -> float:
        return (theta + math.pi) % (2.0 * math.pi) - math.pi

    def _observe(self, state: list[float]) -> NDArray[np.float32]:
        x, _, theta, xdot, _, thetadot = state
        return clipped_float32((x, xdot, math.cos(theta), math.sin(theta), thetadot), self._obs_high)

    def _reward(self, state: list[float]) -> float:
        cfg = self.config
        theta = self._wrap(state[2])
        return (
            cfg.rew_alive
            + cfg.rew_pole_angle * theta * theta
            + cfg.rew_cart_vel * abs(state[3])
            + cfg.rew_pole_vel * abs(state[5])
        )

    # -- ParamEnv ------------------------------------------------------------------------------

    def _reset_model(self, xi: NDArray[np.float64]) -> NDArray[np.float32]:
        a = self.config.initial_pole_angle
        theta0 = float(self.np_random.uniform(-a, a)) if a > 0 else 0.0
        state = self._initial_plant_state(xi, theta0)
        self._initial_state = state.copy()
        self._start(xi, state)
        return self._observe(state.tolist())

    def _step_model(self, action: NDArray[np.float64]) -> tuple[NDArray[np.float32], float, bool, dict[str, Any]]:
        force = self.config.max_force * min(1.0, max(-1.0, float(action[0])))
        state = self._advance(force)
        return self._observe(state), self._reward(state), False, {}

    # -- rendering -----------------------------------------------------------------------------

    def _make_renderer(self):
        """A fixed camera on the rail from -y; the cart, pole and rail with its end stops are
        image-only shapes (the model's only geometry is the wheel and the ground)."""
        from pydrake.geometry import Box
        from pydrake.math import RigidTransform

        from assembly.envs.rendering import CameraView, SceneRenderer

        cfg, plant = self.config, self._plant
        view = CameraView(target=(0.0, 0.0, 0.5), eye_offset=(0.0, -5.5, 0.6))
        r = SceneRenderer(self._scene_graph, self._context, plant.get_source_id(), view)
        cart = plant.GetBodyFrameIdOrThrow(self._cart.index())
        pole = plant.GetBodyFrameIdOrThrow(self._pole.index())
        world = self._scene_graph.world_frame_id()
        h, rail_y = self._cart_height, 0.5 * cfg.cart_size[1] + 0.05
        r.add_visual(cart, Box(*cfg.cart_size), RigidTransform(), (0.2, 0.4, 0.8, 1.0), "cart")
        r.add_visual(
            pole,
            Box(0.04, 0.06, cfg.pole_length),
            RigidTransform([0.0, 0.0, 0.5 * cfg.pole_length]),
            (0.9, 0.5, 0.1, 1.0),
            "pole",
        )
        r.add_visual(
            world,
            Box(2.0 * cfg.slider_limit, 0.02, 0.02),
            RigidTransform([0.0, rail_y, h]),
            (0.4, 0.4, 0.4, 1.0),
            "rail",
        )
        for side in (-1.0, 1.0):
            r.add_visual(
                world,
                Box(0.05, 0.05, 0.3),
                RigidTransform([side * cfg.slider_limit, rail_y, h]),
                (0.6, 0.1, 0.1, 1.0),
                f"stop_{side:+.0f}",
            )
        r.show_collision_geometry((0.75, 0.75, 0.75, 1.0), {"wheel": (0.1, 0.1, 0.1, 1.0)})  # ground, wheel
        return r

    # -- tools ---------------------------------------------------------------------------------

    def _default_state(self, xi: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._initial_plant_state(xi)  # pole upright, at rest

    def _inputs(self, actions: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.config.max_force * np.clip(actions, -1.0, 1.0)  # slider force [N], (T, 1)
