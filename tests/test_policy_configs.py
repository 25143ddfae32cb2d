"""Every policy config round-trips through Drake's typed YAML."""

from __future__ import annotations

import pytest
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from vamg_drake.config_validation import InputError
from vamg_drake.diagram import DiagramConfig, load_diagram_config
from vamg_drake.policy.behaviour_tree import BehaviourConfig
from vamg_drake.policy.grasp_candidates import AntipodalGraspConfig
from vamg_drake.policy.ik import IkConfig
from vamg_drake.policy.kinematic_maps import KinematicMapsConfig
from vamg_drake.policy.subgoal_pipeline import SubgoalPipelineConfig
from vamg_drake.policy.visibility import VisibilityConfig
from vamg_drake.systems.subgoal_policy_system import SubgoalPolicyConfig


@pytest.mark.parametrize(
    "schema",
    [SubgoalPipelineConfig, KinematicMapsConfig, AntipodalGraspConfig, BehaviourConfig, SubgoalPolicyConfig, VisibilityConfig, IkConfig],
)
def test_yaml_round_trip(schema) -> None:
    assert yaml_load_typed(schema=schema, data=yaml_dump_typed(schema())) == schema()


def test_partial_yaml_overrides() -> None:
    c = yaml_load_typed(schema=SubgoalPipelineConfig, data="pregrasp: {num_bases: 10}\nobserve: {standoff: [1.0, 1.5]}")
    assert c.pregrasp.num_bases == 10 and c.observe.standoff == [1.0, 1.5]
    assert c.pregrasp.samples_per_base == 128


def test_bad_values_name_the_field() -> None:
    # yaml_load_typed skips __post_init__: validate() checks a loaded config.
    c = yaml_load_typed(schema=AntipodalGraspConfig, data="friction_coefficient: 0.0")
    with pytest.raises(ValueError, match="friction_coefficient"):
        c.validate()
    b = yaml_load_typed(schema=BehaviourConfig, data="max_total_failures: -2")
    with pytest.raises(ValueError, match="max_total_failures"):
        b.validate()
    p = yaml_load_typed(schema=SubgoalPipelineConfig, data="pregrasp: {base_radius: [1.0, 0.5]}")
    with pytest.raises(ValueError, match="base_radius"):
        p.validate()
    p = yaml_load_typed(schema=SubgoalPipelineConfig, data="observe: {costmap: {decay_distance: 0.0}}")
    with pytest.raises(ValueError, match="decay_distance"):
        p.validate()
    with pytest.raises(ValueError, match="num_seeds"):
        AntipodalGraspConfig(num_seeds=0)  # direct construction validates


@pytest.mark.parametrize("subgoal, field", [
    ("grasps: {friction_coefficient: 0.0}", "friction_coefficient"),
    ("pregrasp: {base_radius: [1.0, 0.5]}", "base_radius"),
    ("observe: {standoff: []}", "standoff"),
    ("pregrasp: {ik_seed_arm: [0.0, 1.0]}", "ik_seed_arm"),
])
def test_the_diagram_config_validates_the_nested_policy_configs(subgoal: str, field: str) -> None:
    with pytest.raises(InputError, match=field):
        load_diagram_config("bad.yaml", text=f"subgoal: {{{subgoal}}}")
    config = DiagramConfig()
    config.subgoal = yaml_load_typed(schema=SubgoalPipelineConfig, data=subgoal)
    with pytest.raises(ValueError, match=field):
        config.validate()


def test_the_pregrasp_leaves_the_torso_room_for_the_whole_lift() -> None:
    from vamg_drake.policy.behaviour_tree import BehaviourConfig
    from vamg_drake.policy.pregrasp_sampler import PregraspConfig
    from vamg_drake.world.episode_monitor import EpisodeMonitorConfig

    lift = BehaviourConfig().lift_height
    assert PregraspConfig().lift_headroom >= lift
    # The commanded lift clears the success height with room for the object to settle in the fingers.
    assert lift >= EpisodeMonitorConfig().lift_height + 0.03
