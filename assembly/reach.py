"""Where the arm gets to, predicted without dynamics: the controller's redundancy resolution as a
quasi-static tracker, so that a motion's target can be chosen reachable before it is played
(the inspect yaw in `assembly.inspection`; docs/planning.md, "Reach")."""

from __future__ import annotations

import numpy as np
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import JacobianWrtVariable

from assembly.impedance import (
    ImpedanceGains,
    arm_position_limits,
    distance_to_limits,
    limit_avoidance_torque,
    rotation_error,
)
from assembly.panda_model import Q_HOME
from assembly.station import make_controller_plant

__all__ = ["QuasiStaticTracker", "predicted_posture", "shared_tracker", "turns_by_size"]


class QuasiStaticTracker:
    """Where the controller's redundancy goes, without dynamics: the arm tracking a straight-line
    (slerp) tool move quasi-statically, each step a damped least-squares step onto the path with
    the posture task and the joint-limit avoidance of `gains` in the Jacobian's null space, the
    joints clipped at their limits as the plant's are. `track` returns the final joint positions
    and the tool's distance from the target there: a pose the controller would stop short of shows
    up as a joint on its limit and a residual error (used to choose reachable inspect poses)."""

    def __init__(self, gains: ImpedanceGains | None = None, q_nominal: np.ndarray | None = None) -> None:
        self._plant, self._arm, self._tool = make_controller_plant()
        self._context = self._plant.CreateDefaultContext()
        self._gains = gains or ImpedanceGains()
        self._q_nominal = np.asarray(Q_HOME if q_nominal is None else q_nominal, dtype=float)
        self._idx, self._q_min, self._q_max = arm_position_limits(self._plant, self._arm)

    def margin(self, q: np.ndarray) -> np.ndarray:
        """Each joint's distance to its nearer position limit [rad]."""
        return distance_to_limits(q, self._q_min, self._q_max)

    def tool_pose(self, q: np.ndarray) -> RigidTransform:
        self._plant.SetPositions(self._context, self._arm, q)
        return self._tool.CalcPoseInWorld(self._context)

    def track(
        self, q0: np.ndarray, X_to: RigidTransform, steps: int = 30, settle: int = 60
    ) -> tuple[np.ndarray, float]:
        """(q, error [m]) after a straight move from FK(q0) to X_to in `steps` and `settle` more
        steps of holding X_to."""
        g = self._gains
        q = np.clip(np.asarray(q0, dtype=float), self._q_min, self._q_max)
        X_from = self.tool_pose(q)
        R_ab = X_from.rotation().inverse() @ X_to.rotation()
        aa = R_ab.ToAngleAxis()
        plant, pc = self._plant, self._context
        # Null-space gains per step: the posture's and the limit band's stiffness relative to the
        # Cartesian spring's, so that their ratio matches the controller's.
        k_scale = 1.0 / max(float(np.min(g.stiffness[3:])), 1e-9)
        for k in range(steps + settle):
            s = min((k + 1) / steps, 1.0)
            R = X_from.rotation() @ RotationMatrix(AngleAxis(s * aa.angle(), aa.axis()))
            p = X_from.translation() + s * (X_to.translation() - X_from.translation())
            plant.SetPositions(pc, self._arm, q)
            X = self._tool.CalcPoseInWorld(pc)
            J = plant.CalcJacobianSpatialVelocity(
                pc, JacobianWrtVariable.kV, self._tool, np.zeros(3), plant.world_frame(), plant.world_frame()
            )[:, self._idx]
            e = np.concatenate([rotation_error(R.matrix(), X.rotation().matrix()), p - X.translation()])
            J_pinv = J.T @ np.linalg.inv(J @ J.T + 1e-4 * np.eye(6))
            N = np.eye(len(q)) - J_pinv @ J
            push = g.nullspace_stiffness * (self._q_nominal - q) + limit_avoidance_torque(
                q, self._q_min, self._q_max, g
            )
            dq = J_pinv @ e + N @ (k_scale * push)
            q = np.clip(q + np.clip(dq, -0.1, 0.1), self._q_min, self._q_max)
        return q, float(np.linalg.norm(self.tool_pose(q).translation() - X_to.translation()))


_SHARED_TRACKER: QuasiStaticTracker | None = None


def shared_tracker() -> QuasiStaticTracker:
    """One QuasiStaticTracker with the default gains and posture, made on first use (the planner's
    inspect and pick choices share it)."""
    global _SHARED_TRACKER
    if _SHARED_TRACKER is None:
        _SHARED_TRACKER = QuasiStaticTracker()
    return _SHARED_TRACKER


def predicted_posture(X_WT: RigidTransform) -> np.ndarray:
    """Where the arm's redundancy has left it with the tool at X_WT, as the planner guesses it
    without joint measurements: the shared tracker's joints after a move there from Q_HOME."""
    return shared_tracker().track(Q_HOME, X_WT)[0]


def turns_by_size(step: float, max_turn: float) -> list[float]:
    """Turns [rad] ordered by size: 0, +step, -step, +2 step, ... up to max_turn either way, a turn
    of pi once (+pi and -pi are one heading). The candidates of a reachable choice, nearest first."""
    n = int(np.floor(max_turn / step + 1e-9))
    turns = [0.0]
    for k in range(1, n + 1):
        for sign in (1.0, -1.0):
            turn = sign * k * step
            if abs(abs(turn) - np.pi) < 1e-9 and any(abs(abs(t) - np.pi) < 1e-9 for t in turns):
                continue
            turns.append(turn)
    return turns
