"""Exit 0 when pydrake imports and RenderEngineVtk renders one headless frame."""

import numpy as np
from pydrake.geometry import (
    Box,
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo, RgbdSensor

builder = DiagramBuilder()
plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
plant.RegisterVisualGeometry(plant.world_body(), RigidTransform(), Box(1, 1, 0.1), "box", [1, 0, 0, 1])
plant.Finalize()
core = RenderCameraCore("vtk", CameraInfo(32, 24, np.pi / 4), ClippingRange(0.01, 10), RigidTransform())
sensor = builder.AddSystem(
    RgbdSensor(
        scene_graph.world_frame_id(),
        RigidTransform(RollPitchYaw(np.pi, 0, 0), [0, 0, 1]),
        ColorRenderCamera(core),
        DepthRenderCamera(core, DepthRange(0.01, 10)),
    )
)
builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
diagram = builder.Build()
context = diagram.CreateDefaultContext()
depth = sensor.depth_image_32F_output_port().Eval(sensor.GetMyContextFromRoot(context))
assert abs(float(np.asarray(depth.data)[12, 16, 0]) - 0.95) < 1e-3
