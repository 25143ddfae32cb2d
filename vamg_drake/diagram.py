"""build_diagram(): the whole episode as one Drake `Diagram`.

    Scenario ─► World (plant + scene graph + head RgbdSensor)
                 │ plant state                      │ depth, X_WC
                 ▼                                  ▼
          RobotStateSelector ──► policy ──► RobotCommandIntegrator ──► plant desired state
                 │                                  DepthSampler (10 Hz) ──► depth_frame
                 └──► DynamicObstacleDriver ──► obstacle desired states
          EpisodeMonitor (collision / success / time limit) ──► outcome

The policy is chosen by `DiagramConfig.policy`; "scripted" drives a waypoint
list and sweeps the head (`ScriptedDriver`).
"""


import dataclasses as dc

import numpy as np
from pydrake.geometry import (
    CollisionFilterDeclaration,
    GeometrySet,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Role,
)
from pydrake.systems.framework import Diagram, DiagramBuilder

from vamg_drake.robot import layout
from vamg_drake.systems.depth_sampler import DepthSampler
from vamg_drake.systems.dynamic_obstacles import DynamicObstacleDriver
from vamg_drake.systems.episode_monitor_system import EpisodeMonitor
from vamg_drake.systems.robot_command import RobotCommandIntegrator
from vamg_drake.systems.robot_state import RobotStateSelector
from vamg_drake.systems.scripted_driver import ScriptedDriver, ScriptedDriverConfig
from vamg_drake.systems.timing import ModuleTimings
from vamg_drake.world.episode_monitor import EpisodeMonitorConfig
from vamg_drake.world.scenario import Scenario
from vamg_drake.world.world_builder import World, WorldConfig, build_world, initial_robot_configuration

POLICIES = ("scripted",)


@dc.dataclass
class DiagramConfig:
    """Configuration of an episode diagram."""

    world: WorldConfig = dc.field(default_factory=WorldConfig)
    monitor: EpisodeMonitorConfig = dc.field(default_factory=EpisodeMonitorConfig)
    policy: str = "scripted"
    scripted: ScriptedDriverConfig = dc.field(default_factory=ScriptedDriverConfig)
    #: Scripted waypoints [[x, y], ...]; empty = towards the target, stopping short.
    waypoints: list[list[float]] = dc.field(default_factory=list)
    #: Period of the command integrator [s].
    command_period: float = 0.01


@dc.dataclass
class EpisodeDiagram:
    """The built diagram and handles to its systems."""

    diagram: Diagram
    world: World
    monitor: EpisodeMonitor
    command: RobotCommandIntegrator
    robot_state: RobotStateSelector
    obstacles: DynamicObstacleDriver
    depth: DepthSampler | None
    policy: object
    timings: ModuleTimings
    visualizer: MeshcatVisualizer | None = None


def default_waypoints(scenario: Scenario, standoff: float = 1.2) -> np.ndarray:
    """A straight line from the start towards the target, stopping `standoff` short."""
    start = np.array([scenario.robot_start.x, scenario.robot_start.y])
    target = scenario.target_point()[:2]
    d = np.linalg.norm(target - start)
    if d <= standoff:
        return start[None]
    return (start + (target - start) * (1.0 - standoff / d))[None]


def _filter_obstacles_against_scene(world: World) -> None:
    """Parked/rising obstacles pass through floor and furniture without contact."""
    plant = world.plant
    scene_geoms = [g for b in plant.GetBodyIndices(world.scene.scene_instance)
                   for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))]
    for handle in world.scene.obstacles.values():
        geoms = plant.GetCollisionGeometriesForBody(handle.body)
        world.scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeBetween(GeometrySet(geoms), GeometrySet(scene_geoms))
        )


def build_diagram(scenario: Scenario, config: DiagramConfig | None = None, meshcat: Meshcat | None = None) -> EpisodeDiagram:
    """Builds the episode diagram for `scenario`."""
    config = config or DiagramConfig()
    if config.policy not in POLICIES:
        raise ValueError(f"DiagramConfig.policy: unknown policy '{config.policy}' (known: {', '.join(POLICIES)})")
    builder = DiagramBuilder()
    timings = ModuleTimings()
    world = build_world(builder, scenario, config.world)
    plant = world.plant
    _filter_obstacles_against_scene(world)

    robot_state = builder.AddNamedSystem(
        "robot_state",
        RobotStateSelector(plant.num_positions(), plant.num_velocities(), world.position_index, world.velocity_index),
    )
    builder.Connect(plant.get_state_output_port(), robot_state.get_input_port(0))

    command = builder.AddNamedSystem(
        "command",
        RobotCommandIntegrator(initial_robot_configuration(scenario), world.actuator_joint_order, config.command_period),
    )
    builder.Connect(command.GetOutputPort("desired_state"), plant.get_desired_state_input_port(world.robot))

    obstacles = builder.AddNamedSystem("obstacles", DynamicObstacleDriver(world.scene.obstacles))
    builder.Connect(robot_state.GetOutputPort("configuration"), obstacles.GetInputPort("robot_configuration"))
    for name, handle in world.scene.obstacles.items():
        builder.Connect(obstacles.GetOutputPort(f"{name}_desired_state"), plant.get_desired_state_input_port(handle.model_instance))

    depth = None
    if world.camera is not None:
        depth = builder.AddNamedSystem("depth_sampler", DepthSampler(config.world.camera.period, timings))
        builder.Connect(world.camera.depth_image_32F_output_port(), depth.GetInputPort("depth_image"))
        builder.Connect(world.camera.body_pose_in_world_output_port(), depth.GetInputPort("X_WC"))

    waypoints = np.asarray(config.waypoints, float) if config.waypoints else default_waypoints(scenario)
    policy = builder.AddNamedSystem("scripted_driver", ScriptedDriver(waypoints, config.scripted))
    builder.Connect(robot_state.GetOutputPort("configuration"), policy.GetInputPort("robot_configuration"))
    for port in ("base_velocity", "joint_velocity", "head_command", "gripper_command"):
        builder.Connect(policy.GetOutputPort(port), command.GetInputPort(port))

    monitor = builder.AddNamedSystem("monitor", EpisodeMonitor(world, scenario.time_limit, config.monitor))
    builder.Connect(world.scene_graph.get_query_output_port(), monitor.GetInputPort("query_object"))
    builder.Connect(plant.get_state_output_port(), monitor.GetInputPort("plant_state"))
    builder.Connect(policy.GetOutputPort("gripper_command"), monitor.GetInputPort("gripper_command"))

    visualizer = None
    if meshcat is not None:
        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, world.scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration, publish_period=0.05)
        )
    diagram = builder.Build()
    diagram.set_name("vamg_episode")
    return EpisodeDiagram(diagram, world, monitor, command, robot_state, obstacles, depth, policy, timings, visualizer)
