"""The subgoal behaviour tree with injected samplers (no robot model needed)."""

from __future__ import annotations

import numpy as np
import pytest

from behaviour_stepper import Stepper
from vamg_drake.policy.behaviour_tree import (
    BehaviourConfig,
    FailureCategory,
    MotionEvent,
    Phase,
    PolicyInputs,
    SubgoalBehaviour,
    SubgoalProposal,
    SubgoalSamplers,
)
from vamg_drake.robot import layout


class ScriptedSampler:
    """Answers from a list (the last answer repeats) and records its calls."""

    def __init__(self, name: str, answers: list[bool], category=FailureCategory.SUBGOAL) -> None:
        self.name, self.answers, self.category, self.calls = name, answers, category, 0

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        ok = self.answers[min(self.calls, len(self.answers) - 1)]
        self.calls += 1
        if not ok:
            return SubgoalProposal.failure(f"{self.name} failed #{self.calls}", self.category)
        q = np.asarray(inputs.q, float).copy()
        q[0] += {"grasp": 0.0, "pregrasp": 1.0, "observe": -1.0}[self.name]
        q_grasp = q + 0.01 if self.name == "grasp" else None
        return SubgoalProposal(True, q, q_grasp, np.zeros(2))


def _inputs(t: float = 0.0, q: np.ndarray | None = None) -> PolicyInputs:
    return PolicyInputs(t, layout.stow_configuration(0, 0, 0) if q is None else q, np.zeros((0, 3)), np.array([1.0, 0, 0.8]))


def _make(grasp, pre, obs, **cfg):
    samplers = SubgoalSamplers(ScriptedSampler("grasp", grasp), ScriptedSampler("pregrasp", pre), ScriptedSampler("observe", obs))
    return Stepper(SubgoalBehaviour(samplers, BehaviourConfig(**cfg))), samplers


def test_grasp_first_then_full_grasp_sequence() -> None:
    bt, s = _make([True], [True], [True])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.GRASP_MOVE and cmd.motion == "plan" and s.pregrasp.calls == 0
    assert cmd.gripper_opening == layout.GRIPPER_MAX_OPENING
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_APPROACH and cmd.motion == "linear"
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_CLOSE and cmd.gripper_opening == 0.0
    cmd = bt.step(_inputs(2.5, cmd.q_goal))
    assert cmd.phase == Phase.GRASP_CLOSE  # still closing
    cmd = bt.step(_inputs(3.1, cmd.q_goal))
    assert cmd.phase == Phase.GRASP_LIFT and cmd.motion == "linear"
    assert cmd.q_goal[layout.TORSO] > layout.TORSO_STOW
    cmd = bt.step(_inputs(5.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.SUCCEEDED and cmd.failure == FailureCategory.NONE


@pytest.mark.parametrize("proposed, lifted", [(None, 0.15), (0.12, 0.12), (0.5, 0.15)])
def test_the_lift_is_the_grasp_proposal_s_when_it_gives_one(proposed, lifted) -> None:
    q = layout.stow_configuration(0, 0, 0)
    q_grasp = q + 0.01

    class OneGrasp:
        def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
            return SubgoalProposal(True, q, q_grasp, np.zeros(2), lift_height=proposed)

    fail = ScriptedSampler("pregrasp", [False])
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(OneGrasp(), fail, fail), BehaviourConfig(lift_height=0.15)))
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(3.1, cmd.q_goal))
    assert cmd.phase == Phase.GRASP_LIFT
    assert cmd.q_goal[layout.TORSO] == pytest.approx(q_grasp[layout.TORSO] + lifted)


def test_a_grasp_proposed_with_a_pull_out_pulls_then_lifts_from_there() -> None:
    q = layout.stow_configuration(0, 0, 0)
    q_grasp, q_pull = q + 0.01, q + 0.03

    class PulledGrasp:
        def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
            return SubgoalProposal(True, q, q_grasp, np.zeros(2), lift_height=0.12, q_pull=q_pull)

    fail = ScriptedSampler("pregrasp", [False])
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(PulledGrasp(), fail, fail), BehaviourConfig(lift_height=0.15)))
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    pull = bt.step(_opening_inputs(3.1, cmd.q_goal, 0.02))
    assert pull.phase == Phase.GRASP_PULL and pull.motion == "linear" and pull.gripper_opening == 0.0
    np.testing.assert_array_equal(pull.q_goal, q_pull)
    lift = bt.step(_opening_inputs(4.0, pull.q_goal, 0.02), MotionEvent.REACHED)
    assert lift.phase == Phase.GRASP_LIFT and lift.gripper_opening == 0.0
    assert lift.q_goal[layout.TORSO] == pytest.approx(q_pull[layout.TORSO] + 0.12)
    np.testing.assert_array_equal(np.delete(lift.q_goal, layout.TORSO), np.delete(q_pull, layout.TORSO))
    assert bt.step(_opening_inputs(5.0, lift.q_goal, 0.02), MotionEvent.REACHED).phase == Phase.SUCCEEDED
    # A grasp that slips out while being pulled backs off like one that slips while lifting.
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(PulledGrasp(), fail, fail), BehaviourConfig()))
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    pull = bt.step(_opening_inputs(3.1, cmd.q_goal, 0.02))
    assert bt.step(_opening_inputs(3.5, pull.q_goal, 0.0)).phase == Phase.GRASP_RETREAT


def test_fallback_order_grasp_pregrasp_observe_fail() -> None:
    bt, s = _make([False], [False], [True])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.OBSERVE and (s.grasp.calls, s.pregrasp.calls, s.observe.calls) == (1, 1, 1)
    assert "Observe" in bt.tree_status() and bt.stage_failures["pre_grasp"][0] == "pregrasp failed #1"

    bt, s = _make([False], [False], [False])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.SUBGOAL and cmd.motion == "hold"
    assert "pregrasp failed" in cmd.reason
    # Terminal: no more sampling.
    bt.step(_inputs(1.0))
    assert s.grasp.calls == 1


def test_pregrasp_reached_retries_grasp_first() -> None:
    bt, s = _make([False, True], [True], [True])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.PREGRASP
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE and s.grasp.calls == 2


def test_recovers_after_injected_motion_failure() -> None:
    bt, s = _make([True], [True], [True])
    q0 = layout.stow_configuration(0, 0, 0)
    cmd = bt.step(_inputs(0.0, q0))
    assert cmd.phase == Phase.GRASP_MOVE
    first_goal = cmd.goal_id
    # The grasp motion fails: the grasp is blocked at this base, the tree falls back to pre-grasp.
    cmd = bt.step(_inputs(1.0, q0), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP and cmd.goal_id > first_goal
    assert bt.motion_failures["grasp"] == 1 and s.grasp.calls == 1
    # Reaching the pre-grasp base unblocks grasping.
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE and s.grasp.calls == 2


def test_invalidated_goal_is_resampled_without_failure() -> None:
    bt, s = _make([False], [True], [True])
    cmd = bt.step(_inputs())
    cmd2 = bt.step(_inputs(0.5), MotionEvent.INVALIDATED)
    assert cmd2.phase == Phase.PREGRASP and cmd2.goal_id > cmd.goal_id and s.pregrasp.calls == 2
    assert bt.total_failures == 0


def test_a_replanned_pregrasp_goal_is_kept_unless_a_grasp_is_found() -> None:
    """REPLANNED (the trajectory was invalidated, the goal was not) keeps the
    pre-grasp goal without drawing a new one; the grasp stage is tried first."""
    bt, s = _make([False, False, True], [True], [True])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.PREGRASP and s.pregrasp.calls == 1
    kept = bt.step(_inputs(0.5), MotionEvent.REPLANNED)
    assert kept.phase == Phase.PREGRASP and kept.goal_id == cmd.goal_id
    np.testing.assert_array_equal(kept.q_goal, cmd.q_goal)
    assert s.grasp.calls == 2 and s.pregrasp.calls == 1 and bt.total_failures == 0
    grasp = bt.step(_inputs(1.0), MotionEvent.REPLANNED)
    assert grasp.phase == Phase.GRASP_MOVE and grasp.goal_id > cmd.goal_id and s.grasp.calls == 3


def test_a_goal_replanned_too_often_is_resampled_without_a_failure() -> None:
    bt, s = _make([False], [True], [True], max_kept_replans=2)
    cmd = bt.step(_inputs())
    for k in range(2):
        kept = bt.step(_inputs(0.1 * (k + 1)), MotionEvent.REPLANNED)
        assert kept.goal_id == cmd.goal_id
    new = bt.step(_inputs(0.5), MotionEvent.REPLANNED)
    assert new.phase == Phase.PREGRASP and new.goal_id > cmd.goal_id and s.pregrasp.calls == 2
    assert bt.total_failures == 0
    again = bt.step(_inputs(0.6), MotionEvent.REPLANNED)  # the new goal's count starts again
    assert again.goal_id == new.goal_id


def test_a_replanned_observe_goal_gives_way_to_a_pregrasp() -> None:
    bt, s = _make([False], [False, False, True], [True])
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.OBSERVE and s.observe.calls == 1
    kept = bt.step(_inputs(0.5), MotionEvent.REPLANNED)
    assert kept.phase == Phase.OBSERVE and kept.goal_id == cmd.goal_id and s.pregrasp.calls == 2
    pre = bt.step(_inputs(1.0), MotionEvent.REPLANNED)
    assert pre.phase == Phase.PREGRASP and pre.goal_id > cmd.goal_id and s.observe.calls == 1


def test_the_invalidation_budget_counts_since_the_last_reached_goal() -> None:
    """Two invalidations are allowed; a reached goal resets the count, so four
    spread over two goals do not end the episode, three in a row do."""
    bt, s = _make([False], [True] * 20, [True], max_invalidations=2, max_pregrasp_goals=20)
    cmd = bt.step(_inputs())
    for k in range(2):
        cmd = bt.step(_inputs(0.1 * (k + 1)), MotionEvent.INVALIDATED)
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    for k in range(2):
        cmd = bt.step(_inputs(1.1 + 0.1 * k), MotionEvent.INVALIDATED)
    assert cmd.phase == Phase.PREGRASP
    cmd = bt.step(_inputs(1.5), MotionEvent.INVALIDATED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING


def test_repeated_motion_failures_end_with_planning() -> None:
    bt, s = _make([False], [True], [True], max_total_failures=3)
    cmd = bt.step(_inputs())
    for k in range(10):
        cmd = bt.step(_inputs(float(k + 1)), MotionEvent.FAILED)
        if cmd.phase == Phase.FAILED:
            break
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING
    assert bt.history[-1][1] == "failed"


def test_budgets_prevent_endless_cycling() -> None:
    bt, s = _make([False], [True], [True], max_pregrasp_goals=2, max_observe_goals=1)
    cmd = bt.step(_inputs())
    for k in range(20):
        cmd = bt.step(_inputs(float(k + 1), cmd.q_goal), MotionEvent.REACHED)
        if cmd.phase == Phase.FAILED:
            break
    assert cmd.phase == Phase.FAILED
    assert bt.goals_issued == {"grasp": 0, "pre_grasp": 2, "observe": 1}


@pytest.mark.parametrize(
    "pregrasp_category, expected",
    [
        # No grasp candidates and a pre-grasp sample that found nothing: perception.
        (FailureCategory.SUBGOAL, FailureCategory.PERCEPTION),
        # No pre-grasp sample reaches the target (capability and IK both 0) and the
        # camera saw none of it: reachability, the cause no view would remove.
        (FailureCategory.REACHABILITY, FailureCategory.REACHABILITY),
    ],
)
def test_failure_category_when_no_grasp_and_no_pregrasp(pregrasp_category, expected) -> None:
    samplers = SubgoalSamplers(
        ScriptedSampler("grasp", [False], FailureCategory.PERCEPTION),
        ScriptedSampler("pregrasp", [False], pregrasp_category),
        ScriptedSampler("observe", [False]),
    )
    cmd = Stepper(SubgoalBehaviour(samplers)).step(_inputs())
    assert cmd.failure == expected


def test_sampler_exception_is_a_recorded_failure() -> None:
    def broken(inputs):
        raise RuntimeError("boom")

    samplers = SubgoalSamplers(broken, ScriptedSampler("pregrasp", [True]), ScriptedSampler("observe", [True]))
    bt = Stepper(SubgoalBehaviour(samplers))
    cmd = bt.step(_inputs())
    # Recorded as the stage's failure, and the episode ends as an error (see the test below).
    assert bt.stage_failures["grasp"] == ("grasp sampler raised RuntimeError: boom", "error")
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.ERROR


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="max_total_failures"):
        BehaviourConfig(max_total_failures=-1)


def test_a_raising_sampler_ends_the_episode_as_an_error_with_its_traceback() -> None:
    """A sampler bug is an error, not a subgoal (planning) failure, even when
    another stage could still produce a goal."""

    def broken(inputs: PolicyInputs) -> SubgoalProposal:
        raise ZeroDivisionError("injected sampler fault")

    samplers = SubgoalSamplers(broken, ScriptedSampler("pregrasp", [True]), ScriptedSampler("observe", [True]))
    cmd = Stepper(SubgoalBehaviour(samplers, BehaviourConfig())).step(_inputs())
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.ERROR and cmd.motion == "hold"
    assert "Traceback" in cmd.reason and "ZeroDivisionError: injected sampler fault" in cmd.reason


class RandomSampler:
    """Proposes a goal a random distance ahead; remembers its generator (a `SamplerMemory`)."""

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        q = np.asarray(inputs.q, float).copy()
        q[0] += self.rng.uniform(0.5, 1.5)
        return SubgoalProposal(True, q, q + 0.01, np.zeros(2))

    def save_state(self) -> dict:
        return self.rng.bit_generator.state

    def load_state(self, state: dict) -> None:
        self.rng.bit_generator.state = state


def test_a_step_is_a_function_of_the_state_and_the_inputs() -> None:
    """The state a step is given is left as it was, and stepping it again
    gives the same answer: the samplers' random generator is part of it."""
    sampler = RandomSampler()
    bt = SubgoalBehaviour(SubgoalSamplers(sampler, sampler, sampler, memory=(sampler,)))
    initial = bt.initial_state()
    first, cmd = bt.step(initial, _inputs())
    again, cmd_again = bt.step(initial, _inputs())
    assert initial.phase == Phase.IDLE and initial.history == () and initial.goal_id == 0
    assert cmd.goal_id == cmd_again.goal_id == 1 and cmd.phase == Phase.GRASP_MOVE
    np.testing.assert_array_equal(cmd.q_goal, cmd_again.q_goal)
    assert first.history == again.history
    # A failed motion resamples: a new random goal, the same from both copies of the state.
    _, failed = bt.step(first, _inputs(1.0), MotionEvent.FAILED)
    _, failed_again = bt.step(again, _inputs(1.0), MotionEvent.FAILED)
    assert failed.goal_id == 2 and failed.phase == Phase.PREGRASP
    np.testing.assert_array_equal(failed.q_goal, failed_again.q_goal)
    assert failed.q_goal[0] != cmd.q_goal[0]
    assert first.motion_failure_counts["grasp"] == 0  # the step did not change the state it was given


def test_the_bases_of_failed_pre_grasp_motions_are_given_to_the_samplers() -> None:
    seen = []

    class RecordingPregrasp(ScriptedSampler):
        def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
            seen.append(None if inputs.failed_bases is None else np.array(inputs.failed_bases))
            return super().__call__(inputs)

    samplers = SubgoalSamplers(ScriptedSampler("grasp", [False]), RecordingPregrasp("pregrasp", [True]),
                               ScriptedSampler("observe", [True]))
    bt = Stepper(SubgoalBehaviour(samplers))
    first = bt.step(_inputs())
    assert first.phase == Phase.PREGRASP and seen == [None]
    second = bt.step(_inputs(1.0), MotionEvent.FAILED)
    assert second.phase == Phase.PREGRASP
    np.testing.assert_array_equal(seen[1], [first.q_goal[layout.BASE_XY]])
    bt.step(_inputs(2.0), MotionEvent.INVALIDATED)  # an invalidated goal is not a failed one
    assert len(seen[2]) == 1


class RecordingGrasp(ScriptedSampler):
    """A grasp sampler that always succeeds and keeps the failed grasps it was shown."""

    def __init__(self) -> None:
        super().__init__("grasp", [True])
        self.failed_seen: list = []

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        self.failed_seen.append(None if inputs.failed_grasps is None else len(inputs.failed_grasps))
        return super().__call__(inputs)


def _opening_inputs(t: float, q: np.ndarray, opening: float | None) -> PolicyInputs:
    return PolicyInputs(t, q, np.zeros((0, 3)), np.array([1.0, 0, 0.8]), gripper_opening=opening)


def _to_closing(bt: Stepper):
    """Steps a fresh grasp to GRASP_CLOSE; returns (pre-grasp command, closing command)."""
    move = bt.step(_opening_inputs(0.0, layout.stow_configuration(0, 0, 0), 0.1))
    approach = bt.step(_opening_inputs(1.0, move.q_goal, 0.1), MotionEvent.REACHED)
    close = bt.step(_opening_inputs(2.0, approach.q_goal, 0.1), MotionEvent.REACHED)
    assert close.phase == Phase.GRASP_CLOSE
    return move, close


def test_a_grasp_that_closes_on_nothing_backs_off_and_another_is_sampled() -> None:
    grasp, fail = RecordingGrasp(), ScriptedSampler("pregrasp", [False])
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(grasp, fail, fail), BehaviourConfig(max_grasp_retries=2)))
    move, close = _to_closing(bt)
    assert bt.step(_opening_inputs(2.5, close.q_goal, 0.03)).phase == Phase.GRASP_CLOSE  # still closing
    back = bt.step(_opening_inputs(2.8, close.q_goal, 0.0005))
    assert back.phase == Phase.GRASP_RETREAT and back.motion == "linear"
    assert back.gripper_opening == layout.GRIPPER_MAX_OPENING  # the fingers open as the arm backs off
    # Back to the pre-grasp pose (the torso no lower than it is).
    np.testing.assert_allclose(np.delete(back.q_goal, layout.TORSO), np.delete(move.q_goal, layout.TORSO))
    assert back.q_goal[layout.TORSO] == pytest.approx(close.q_goal[layout.TORSO])
    again = bt.step(_opening_inputs(4.0, back.q_goal, 0.1), MotionEvent.REACHED)
    assert again.phase == Phase.GRASP_MOVE and again.goal_id > back.goal_id
    assert grasp.failed_seen == [None, 1]  # the retry's sampler was shown the failed grasp
    assert len(bt.state.failed_grasps) == 1 and bt.state.failure == FailureCategory.NONE


def test_a_grasp_that_slips_while_lifting_backs_off_at_the_height_reached() -> None:
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(RecordingGrasp(), *[ScriptedSampler("pregrasp", [False])] * 2)))
    move, close = _to_closing(bt)
    lift = bt.step(_opening_inputs(3.1, close.q_goal, 0.02))
    assert lift.phase == Phase.GRASP_LIFT  # something is held: lifting
    half_lifted = close.q_goal.copy()
    half_lifted[layout.TORSO] += 0.05
    back = bt.step(_opening_inputs(3.6, half_lifted, 0.001))
    assert back.phase == Phase.GRASP_RETREAT
    assert back.q_goal[layout.TORSO] == pytest.approx(max(move.q_goal[layout.TORSO], half_lifted[layout.TORSO]))
    np.testing.assert_allclose(np.delete(back.q_goal, layout.TORSO), np.delete(move.q_goal, layout.TORSO))


@pytest.mark.parametrize("opening", [None, 0.02])
def test_a_held_or_unmeasured_grasp_is_lifted_as_before(opening) -> None:
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(RecordingGrasp(), *[ScriptedSampler("pregrasp", [False])] * 2)))
    _, close = _to_closing(bt)
    lift = bt.step(_opening_inputs(3.1, close.q_goal, opening))
    assert lift.phase == Phase.GRASP_LIFT
    done = bt.step(_opening_inputs(5.0, lift.q_goal, opening), MotionEvent.REACHED)
    assert done.phase == Phase.SUCCEEDED


def test_the_last_retry_is_lifted_whatever_it_holds() -> None:
    grasp = RecordingGrasp()
    bt = Stepper(SubgoalBehaviour(SubgoalSamplers(grasp, *[ScriptedSampler("pregrasp", [False])] * 2),
                                  BehaviourConfig(max_grasp_retries=1)))
    _, close = _to_closing(bt)
    back = bt.step(_opening_inputs(3.1, close.q_goal, 0.0))
    assert back.phase == Phase.GRASP_RETREAT
    move = bt.step(_opening_inputs(4.0, back.q_goal, 0.1), MotionEvent.REACHED)
    approach = bt.step(_opening_inputs(5.0, move.q_goal, 0.1), MotionEvent.REACHED)
    close = bt.step(_opening_inputs(6.0, approach.q_goal, 0.1), MotionEvent.REACHED)
    lift = bt.step(_opening_inputs(7.1, close.q_goal, 0.0))
    assert lift.phase == Phase.GRASP_LIFT  # no retries left: the episode judges the lift
    assert bt.step(_opening_inputs(9.0, lift.q_goal, 0.0), MotionEvent.REACHED).phase == Phase.SUCCEEDED
