"""The nominal Panda arm model the diagnosis replays logs against, and its terms taken apart.

The model is the project's own Panda (assembly/panda_model.py): rigid links with Gaz et al.'s
inertias, the end effector the log names (none, the hand, the hand holding a gear), the reflected
rotor inertia and the viscous joint damping. `ArmModel.terms` evaluates each term separately at
the logged states, so the diagnosis can ask which of them the log supports (the model audit).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from assembly.panda_model import JOINT_DAMPING, REFLECTED_INERTIA
from assembly.world import X_FLANGE_HAND, add_held_gear, model_parser, tool_frame
from assembly.panda_model import panda_model_paths
from goflow_common.checks import check_choice
from goflow_common.errors import InputError

__all__ = ["END_EFFECTORS", "ArmTerms", "arm_plant", "ArmModel"]

#: End effectors a log may name in meta["end_effector"].
END_EFFECTORS: tuple[str, ...] = ("none", "hand", "hand+gear_small", "hand+gear_medium", "hand+gear_large")
N_ARM = 7


def arm_plant(end_effector: str = "hand", time_step: float = 0.0) -> tuple[MultibodyPlant, ModelInstanceIndex]:
    """A finalized plant of the Panda arm welded to the world at its base, with `end_effector`
    (one of END_EFFECTORS) welded to the flange; the arm's 7 joints come first in q and v.
    Returns (plant, arm instance). The plant has no scene graph (no geometry queries)."""
    check_choice(end_effector, END_EFFECTORS, "end_effector")
    plant = MultibodyPlant(time_step)
    arm_urdf, hand_urdf = panda_model_paths()
    parser = model_parser(plant)
    arm = parser.AddModels(str(arm_urdf))[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0", arm))
    if end_effector != "none":
        hand = parser.AddModels(str(hand_urdf))[0]
        plant.WeldFrames(
            plant.GetFrameByName("panda_link8", arm), plant.GetFrameByName("panda_hand", hand), X_FLANGE_HAND
        )
        if end_effector.startswith("hand+gear_"):
            add_held_gear(plant, end_effector.split("_", 1)[1], tool_frame(plant, hand))
    plant.Finalize()
    return plant, arm


@dataclasses.dataclass(frozen=True)
class ArmTerms:
    """The nominal model's torque terms at T logged samples, each (T, 7) [N m].

    rigid: M_links(q) ddq + C(q, dq) dq - g(q) of the links and end effector;
    rotor: the reflected rotor inertia's diag(I_r) ddq; damping: the joint damping's D dq.
    mass: (T, 7, 7) the links' mass matrix (without rotor inertia), for forward replay."""

    rigid: NDArray[np.float64]
    rotor: NDArray[np.float64]
    damping: NDArray[np.float64]
    mass: NDArray[np.float64]

    @property
    def total(self) -> NDArray[np.float64]:
        return self.rigid + self.rotor + self.damping


class ArmModel:
    """The nominal arm with `end_effector`; `terms(q, dq, ddq)` evaluates its torque terms."""

    def __init__(self, end_effector: str = "hand") -> None:
        self.end_effector = end_effector
        self.plant, self.arm = arm_plant(end_effector)
        self.context = self.plant.CreateDefaultContext()
        for index in self.plant.GetJointActuatorIndices():  # rotor inertia is its own term
            self.plant.get_joint_actuator(index).SetRotorInertia(self.context, 0.0)
        self.nq = self.plant.num_positions()
        self.reflected_inertia = REFLECTED_INERTIA.copy()
        self.damping = JOINT_DAMPING.copy()
        self.flange = self.plant.GetFrameByName("panda_link8", self.arm)

    def _state(self, q: NDArray[np.float64], dq: NDArray[np.float64]) -> None:
        x = np.zeros(2 * self.nq)
        x[:N_ARM] = q
        x[self.nq : self.nq + N_ARM] = dq
        if self.nq > N_ARM:  # fingers held half open and still
            x[N_ARM : self.nq] = 0.02
        self.plant.SetPositionsAndVelocities(self.context, x)

    def terms(self, q: NDArray[np.float64], dq: NDArray[np.float64], ddq: NDArray[np.float64]) -> ArmTerms:
        """The nominal torque terms at each sample of (T, 7) arrays q, dq, ddq."""
        q, dq, ddq = (np.asarray(a, dtype=np.float64) for a in (q, dq, ddq))
        if q.ndim != 2 or q.shape[1] != N_ARM or dq.shape != q.shape or ddq.shape != q.shape:
            raise InputError(f"q, dq, ddq have shapes {q.shape}, {dq.shape}, {ddq.shape}; expected (T, {N_ARM}) each")
        T = q.shape[0]
        rigid = np.empty((T, N_ARM))
        mass = np.empty((T, N_ARM, N_ARM))
        for k in range(T):
            self._state(q[k], dq[k])
            M = self.plant.CalcMassMatrix(self.context)[:N_ARM, :N_ARM]
            bias = self.plant.CalcBiasTerm(self.context)[:N_ARM]
            grav = self.plant.CalcGravityGeneralizedForces(self.context)[:N_ARM]
            mass[k] = M
            rigid[k] = M @ ddq[k] + bias - grav
        return ArmTerms(rigid=rigid, rotor=ddq * self.reflected_inertia, damping=dq * self.damping, mass=mass)

    def flange_kinematics(
        self, q: NDArray[np.float64], dq: NDArray[np.float64], ddq: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Per sample: the flange's spatial Jacobian J (T, 6, 7) (angular rows first, expressed
        in the flange frame, about the flange origin), its angular velocity w (T, 3), angular
        acceleration alpha (T, 3) and the origin's linear acceleration minus gravity a (T, 3),
        all in the flange frame. They make the payload regressor (sim2real/effects.py)."""
        from pydrake.multibody.tree import JacobianWrtVariable

        T = q.shape[0]
        J = np.empty((T, 6, N_ARM))
        w = np.empty((T, 3))
        alpha = np.empty((T, 3))
        a = np.empty((T, 3))
        g_W = self.plant.gravity_field().gravity_vector()
        world = self.plant.world_frame()
        for k in range(T):
            self._state(q[k], dq[k])
            R_WF = self.flange.CalcPoseInWorld(self.context).rotation().matrix()
            Jw = self.plant.CalcJacobianSpatialVelocity(
                self.context, JacobianWrtVariable.kV, self.flange, np.zeros(3), world, world
            )[:, :N_ARM]
            bias = self.plant.CalcBiasSpatialAcceleration(
                self.context, JacobianWrtVariable.kV, self.flange, np.zeros(3), world, world
            )
            A = Jw @ ddq[k] + np.concatenate([bias.rotational(), bias.translational()])
            V = Jw @ dq[k]
            J[k, :3] = R_WF.T @ Jw[:3]
            J[k, 3:] = R_WF.T @ Jw[3:]
            w[k] = R_WF.T @ V[:3]
            alpha[k] = R_WF.T @ A[:3]
            a[k] = R_WF.T @ (A[3:] - g_W)
        return J, w, alpha, a
