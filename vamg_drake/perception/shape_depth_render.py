"""Depth images of a fixed set of Drake shapes, rendered with RenderEngineVtk.

A small offline renderer for perception tests, benchmarks and parameter studies:
the same renderer (VTK) and sensor model (Drake's `RgbdSensor`: +inf beyond the
range, 0 below it) as the full `World` diagram, without a plant or a robot.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.geometry import (
    ClippingRange,
    DepthRange,
    DepthRenderCamera,
    GeometryInstance,
    MakeRenderEngineVtk,
    PerceptionProperties,
    RenderCameraCore,
    RenderEngineVtkParams,
    RenderLabel,
    SceneGraph,
    Shape,
)
from pydrake.math import RigidTransform
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo, RgbdSensor

from vamg_drake.robot.head_camera import CameraIntrinsics


class ShapeDepthRenderer:
    """Renders depth images of anchored shapes from arbitrary camera poses X_WC."""

    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        shapes: Sequence[tuple[Shape, RigidTransform]],
        depth_range: tuple[float, float] = (0.2, 5.0),
    ):
        builder = DiagramBuilder()
        scene_graph = builder.AddSystem(SceneGraph())
        scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
        source = scene_graph.RegisterSource("shapes")
        for k, (shape, X_WS) in enumerate(shapes):
            gid = scene_graph.RegisterAnchoredGeometry(source, GeometryInstance(RigidTransform(X_WS), shape, f"shape_{k}"))
            props = PerceptionProperties()
            props.AddProperty("label", "id", RenderLabel(k + 1))
            scene_graph.AssignRole(source, gid, props)
        info = CameraInfo(intrinsics.width, intrinsics.height, intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
        core = RenderCameraCore("vtk", info, ClippingRange(0.01, 2.0 * depth_range[1]), RigidTransform())
        camera = DepthRenderCamera(core, DepthRange(*depth_range))
        self._sensor = builder.AddSystem(RgbdSensor(scene_graph.world_frame_id(), RigidTransform(), camera, False))
        builder.Connect(scene_graph.get_query_output_port(), self._sensor.query_object_input_port())
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._sensor_context = self._sensor.GetMyMutableContextFromRoot(self._context)

    def render(self, X_WC: np.ndarray | RigidTransform) -> np.ndarray:
        """The (H, W) float32 depth image seen from camera pose X_WC (optical frame)."""
        self._sensor.SetX_PB(self._sensor_context, RigidTransform(X_WC) if not isinstance(X_WC, RigidTransform) else X_WC)
        image = self._sensor.depth_image_32F_output_port().Eval(self._sensor_context)
        return np.array(image.data[:, :, 0], copy=True)


def look_at(p_WC: np.ndarray, p_WTarget: np.ndarray, up_W: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """X_WC (4, 4) of an optical frame at p_WC whose +z axis points at p_WTarget (+y down)."""
    z = np.asarray(p_WTarget, dtype=float) - np.asarray(p_WC, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up_W)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, y, z])
    X[:3, 3] = p_WC
    return X
