"""WholeBodyPlanner system: the LeafSystem of the motion layer between the subgoal policy and the tracker.

The decisions (plan, re-check, replan, back out, approach straight, report)
are `vamg_drake.planning.motion_supervisor.MotionSupervisor`'s; this system
feeds it the goal, the map and the robot's configuration at a fixed period,
keeps its `MotionState` in the Context, and keeps the planner's collision
environment up to date with the map.
"""

import dataclasses as dc
import functools
import logging
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.motion_messages import MotionEvent, MotionFeedback, PlannedTrajectory, SubgoalCommand
from vamg_drake.planning.motion_supervisor import MotionInputs, MotionState, MotionSupervisor, PlannerSystemConfig
from vamg_drake.planning.whole_body_planner import WholeBodyPlanner
from vamg_drake.policy.ik import FastIk
from vamg_drake.robot import layout
from vamg_drake.systems.timing import ModuleTimings

_log = logging.getLogger(__name__)


@dc.dataclass(frozen=True)
class EnvironmentState:
    """Which map the planner's collision environment stands for (the PlannerSystem's abstract state).

    Attributes:
        snapshot: the map the planning environment is built from (the
            environment itself is a cache keyed by this snapshot).
        key: the revision of `snapshot` (-1: no map; None: no environment yet).
        revision: the map revision the current trajectory was last checked on.
        time: when the trajectory was last checked against a map [s].
    """

    snapshot: PointMapSnapshot | None = None
    key: int | None = None
    revision: int = -1
    time: float = -np.inf

    def __deepcopy__(self, memo) -> "EnvironmentState":
        return self  # immutable (the snapshot too)


@dc.dataclass(frozen=True)
class _Environment:
    """The planning environment built from one snapshot, with its sorted voxel keys and points."""

    snapshot: PointMapSnapshot | None
    env: CollisionEnvironment
    keys: np.ndarray
    points: np.ndarray


class PlannerSystem(LeafSystem):
    """Plans on request, re-validates on every new map, replans when invalidated.

    .. pydrake_system::

        name: WholeBodyPlanner
        input_ports:
        - goal (SubgoalCommand: goal_id, q_goal, motion, ...)
        - point_map (PointMapSnapshot or None)
        - robot_configuration (11-vector q)
        - target (3-vector p_WT, optional)
        output_ports:
        - trajectory (PlannedTrajectory: the plan and its status; the tracker
          and the gaze follow its ``trajectory``, None: hold still)
        - motion_feedback (MotionFeedback for the SubgoalPolicy)

    Goals: "plan" runs the whole-body planner from the current q; "linear"
    (approach, lift) is a straight joint-space motion at
    `linear_speed_fraction` of the limits; "hold" stops. Every new map
    revision re-checks the rest of a planned trajectory from the robot's
    current q; when it is invalidated the system replans (REPLANNED), or
    reports INVALIDATED when the map put the goal itself in collision, or
    FAILED. A planner exception is logged with its traceback and
    becomes a FAILED motion with reason `EXCEPTION_REASON`; the system never
    raises in an episode.

    State: the `MotionState` (the plan, the retreat history, the approach IK's
    random generator) and the `EnvironmentState` (the map the planning
    environment stands for, when it was last checked) are Context abstract
    state, advanced by the periodic event. The planner, its compiled kernels
    and the collision environment built from the state's map snapshot are
    resources and caches (the environment is rebuilt when the Context's
    snapshot is not the one it was built from), so one built system runs in
    any number of Contexts.
    """

    def __init__(self, config: PlannerSystemConfig | None = None, planner: WholeBodyPlanner | None = None,
                 timings: ModuleTimings | None = None):
        super().__init__()
        self._config = config or PlannerSystemConfig()
        self._planner = planner or WholeBodyPlanner.for_fetch(CollisionEnvironment(), self._config.planner)
        if self._config.warm_up:
            self._planner.warm_up()
        self._supervisor = MotionSupervisor(self._planner, self._config, FastIk(), timings)
        self._timings = timings
        self._environment: _Environment | None = None  # cache: the environment of one snapshot
        self._goal_port = self.DeclareAbstractInputPort("goal", AbstractValue.Make(SubgoalCommand.initial()))
        self._map_port = self.DeclareAbstractInputPort("point_map", AbstractValue.Make(PointMapSnapshot.empty()))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._target_port = self.DeclareVectorInputPort("target", 3)
        self._motion_index = self.DeclareAbstractState(AbstractValue.Make(self._supervisor.initial_state()))
        self._environment_index = self.DeclareAbstractState(AbstractValue.Make(EnvironmentState()))
        self._feedback_index = self.DeclareAbstractState(AbstractValue.Make(MotionFeedback()))
        motion_ticket = {self.abstract_state_ticket(self._motion_index)}
        self.DeclareAbstractOutputPort(
            "trajectory", lambda: AbstractValue.Make(PlannedTrajectory()),
            lambda context, value: value.set_value(self._motion(context).plan), motion_ticket)
        self.DeclareStateOutputPort("motion_feedback", self._feedback_index)
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)

    @property
    def planner(self) -> WholeBodyPlanner:
        return self._planner

    @property
    def config(self) -> PlannerSystemConfig:
        return self._config

    def _motion(self, context) -> MotionState:
        return context.get_abstract_state(self._motion_index).get_value()

    def motion_state(self, context) -> MotionState:
        """The motion supervisor's state in this system's `context`."""
        return self._motion(context)

    def _use_environment(self, snapshot: PointMapSnapshot | None) -> _Environment:
        """Makes the planner's environment the one built from `snapshot` (built when not cached)."""
        cached = self._environment
        if cached is None or cached.snapshot is not snapshot:
            t0 = time.perf_counter()
            if snapshot is None or snapshot.num_points == 0:
                cached = _Environment(snapshot, CollisionEnvironment(), np.zeros(0, np.int64), np.zeros((0, 3)))
            else:
                keys, points = self._obstacles(snapshot)
                order = np.argsort(keys, kind="stable")
                cached = _Environment(snapshot, CollisionEnvironment.from_points(
                    points, resolution=float(snapshot.voxel_size)), keys[order], points[order])
            self._environment = cached
            if self._timings is not None:
                self._timings.add("planner_environment", 1e3 * (time.perf_counter() - t0))
        if self._planner.checker.env is not cached.env:
            self._planner.set_environment(cached.env)
        return cached

    def _set_map(self, environment: EnvironmentState, snapshot) -> EnvironmentState:
        """The environment state for `snapshot`: the planning environment
        rebuilt when the map revision changed, else the one of `environment`."""
        revision = -1 if snapshot is None else int(snapshot.revision)
        if revision != environment.key:
            environment = dc.replace(environment, snapshot=snapshot, key=revision)
        self._use_environment(environment.snapshot)
        return environment

    def _obstacles(self, snapshot) -> tuple[np.ndarray, np.ndarray]:
        """The map's voxel keys and points above `floor_z`."""
        p = np.asarray(snapshot.points, dtype=float)
        keep = p[:, 2] >= self._config.floor_z
        return np.asarray(snapshot.voxel_keys)[keep], p[keep]

    #: With more new points than this fraction of the map, the environment is rebuilt instead.
    _REBUILD_FRACTION = 0.25

    def _new_points_check(self, environment: EnvironmentState, snapshot, p_WT: np.ndarray | None):
        """A path check (path, exempt) against only the map points of
        `snapshot` that the planning environment lacks (new voxels, or a
        voxel's point moved), with the grasp target and support floor of the
        planning environment (or, where `exempt`, of the supervisor's
        `exempt_checker`); None when they are too many (`_REBUILD_FRACTION`)."""
        built = self._use_environment(environment.snapshot)
        t0 = time.perf_counter()
        keys, points = self._obstacles(snapshot)
        old_keys, old_points = built.keys, built.points
        i = np.minimum(np.searchsorted(old_keys, keys), max(old_keys.shape[0] - 1, 0))
        same = np.zeros(keys.shape[0], dtype=bool)
        if old_keys.shape[0]:
            same = (old_keys[i] == keys) & np.all(old_points[i] == points, axis=1)
        new = points[~same]
        if self._timings is not None:
            self._timings.add("planner_new_points", 1e3 * (time.perf_counter() - t0))
        if new.shape[0] > self._REBUILD_FRACTION * points.shape[0]:
            return None  # as costly as a rebuild: rebuild instead
        if new.shape[0] == 0:
            return lambda path, exempt: True
        delta = CollisionEnvironment.from_points(new, resolution=float(snapshot.voxel_size))
        checker = self._planner.checker
        exempt = self._supervisor.exempt_checker(p_WT)
        checkers = {False: checker.with_environment(delta), True: None if exempt is None else checker.with_environment(
            dc.replace(delta, grasp_target=exempt.env.grasp_target, grasp_target_radius=exempt.env.grasp_target_radius,
                       grasp_target_floor=exempt.env.grasp_target_floor))}

        def check(path: np.ndarray, exempt: bool) -> bool:
            return checkers[exempt] is not None and self._planner.path_is_valid(path, checker=checkers[exempt])
        return check

    def _update(self, context, state) -> EventStatus:
        motion = self._motion(context)
        plan = motion.plan
        goal = self._goal_port.Eval(context) if self._goal_port.HasValue(context) else None
        if goal is None:
            return EventStatus.Succeeded()
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        if not np.all(np.isfinite(q)):
            _log.error("WholeBodyPlanner: robot_configuration is not finite (%s); stopping", q)
            state.get_mutable_abstract_state(self._motion_index).set_value(
                dc.replace(motion, plan=dc.replace(plan, trajectory=None)))
            return EventStatus.Succeeded()
        snapshot = self._map_port.Eval(context) if self._map_port.HasValue(context) else None
        p_WT = None
        if self._target_port.HasValue(context):
            p = np.asarray(self._target_port.Eval(context), dtype=float)
            p_WT = p if np.all(np.isfinite(p)) else None
        t = context.get_time()
        environment: EnvironmentState = context.get_abstract_state(self._environment_index).get_value()
        # The planner's environment is the one of this Context's state (a cache of another Context's is replaced).
        if environment.key is not None:
            self._use_environment(environment.snapshot)
        new_goal = goal.goal_id != plan.goal_id
        refresh = new_goal or t - environment.time >= self._config.recheck_period - 1e-9
        path_check = None
        if refresh:
            revision = -1 if snapshot is None else int(snapshot.revision)
            try:
                check = None
                if (self._config.incremental_check and not new_goal and environment.key is not None
                        and snapshot is not None and revision != environment.revision):
                    check = self._new_points_check(environment, snapshot, p_WT)
                if check is not None:
                    path_check = check  # the new points only; rebuilt to plan
                    environment = dc.replace(environment, revision=revision)
                else:
                    environment = self._set_map(environment, snapshot)
                    environment = dc.replace(environment, revision=revision)
            except ValueError as e:
                _log.error("WholeBodyPlanner: bad map (%s)", e)
                return EventStatus.Succeeded()
            environment = dc.replace(environment, time=t)
        # Whatever the supervisor plans is planned on this tick's map.
        planned_on = []

        def before_planning() -> None:
            planned_on.append(self._set_map(environment, snapshot))

        motion, event = self._supervisor.step(motion, MotionInputs(goal, q, t, environment.revision, p_WT, path_check,
                                                                   before_planning))
        if planned_on:
            environment = dc.replace(environment, snapshot=planned_on[-1].snapshot, key=planned_on[-1].key)
        state.get_mutable_abstract_state(self._motion_index).set_value(motion)
        state.get_mutable_abstract_state(self._environment_index).set_value(environment)
        if event != MotionEvent.NONE:
            last = context.get_abstract_state(self._feedback_index).get_value()
            state.get_mutable_abstract_state(self._feedback_index).set_value(
                MotionFeedback(goal.goal_id, event, last.number + 1))
        return EventStatus.Succeeded()
