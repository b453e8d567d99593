"""The reduced gear-insertion model (GearInsertion-v0, variant "fast"), made for training speed.

The Panda is replaced by its tool frame on four actuated joints (x, y, z prismatic, yaw revolute),
with the tool pointing down. The same impedance law acts on them: each joint is a PD actuator with
the station's stiffness and damping, solved implicitly by Drake's discrete solver (no Python in
the physics loop), and each joint carries as reflected inertia the Panda's apparent (operational-
space) inertia at the insertion pose, so the reduced tool is as heavy as the arm feels. Gravity on
the tool and gear is cancelled by a constant feedforward force, as the station's controller does.

Contact spends resolution only where insertion needs it: the gear's rigid mesh meets the
compliant shafts hydroelastically, while the plate is a point-contact box (the gear's flat bottom
on a compliant plate is what dominates the full station's cost; measured in
docs/models.md#contact-geometry-and-speed). The hand's own geometry is not modelled: only the held
gear touches anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddContactMaterial,
    Box,
    Convex,
    ProximityProperties,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    CoulombFriction,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import (
    FixedOffsetFrame,
    PdControllerGains,
    PrismaticJoint,
    RevoluteJoint,
    SpatialInertia,
    UnitInertia,
)
from pydrake.systems.framework import Diagram, DiagramBuilder

from assembly.gear_meshes import PLATE_CONTACT, SHAFT_CONTACT, gearset_model_paths
from assembly.gearset import GEAR_NAMES, PLATE_SIZE, shaft_position_in_plate
from assembly.impedance import ImpedanceGains
from assembly.world import HeldGear, add_held_gear, planar_pose

# Mass and inertia of the moving tool (the Panda hand, 0.73 kg + 2 x 0.015 kg fingers).
TOOL_MASS = 0.76
GRAVITY = 9.81
JOINT_NAMES = ("tool_x", "tool_y", "tool_z", "tool_yaw")


@dataclass
class FastInsertionConfig:
    """The reduced model's physics."""

    gear: str = "medium"
    plate_pose: tuple[float, float, float] = (0.55, 0.0, np.pi / 2)
    time_step: float = 0.008
    gains: ImpedanceGains = field(default_factory=ImpedanceGains)
    # Reflected inertia per joint [kg, kg, kg, kg m^2]: the Panda's operational-space inertia at
    # the insertion pose (assembly.envs.gear_insertion measures it; these are its values for the
    # default plate pose, rounded).
    apparent_inertia: tuple[float, float, float, float] = (8.0, 8.0, 8.0, 0.25)
    effort_limit: tuple[float, float, float, float] = (100.0, 100.0, 100.0, 12.0)


@dataclass
class FastInsertionModel:
    """Handles into the built reduced model."""

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    held: HeldGear
    X_WP: RigidTransform
    config: FastInsertionConfig

    def X_WS(self, gear: str) -> RigidTransform:
        return self.X_WP @ RigidTransform(shaft_position_in_plate(gear))

    def joint_positions_for(self, X_WT: RigidTransform) -> np.ndarray:
        """Joint positions (x, y, z, yaw) that put the tool at X_WT (tool z must point down)."""
        R = X_WT.rotation().matrix()
        return np.array([*X_WT.translation(), np.arctan2(R[1, 0], R[0, 0])])

    @staticmethod
    def tool_pose_of(q: np.ndarray) -> RigidTransform:
        """Tool pose for joint positions (x, y, z, yaw)."""
        return RigidTransform(RotationMatrix.MakeZRotation(q[3]) @ RotationMatrix.MakeXRotation(np.pi), q[:3])


def _proximity(contact, compliant: bool) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(
        contact.hunt_crossley_dissipation, None, CoulombFriction(contact.mu_static, contact.mu_dynamic), props
    )
    if compliant:
        AddCompliantHydroelasticProperties(contact.mesh_resolution_hint, contact.hydroelastic_modulus, props)
    return props


def add_fast_fixtures(plant: MultibodyPlant, config: FastInsertionConfig) -> RigidTransform:
    """Add the plate (a point-contact box) and its shafts (compliant convex meshes, as in the
    station's plate model) to the world of an unfinalized plant; return the plate pose X_WP."""
    X_WP = planar_pose(*config.plate_pose)
    world = plant.world_body()
    plate_props = _proximity(PLATE_CONTACT, compliant=False)
    plant.RegisterCollisionGeometry(
        world, X_WP @ RigidTransform([0, 0, PLATE_SIZE[2] / 2]), Box(*PLATE_SIZE), "plate", plate_props
    )
    shaft_mesh = gearset_model_paths()["plate"].parent / "meshes" / "shaft_collision.obj"
    for name in GEAR_NAMES:
        plant.RegisterCollisionGeometry(
            world,
            X_WP @ RigidTransform(shaft_position_in_plate(name)),
            Convex(str(shaft_mesh)),
            f"shaft_{name}",
            _proximity(SHAFT_CONTACT, compliant=True),
        )
    return X_WP


def add_fast_tool(plant: MultibodyPlant, config: FastInsertionConfig, instance=None) -> tuple[Any, HeldGear]:
    """Add the tool on x, y, z, yaw joints (PD-actuated, with the Panda's reflected inertia) and the
    gear it holds to an unfinalized plant, the tool in model instance `instance` (default: the
    plant's default instance; another instance numbers the gear's instance); return (tool body,
    HeldGear)."""
    from pydrake.multibody.tree import default_model_instance

    copy = instance is not None
    instance = default_model_instance() if instance is None else instance
    world = plant.world_body()
    inertia = SpatialInertia(1e-3, np.zeros(3), UnitInertia.SolidSphere(0.01))
    links = [plant.AddRigidBody(f"{n}_link", instance, inertia) for n in JOINT_NAMES[:3]]
    tool = plant.AddRigidBody(
        "tool", instance, SpatialInertia(TOOL_MASS, np.zeros(3), UnitInertia.SolidBox(0.06, 0.2, 0.06))
    )
    parents = [world] + links
    children = links + [tool]
    axes = [np.array(a, dtype=float) for a in ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
    joints = []
    for k, name in enumerate(JOINT_NAMES):
        if k < 3:
            joint = PrismaticJoint(name, parents[k].body_frame(), children[k].body_frame(), axes[k])
        else:
            joint = RevoluteJoint(name, parents[k].body_frame(), children[k].body_frame(), [0, 0, 1])
        joints.append(plant.AddJoint(joint))
        actuator = plant.AddJointActuator(f"{name}_motor", joints[-1], config.effort_limit[k])
        actuator.set_default_rotor_inertia(config.apparent_inertia[k])
        K = config.gains.stiffness[3 + k] if k < 3 else config.gains.stiffness[2]
        D = config.gains.damping[3 + k] if k < 3 else config.gains.damping[2]
        actuator.set_controller_gains(PdControllerGains(p=float(K), d=float(D)))
    tcp = plant.AddFrame(
        FixedOffsetFrame(
            "tool_tcp", tool.body_frame(), RigidTransform(RotationMatrix.MakeXRotation(np.pi), np.zeros(3))
        )
    )
    return tool, add_held_gear(plant, config.gear, tcp, auto_renaming=copy)


def fast_plant_config(config: FastInsertionConfig) -> MultibodyPlantConfig:
    """The reduced model's plant: discrete at config.time_step, hydroelastic with point-contact
    fallback, SAP "lagged"."""
    return MultibodyPlantConfig(
        time_step=config.time_step, contact_model="hydroelastic_with_fallback", discrete_contact_approximation="lagged"
    )


def build_fast_insertion(config: FastInsertionConfig | None = None) -> FastInsertionModel:
    """Build the reduced insertion Diagram. Its exported inputs: "desired_state" (8: q_d, v_d for
    x, y, z, yaw) and "feedforward" (4); output "state" (8)."""
    config = config or FastInsertionConfig()
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(fast_plant_config(config), builder)
    X_WP = add_fast_fixtures(plant, config)
    tool, held = add_fast_tool(plant, config)
    plant.Finalize()

    builder.ExportInput(plant.get_desired_state_input_port(tool.model_instance()), "desired_state")
    builder.ExportInput(plant.get_actuation_input_port(tool.model_instance()), "feedforward")
    builder.ExportOutput(plant.get_state_output_port(tool.model_instance()), "state")
    builder.ExportOutput(plant.get_contact_results_output_port(), "contact_results")
    diagram = builder.Build()
    diagram.set_name("fast_insertion")
    return FastInsertionModel(diagram, plant, scene_graph, held, X_WP, config)


def gravity_feedforward(model: FastInsertionModel) -> np.ndarray:
    """Constant actuation that holds the tool and gear up against gravity (z joint)."""
    held_mass = sum(model.plant.get_body(b).default_mass() for b in model.plant.GetBodyIndices(model.held.instance))
    return np.array([0.0, 0.0, (TOOL_MASS + held_mass + 3e-3) * GRAVITY, 0.0])
