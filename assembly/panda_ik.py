"""Inverse kinematics of the Panda's tool frame (for start configurations)."""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.solvers import Solve

from assembly.impedance import arm_position_limits, arm_velocity_columns, tool_jacobian
from assembly.panda_model import Q_HOME


def solve_tool_ik(
    X_WT: RigidTransform, q_nominal: np.ndarray | None = None, position_tol: float = 1e-5, angle_tol: float = 1e-4
) -> np.ndarray:
    """Arm joint positions (7) that put the tool frame at X_WT, closest to q_nominal (Q_HOME by
    default); ValueError if the pose is unreachable."""
    from assembly.station import make_controller_plant  # the controller's arm+hand model

    plant, arm, tool = make_controller_plant()
    q_nominal = Q_HOME if q_nominal is None else np.asarray(q_nominal, dtype=float)
    ik = InverseKinematics(plant)
    q = ik.q()
    p = X_WT.translation()
    ik.AddPositionConstraint(tool, np.zeros(3), plant.world_frame(), p - position_tol, p + position_tol)
    ik.AddOrientationConstraint(
        tool, X_WT.rotation().inverse() @ X_WT.rotation(), plant.world_frame(), X_WT.rotation(), angle_tol
    )
    arm_idx = arm_position_limits(plant, arm)[0]
    guess = plant.GetPositions(plant.CreateDefaultContext()).copy()
    guess[arm_idx] = q_nominal
    ik.prog().AddQuadraticErrorCost(np.eye(len(arm_idx)), q_nominal, q[arm_idx])
    result = Solve(ik.prog(), guess)
    if not result.is_success():
        raise ValueError(
            f"tool pose {np.round(p, 4).tolist()} has no inverse-kinematics solution within the Panda's joint limits"
        )
    return result.GetSolution(q)[arm_idx]


def panda_jacobian_at(X_WT: RigidTransform) -> np.ndarray:
    """The Panda tool's spatial-velocity Jacobian (6, 7) [w; v] in the world frame at the
    inverse-kinematics solution for tool pose X_WT (`solve_tool_ik`); ValueError if X_WT is out
    of reach."""
    from assembly.station import make_controller_plant

    plant, arm, tool = make_controller_plant()
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, arm, solve_tool_ik(X_WT))
    return tool_jacobian(plant, context, tool, arm_velocity_columns(plant, arm))
