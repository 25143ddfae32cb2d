"""The oracle grasp check: a free gripper lifts what it can, and only that enters a suite."""

import copy
import json

import pytest

from vamg_drake.bench.oracle_grasp import OracleGraspConfig, check_graspable, grasp_candidates
from vamg_drake.bench.suites import SuiteConfig, materialize_suite
from vamg_drake.world.rooms import generate_scenario


@pytest.fixture(scope="module")
def scene0():
    return generate_scenario(0)


def test_a_free_gripper_lifts_a_small_object(scene0):
    result = check_graspable(scene0, "golf_ball")
    assert result.graspable, result.reason
    assert result.lift >= 0.03


def test_a_target_wider_than_the_opening_is_not_graspable(scene0):
    scenario = copy.deepcopy(scene0)
    obj = scenario.object("bleach_cleanser")
    obj.name = "bowl"  # 16 cm across: no grasp fits the 10 cm opening
    scenario.target = "bowl"
    assert grasp_candidates(scenario, "bowl") == []
    result = check_graspable(scenario)
    assert not result.graspable
    assert "opening" in result.reason


def test_a_gripper_too_weak_to_lift_fails_in_physics(scene0):
    # Candidates fit, but 0.2 N of grip cannot hold a 0.43 kg bottle against gravity.
    config = OracleGraspConfig(grip_force=0.2, max_candidates=2)
    assert grasp_candidates(scene0, "bleach_cleanser", config)
    result = check_graspable(scene0, "bleach_cleanser", config)
    assert not result.graspable
    assert result.tried == 2
    assert "no candidate lifted it" in result.reason


def test_suite_excludes_targets_the_oracle_cannot_lift(tmp_path):
    # A gripper that can lift nothing: every object of the scene is excluded,
    # with the reason in the manifest, and no scenario enters the suite.
    weak = SuiteConfig(name="weak", scenes=1, targets_per_scene=2, time_limit=3.0,
                       oracle_config=OracleGraspConfig(grip_force=0.2, max_candidates=1))
    suite = materialize_suite(weak, tmp_path, progress=False)
    assert suite.scenarios == []
    excluded = {e["object"] for e in suite.excluded}
    assert "marbles_a" in excluded  # the generator's own target of scene 0
    assert all("oracle grasp check" in e["reason"] for e in suite.excluded)
    manifest = json.loads((tmp_path / "suites" / "weak" / "manifest.json").read_text())
    assert len(manifest["excluded"]) == len(suite.excluded)
