"""The world diagram: builds, steps, renders depth, and judges episodes."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from scenes import box_room_scenario, table
from vamg_drake.diagram import DiagramConfig, build_diagram
from vamg_drake.robot.kinematics import FINGER_SLICE, FetchKinematics
from vamg_drake.world.clutter_sleep import ClutterSleepConfig, sleeping_objects
from vamg_drake.world.episode_monitor import COLLISION, PLANNING, RUNNING, SUCCESS, Contact, EpisodeJudge
from vamg_drake.world.scenario import Box, Furniture, Part, PlanarPose


def _simulate(scenario, t, config=None):
    ed = build_diagram(scenario, config or DiagramConfig(policy="scripted"))
    sim = Simulator(ed.diagram)
    sim.Initialize()
    status = sim.AdvanceTo(t)
    return ed, sim, status


def _eval(system, port, sim):
    return system.GetOutputPort(port).Eval(system.GetMyContextFromRoot(sim.get_context()))


def test_diagram_builds_and_steps():
    ed, sim, _ = _simulate(box_room_scenario(), 1.0)
    sim.AdvanceTo(1.0 + 1e-4)  # process the 10 Hz camera sample at t = 1.0
    V = _eval(ed.robot_state, "configuration", sim)
    assert V.shape == (15,) and np.all(np.isfinite(V))
    assert V[0] > -1.5 + 0.2  # the scripted driver moved the base forward
    frame = _eval(ed.depth, "depth_frame", sim)
    assert frame.time == pytest.approx(1.0) and frame.depth.shape == (240, 320)
    # The sensor's pose is the model's head camera pose (pan/tilt included).
    np.testing.assert_allclose(
        frame.X_WC, FetchKinematics.instance().camera_pose(V[:11], V[11], V[12]), atol=0.012  # one 10 ms plant step apart
    )


def test_depth_of_a_box_at_known_distance():
    scenario = box_room_scenario()
    scenario.dynamic_events = []
    # A tall cabinet face at x = 1.5 straight ahead of the robot at x = -0.5.
    cabinet = Furniture("cabinet_0", "cabinet", PlanarPose(1.8, 0.0, 0.0), [Part("body", Box([0.6, 1.5, 2.0]), [0, 0, 1.0])])
    scenario.furniture = [cabinet, table("table_0", 2.6, 1.8)]
    scenario.objects[0].xyz = [2.6, 1.8, 0.80]
    scenario.robot_start = PlanarPose(-0.5, 0.0, 0.0)
    config = DiagramConfig(policy="scripted", waypoints=[[-0.5, 0.0]])
    config.scripted.head_pan_amplitude = 0.0
    config.scripted.head_tilt = 0.0
    ed, sim, _ = _simulate(scenario, 0.0, config)
    frame = _eval(ed.depth, "depth_frame", sim)
    X_WC = frame.X_WC
    h, w = frame.depth.shape
    expected = 1.5 - X_WC[0, 3]  # optical axis along +x at head tilt 0
    centre = frame.depth[h // 2 - 2 : h // 2 + 2, w // 2 - 2 : w // 2 + 2]
    assert np.all(np.abs(centre - expected) < 0.01), (centre, expected)


def test_driving_into_a_wall_is_a_collision_at_the_right_time():
    scenario = box_room_scenario(time_limit=10.0)
    scenario.robot_start = PlanarPose(0.0, -1.5, 0.0)
    config = DiagramConfig(policy="scripted", waypoints=[[6.0, -1.5]])  # through the wall at x = 3
    ed, sim, status = _simulate(scenario, 10.0, config)
    outcome = _eval(ed.monitor, "outcome", sim)
    assert outcome.status == COLLISION and "wall" in outcome.detail
    # Base radius 0.29 m: contact when the base centre reaches x = 2.71 at 0.5 m/s.
    assert outcome.time == pytest.approx(2.71 / 0.5, abs=0.2)
    assert status.reason() == status.ReturnReason.kReachedTerminationCondition


def test_pedestrian_appears_at_trigger_distance():
    scenario = box_room_scenario(with_pedestrian=True)
    ed, sim, _ = _simulate(scenario, 1.5)
    events = _eval(ed.obstacles, "events", sim)
    t = events.time_of("pedestrian")
    # The robot starts 2.0 m away at 0.5 m/s: inside 1.7 m after ~0.6 s.
    assert t is not None and 0.5 <= t <= 0.8
    plant = ed.world.plant
    p = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(sim.get_context()), ed.world.scene.obstacles["pedestrian"].body)
    np.testing.assert_allclose(p.translation(), [0.5, 0.0, 0.85], atol=0.02)


def test_judge_success_needs_lift_held_two_seconds():
    judge = EpisodeJudge(target_rest_height=0.8, time_limit=30.0)
    t = 0.0
    for _ in range(20):  # lifted 12 cm for 1 s, then dropped
        assert judge.update(t, [], 0.92, True).status == RUNNING
        t += 0.05
    judge.update(t, [], 0.85, True)
    t += 0.05
    times = []
    while judge.outcome.status == RUNNING:
        judge.update(t, [], 0.93, True)
        times.append(t)
        t += 0.05
    assert judge.outcome.status == SUCCESS
    assert judge.outcome.time - times[0] == pytest.approx(2.0, abs=1e-6)


def test_judge_collision_rules():
    palm_on_target = Contact("gripper_link", "tomato_soup_can", True, False, 0.002)
    finger = Contact("l_gripper_finger_link", "table_0", False, False, 0.002)
    elbow = Contact("elbow_flex_link", "table_0", False, False, 0.002)
    judge = EpisodeJudge(0.8, 30.0)
    assert judge.update(0.0, [finger], 0.8, False).status == RUNNING
    assert judge.update(0.1, [palm_on_target], 0.8, True).status == RUNNING
    assert judge.update(0.2, [elbow], 0.8, True).status == COLLISION
    judge = EpisodeJudge(0.8, 30.0)
    assert judge.update(0.0, [palm_on_target], 0.8, False).status == COLLISION
    # After grasp initiation the palm may touch the support too, but a
    # self-contact of the palm still counts.
    palm_on_table = Contact("gripper_link", "table_0/top", False, False, 0.002)
    palm_on_base = Contact("gripper_link", "base_link", False, True, 0.002)
    judge = EpisodeJudge(0.8, 30.0)
    assert judge.update(0.0, [palm_on_table], 0.8, True).status == RUNNING
    assert judge.update(0.1, [palm_on_base], 0.8, True).status == COLLISION
    judge = EpisodeJudge(0.8, 30.0)
    assert judge.update(0.0, [palm_on_table], 0.8, False).status == COLLISION
    judge = EpisodeJudge(0.8, 1.0)
    outcome = judge.update(1.0, [], 0.8, False)
    assert outcome.status == PLANNING and outcome.kind == "time_limit"


def test_missing_rendering_library_names_the_package(monkeypatch):
    import ctypes.util

    from vamg_drake import rendering_check

    real = ctypes.util.find_library
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None if name == "EGL" else real(name))
    with pytest.raises(rendering_check.RenderingLibrariesMissing, match="libegl1"):
        rendering_check.check_rendering_libraries()


def test_unknown_policy_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown policy 'nope'"):
        build_diagram(box_room_scenario(), DiagramConfig(policy="nope"))


def test_diagram_config_loads_from_yaml():
    from pydrake.common.yaml import yaml_load_typed

    config = yaml_load_typed(
        schema=DiagramConfig,
        data="world: {time_step: 0.005, camera: {width: 640, height: 480}}\nscripted: {speed: 0.3}\nmonitor: {hold_time: 1.0}",
    )
    assert config.world.camera.width == 640 and config.world.time_step == 0.005
    assert config.scripted.speed == 0.3 and config.monitor.hold_time == 1.0


def test_finger_pads_are_rigid_hydroelastic():
    """The pads make contact patches with the compliant objects (as point
    contacts they squeezed objects out of the grasp); the palm stays a point
    contact geometry."""
    from pydrake.systems.framework import DiagramBuilder

    from vamg_drake.world.world_builder import WorldConfig, build_world

    for fingers in (True, False):
        builder = DiagramBuilder()
        world = build_world(builder, box_room_scenario(), WorldConfig(enable_camera=False, hydroelastic_fingers=fingers))
        inspector = world.scene_graph.model_inspector()
        for link, expected in (("l_gripper_finger_link", fingers), ("r_gripper_finger_link", fingers),
                               ("gripper_link", False)):
            for g in world.plant.GetCollisionGeometriesForBody(world.plant.GetBodyByName(link, world.robot)):
                assert inspector.GetProximityProperties(g).HasGroup("hydroelastic") == expected, link


def _two_object_room():
    import dataclasses as dc

    from vamg_drake.world.scenario import PlacedObject

    scenario = box_room_scenario()
    near = PlacedObject("mug", [2.0, 0.3, 0.80], [0, 0, 0], "table_0/top", 0.75)
    return dc.replace(scenario, objects=scenario.objects + [near])


def test_clutter_sleeps_by_the_gap_between_bounding_spheres():
    """An object sleeps when its bounding sphere stays more than the gap away
    from the target's: a large object stays awake farther out than a small one."""
    import dataclasses as dc

    from vamg_drake.world.scenario import PlacedObject

    scenario = box_room_scenario()  # the target: a soup can at (2, 0, 0.8)
    near_small = PlacedObject("golf_ball", [2.0, 0.35, 0.8], [0, 0, 0], "table_0/top", 0.75)
    far_small = PlacedObject("tennis_ball", [2.0, -0.40, 0.8], [0, 0, 0], "table_0/top", 0.75)
    far_large = PlacedObject("hammer", [2.4, 0.0, 0.8], [0, 0, 0], "table_0/top", 0.75)
    scenario = dc.replace(scenario, objects=scenario.objects + [near_small, far_small, far_large])
    radius = {"tomato_soup_can": 0.05, "golf_ball": 0.02, "tennis_ball": 0.03, "hammer": 0.2}.__getitem__
    config = ClutterSleepConfig(awake_gap=0.2)
    # Gaps: golf ball 0.35 - 0.07 = 0.28, tennis ball 0.40 - 0.08 = 0.32, hammer 0.40 - 0.25 = 0.15.
    assert sleeping_objects(scenario, config, radius) == ["golf_ball", "tennis_ball"]
    assert sleeping_objects(scenario, ClutterSleepConfig(awake_gap=0.3), radius) == ["tennis_ball"]
    assert sleeping_objects(scenario, ClutterSleepConfig(enabled=False), radius) == []
    # The converted hulls' radii (soup can 0.07, golf ball 0.04, tennis ball 0.06, hammer 0.21 m).
    assert sleeping_objects(scenario, config) == ["golf_ball", "tennis_ball"]


@pytest.mark.parametrize("awake_gap, asleep", [(0.1, True), (0.2, False)])
def test_clutter_away_from_the_target_is_built_asleep(awake_gap, asleep):
    config = DiagramConfig(policy="scripted")
    config.world.clutter_sleep = ClutterSleepConfig(awake_gap=awake_gap)
    ed = build_diagram(_two_object_room(), config)
    scene = ed.world.scene
    # The mug is 0.3 m from the target (which never sleeps): their bounding spheres are 0.14 m apart.
    assert scene.asleep == (["mug"] if asleep else [])
    plant = ed.world.plant
    if asleep:
        with pytest.raises(KeyError, match="asleep"):
            scene.object_body("mug")
        # Anchored at its pose, owned by name, so a robot touching it is reported as touching the mug.
        inspector = ed.world.scene_graph.model_inspector()
        (gid,) = [g for g, name in scene.static_geometry_owner.items() if name == "mug"]
        assert inspector.GetFrameId(gid) == inspector.world_frame_id()
        assert np.allclose(inspector.GetPoseInFrame(gid).translation(), [2.0, 0.3, 0.80])
        return
    sim = Simulator(ed.diagram)
    sim.Initialize()
    context = sim.get_mutable_context()
    mug = scene.object_body("mug")
    # Lift the awake mug 5 cm: it falls back onto the table.
    X = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(context), mug)
    X.set_translation(X.translation() + [0, 0, 0.05])
    plant.SetFreeBodyPose(plant.GetMyMutableContextFromRoot(context), mug, X)
    sim.AdvanceTo(1.0)
    z = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(context), mug).translation()[2]
    assert X.translation()[2] - 0.065 < z < X.translation()[2] - 0.035


def test_static_scene_collision_geometry_is_anchored_and_named():
    """Floor, walls and furniture collide as anchored geometry (no broad-phase
    cost per step) and keep their part names for the monitor's reports."""
    ed = build_diagram(_two_object_room(), DiagramConfig(policy="scripted"))
    inspector = ed.world.scene_graph.model_inspector()
    owner = ed.world.scene.static_geometry_owner
    assert {"floor", "walls", "table_0"} <= set(owner.values())
    assert all(inspector.GetFrameId(g) == inspector.world_frame_id() for g in owner)
    plant = ed.world.plant
    for b in plant.GetBodyIndices(ed.world.scene.scene_instance):
        assert not plant.GetCollisionGeometriesForBody(plant.get_body(b))


def test_gripper_opening_is_the_measured_gap_between_the_fingers():
    ed, sim, _ = _simulate(box_room_scenario(), 0.5)
    V = _eval(ed.robot_state, "configuration", sim)
    opening = _eval(ed.robot_state, "gripper_opening", sim)
    assert opening.shape == (1,) and opening[0] == pytest.approx(V[FINGER_SLICE].sum())
    assert opening[0] == pytest.approx(0.1, abs=0.005)  # the scripted driver holds the gripper open
