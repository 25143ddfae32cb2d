"""WholeBodyPlanner system: the LeafSystem adapter over
`vamg_drake.planning.whole_body_planner.WholeBodyPlanner`."""

import dataclasses as dc
import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from vamg_drake.planning.collision import CollisionEnvironment
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.planning.whole_body_planner import FailureReason, PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout

_log = logging.getLogger(__name__)


@dc.dataclass(frozen=True, eq=False)
class PlannedTrajectory:
    """The value of the `trajectory` output port.

    Attributes:
        goal_id: the policy goal this trajectory serves (-1: none yet).
        trajectory: timed whole-body waypoints on the simulation clock, or None.
        success: whether the last planning request for goal_id succeeded.
        reason: a `FailureReason` value when it did not.
        map_revision: the map revision it was planned or last validated on.
        plan_ms: wall time of the last planning call [ms].
    """

    goal_id: int = -1
    trajectory: TimedTrajectory | None = None
    success: bool = False
    reason: str = ""
    map_revision: int = -1
    plan_ms: float = 0.0


@dc.dataclass
class PlannerSystemConfig:
    """Parameters of the WholeBodyPlanner system.

    Attributes:
        period: how often the system looks for work (new goal, new map) [s].
        floor_z: map points below this height are the floor, not obstacles [m].
        reach_tolerance: q within this of the goal (every joint) reports REACHED.
        planner: the planner's `PlannerConfig`.
    """

    period: float = 0.1
    floor_z: float = 0.03
    reach_tolerance: float = 0.03
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)


class PlannerSystem(LeafSystem):
    """Plans on request, re-validates on every new map, replans when invalidated.

    .. pydrake_system::

        name: WholeBodyPlanner
        input_ports:
        - goal (SubgoalCommand: goal_id, q_goal, motion, ...)
        - point_map (PointMapSnapshot or None)
        - robot_configuration (11-vector q)
        output_ports:
        - trajectory (PlannedTrajectory)
        - motion_feedback (MotionFeedback for the SubgoalPolicy)

    A goal with ``motion == "plan"`` and a new goal_id triggers planning from
    the current q. Each new map revision re-checks the rest of the current
    trajectory; when it is invalidated the system replans from the current q
    and reports INVALIDATED (or FAILED when replanning fails). A failure is
    logged and reported with its reason; the system never raises in an episode.
    The planner core (with its collision environment) lives in the system
    object: use one Context per system instance.
    """

    def __init__(self, config: PlannerSystemConfig | None = None, planner: WholeBodyPlanner | None = None):
        super().__init__()
        from vamg_drake.policy.behaviour_tree import MotionEvent
        from vamg_drake.systems.subgoal_policy_system import MotionFeedback

        self._MotionEvent = MotionEvent
        self._MotionFeedback = MotionFeedback
        self._config = config or PlannerSystemConfig()
        self._planner = planner or WholeBodyPlanner.for_fetch(CollisionEnvironment(), self._config.planner)
        self._goal_port = self.DeclareAbstractInputPort("goal", AbstractValue.Make(None))
        self._map_port = self.DeclareAbstractInputPort("point_map", AbstractValue.Make(None))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._plan_index = self.DeclareAbstractState(AbstractValue.Make(PlannedTrajectory()))
        self._feedback_index = self.DeclareAbstractState(AbstractValue.Make(MotionFeedback()))
        self.DeclareStateOutputPort("trajectory", self._plan_index)
        self.DeclareStateOutputPort("motion_feedback", self._feedback_index)
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)
        self._env_revision = None

    @property
    def planner(self) -> WholeBodyPlanner:
        return self._planner

    def _set_map(self, snapshot) -> int:
        """Rebuilds the collision environment when the map revision changed."""
        revision = -1 if snapshot is None else int(snapshot.revision)
        if revision != self._env_revision:
            if snapshot is None or snapshot.num_points == 0:
                env = CollisionEnvironment()
            else:
                p = np.asarray(snapshot.points, dtype=float)
                p = p[p[:, 2] >= self._config.floor_z]
                env = CollisionEnvironment.from_points(p, resolution=float(snapshot.voxel_size))
            self._planner.set_environment(env)
            self._env_revision = revision
        return revision

    def _update(self, context, state) -> EventStatus:
        MotionEvent = self._MotionEvent
        plan: PlannedTrajectory = context.get_abstract_state(self._plan_index).get_value()
        goal = self._goal_port.Eval(context) if self._goal_port.HasValue(context) else None
        if goal is None or goal.motion != "plan":
            return EventStatus.Succeeded()
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        snapshot = self._map_port.Eval(context) if self._map_port.HasValue(context) else None
        t = context.get_time()
        try:
            revision = self._set_map(snapshot)
        except ValueError as e:
            _log.error("WholeBodyPlanner: bad map (%s)", e)
            return EventStatus.Succeeded()
        feedback = None
        if goal.goal_id != plan.goal_id:
            plan = self._plan(goal, q, t, revision)
            if not plan.success:
                feedback = self._MotionFeedback(goal.goal_id, MotionEvent.FAILED)
        elif plan.success and plan.trajectory is not None:
            if np.all(np.abs(layout.wrap_angle(q - goal.q_goal)) <= self._config.reach_tolerance) and \
                    t >= plan.trajectory.end_time:
                feedback = self._MotionFeedback(goal.goal_id, MotionEvent.REACHED)
            elif revision != plan.map_revision:
                if self._planner.trajectory_is_valid(plan.trajectory, from_time=t):
                    plan = dc.replace(plan, map_revision=revision)
                else:
                    _log.info("WholeBodyPlanner t=%.2f: trajectory invalidated by map %d; replanning", t, revision)
                    plan = self._plan(goal, q, t, revision)
                    event = MotionEvent.INVALIDATED if plan.success else MotionEvent.FAILED
                    feedback = self._MotionFeedback(goal.goal_id, event)
        state.get_mutable_abstract_state(self._plan_index).set_value(plan)
        if feedback is not None:
            state.get_mutable_abstract_state(self._feedback_index).set_value(feedback)
        return EventStatus.Succeeded()

    def _plan(self, goal, q: np.ndarray, t: float, revision: int) -> PlannedTrajectory:
        result = self._planner.plan(q, np.asarray(goal.q_goal, dtype=float))
        if not result.success:
            _log.warning("WholeBodyPlanner t=%.2f: goal %d failed: %s (%s)", t, goal.goal_id, result.reason,
                         result.message)
            return PlannedTrajectory(goal.goal_id, None, False, result.reason or FailureReason.TIMEOUT, revision,
                                     result.timings["total"])
        return PlannedTrajectory(goal.goal_id, result.trajectory.shifted(t), True, "", revision,
                                 result.timings["total"])
