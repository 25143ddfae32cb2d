"""The judge's outcome categories from the policy's and the planner's reports."""

import pytest

from vamg_drake.world.episode_monitor import (
    CATEGORIES,
    COLLISION,
    GRASP,
    PERCEPTION,
    PLANNING,
    REACHABILITY,
    RUNNING,
    SUCCESS,
    Contact,
    EpisodeJudge,
    PolicyReport,
)


@pytest.mark.parametrize("failure, status, kind", [
    ("reachability", REACHABILITY, ""),
    ("perception", PERCEPTION, ""),
    ("ik", "ik", ""),
    ("planning", PLANNING, "timeout"),
    ("subgoal", PLANNING, "subgoal"),
])
def test_policy_failure_categories(failure, status, kind):
    judge = EpisodeJudge(0.8, 60.0)
    assert judge.update(0.0, [], 0.8, False, PolicyReport("observe")).status == RUNNING
    outcome = judge.update(0.05, [], 0.8, False, PolicyReport("failed", failure, "no reachable base pose"))
    assert (outcome.status, outcome.kind) == (status, kind)
    assert outcome.detail == "no reachable base pose" and outcome.status in CATEGORIES


def test_planner_exception_is_an_error_not_a_planning_failure():
    traceback = "Traceback (most recent call last):\n  File \"x.py\", line 1\nRuntimeError: boom"
    outcome = EpisodeJudge(0.8, 60.0).update(1.0, [], 0.8, False,
                                             PolicyReport("pre_grasp", planner_error=traceback))
    assert outcome.status == "error" and outcome.status not in CATEGORIES
    assert outcome.detail == "planner raised: RuntimeError: boom" and outcome.error == traceback


def test_policy_error_failure_is_an_error_with_its_traceback():
    judge = EpisodeJudge(0.8, 60.0)
    outcome = judge.update(0.05, [], 0.8, False, PolicyReport("failed", "error", "Traceback ...\nKeyError: 'x'"))
    assert outcome.status == "error" and outcome.detail == "KeyError: 'x'" and "Traceback" in outcome.error


def test_lift_done_but_not_held_is_a_grasp_failure():
    judge = EpisodeJudge(0.8, 60.0)
    t, outcome = 0.0, None
    while t < 10.0:
        outcome = judge.update(t, [], 0.81, True, PolicyReport("succeeded"))
        if outcome.done:
            break
        t += 0.05
    assert outcome.status == GRASP
    assert outcome.time == pytest.approx(judge.config.grasp_verdict_time, abs=0.06)


def test_held_lift_is_success_even_while_the_policy_reports_done():
    judge = EpisodeJudge(0.8, 60.0)
    t, outcome = 0.0, None
    while t < 10.0:
        outcome = judge.update(t, [], 0.93, True, PolicyReport("succeeded"))
        if outcome.done:
            break
        t += 0.05
    assert outcome.status == SUCCESS


def test_collision_wins_over_a_policy_failure_in_the_same_tick():
    elbow = Contact("elbow_flex_link", "table_0", False, False, 0.002)
    outcome = EpisodeJudge(0.8, 60.0).update(0.0, [elbow], 0.8, False, PolicyReport("failed", "perception"))
    assert outcome.status == COLLISION
