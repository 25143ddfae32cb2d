"""The subgoal policy models the world's head camera, sees as far as the map
integrates points, and checks its goals with the planner's collision padding:
one truth for each, taken from the DiagramConfig."""

from __future__ import annotations

import dataclasses as dc

import numpy as np

import pytest

from scenes import box_room_scenario
from vamg_drake.diagram import DiagramConfig, build_diagram
from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.planning.whole_body_planner import PlannerConfig
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.systems import subgoal_policy_system


def test_the_pipeline_checks_with_the_given_camera_and_padding() -> None:
    camera = HeadCameraConfig(width=160, height=120, depth_max=4.0)
    planner = PlannerConfig(motion_resolution=0.04, extra_padding=0.02)
    pipeline = SubgoalPipeline(KinematicMaps.load_or_build(), camera, 2.5, collision=planner.checker_config())
    assert pipeline.visibility.camera is camera
    assert pipeline.visibility.max_depth == 2.5
    assert pipeline.visibility.intrinsics == CameraIntrinsics.from_config(camera)
    assert pipeline.pregrasp.visibility is pipeline.visibility and pipeline.observe.visibility is pipeline.visibility
    is_free = pipeline.collision_fn(np.array([[5.0, 5.0, 0.5]]), np.array([1.0, 0.0, 0.8]), layout.stow_configuration(0, 0, 0))
    assert is_free.__self__.padding == 0.5 * 0.04 + 0.02
    # Without one, the padding is the default planner's.
    default = SubgoalPipeline(KinematicMaps.load_or_build(), camera, DepthToPointsConfig().depth_max)
    assert default.collision == PlannerConfig().checker_config()


@pytest.fixture
def built_pipelines(monkeypatch) -> list[SubgoalPipeline]:
    """The subgoal pipelines the diagram builds from here on."""
    built = []

    class Recording(SubgoalPipeline):
        def __init__(self, maps, camera, max_depth, **kwargs) -> None:
            super().__init__(maps, camera, max_depth, **kwargs)
            built.append(self)

    monkeypatch.setattr(subgoal_policy_system, "SubgoalPipeline", Recording)
    return built


def test_the_diagram_gives_the_policy_the_world_camera_and_the_planner_padding(built_pipelines) -> None:
    config = DiagramConfig()
    config.world.camera = HeadCameraConfig(width=160, height=120)
    config.planner.planner.extra_padding = 0.01
    ed = build_diagram(box_room_scenario(), config)
    (pipeline,) = built_pipelines
    assert dc.asdict(pipeline.visibility.camera) == dc.asdict(config.world.camera)
    assert pipeline.visibility.intrinsics == ed.world.intrinsics
    assert pipeline.collision == config.planner.planner.checker_config()
    assert pipeline.collision == ed.planner.planner.checker.config


def test_the_policy_sees_the_target_only_within_the_map_range(built_pipelines) -> None:
    config = DiagramConfig()
    config.map.depth.depth_max = 2.2
    assert config.map.depth.depth_max != DepthToPointsConfig().depth_max
    build_diagram(box_room_scenario(), config)
    (pipeline,) = built_pipelines
    vis = pipeline.visibility
    assert vis.max_depth == config.map.depth.depth_max
    assert pipeline.pregrasp.visibility is vis and pipeline.observe.visibility is vis
    # A target straight ahead of the camera counts as seen just inside the map's range, not just beyond it.
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    X_WC = vis.kin.link_poses(q[None], vis.aim_head(q, np.array([2.0, 0.0, 1.0])))[0, vis._camera]
    for depth, seen in ((2.15, True), (2.25, False)):
        p_WT = X_WC[:3, 3] + depth * X_WC[:3, 2]
        assert vis.check(q[None], p_WT)[0][0] == seen, depth


def test_the_visibility_range_must_lie_beyond_the_camera_minimum() -> None:
    with pytest.raises(ValueError, match="max_depth"):
        SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), 0.1)
