"""build_diagram(): the whole episode as one Drake `Diagram`.

The full system (``policy: full``, the default)::

    Scenario ─► World (plant + scene graph + head RgbdSensor)
      plant state ─► RobotStateSelector ─► q, gripper_opening
      depth, X_WC, q ─► RayCastMap (10 Hz) ─► point_map
      depth, X_WC, target ─► TargetCloud ─► target_cloud
      point_map, q, target, motion_feedback, target_cloud,
        gripper_opening ─► SubgoalPolicy ─► goal, phase, gripper_command
      goal, planner's point_map, q, target ─► WholeBodyPlanner ─► trajectory, motion_feedback
      depth, X_WC, q ─► SeenSpace (10 Hz) ─► seen_space
      point_map, seen_space ─► HiddenCellMap ─► the planner's point_map
      trajectory, q, seen_space ─► WholeBodyTracker (20 Hz) ─► base_velocity, joint_velocity,
                                                               trajectory_time, look_request
      trajectory, trajectory_time, look_request, q, target ─► GazeOptimizer (10 Hz) ─► head_command
      velocities, head, gripper ─► RobotCommandIntegrator ─► plant desired state
      phase, q ─► DynamicObstacleDriver ─► obstacle desired states
      EpisodeMonitor (collision / success / policy and planner verdicts / time limit) ─► outcome

``policy: scripted`` replaces everything between the map and the integrator
by `ScriptedDriver` (a waypoint list and a head sweep), to exercise the world.
"""


import dataclasses as dc
from pathlib import Path

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
from pydrake.systems.primitives import ConstantVectorSource

from vamg_drake.config_validation import InputError, check_diagram_config, load_typed_file, load_typed_text
from vamg_drake.control.whole_body_tracker import TrackerConfig
from vamg_drake.perception.gaze import GazeConfig
from vamg_drake.perception.raycast_map import RayCastMapConfig
from vamg_drake.perception.seen_space import LookGateConfig, SeenSpaceConfig
from vamg_drake.planning.motion_supervisor import PlannerSystemConfig
from vamg_drake.policy.behaviour_tree import BehaviourConfig
from vamg_drake.policy.learned_grasps import GraspQualityModel
from vamg_drake.policy.strategies import BEHAVIOURS
from vamg_drake.policy.subgoal_pipeline import SubgoalPipelineConfig
from vamg_drake.systems.depth_sampler import DepthSampler
from vamg_drake.systems.dynamic_obstacles import DynamicObstacleDriver
from vamg_drake.systems.episode_monitor_system import EpisodeMonitor
from vamg_drake.systems.gaze_system import GazeOptimizer
from vamg_drake.systems.planner_system import PlannerSystem
from vamg_drake.systems.raycast_map_system import RayCastMap
from vamg_drake.systems.robot_command import RobotCommandIntegrator
from vamg_drake.systems.robot_state import RobotStateSelector
from vamg_drake.systems.scripted_driver import ScriptedDriver, ScriptedDriverConfig
from vamg_drake.systems.seen_space_system import HiddenCellMap, SeenSpace
from vamg_drake.systems.subgoal_policy_system import SubgoalPolicyConfig, make_subgoal_policy
from vamg_drake.systems.target_cloud import TargetCloud, TargetCloudConfig
from vamg_drake.systems.timing import ModuleTimings
from vamg_drake.systems.tracker_system import WholeBodyTracker
from vamg_drake.world.episode_monitor import EpisodeMonitorConfig
from vamg_drake.world.scenario import Scenario
from vamg_drake.world.static_cloud import static_scene_points
from vamg_drake.world.world_builder import World, WorldConfig, build_world, initial_robot_configuration

POLICIES = ("full", "scripted")
#: What the map knows at the start (DiagramConfig.prior_map).
PRIOR_MAPS = ("none", "static")


@dc.dataclass
class DiagramConfig:
    """Configuration of an episode diagram (loadable with `yaml_load_typed`).

    Attributes:
        world: the simulated world.
        monitor: success and collision criteria.
        policy: "full" (the paper's system) or "scripted" (drives waypoints).
        method: the method's name, recorded in results.
        strategy: how the full system organises its subgoals, a key of
            `vamg_drake.policy.strategies.BEHAVIOURS` (see `vamg_drake.bench`
            for the methods). It selects the subgoals only: the system
            settings a method needs (``gaze.variant``, ``planner.replan_period``)
            are stated in its YAML file, and `build_diagram` uses the config as
            given. A strategy with settings other than its method file's (e.g.
            ``direct_grasping`` with the velocity-aware gaze) is an explicit
            choice and is kept.
        seed: seed of the samplers and the planner.
        prior_map: "none" (the paper's setting: the map starts empty) or
            "static" (it starts with a point cloud of the room's static
            geometry, as the paper authors' released runner does).
        map: the ray-cast map.
        gaze: the gaze optimizer (``variant`` selects the velocity-agnostic ablation).
        subgoal: the subgoal samplers.
        behaviour: the behaviour tree's budgets.
        policy_system: the SubgoalPolicy system.
        target_cloud: the dense cloud around the target (grasp candidates).
        planner: the WholeBodyPlanner system.
        tracker: the 20 Hz whole-body tracker.
        seen_space: the seen-floor grid (its depth range and crop follow `map.depth`).
        look: the tracker's look-before-you-leave rule (the base does not enter unseen cells).
        scripted: the scripted driver.
        waypoints: scripted waypoints [[x, y], ...]; empty = towards the target, stopping short.
        command_period: period of the command integrator [s].
        start_sweep: the initial look around [s].
    """

    world: WorldConfig = dc.field(default_factory=WorldConfig)
    monitor: EpisodeMonitorConfig = dc.field(default_factory=EpisodeMonitorConfig)
    policy: str = "full"
    method: str = "full"
    strategy: str = "subgoal_tree"
    seed: int = 0
    prior_map: str = "none"
    map: RayCastMapConfig = dc.field(default_factory=RayCastMapConfig)
    gaze: GazeConfig = dc.field(default_factory=GazeConfig)
    subgoal: SubgoalPipelineConfig = dc.field(default_factory=SubgoalPipelineConfig)
    behaviour: BehaviourConfig = dc.field(default_factory=BehaviourConfig)
    #: The episode's policy first waits 0.5 s for a first map (raise it with start_sweep).
    policy_system: SubgoalPolicyConfig = dc.field(default_factory=lambda: SubgoalPolicyConfig(start_delay=0.5))
    target_cloud: TargetCloudConfig = dc.field(default_factory=TargetCloudConfig)
    planner: PlannerSystemConfig = dc.field(default_factory=PlannerSystemConfig)
    tracker: TrackerConfig = dc.field(default_factory=TrackerConfig)
    seen_space: SeenSpaceConfig = dc.field(default_factory=SeenSpaceConfig)
    look: LookGateConfig = dc.field(default_factory=LookGateConfig)
    scripted: ScriptedDriverConfig = dc.field(default_factory=ScriptedDriverConfig)
    waypoints: list[list[float]] = dc.field(default_factory=list)
    command_period: float = 0.01
    #: The head first looks right, then left for this long (policy_system.start_delay should cover it).
    #: Off by default: in two traced early-collision rooms it put the furniture
    #: beside the robot into the map but the base still met table legs hidden
    #: under the top [s].
    start_sweep: float = 0.0

    def validate(self) -> None:
        """Raises ValueError naming the bad field (every type, finiteness and
        range problem of the whole tree, see `vamg_drake.config_validation`,
        and each nested config's own `validate`: the components built from
        them do not check them again)."""
        check_diagram_config(self)
        if self.policy not in POLICIES:
            raise ValueError(f"DiagramConfig.policy: unknown policy '{self.policy}' (known: {', '.join(POLICIES)})")
        if self.prior_map not in PRIOR_MAPS:
            raise ValueError(f"DiagramConfig.prior_map: unknown prior map '{self.prior_map}' (known: {', '.join(PRIOR_MAPS)})")
        if self.strategy not in BEHAVIOURS:
            raise ValueError(f"DiagramConfig.strategy: unknown strategy '{self.strategy}' "
                             f"(known: {', '.join(BEHAVIOURS)})")
        if self.policy == "full" and not self.world.enable_camera:
            raise ValueError("DiagramConfig.world.enable_camera: the full system needs the head camera")
        self.gaze.validate()
        self.subgoal.validate()
        self.behaviour.validate()
        grasp_source = self.subgoal.grasp_source
        grasp_source.validate("DiagramConfig.subgoal.grasp_source")
        if grasp_source.source == "learned" and not grasp_source.fallback_to_geometric:
            GraspQualityModel.load(grasp_source.model_path())  # GraspModelError names the file


def load_diagram_config(path: str | Path, source: str | None = None, text: str | None = None) -> DiagramConfig:
    """Reads and fully checks a (partial) ``DiagramConfig`` YAML file; defaults fill the rest.

    Args:
        path: the file.
        source: how problems name the file (default: the path as given).
        text: the file's text when the caller has read it already.

    Raises:
        InputError: one "<source>: <field>: <message>" line per problem.
    """
    source = source or str(path)
    if text is None:
        config = load_typed_file(path, DiagramConfig, DiagramConfig(), source)
    else:
        config = load_typed_text(text, DiagramConfig, DiagramConfig(), source)
    check_diagram_config(config, source)
    try:
        config.validate()  # the enumerations (policy, strategy, gaze variant)
    except InputError as e:
        raise InputError([f"{source}: {p}" for p in e.problems]) from None
    except ValueError as e:
        raise InputError([f"{source}: {' '.join(str(e).split())}"]) from None
    return config


@dc.dataclass
class EpisodeDiagram:
    """The built diagram and handles to its systems (None where the policy has none)."""

    diagram: Diagram
    world: World
    config: DiagramConfig
    monitor: EpisodeMonitor
    command: RobotCommandIntegrator
    robot_state: RobotStateSelector
    obstacles: DynamicObstacleDriver
    policy: object
    timings: ModuleTimings
    depth: DepthSampler | None = None
    point_map: RayCastMap | None = None
    planner: PlannerSystem | None = None
    tracker: WholeBodyTracker | None = None
    gaze: GazeOptimizer | None = None
    seen_space: SeenSpace | None = None
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
    scene_geoms += list(world.scene.static_geometry_owner)  # anchored on the world body
    for handle in world.scene.obstacles.values():
        geoms = plant.GetCollisionGeometriesForBody(handle.body)
        world.scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeBetween(GeometrySet(geoms), GeometrySet(scene_geoms))
        )


def build_diagram(scenario: Scenario, config: DiagramConfig | None = None, meshcat: Meshcat | None = None) -> EpisodeDiagram:
    """Builds the episode diagram for `scenario`."""
    config = config or DiagramConfig()
    config.validate()
    builder = DiagramBuilder()
    timings = ModuleTimings()
    world = build_world(builder, scenario, config.world)
    plant = world.plant
    _filter_obstacles_against_scene(world)

    robot_state = builder.AddNamedSystem(
        "robot_state",
        RobotStateSelector(plant.num_positions(), plant.num_velocities(), world.position_index, world.velocity_index),
    )
    builder.Connect(plant.get_state_output_port(), robot_state.GetInputPort("plant_state"))

    command = builder.AddNamedSystem(
        "command",
        RobotCommandIntegrator(initial_robot_configuration(scenario), world.actuator_joint_order, config.command_period),
    )
    builder.Connect(command.GetOutputPort("desired_state"), plant.get_desired_state_input_port(world.robot))
    builder.Connect(robot_state.GetOutputPort("configuration"), command.GetInputPort("measured_configuration"))

    obstacles = builder.AddNamedSystem("obstacles", DynamicObstacleDriver(world.scene.obstacles))
    builder.Connect(robot_state.GetOutputPort("configuration"), obstacles.GetInputPort("robot_configuration"))
    for name, handle in world.scene.obstacles.items():
        builder.Connect(obstacles.GetOutputPort(f"{name}_desired_state"), plant.get_desired_state_input_port(handle.model_instance))

    monitor = builder.AddNamedSystem("monitor", EpisodeMonitor(world, scenario.time_limit, config.monitor))
    builder.Connect(world.scene_graph.get_query_output_port(), monitor.GetInputPort("query_object"))
    builder.Connect(plant.get_state_output_port(), monitor.GetInputPort("plant_state"))

    ed = EpisodeDiagram(None, world, config, monitor, command, robot_state, obstacles, None, timings)
    if config.policy == "scripted":
        _add_scripted_policy(builder, ed, scenario)
    else:
        _add_full_system(builder, ed, scenario)

    if meshcat is not None:
        ed.visualizer = MeshcatVisualizer.AddToBuilder(
            builder, world.scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration, publish_period=0.05)
        )
    ed.diagram = builder.Build()
    ed.diagram.set_name("vamg_episode")
    return ed


def _add_scripted_policy(builder: DiagramBuilder, ed: EpisodeDiagram, scenario: Scenario) -> None:
    config, world = ed.config, ed.world
    if world.camera is not None:
        ed.depth = builder.AddNamedSystem("depth_sampler", DepthSampler(config.world.camera.period, ed.timings))
        builder.Connect(world.camera.depth_image_32F_output_port(), ed.depth.GetInputPort("depth_image"))
        builder.Connect(world.camera.body_pose_in_world_output_port(), ed.depth.GetInputPort("X_WC"))
    waypoints = np.asarray(config.waypoints, float) if config.waypoints else default_waypoints(scenario)
    ed.policy = builder.AddNamedSystem("scripted_driver", ScriptedDriver(waypoints, config.scripted))
    builder.Connect(ed.robot_state.GetOutputPort("configuration"), ed.policy.GetInputPort("robot_configuration"))
    for port in ("base_velocity", "joint_velocity", "head_command", "gripper_command"):
        builder.Connect(ed.policy.GetOutputPort(port), ed.command.GetInputPort(port))
    builder.Connect(ed.policy.GetOutputPort("gripper_command"), ed.monitor.GetInputPort("gripper_command"))


def _add_full_system(builder: DiagramBuilder, ed: EpisodeDiagram, scenario: Scenario) -> None:
    config, world, timings = ed.config, ed.world, ed.timings
    camera = world.camera
    period = config.world.camera.period
    q = ed.robot_state.GetOutputPort("whole_body_configuration")
    depth_image, X_WC = camera.depth_image_32F_output_port(), camera.body_pose_in_world_output_port()
    target = builder.AddNamedSystem("target", ConstantVectorSource(np.asarray(scenario.target_point(), float)))

    prior = None
    if config.prior_map == "static":
        prior = static_scene_points(scenario, config.map.voxel_size, config.map.ground_height)
    point_map = builder.AddNamedSystem("raycast_map", RayCastMap(world.intrinsics, config.map, period, timings=timings,
                                                                 prior_points=prior))
    builder.Connect(depth_image, point_map.GetInputPort("depth_image"))
    builder.Connect(X_WC, point_map.GetInputPort("X_WC"))
    builder.Connect(q, point_map.GetInputPort("robot_configuration"))

    cloud = builder.AddNamedSystem("target_cloud", TargetCloud(world.intrinsics, config.target_cloud))
    builder.Connect(depth_image, cloud.GetInputPort("depth_image"))
    builder.Connect(X_WC, cloud.GetInputPort("X_WC"))
    builder.Connect(target.get_output_port(), cloud.GetInputPort("target"))
    builder.Connect(q, cloud.GetInputPort("robot_configuration"))

    policy = builder.AddNamedSystem("subgoal_policy", make_subgoal_policy(
        config.world.camera, config.map.depth.depth_max, config.subgoal, config.behaviour, config.policy_system,
        seed=config.seed, timings=timings, strategy=config.strategy, collision=config.planner.planner.checker_config()))
    planner = builder.AddNamedSystem("planner", PlannerSystem(_seeded_planner_config(config), timings=timings))
    tracker = builder.AddNamedSystem("tracker", WholeBodyTracker(config.tracker, config.look))
    depth_range = config.map.depth
    seen = builder.AddNamedSystem("seen_space", SeenSpace(
        world.intrinsics, [scenario.robot_start.x, scenario.robot_start.y],
        dc.replace(config.seen_space, depth_min=depth_range.depth_min, depth_max=depth_range.depth_max,
                   crop_radius=depth_range.crop_radius), period))
    builder.Connect(depth_image, seen.GetInputPort("depth_image"))
    builder.Connect(X_WC, seen.GetInputPort("X_WC"))
    builder.Connect(q, seen.GetInputPort("robot_configuration"))
    gaze = builder.AddNamedSystem("gaze", GazeOptimizer(world.intrinsics, config.gaze, period, timings=timings,
                                                        start_sweep=config.start_sweep))

    builder.Connect(point_map.GetOutputPort("point_map"), policy.GetInputPort("point_map"))
    builder.Connect(q, policy.GetInputPort("robot_configuration"))
    builder.Connect(target.get_output_port(), policy.GetInputPort("target"))
    builder.Connect(planner.GetOutputPort("motion_feedback"), policy.GetInputPort("motion_feedback"))
    builder.Connect(cloud.GetOutputPort("target_cloud"), policy.GetInputPort("target_cloud"))
    builder.Connect(ed.robot_state.GetOutputPort("gripper_opening"), policy.GetInputPort("gripper_opening"))

    builder.Connect(policy.GetOutputPort("goal"), planner.GetInputPort("goal"))
    planner_map = builder.AddNamedSystem("hidden_cell_map", HiddenCellMap())
    builder.Connect(point_map.GetOutputPort("point_map"), planner_map.GetInputPort("point_map"))
    builder.Connect(seen.GetOutputPort("seen_space"), planner_map.GetInputPort("seen_space"))
    builder.Connect(planner_map.GetOutputPort("point_map"), planner.GetInputPort("point_map"))
    builder.Connect(q, planner.GetInputPort("robot_configuration"))
    builder.Connect(target.get_output_port(), planner.GetInputPort("target"))

    trajectory = planner.GetOutputPort("trajectory")  # PlannedTrajectory: the monitor reads its status
    builder.Connect(trajectory, tracker.GetInputPort("trajectory"))
    builder.Connect(q, tracker.GetInputPort("robot_configuration"))
    builder.Connect(seen.GetOutputPort("seen_space"), tracker.GetInputPort("seen_space"))
    builder.Connect(trajectory, gaze.GetInputPort("trajectory"))
    builder.Connect(tracker.GetOutputPort("trajectory_time"), gaze.GetInputPort("trajectory_time"))
    builder.Connect(tracker.GetOutputPort("look_request"), gaze.GetInputPort("look_request"))
    builder.Connect(q, gaze.GetInputPort("robot_configuration"))
    builder.Connect(target.get_output_port(), gaze.GetInputPort("target"))

    builder.Connect(tracker.GetOutputPort("base_velocity"), ed.command.GetInputPort("base_velocity"))
    builder.Connect(tracker.GetOutputPort("joint_velocity"), ed.command.GetInputPort("joint_velocity"))
    builder.Connect(gaze.GetOutputPort("head_command"), ed.command.GetInputPort("head_command"))
    builder.Connect(policy.GetOutputPort("gripper_command"), ed.command.GetInputPort("gripper_command"))

    builder.Connect(policy.GetOutputPort("phase"), ed.obstacles.GetInputPort("phase"))
    builder.Connect(policy.GetOutputPort("gripper_command"), ed.monitor.GetInputPort("gripper_command"))
    builder.Connect(policy.GetOutputPort("goal"), ed.monitor.GetInputPort("policy_goal"))
    builder.Connect(trajectory, ed.monitor.GetInputPort("planner_status"))
    ed.policy, ed.point_map, ed.planner, ed.tracker, ed.gaze = policy, point_map, planner, tracker, gaze
    ed.seen_space = seen


def _seeded_planner_config(config: DiagramConfig) -> PlannerSystemConfig:
    """The planner system's config with the episode's seed."""
    return dc.replace(config.planner, planner=dc.replace(config.planner.planner, seed=config.seed))
