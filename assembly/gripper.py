"""Position control of the Panda's two fingers through Drake's implicit PD actuators."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JointActuatorIndex, ModelInstanceIndex, PdControllerGains
from pydrake.systems.framework import Context, LeafSystem

from assembly.panda_model import FINGER_MAX_WIDTH


@dataclass
class GripperGains:
    """Per-finger PD gains. The finger actuators' effort limit caps the grasp force."""

    kp: float = 2000.0  # N/m
    kd: float = 60.0  # N s/m


def set_gripper_gains(plant: MultibodyPlant, hand: ModelInstanceIndex, gains: GripperGains) -> None:
    """Make the hand's finger actuators PD-controlled (solved implicitly by the discrete solver)."""
    # (GetJointActuatorIndices(instance) is empty before Finalize: scan all actuators instead.)
    for i in range(plant.num_actuators()):
        actuator = plant.get_mutable_joint_actuator(JointActuatorIndex(i))
        if actuator.model_instance() == hand:
            actuator.set_controller_gains(PdControllerGains(p=gains.kp, d=gains.kd))


class GripperCommand(LeafSystem):
    """Maps a commanded finger-to-finger width [m] to the hand's desired state [q1, q2, v1, v2].

    A width below the object's size squeezes it: the PD force saturates at the actuators' limit.
    """

    def __init__(self) -> None:
        super().__init__()
        self._width = self.DeclareVectorInputPort("width", 1)
        self.DeclareVectorOutputPort("desired_state", 4, self._calc)

    def _calc(self, context: Context, output) -> None:
        w = float(self._width.Eval(context)[0])
        if not np.isfinite(w):
            raise RuntimeError(f"GripperCommand: non-finite width command {w}")
        half = 0.5 * float(np.clip(w, -0.02, FINGER_MAX_WIDTH))
        output.SetFromVector([half, half, 0.0, 0.0])
