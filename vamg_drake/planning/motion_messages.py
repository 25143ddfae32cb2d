"""The messages between the subgoal policy and the motion layer.

The policy sends a `SubgoalCommand` (a goal, its motion kind and the policy's
`Phase`); the motion layer answers with a `PlannedTrajectory` (what it
executes, and why a plan failed; the tracker and the gaze follow its
trajectory) and a `MotionFeedback` (a `MotionEvent` about the goal). Both
sides, and the systems that watch them (the episode monitor, the tracker,
the gaze), import the types from here, below both.
"""

import dataclasses as dc
import enum

import numpy as np

from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout


class Phase(enum.Enum):
    """What the robot is doing for the current subgoal."""

    IDLE = "idle"
    GRASP_MOVE = "grasp_move"  # planned motion to the pre-grasp pose of a grasp
    GRASP_APPROACH = "grasp_approach"  # linear approach to the grasp pose
    GRASP_CLOSE = "grasp_close"
    GRASP_PULL = "grasp_pull"  # linear motion pulling the closed grasp out from under what overhangs it
    GRASP_LIFT = "grasp_lift"
    GRASP_RETREAT = "grasp_retreat"  # the gripper closed on nothing: linear motion back to the pre-grasp pose
    PREGRASP = "pre_grasp"
    OBSERVE = "observe"
    SUCCEEDED = "succeeded"
    FAILED = "failed"


TERMINAL = (Phase.SUCCEEDED, Phase.FAILED)
GRASP_PHASES = (Phase.GRASP_MOVE, Phase.GRASP_APPROACH, Phase.GRASP_CLOSE, Phase.GRASP_PULL, Phase.GRASP_LIFT,
                Phase.GRASP_RETREAT)


def stage_name(phase: Phase) -> str:
    """The coarse phase name other systems key on: "grasp" for every grasp
    phase, "pre_grasp", "observe" (`vamg_drake.world.scenario.POLICY_PHASES`),
    else the phase's own value ("idle", "succeeded", "failed")."""
    return "grasp" if phase in GRASP_PHASES else phase.value


class FailureCategory(enum.Enum):
    """The paper's failure categories that the subgoal policy can decide."""

    NONE = "none"
    REACHABILITY = "reachability"
    PERCEPTION = "perception"
    PLANNING = "planning"
    SUBGOAL = "subgoal"
    IK = "ik"
    #: A sampler raised: a bug, recorded as the episode status "error" with
    #: its traceback, never as one of the paper's categories.
    ERROR = "error"


class MotionEvent(enum.Enum):
    """Feedback from motion execution about the current goal.

    INVALIDATED: the map put the goal itself in collision. REPLANNED: the map
    invalidated the trajectory and the planner replanned to the same goal,
    which is still valid.
    """

    NONE = "none"
    REACHED = "reached"
    FAILED = "failed"
    INVALIDATED = "invalidated"
    REPLANNED = "replanned"


@dc.dataclass(frozen=True)
class SubgoalCommand:
    """The policy's output (the value of the SubgoalPolicy's goal port).

    Attributes:
        goal_id: increments whenever the goal changes.
        q_goal: (11,) goal configuration (the current q while idle or terminal).
        motion: "plan" (whole-body planner), "linear" (straight joint-space
            approach or lift), or "hold".
        phase: the current `Phase`.
        gripper_opening: commanded finger gap [m].
        head: (2,) pan/tilt that sees the target from the goal, or NaN.
        failure: the failure category (NONE unless phase is FAILED).
        reason: a human-readable reason for the last transition.
    """

    goal_id: int
    q_goal: np.ndarray
    motion: str
    phase: Phase
    gripper_opening: float
    head: np.ndarray
    failure: FailureCategory = FailureCategory.NONE
    reason: str = ""

    @staticmethod
    def initial() -> "SubgoalCommand":
        """The command before the policy's first update (goal 0, IDLE): hold
        still with the gripper open; also the model value of goal ports."""
        return SubgoalCommand(0, np.full(layout.NQ, np.nan), "hold", Phase.IDLE, layout.GRIPPER_MAX_OPENING,
                              np.full(2, np.nan))


@dc.dataclass(frozen=True)
class MotionFeedback:
    """What the motion layer reports about goal ``goal_id`` (the value of the
    planner's ``motion_feedback`` output, the policy's input of that name).
    ``number`` counts the planner's reports, so that the same event about the
    same goal twice (two replans) are two reports."""

    goal_id: int = -1
    event: MotionEvent = MotionEvent.NONE
    number: int = 0


@dc.dataclass(frozen=True, eq=False)
class PlannedTrajectory:
    """The value of the `trajectory` output port.

    Attributes:
        goal_id: the policy goal this trajectory serves (-1: none yet).
        trajectory: timed whole-body waypoints on the simulation clock, or None
            (hold still: no goal, a "hold" goal, or a failed plan).
        success: whether the last planning request for goal_id succeeded.
        reason: a `FailureReason` value, or one of the motion supervisor's reasons
            (`vamg_drake.planning.motion_supervisor.EXCEPTION_REASON`, ...) when it did not.
        map_revision: the map revision it was planned or last validated on.
        plan_ms: wall time of the last planning call [ms].
        replans: how often this goal was replanned after an invalidation.
        motion: the goal's motion kind ("plan", "linear", "hold").
        error: the traceback when the planner raised.
        retreat: the trajectory backs out along the robot's own recent path
            (the map put the start in collision); the goal is planned from its end.
        approach_index: from this waypoint on, the gripper may touch the
            target's points: the straight approach that ends a pre-grasp or
            grasp-move motion (`PlannerSystemConfig.approach_retreat`), or 0
            for a grasp-move that starts around the target; -1: nowhere.
        exit_index: up to this waypoint, too, the gripper may touch the
            target's points: a grasp-move that starts around the target and
            leaves it straight along the approach first; -1: nowhere.
    """

    goal_id: int = -1
    trajectory: TimedTrajectory | None = None
    success: bool = False
    reason: str = ""
    map_revision: int = -1
    plan_ms: float = 0.0
    replans: int = 0
    motion: str = "hold"
    error: str = ""
    retreat: bool = False
    approach_index: int = -1
    exit_index: int = -1

