"""Cartesian impedance control of the Panda's hand frame, as a Drake LeafSystem.

tau = J^T (Lambda (A_d - Jdot v) + K e + D (V_d - V)) + g(q) + C(q, v) v + b v
      + N^T (k_n (q_n - q) - d_n v + tau_lim),
clipped to the torque limits, where e stacks the rotation error (axis-angle of R_WTd R_WT^T, world
frame) and the position error of the tool frame T, V is T's spatial velocity in the world, J its
spatial-velocity Jacobian, Lambda = (J M^-1 J^T)^-1 the operational-space inertia and
N^T = I - J^T Lambda J M^-1 the dynamically consistent null-space projector (Khatib 1987), and
g, C v, b v the model's gravity, Coriolis/centripetal and viscous joint-friction torques;
tau_lim = k_l (max(m - (q - q_min), 0) - max(m - (q_max - q), 0)) pushes a joint that comes within
m of a position limit back out (joint-limit avoidance: zero outside the band, so the law is the
plain posture task there; "Reach" in docs/planning.md). The
feedforward Lambda (A_d - Jdot v) makes a planned trajectory's accelerations happen on time and
keeps null-space motion from pushing the tool; the static
behaviour is the 6-D spring K, so a contact force equals K times the commanded offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, JacobianWrtVariable, ModelInstanceIndex
from pydrake.systems.framework import Context, LeafSystem, ValueProducer


@dataclass
class ImpedanceGains:
    """Stiffness and damping of the hand frame and of the null-space posture.

    Stiffness follows IndustReal's task-space gains for gear insertion (Tang et al., RSS 2023;
    IsaacGymEnvs IndustRealTaskGearsInsert.yaml: Kp = [300, 300, 300, 50, 50, 50]). Damping is
    not 2 sqrt(Kp) (that assumes unit mass): the Panda's apparent mass at the hand, rotor inertia
    included, is several kg, and the values below settle a 17 cm step in about 2 s without
    overshoot beyond a few mm (docs/station.md).
    """

    # [rx, ry, rz, x, y, z] order is Drake's SpatialVelocity order (rotational first).
    stiffness: np.ndarray = field(default_factory=lambda: np.array([50.0, 50.0, 50.0, 300.0, 300.0, 300.0]))
    damping: np.ndarray = field(default_factory=lambda: np.array([5.0, 5.0, 5.0, 100.0, 100.0, 100.0]))
    nullspace_stiffness: float = 10.0
    nullspace_damping: float = 3.0
    # Joint-limit avoidance in the null space: within limit_margin [rad] of a position limit a
    # joint is pushed back by limit_stiffness [N m/rad] times its depth in the band. Off (0) by
    # default, so the law is the one the skills were trained and sim2real replays with: where
    # joint 4 ran onto its limit near the base, the task itself needs it there at the hand's yaw
    # and no null-space push frees it; the reachable inspect yaw does (docs/planning.md, "Reach").
    limit_margin: float = 0.3
    limit_stiffness: float = 0.0

    def __post_init__(self) -> None:
        self.stiffness = np.asarray(self.stiffness, dtype=float)
        self.damping = np.asarray(self.damping, dtype=float)
        for name in ("stiffness", "damping"):
            value = getattr(self, name)
            if value.shape != (6,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(
                    f"ImpedanceGains.{name} = {value!r}; expected 6 finite non-negative values "
                    "ordered [rx, ry, rz, x, y, z]"
                )
        for name in ("nullspace_stiffness", "nullspace_damping", "limit_margin", "limit_stiffness"):
            value = getattr(self, name)
            number = not isinstance(value, bool) and isinstance(value, (int, float, np.number))
            if not (number and np.isfinite(value) and value >= 0):
                raise ValueError(f"ImpedanceGains.{name} = {value!r}; expected a finite number >= 0")
            setattr(self, name, float(value))
        if self.limit_margin > 1.0:
            raise ValueError(
                f"ImpedanceGains.limit_margin = {self.limit_margin!r} rad; expected 0..1 rad "
                "(the band below each joint-position limit)"
            )


def rotation_error(R_desired: np.ndarray, R_actual: np.ndarray) -> np.ndarray:
    """Axis-angle vector (world frame) rotating R_actual onto R_desired."""
    R = R_desired @ R_actual.T
    cos = np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)
    angle = np.arccos(cos)
    axis_sin = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return axis_sin
    if np.pi - angle < 1e-4:  # near pi: take the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(R) + 1.0) / 2.0, 0.0))
        axis *= np.sign(axis_sin + (axis_sin == 0))
        return angle * axis / max(np.linalg.norm(axis), 1e-12)
    return angle * axis_sin / np.sin(angle)


class CartesianImpedanceController(LeafSystem):
    """Torques for a torque-controlled arm that make a tool frame behave like a 6-D spring-damper.

    Ports:
      input  "arm_state"      (2 n): measured [q, v] of the arm.
      input  "X_WT_desired"   (abstract RigidTransform): desired pose of the tool frame.
      input  "V_WT_desired"   (6, optional): desired spatial velocity [w; v] of the tool, world
                              frame; the damping acts on the velocity error. Zero if unconnected.
      input  "A_WT_desired"   (6, optional): desired spatial acceleration [alpha; a], world frame,
                              fed forward through Lambda(q). Zero if unconnected.
      output "torque"         (n): joint torques, clipped to the limits.
      output "X_WT"           (abstract RigidTransform): the measured tool pose.
      output "wrench"         (6): the commanded spatial force on the tool [torque; force], world frame.
    The controller owns `plant`, a model of the arm (and anything rigidly attached) used only for
    kinematics and gravity; the arm is the model instance `arm` in that plant.
    """

    def __init__(
        self,
        plant: MultibodyPlant,
        arm: ModelInstanceIndex,
        tool_frame: Frame,
        gains: ImpedanceGains,
        torque_limits: np.ndarray,
        q_nominal: np.ndarray,
    ) -> None:
        super().__init__()
        self._plant = plant
        self._plant_context = plant.CreateDefaultContext()
        self._arm = arm
        self._tool = tool_frame
        self._gains = gains
        self._n = plant.num_positions(arm)
        if plant.num_velocities(arm) != self._n:
            raise ValueError("the arm model instance must have as many velocities as positions")
        self._tau_max = np.asarray(torque_limits, dtype=float)
        self._q_nominal = np.asarray(q_nominal, dtype=float)
        if self._tau_max.shape != (self._n,) or self._q_nominal.shape != (self._n,):
            raise ValueError(f"torque_limits and q_nominal must have {self._n} entries")
        if not np.all(np.isfinite(self._q_nominal)):
            raise ValueError(f"q_nominal = {self._q_nominal.tolist()}; expected {self._n} finite joint positions")
        self._q_idx, self._q_min, self._q_max = arm_position_limits(plant, arm)
        if gains.limit_stiffness > 0 and not (np.all(np.isfinite(self._q_min)) and np.all(np.isfinite(self._q_max))):
            raise ValueError(
                "joint-limit avoidance (limit_stiffness > 0) needs finite position limits on every arm joint"
            )
        self._joint_damping = np.concatenate(
            [plant.get_joint(j).default_damping_vector() for j in plant.GetJointIndices(arm)]
        )
        self._v_idx = arm_velocity_columns(plant, arm)  # the arm's columns of the full-plant Jacobian

        self._state_port = self.DeclareVectorInputPort("arm_state", 2 * self._n)
        self._pose_port = self.DeclareAbstractInputPort("X_WT_desired", AbstractValue.Make(RigidTransform()))
        self._velocity_port = self.DeclareVectorInputPort("V_WT_desired", 6)
        self._acceleration_port = self.DeclareVectorInputPort("A_WT_desired", 6)
        cache = self.DeclareCacheEntry(
            "solution",
            ValueProducer(allocate=AbstractValue.Make(_Solution(self._n)).Clone, calc=self._solve),
            {self.all_input_ports_ticket()},
        )
        self._cache = cache
        self.DeclareVectorOutputPort(
            "torque", self._n, lambda c, o: o.SetFromVector(self._get(c).torque), {cache.ticket()}
        )
        self.DeclareAbstractOutputPort(
            "X_WT",
            lambda: AbstractValue.Make(RigidTransform()),
            lambda c, o: o.set_value(self.tool_pose(self._state_port.Eval(c)[: self._n])),
            {self._state_port.ticket()},
        )
        self.DeclareVectorOutputPort("wrench", 6, lambda c, o: o.SetFromVector(self._get(c).wrench), {cache.ticket()})

    @property
    def gains(self) -> ImpedanceGains:
        return self._gains

    def tool_pose(self, q: np.ndarray) -> RigidTransform:
        """Forward kinematics of the tool frame for arm positions q."""
        self._plant.SetPositions(self._plant_context, self._arm, q)
        return self._tool.CalcPoseInWorld(self._plant_context)

    def _get(self, context: Context) -> "_Solution":
        return self._cache.Eval(context)

    @staticmethod
    def _optional(port, context: Context) -> np.ndarray:
        return port.Eval(context) if port.HasValue(context) else np.zeros(6)

    def _solve(self, context: Context, value: AbstractValue) -> None:
        out = value.get_mutable_value()
        x = self._state_port.Eval(context)
        n = self._n
        q, v = x[:n], x[n:]
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise RuntimeError(f"CartesianImpedanceController: non-finite arm state {x}")
        X_WTd = self._pose_port.Eval(context)
        plant, pc = self._plant, self._plant_context
        plant.SetPositions(pc, self._arm, q)
        plant.SetVelocities(pc, self._arm, v)
        X_WT = self._tool.CalcPoseInWorld(pc)
        J = tool_jacobian(plant, pc, self._tool, self._v_idx)
        V = J @ v
        error = np.concatenate(
            [
                rotation_error(X_WTd.rotation().matrix(), X_WT.rotation().matrix()),
                X_WTd.translation() - X_WT.translation(),
            ]
        )
        g = self._gains
        wrench = g.stiffness * error + g.damping * (self._optional(self._velocity_port, context) - V)
        # Operational-space inertia; the reflected rotor inertia is part of M.
        M = plant.CalcMassMatrix(pc)[np.ix_(self._v_idx, self._v_idx)]
        M_inv_JT = np.linalg.solve(M, J.T)
        Lambda = np.linalg.inv(J @ M_inv_JT + 1e-6 * np.eye(6))
        # Desired tool acceleration minus the part J-dot v that joint velocities already produce.
        Jdot_v = plant.CalcBiasSpatialAcceleration(
            pc, JacobianWrtVariable.kV, self._tool, np.zeros(3), plant.world_frame(), plant.world_frame()
        ).get_coeffs()
        A_desired = self._optional(self._acceleration_port, context)
        tau = J.T @ (wrench + Lambda @ (A_desired - Jdot_v))
        # Null-space posture through Khatib's dynamically consistent projector
        # N^T = I - J^T Lambda J M^-1: it produces no acceleration of the tool frame.
        N_T = np.eye(n) - J.T @ Lambda @ M_inv_JT.T
        tau_null = g.nullspace_stiffness * (self._q_nominal - q) - g.nullspace_damping * v
        if g.limit_stiffness > 0:
            tau_null = tau_null + self._limit_torque(q)
        tau += N_T @ tau_null
        # Model compensation: gravity, Coriolis/centripetal terms and viscous joint friction.
        tau -= plant.CalcGravityGeneralizedForces(pc)[self._v_idx]
        tau += plant.CalcBiasTerm(pc)[self._v_idx] + self._joint_damping * v
        out.torque = np.clip(tau, -self._tau_max, self._tau_max)
        out.wrench = wrench

    def _limit_torque(self, q: np.ndarray) -> np.ndarray:
        return limit_avoidance_torque(q, self._q_min, self._q_max, self._gains)

    def joint_limit_margin(self, q: np.ndarray) -> np.ndarray:
        """Each arm joint's distance to its nearer position limit [rad] at positions q."""
        return distance_to_limits(q, self._q_min, self._q_max)


def arm_position_limits(plant: MultibodyPlant, arm: ModelInstanceIndex) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices into the plant's positions, lower limits, upper limits) of the joints of model
    instance `arm` that have positions, in joint order."""
    idx = np.array(
        [
            plant.get_joint(j).position_start() + k
            for j in plant.GetJointIndices(arm)
            for k in range(plant.get_joint(j).num_positions())
        ],
        dtype=int,
    )
    return idx, plant.GetPositionLowerLimits()[idx], plant.GetPositionUpperLimits()[idx]


def arm_velocity_columns(plant: MultibodyPlant, arm: ModelInstanceIndex) -> np.ndarray:
    """Indices into the plant's velocities (the columns of its Jacobians) of the joints of model
    instance `arm`, in joint order."""
    return np.array(
        [
            plant.get_joint(j).velocity_start() + k
            for j in plant.GetJointIndices(arm)
            for k in range(plant.get_joint(j).num_velocities())
        ],
        dtype=int,
    )


def tool_jacobian(plant: MultibodyPlant, context: Context, tool: Frame, columns: np.ndarray) -> np.ndarray:
    """The `tool` frame's spatial-velocity Jacobian [w; v] in the world frame at the state in
    `context`, restricted to the velocity `columns` (an arm's: `arm_velocity_columns`), (6, n)."""
    J = plant.CalcJacobianSpatialVelocity(
        context, JacobianWrtVariable.kV, tool, np.zeros(3), plant.world_frame(), plant.world_frame()
    )
    return J[:, columns]


def distance_to_limits(q: np.ndarray, q_min: np.ndarray, q_max: np.ndarray) -> np.ndarray:
    """Each joint's distance to its nearer position limit [rad] at positions q (negative beyond)."""
    q = np.asarray(q, dtype=float)
    return np.minimum(q - q_min, q_max - q)


def limit_avoidance_torque(q: np.ndarray, q_min: np.ndarray, q_max: np.ndarray, gains: ImpedanceGains) -> np.ndarray:
    """Joint-limit avoidance: gains.limit_stiffness times each joint's depth in the band of width
    gains.limit_margin inside its limits [q_min, q_max], pushing it out; exactly zero outside the
    bands (and everywhere when limit_stiffness is 0)."""
    m = gains.limit_margin
    return gains.limit_stiffness * (np.maximum(m - (q - q_min), 0.0) - np.maximum(m - (q_max - q), 0.0))


class _Solution:
    """Cached result of one controller evaluation."""

    def __init__(self, n: int) -> None:
        self.torque = np.zeros(n)
        self.wrench = np.zeros(6)
