"""The station Diagram: plant + scene graph (hydroelastic), impedance-controlled Panda, gripper,
RGB-D cameras and, optionally, Meshcat.

Exported ports of `Station.diagram`:
  inputs  "X_WT_desired" (abstract RigidTransform) hand-tool target; "V_WT_desired" and
          "A_WT_desired" (6 each, optional) its velocity and acceleration feedforward [w; v],
          [alpha; a]; "gripper_width" (1) [m].
  outputs "arm_state" (14), "hand_state" (4), "X_WT" (abstract RigidTransform), "wrench" (6),
          "torque" (7), "body_poses", "contact_results", "tau_contact" (7: the joint torques contact
          puts on the arm), "tool_jacobian" (42: the tool's (6, 7) Jacobian, row-major),
          "external_wrench" (4: libfranka's estimate of the external wrench at the tool, Fx, Fy,
          Fz [N], Mz [N m], with StationConfig.wrench_sensor's errors; assembly.wrench_sensor),
          and per camera "<name>_rgb", "<name>_depth" (32-bit float metres), "<name>_label".
With WorldConfig.grasp_hold, a GraspAnchor moves the hold's spring rest points as the gear slips.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    Meshcat,
    MeshcatParams,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.sensors import RgbdSensor

from assembly.cameras import CamerasConfig, add_camera
from assembly.gearset import gear_spec
from assembly.gripper import GripperCommand, GripperGains, set_gripper_gains
from assembly.impedance import CartesianImpedanceController, ImpedanceGains
from assembly.panda_model import Q_HOME, TAU_MAX
from assembly.rgbd_sensor import CameraSensor, RgbdSensorNoise
from assembly.wrench_sensor import WRENCH_MODELS, ExternalWrenchEstimate, ToolJacobian
from goflow_common.checks import check_choice, check_number
from assembly.world import (
    GraspHold,
    WorldConfig,
    WorldModels,
    add_panda,
    add_world,
    gear_body,
    insertion_error,
    is_seated,
    tool_frame,
)


@dataclass
class StationConfig:
    """Everything that shapes the station. Time step and contact approximation were chosen by the
    measurement in docs/station.md (benchmarks/sim_speed.py). wrench_sensor: the errors of the
    "external_wrench" estimate (assembly.wrench_sensor.WRENCH_MODELS: "panda" or "ideal"), its
    noise sized for samples every `wrench_period` [s], drawn from `wrench_seed`."""

    world: WorldConfig = field(default_factory=WorldConfig)
    time_step: float = 0.008
    contact_model: str = "hydroelastic_with_fallback"
    discrete_contact_approximation: str = "lagged"
    gains: ImpedanceGains = field(default_factory=ImpedanceGains)
    gripper: GripperGains = field(default_factory=GripperGains)
    cameras: CamerasConfig = field(default_factory=CamerasConfig)
    sensors: dict[str, CameraSensor] = field(default_factory=dict)
    wrench_sensor: str = "panda"
    wrench_period: float = 0.04
    wrench_seed: int = 0

    def __post_init__(self) -> None:
        check_choice(self.wrench_sensor, WRENCH_MODELS, "StationConfig.wrench_sensor")
        check_number(self.wrench_period, "StationConfig.wrench_period", 0.0, low_open=True)
        if not (np.isfinite(self.time_step) and 0 < self.time_step <= 0.02):
            raise ValueError(f"time_step = {self.time_step}; expected a discrete step in (0, 0.02] s")
        allowed = ("hydroelastic_with_fallback", "hydroelastic", "point")
        if self.contact_model not in allowed:
            raise ValueError(f"contact_model = {self.contact_model!r}; expected one of {allowed}")
        approx = ("lagged", "similar", "sap", "tamsi")
        if self.discrete_contact_approximation not in approx:
            raise ValueError(
                f"discrete_contact_approximation = {self.discrete_contact_approximation!r}; expected one of {approx}"
            )
        names = [c.name for c in (self.cameras.scene, self.cameras.wrist) if c is not None]
        unknown = [n for n in self.sensors if n not in names]
        if unknown or not all(isinstance(s, CameraSensor) for s in self.sensors.values()):
            raise ValueError(f"sensors for {list(self.sensors)}; expected CameraSensors for cameras among {names}")


@dataclass
class InsertionError:
    """Where a gear is relative to its shaft's seated pose."""

    lateral_m: float
    height_m: float  # signed: positive above the seated height

    @property
    def inserted(self) -> bool:
        return is_seated(self.lateral_m, self.height_m)


@dataclass
class Station:
    """A built station and handles into it."""

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    models: WorldModels
    controller: CartesianImpedanceController
    cameras: dict[str, RgbdSensor]
    config: StationConfig
    meshcat_visualizer: MeshcatVisualizer | None = None
    grasp_anchor: GraspAnchor | None = None  # with WorldConfig.grasp_hold

    def plant_context(self, root: Context) -> Context:
        return self.plant.GetMyContextFromRoot(root)

    def gear_pose(self, root: Context, gear: str) -> RigidTransform:
        """World pose X_WG of a gear's frame."""
        return gear_body(self.plant, self._gear(gear)).EvalPoseInWorld(self.plant_context(root))

    def set_gear_pose(self, root: Context, gear: str, X_WG: RigidTransform) -> None:
        """Place a gear (zero velocity)."""
        body = gear_body(self.plant, self._gear(gear))
        pc = self.plant.GetMyMutableContextFromRoot(root)
        self.plant.SetFreeBodyPose(pc, body, X_WG)
        self.plant.SetFreeBodySpatialVelocity(pc, body, SpatialVelocity(np.zeros(6)))  # () is NaN

    def insertion_error(self, root: Context, gear: str) -> InsertionError:
        """Lateral and height error of a gear's frame from its seated pose on its shaft."""
        return InsertionError(*insertion_error(self.models.X_WS(gear).inverse(), self.gear_pose(root, gear)))

    def tool_pose(self, root: Context) -> RigidTransform:
        """Measured pose X_WT of the hand's tool frame."""
        return self.diagram.GetOutputPort("X_WT").Eval(self.diagram.GetMyContextFromRoot(root))

    def set_grasp(self, root: Context, X_TG: RigidTransform) -> None:
        """Set the held gear's pose in the tool frame (WorldConfig.held_gear); with a GraspHold,
        the hold's joints, velocities and spring rest points are zeroed too (no slip yet)."""
        held = self.models.held
        if held is None:
            raise ValueError("this station holds no gear; build it with WorldConfig(held_gear=...)")
        pc = self.plant.GetMyMutableContextFromRoot(root)
        if held.hold_instance is None:
            held.grasp_frame.SetPoseInParentFrame(pc, X_TG)
            return
        held.grasp_frame.SetPoseInParentFrame(pc, X_TG.inverse())
        self.plant.SetPositions(pc, held.hold_instance, np.zeros(3))
        self.plant.SetVelocities(pc, held.hold_instance, np.zeros(3))
        self.grasp_anchor.GetMyMutableContextFromRoot(root).SetDiscreteState(np.zeros(3))

    def _gear(self, gear: str):
        gear_spec(gear)
        if self.models.held is not None and gear == self.models.held.name:
            return self.models.held.instance
        if gear not in self.models.gears:
            raise ValueError(f"gear {gear!r} is not in this station; it has {sorted(self.models.gears)}")
        return self.models.gears[gear]


class GraspAnchor(LeafSystem):
    """The rest points of a GraspHold's springs, moved as the gear slips (elastic-plastic friction).

    Ports: input "hold_state" (6) the hold joints' [q, v]; output "desired_state" (6) [anchor, 0]
    for the plant's PD actuators. Every `period` the anchor a is pulled to within the elastic
    range of q: a <- q - clip(q - a, -limit / stiffness, +limit / stiffness), so that a spring at
    its effort limit moves with the gear and the slip stays when the load goes.
    """

    def __init__(self, hold: GraspHold, period: float) -> None:
        super().__init__()
        self._slack = hold.limits() / hold.stiffnesses()
        self._state = self.DeclareVectorInputPort("hold_state", 6)
        self.DeclareDiscreteState(3)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("desired_state", 6, self._calc, prerequisites_of_calc={self.xd_ticket()})

    def _update(self, context: Context, xd) -> None:
        q = self._state.Eval(context)[:3]
        a = context.get_discrete_state_vector().CopyToVector()
        xd.set_value(q - np.clip(q - a, -self._slack, self._slack))

    def _calc(self, context: Context, output) -> None:
        output.SetFromVector(np.r_[context.get_discrete_state_vector().CopyToVector(), np.zeros(3)])


def make_controller_plant() -> tuple[MultibodyPlant, object, object]:
    """A continuous plant holding only the Panda (arm + hand) for the controller's kinematics and
    gravity model. Returns (plant, arm instance, tool frame)."""
    plant = MultibodyPlant(0.0)
    arm, hand = add_panda(plant)
    plant.Finalize()
    return plant, arm, tool_frame(plant, hand)


def build_station(config: StationConfig | None = None, meshcat: Meshcat | None = None) -> Station:
    """Build the station Diagram described by `config`; attach Meshcat if one is given."""
    config = config or StationConfig()
    builder = DiagramBuilder()
    plant_config = MultibodyPlantConfig(
        time_step=config.time_step,
        contact_model=config.contact_model,
        discrete_contact_approximation=config.discrete_contact_approximation,
    )
    plant, scene_graph = AddMultibodyPlant(plant_config, builder)
    plant.set_name("plant")
    models = add_world(plant, scene_graph, config.world)
    set_gripper_gains(plant, models.hand, config.gripper)
    plant.Finalize()

    ctrl_plant, ctrl_arm, ctrl_tool = make_controller_plant()
    controller = builder.AddSystem(
        CartesianImpedanceController(ctrl_plant, ctrl_arm, ctrl_tool, config.gains, TAU_MAX, Q_HOME)
    )
    controller.set_name("impedance_controller")
    builder.Connect(plant.get_state_output_port(models.arm), controller.get_input_port(0))
    builder.Connect(controller.GetOutputPort("torque"), plant.get_actuation_input_port(models.arm))
    gripper = builder.AddSystem(GripperCommand())
    gripper.set_name("gripper_command")
    builder.Connect(gripper.get_output_port(0), plant.get_desired_state_input_port(models.hand))
    anchor = None
    if config.world.grasp_hold is not None:
        anchor = builder.AddSystem(GraspAnchor(config.world.grasp_hold, config.time_step))
        anchor.set_name("grasp_anchor")
        builder.Connect(plant.get_state_output_port(models.held.hold_instance), anchor.get_input_port(0))
        builder.Connect(anchor.get_output_port(0), plant.get_desired_state_input_port(models.held.hold_instance))

    builder.ExportInput(controller.GetInputPort("X_WT_desired"), "X_WT_desired")
    builder.ExportInput(controller.GetInputPort("V_WT_desired"), "V_WT_desired")
    builder.ExportInput(controller.GetInputPort("A_WT_desired"), "A_WT_desired")
    builder.ExportInput(gripper.GetInputPort("width"), "gripper_width")
    builder.ExportOutput(plant.get_state_output_port(models.arm), "arm_state")
    builder.ExportOutput(plant.get_state_output_port(models.hand), "hand_state")
    builder.ExportOutput(controller.GetOutputPort("X_WT"), "X_WT")
    builder.ExportOutput(controller.GetOutputPort("wrench"), "wrench")
    builder.ExportOutput(controller.GetOutputPort("torque"), "torque")
    builder.ExportOutput(plant.get_body_poses_output_port(), "body_poses")
    builder.ExportOutput(plant.get_contact_results_output_port(), "contact_results")
    # what libfranka's external-wrench estimate is made of (assembly.wrench_sensor)
    builder.ExportOutput(plant.get_generalized_contact_forces_output_port(models.arm), "tau_contact")
    jacobian = builder.AddSystem(ToolJacobian(*make_controller_plant()))
    builder.Connect(plant.get_state_output_port(models.arm), jacobian.get_input_port(0))
    builder.ExportOutput(jacobian.get_output_port(0), "tool_jacobian")
    estimate = builder.AddSystem(
        ExternalWrenchEstimate(WRENCH_MODELS[config.wrench_sensor], config.wrench_period, config.wrench_seed)
    )
    builder.Connect(plant.get_generalized_contact_forces_output_port(models.arm), estimate.get_input_port(0))
    builder.Connect(jacobian.get_output_port(0), estimate.get_input_port(1))
    builder.ExportOutput(estimate.get_output_port(0), "external_wrench")

    cameras: dict[str, RgbdSensor] = {}
    hand_body = plant.GetBodyByName("panda_hand", models.hand)
    for cam, parent in (
        (config.cameras.scene, scene_graph.world_frame_id()),
        (config.cameras.wrist, plant.GetBodyFrameIdOrThrow(hand_body.index())),
    ):
        if cam is None:
            continue
        sensor = add_camera(builder, scene_graph, parent, cam)
        cameras[cam.name] = sensor
        rgb, depth = sensor.color_image_output_port(), sensor.depth_image_32F_output_port()
        real = config.sensors.get(cam.name)
        if real is not None and not real.model.is_ideal:  # the images as the real camera reports them
            noise = builder.AddSystem(
                RgbdSensorNoise(cam.name, real.model, cam.info().focal_y(), real.scale, real.seed)
            )
            builder.Connect(rgb, noise.GetInputPort("rgb"))
            builder.Connect(depth, noise.GetInputPort("depth"))
            rgb, depth = noise.GetOutputPort("rgb"), noise.GetOutputPort("depth")
        builder.ExportOutput(rgb, f"{cam.name}_rgb")
        builder.ExportOutput(depth, f"{cam.name}_depth")
        builder.ExportOutput(sensor.label_image_output_port(), f"{cam.name}_label")

    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration)
        )
    diagram = builder.Build()
    diagram.set_name("station")
    return Station(diagram, plant, scene_graph, models, controller, cameras, config, visualizer, anchor)


COMMAND_PORTS = ("X_WT_desired", "V_WT_desired", "A_WT_desired", "gripper_width")


def drive_station(station: Station, source: LeafSystem) -> Diagram:
    """A Diagram of `station` commanded by `source`: each of the station's command inputs
    (COMMAND_PORTS) is connected to the source's output port of the same name, if it has one."""
    if not source.HasOutputPort("X_WT_desired") or not source.HasOutputPort("gripper_width"):
        raise ValueError(
            f"{source.get_name()!r} must output 'X_WT_desired' and 'gripper_width' "
            f"(optionally 'V_WT_desired', 'A_WT_desired') to drive the station"
        )
    builder = DiagramBuilder()
    builder.AddSystem(station.diagram)
    builder.AddSystem(source)
    for name in COMMAND_PORTS:
        if source.HasOutputPort(name):
            builder.Connect(source.GetOutputPort(name), station.diagram.GetInputPort(name))
    diagram = builder.Build()
    diagram.set_name("commanded_station")
    return diagram


def make_meshcat() -> Meshcat:
    """A Meshcat server bound to localhost only."""
    return Meshcat(MeshcatParams(host="localhost"))
