"""The simulated world: MultibodyPlant + SceneGraph with the Fetch, the room and a head camera.

The robot runs without gravity; every joint is a PD-controlled actuator that
tracks the desired state produced by `RobotCommandIntegrator` (velocity
commands integrated into position targets). Furniture is welded; YCB objects
are free bodies with gravity; dynamic obstacles are PD-driven bodies (see
`scene_geometry`).

The base is three single-DoF joints (x, y, yaw) rather than a `PlanarJoint`:
Drake's PD-controlled actuators need single-DoF joints.
"""


import dataclasses as dc
import logging

import numpy as np
from pydrake.geometry import (
    AddRigidHydroelasticProperties,
    ClippingRange,
    ColorRenderCamera,
    DepthRange,
    DepthRenderCamera,
    MakeRenderEngineVtk,
    ProximityProperties,
    RenderCameraCore,
    RenderEngineVtkParams,
    RoleAssign,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import JointActuatorIndex, ModelInstanceIndex, PdControllerGains
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo, RgbdSensor

from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import CAMERA_FRAME, EXTENDED_JOINTS, NX, fetch_urdf_path
from vamg_drake.robot.spheres import FINGER_LINKS
from vamg_drake.world.clutter_sleep import ClutterSleepConfig
from vamg_drake.world.scenario import Scenario
from vamg_drake.world.scene_geometry import SceneGeometryConfig, SceneHandles, add_scene

log = logging.getLogger(__name__)

RENDERER_NAME = "vamg_vtk"


@dc.dataclass
class RobotGains:
    """PD gains of the robot's joint actuators: kp [N/m or Nm/rad], kd.

    The fingers squeeze with kp times the gap between the closed command and
    the object (capped by the URDF's 60 N effort): at 300 N/m a 6 cm object got
    ~4 N per finger and slipped out during the lift; 3000 N/m gives ~30 N.
    """

    base_xy: tuple[float, float] = (40000.0, 4000.0)
    base_theta: tuple[float, float] = (6000.0, 600.0)
    torso: tuple[float, float] = (20000.0, 2000.0)
    arm: tuple[float, float] = (400.0, 40.0)
    head: tuple[float, float] = (40.0, 4.0)
    fingers: tuple[float, float] = (3000.0, 30.0)


@dc.dataclass
class WorldConfig:
    """Configuration of the simulated world."""

    #: Discrete plant step [s] (SAP).
    time_step: float = 0.01
    camera: HeadCameraConfig = dc.field(default_factory=HeadCameraConfig)
    gains: RobotGains = dc.field(default_factory=RobotGains)
    scene: SceneGeometryConfig = dc.field(default_factory=SceneGeometryConfig)
    #: Render the depth camera (False for planner-only or speed runs).
    enable_camera: bool = True
    #: Viscous damping of the head joints [N m s/rad]. The URDF's 0.5 with the
    #: pan motor's 0.32 N m effort limit capped the pan at 0.64 rad/s, far below
    #: the 1.57 rad/s the gaze optimizer plans with (measured in an episode).
    head_joint_damping: float = 0.05
    #: The finger pads are rigid hydroelastic boxes, so that against the
    #: (compliant hydroelastic) objects they make contact patches. As plain
    #: point contacts, squeezed into a compliant object with up to 60 N, their
    #: contact normals tilted ~30 deg off the pad and the object slid out along
    #: the approach (box room: the tomato soup can left the closing fingers).
    hydroelastic_fingers: bool = True
    #: Objects away from the target are built asleep (anchored geometry: held
    #: still, never paired with the static scene).
    clutter_sleep: ClutterSleepConfig = dc.field(default_factory=ClutterSleepConfig)


@dc.dataclass
class World:
    """Handles into the built world."""

    plant: MultibodyPlant
    scene_graph: SceneGraph
    robot: ModelInstanceIndex
    scene: SceneHandles
    camera: RgbdSensor | None
    intrinsics: CameraIntrinsics
    #: Extended joint index (kinematics.EXTENDED_JOINTS) per robot actuator, in
    #: the order of the plant's desired-state input for the robot.
    actuator_joint_order: np.ndarray
    #: Plant position index per extended joint.
    position_index: np.ndarray
    #: Plant velocity index per extended joint.
    velocity_index: np.ndarray


def _gains_for(joint: str, gains: RobotGains) -> tuple[float, float]:
    if joint in ("base_x", "base_y"):
        return gains.base_xy
    if joint == "base_theta":
        return gains.base_theta
    if joint == layout.TORSO_JOINT:
        return gains.torso
    if joint in layout.HEAD_JOINTS:
        return gains.head
    if joint in layout.FINGER_JOINTS:
        return gains.fingers
    return gains.arm


def initial_robot_configuration(scenario: Scenario) -> np.ndarray:
    """The extended configuration at the start: stowed arm, head level, gripper open."""
    s = scenario.robot_start
    V = np.zeros(NX)
    V[: layout.NQ] = layout.stow_configuration(s.x, s.y, s.yaw)
    V[layout.NQ + 2 :] = layout.FINGER_LIMITS[1]
    return V


def _make_fingers_hydroelastic(plant: MultibodyPlant, scene_graph: SceneGraph, robot: ModelInstanceIndex) -> None:
    """Gives the finger links' collision geometries rigid hydroelastic
    properties (keeping their friction)."""
    inspector = scene_graph.model_inspector()
    for name in FINGER_LINKS:
        for geometry in plant.GetCollisionGeometriesForBody(plant.GetBodyByName(name, robot)):
            props = ProximityProperties(inspector.GetProximityProperties(geometry))
            AddRigidHydroelasticProperties(props)
            scene_graph.AssignRole(plant.get_source_id(), geometry, props, RoleAssign.kReplace)


def build_world(builder: DiagramBuilder, scenario: Scenario, config: WorldConfig | None = None) -> World:
    """Adds plant, scene graph, robot, scene and head camera to `builder`."""
    config = config or WorldConfig()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=config.time_step, discrete_contact_approximation="sap"), builder
    )
    robot = Parser(plant).AddModels(str(fetch_urdf_path()))[0]
    for name in ("head_pan_joint", "head_tilt_joint"):
        plant.GetJointByName(name, robot).set_default_damping(config.head_joint_damping)
    plant.set_gravity_enabled(robot, False)
    if config.hydroelastic_fingers:
        _make_fingers_hydroelastic(plant, scene_graph, robot)
    # (GetJointActuatorIndices() is empty before Finalize(): walk all actuators.)
    for i in range(plant.num_actuators()):
        actuator = plant.get_mutable_joint_actuator(JointActuatorIndex(i))
        if actuator.model_instance() == robot:
            kp, kd = _gains_for(actuator.joint().name(), config.gains)
            actuator.set_controller_gains(PdControllerGains(p=kp, d=kd))
    scene = add_scene(plant, scenario, config.scene, config.clutter_sleep)
    plant.Finalize()

    V0 = initial_robot_configuration(scenario)
    for name, value in zip(EXTENDED_JOINTS, V0):
        plant.GetJointByName(name, robot).set_default_positions([value])

    actuator_joint_order = np.array(
        [EXTENDED_JOINTS.index(plant.get_joint_actuator(i).joint().name()) for i in plant.GetJointActuatorIndices(robot)]
    )
    position_index = np.array([plant.GetJointByName(n, robot).position_start() for n in EXTENDED_JOINTS])
    velocity_index = np.array([plant.GetJointByName(n, robot).velocity_start() for n in EXTENDED_JOINTS])

    intrinsics = CameraIntrinsics.from_config(config.camera)
    camera = None
    if config.enable_camera:
        if not scene_graph.HasRenderer(RENDERER_NAME):
            scene_graph.AddRenderer(RENDERER_NAME, MakeRenderEngineVtk(RenderEngineVtkParams()))
        camera = _add_head_camera(builder, plant, scene_graph, robot, config.camera, intrinsics)
    return World(
        plant, scene_graph, robot, scene, camera, intrinsics, actuator_joint_order, position_index, velocity_index
    )


def _add_head_camera(
    builder: DiagramBuilder,
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    robot: ModelInstanceIndex,
    config: HeadCameraConfig,
    intrinsics: CameraIntrinsics,
) -> RgbdSensor:
    """An RgbdSensor whose frame is the head depth optical frame (follows pan/tilt)."""
    info = CameraInfo(
        width=intrinsics.width,
        height=intrinsics.height,
        focal_x=intrinsics.fx,
        focal_y=intrinsics.fy,
        center_x=intrinsics.cx,
        center_y=intrinsics.cy,
    )
    core = RenderCameraCore(RENDERER_NAME, info, ClippingRange(0.05, 20.0), RigidTransform())
    depth_camera = DepthRenderCamera(core, DepthRange(config.depth_min, config.depth_max))
    color_camera = ColorRenderCamera(core, show_window=False)
    optical = plant.GetFrameByName(CAMERA_FRAME, robot)
    parent_body = optical.body()
    X_PC = optical.GetFixedPoseInBodyFrame()
    frame_id = plant.GetBodyFrameIdOrThrow(parent_body.index())
    sensor = builder.AddNamedSystem(
        "head_camera", RgbdSensor(frame_id, X_PC, color_camera, depth_camera)
    )
    builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
    return sensor
