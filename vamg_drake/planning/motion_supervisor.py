"""The motion layer's decisions, without a simulator: `MotionSupervisor`.

The paper's receding-horizon loop (appendix "Arm Motion with Replanning"):
plan on a new goal, re-check the rest of the trajectory on every new map,
stop and replan when it is invalidated (at most ``max_replans`` times per
goal), back out along the robot's own path when the map puts its start in
collision, approach a grasp target straight from behind, and report REACHED /
FAILED / INVALIDATED (the goal is in collision) / REPLANNED (the trajectory
was, the goal is not) to the policy. `MotionSupervisor.step` maps a
`MotionState` and the tick's `MotionInputs` to the next state and a
`MotionEvent`; `vamg_drake.systems.planner_system.PlannerSystem` is its
LeafSystem, which keeps the state in the Context.
"""

from collections.abc import Callable
import dataclasses as dc
import functools
import logging
import time
import traceback
from typing import Protocol

import numpy as np
from pydrake.math import RotationMatrix

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.planning.motion_messages import MotionEvent, Phase, PlannedTrajectory, SubgoalCommand
from vamg_drake.planning.smoothing import time_parametrize
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.planning.whole_body_planner import FailureReason, PlannerConfig, PlanResult, WholeBodyPlanner
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FetchKinematics

_log = logging.getLogger(__name__)

#: `PlannedTrajectory.reason` when the planner raised (the traceback is logged).
EXCEPTION_REASON = "exception"
#: `PlannedTrajectory.reason` when a goal was invalidated more than `PlannerSystemConfig.max_replans` times.
REPLAN_LIMIT_REASON = "replan_limit"
#: `PlannedTrajectory.reason` when a planned path takes the arm into the floor.
FLOOR_REASON = "arm_below_floor"


def arm_floor_clearance(checker: SphereCollisionChecker, path: np.ndarray) -> float:
    """The lowest point of the arm's (unpadded) spheres over the configurations
    path (K, 11) [m], from the checker's compiled sphere centres.

    The map drops the floor (its points are not obstacles); the planner's
    checker keeps the arm above it (`CollisionCheckerConfig.arm_floor_clearance`)
    at its checked states, and the motion layer checks the planned path too.
    """
    arm = checker.is_arm
    centres = checker.sphere_centers(np.atleast_2d(path))[:, arm]
    return float(np.min(centres[..., 2] - checker.base_radius[arm]))


@dc.dataclass
class PlannerSystemConfig:
    """Parameters of the motion layer: the WholeBodyPlanner system and its `MotionSupervisor`.

    Attributes:
        period: how often the system looks for work (new goal, new map) [s].
        floor_z: map points below this height are the floor, not obstacles [m].
        target_clearance: map points this close to the target are the object
            to grasp, which the gripper may touch (the rest of the robot may
            not) only where it is meant to: on the straight approach that ends
            a pre-grasp or grasp-move motion (`approach_retreat`), and, for a
            grasp-move motion that starts with the gripper already around the
            target (from the reached pre-grasp), on the straight way out
            along its approach (or, where the goal is the same pre-grasp
            adjusted or there is no way out, on the whole motion). Everywhere else they are
            obstacles to the gripper too: with the exemption on every motion,
            the palm could sweep through the target between two pre-grasp
            poses, and the gripper could strike the table while unfolding the
            arm from the stow to a grasp's pre-grasp [m].
        reach_tolerance: every joint of q within this of the goal reports REACHED.
        linear_reach_tolerance: the same for "linear" goals (the grasp approach
            and lift), which must end on the grasp pose: 0.03 rad per arm joint
            can leave the gripper 1.5-2 cm off it, enough to miss a small object.
        settle_time: after the trajectory's end, how long the robot may take to
            settle within `reach_tolerance` [s], plus `settle_time_fraction`
            of the trajectory's duration (the tracker follows the path, not
            the clock, and falls behind on long motions: a 6.4 s motion ending
            in a three-point turn can end 3.5 s late) ...
        settle_tolerance: ... after which a q within this looser tolerance still
            counts as REACHED; farther away the motion FAILED.
        max_replans: replans after invalidations per goal (the appendix's K).
        replan_period: > 0 replans towards the goal at this period whether or not
            the trajectory was invalidated (the closed-loop-replanning baseline) [s].
        linear_speed_fraction: linear motions (approach, lift) move at this
            fraction of the joint velocity limits.
        warm_up: load the planner's compiled kernels when the system is built
            (else the episode's first searches pay it, ~12 ms from numba's
            cache, seconds when compiling).
        floor_clearance: a planned path whose arm spheres come closer to the
            floor than this is rejected (FAILED, `FLOOR_REASON`); the floor is
            not in the map, so nothing else keeps the gripper off it [m].
        approach_retreat: a pre-grasp or grasp-move goal whose gripper touches
            the target's points (the open fingers straddle the object, and the
            sphere model fills the space between them) is reached in two parts: a path free
            of every point to the goal with the gripper drawn back this far
            along its approach axis (or half as far where the arm cannot
            reach back so far; IK, base and torso fixed), then the
            straight joint-space approach, on which the gripper may touch the
            target's points as the pre-grasp sampler allows. Without it such
            goals are "in collision" for the planner, which plans pre-grasp
            motions with the target's points as obstacles to the gripper too,
            so every pre-grasp goal around the target fails [m]; 0 = off.
        retreat_history_time: when the map puts the start in collision (points
            seen late, inside the sphere model that bulges past the robot's
            geometry), the robot backs out along at most this much of its own
            recent path [s] to the first configuration the padded spheres
            find free, and the goal is planned from there (without it every
            motion from such a start fails at once, and the failures end the
            episode); 0 = off.
        recheck_period: the trajectory is re-checked against a newer map at
            most this often, except when a new goal must be planned at once [s].
        incremental_check: re-check the trajectory against only the map points
            added (or moved) since the planning environment was built, in a
            small distance field of their own, and rebuild the planning
            environment only to plan: the rest of the path was free of the
            older points when it was planned or last rebuilt. Rebuilding a
            room-sized distance field costs 0.1-0.6 s, and rebuilding it for
            every re-check (tens of times an episode) can take 40 % of the
            episode's wall time.
        planner: the planner's `PlannerConfig`.
    """

    period: float = 0.1
    floor_z: float = 0.03
    target_clearance: float = 0.10
    reach_tolerance: float = 0.03
    linear_reach_tolerance: float = 0.012
    settle_time: float = 3.0
    settle_time_fraction: float = 0.5
    settle_tolerance: float = 0.12
    max_replans: int = 8
    replan_period: float = 0.0
    linear_speed_fraction: float = 0.25
    recheck_period: float = 0.3
    incremental_check: bool = True
    floor_clearance: float = 0.02
    retreat_history_time: float = 20.0
    approach_retreat: float = 0.10
    warm_up: bool = True
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)


def linear_trajectory(q_from: np.ndarray, q_to: np.ndarray, t0: float, speed_fraction: float,
                      step: float = 0.02) -> TimedTrajectory:
    """A straight joint-space motion from q_from to q_to at a fraction of the velocity limits."""
    q_to = q_from + layout.wrap_configuration(np.asarray(q_to, float) - q_from)
    rate = np.asarray(layout.V_MAX, float) * speed_fraction
    duration = max(float(np.max(np.abs(q_to - q_from) / rate)), 0.2)
    n = max(2, int(np.ceil(duration / step)) + 1)
    s = np.linspace(0.0, 1.0, n)
    return TimedTrajectory(t0 + s * duration, q_from[None] + s[:, None] * (q_to - q_from)[None])


def nearest_waypoint(trajectory: TimedTrajectory, q: np.ndarray) -> int:
    """Index of the waypoint nearest to q (base position, heading and joints weighted alike)."""
    d = layout.wrap_configuration(trajectory.q - q[None])
    return int(np.argmin(np.sum(d * d, axis=1)))


def remaining_path(trajectory: TimedTrajectory, q: np.ndarray) -> np.ndarray:
    """The rest of the path from the robot's q: q itself, then the waypoints after the nearest one."""
    k = nearest_waypoint(trajectory, q)
    q0 = trajectory.q[k] + layout.wrap_configuration(q - trajectory.q[k])
    return np.concatenate([q0[None], trajectory.q[k + 1:]])


class Timings(Protocol):
    """Where the supervisor reports its modules' costs (`vamg_drake.systems.timing.ModuleTimings`)."""

    def add(self, module: str, ms: float) -> None: ...


class ApproachIk(Protocol):
    """Arm-only IK with its random generator exposed (`vamg_drake.policy.ik.FastIk`)."""

    rng: np.random.Generator

    def solve_arm(self, X_WG: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


#: Checks (path, exempt) the rest of a path against the map of the tick, with
#: the gripper allowed the target's points where `exempt`.
PathCheck = Callable[[np.ndarray, bool], bool]


@dc.dataclass(frozen=True)
class MotionInputs:
    """What the supervisor sees at one tick.

    Attributes:
        goal: the policy's goal (None: no goal connected yet).
        q: the robot's configuration (11,).
        t: the simulation time [s].
        revision: the map revision the environment stands for.
        p_WT: the grasp target (3,), or None.
        path_check: checks the rest of a path against this tick's map (None:
            the planner's environment, `MotionSupervisor.check_path`).
        before_planning: brings the planner's environment up to this tick's
            map; called before every plan (None: it is up to date).
    """

    goal: SubgoalCommand | None
    q: np.ndarray
    t: float
    revision: int
    p_WT: np.ndarray | None = None
    path_check: PathCheck | None = None
    before_planning: Callable[[], None] | None = None


@dc.dataclass(frozen=True)
class MotionState:
    """What the supervisor remembers between ticks (the PlannerSystem's abstract state).

    Immutable: `MotionSupervisor.step` returns a new one, and its arrays are
    read-only, so ``copy.deepcopy`` (how Drake clones abstract state) returns
    the state itself.

    Attributes:
        plan: the current `PlannedTrajectory` (the ``trajectory`` output).
        last_replan_time: when the supervisor last planned [s].
        history: (t, q) of the robot's recent configurations, oldest first, for retreats.
        retreats: (goal id, retreats) of the goals the robot backed out for.
        ik_rng: the approach IK's random generator state (None: no approach IK).
    """

    plan: PlannedTrajectory = PlannedTrajectory()
    last_replan_time: float = -np.inf
    history: tuple[tuple[float, np.ndarray], ...] = ()
    retreats: tuple[tuple[int, int], ...] = ()
    ik_rng: dict | None = None

    def __deepcopy__(self, memo) -> "MotionState":
        return self


@dc.dataclass
class _Work:
    """One step's working copy of the state, with the tick's inputs."""

    inputs: MotionInputs
    last_replan_time: float
    history: list
    retreats: dict
    ik_rng: dict | None


class MotionSupervisor:
    """Decides, at each tick, what the motion layer does for the policy's goal.

    Plain Python over a `WholeBodyPlanner`: `step` takes a `MotionState` and
    the tick's `MotionInputs` and returns the next state (with the new
    `PlannedTrajectory`) and a `MotionEvent` for the policy; it never mutates
    the state it is given. The caller sets the planner's environment before
    stepping (`MotionInputs.before_planning` brings it up to date to plan).
    The planner, the approach IK and the checkers derived from the planner's
    environment are fixed resources or caches keyed by what they are built
    from; nothing the next step depends on is kept here.

    Args:
        planner: the whole-body planner (its environment is set by the caller).
        config: the motion layer's parameters.
        approach_ik: arm-only IK for the straight approaches (``solve_arm(X_WG
            (K, 4, 4), q_seed (11,)) -> (q (K, 11), ok (K,))``, random
            restarts drawn from its ``rng``, whose state the supervisor keeps
            in `MotionState.ik_rng`); None: no approaches from behind.
        timings: collects the planner's and the checks' costs (``add(module, ms)``).
    """

    def __init__(self, planner: WholeBodyPlanner, config: PlannerSystemConfig, approach_ik: ApproachIk | None = None,
                 timings: Timings | None = None) -> None:
        self.planner = planner
        self.config = config
        self.timings = timings
        self._ik = approach_ik
        self._initial_ik_rng = None if approach_ik is None else approach_ik.rng.bit_generator.state
        self._exempt: tuple | None = None  # cache: (environment, checker with the target's exemption, target)

    def initial_state(self) -> MotionState:
        """The state before the first tick (no goal, no plan)."""
        return MotionState(ik_rng=self._initial_ik_rng)

    def step(self, state: MotionState, inputs: MotionInputs) -> tuple[MotionState, MotionEvent]:
        """(the next state, the event for the policy) after one tick."""
        w = _Work(inputs, state.last_replan_time, list(state.history), dict(state.retreats), state.ik_rng)
        plan, event = self._tick(w, state.plan)
        return MotionState(plan, w.last_replan_time, tuple(w.history), tuple(sorted(w.retreats.items())),
                           w.ik_rng), event

    def _tick(self, w: "_Work", plan: PlannedTrajectory) -> tuple[PlannedTrajectory, MotionEvent]:
        cfg = self.config
        goal, q, t, revision = w.inputs.goal, w.inputs.q, w.inputs.t, w.inputs.revision
        self._record(w, q, t)
        if goal is None:
            return plan, MotionEvent.NONE
        if goal.goal_id != plan.goal_id:
            return self._start(w, goal, q, t, revision)
        if goal.motion == "hold" or plan.trajectory is None:
            return plan, MotionEvent.NONE
        if plan.retreat:
            # Backing out along the robot's own path: then plan to the goal.
            end = plan.trajectory.q[-1]
            settled = np.all(np.abs(layout.wrap_configuration(q - end)) <= cfg.reach_tolerance)
            if t >= plan.trajectory.end_time and (settled or t >= plan.trajectory.end_time + cfg.settle_time):
                new = self._plan(w, goal, q, t, revision)
                new = dc.replace(new, replans=plan.replans)
                return new, (MotionEvent.NONE if new.success else self._failure_event(new))
            return plan, MotionEvent.NONE
        error = np.abs(layout.wrap_configuration(q - np.asarray(goal.q_goal, float)))
        if t >= plan.trajectory.end_time:
            tolerance = cfg.linear_reach_tolerance if goal.motion == "linear" else cfg.reach_tolerance
            if np.all(error <= tolerance):
                return plan, MotionEvent.REACHED
            slack = cfg.settle_time + cfg.settle_time_fraction * plan.trajectory.duration
            if t >= plan.trajectory.end_time + slack:
                if np.all(error <= cfg.settle_tolerance):
                    return plan, MotionEvent.REACHED
                worst = int(np.argmax(error))
                _log.warning("motion t=%.2f: goal %d not reached %.1f s after the trajectory ended (max error %.3f "
                             "at %s)", t, goal.goal_id, slack, float(error[worst]),
                             layout.WHOLE_BODY_JOINTS[worst])
                return dc.replace(plan, trajectory=None, success=False, reason=FailureReason.TIMEOUT), MotionEvent.FAILED
        if goal.motion != "plan":
            return plan, MotionEvent.NONE
        periodic = cfg.replan_period > 0 and t - w.last_replan_time >= cfg.replan_period
        if revision == plan.map_revision and not periodic:
            return plan, MotionEvent.NONE
        if not periodic:
            t0 = time.perf_counter()
            valid = self._rest_is_valid(w, plan, q)
            if self.timings is not None:
                self.timings.add("trajectory_check", 1e3 * (time.perf_counter() - t0))
            if valid:
                return dc.replace(plan, map_revision=revision), MotionEvent.NONE
        if not periodic:
            if plan.replans >= cfg.max_replans:
                _log.warning("motion t=%.2f: goal %d invalidated more than %d times", t, goal.goal_id, cfg.max_replans)
                return dc.replace(plan, trajectory=None, success=False, reason=REPLAN_LIMIT_REASON), MotionEvent.FAILED
            _log.info("motion t=%.2f: trajectory invalidated by map %d; replanning", t, revision)
        new = self._plan(w, goal, q, t, revision)
        new = dc.replace(new, replans=plan.replans + (0 if periodic else 1))
        if periodic:
            # The baseline keeps executing the old plan when a periodic replan fails.
            return (new if new.success else dc.replace(plan, map_revision=revision)), MotionEvent.NONE
        return new, (MotionEvent.REPLANNED if new.success else self._failure_event(new))

    def _rest_is_valid(self, w: "_Work", plan: PlannedTrajectory, q: np.ndarray) -> bool:
        """The rest of the plan from q: up to its exit (if any) with, then up
        to its approach (if any) without, and from there with, the gripper's
        exemption from the target's points."""
        check = w.inputs.path_check or functools.partial(self.check_path, p_WT=w.inputs.p_WT)
        k = nearest_waypoint(plan.trajectory, q)
        rest = remaining_path(plan.trajectory, q)
        start = max(plan.exit_index - k, 0)
        if start > 0 and not check(rest[:start + 1], True):
            return False
        rest = rest[start:]
        if plan.approach_index < 0:
            return check(rest, False)
        split = max(plan.approach_index - k - start, 0)
        return ((split == 0 or check(rest[:split + 1], False))
                and (split >= len(rest) - 1 or check(rest[split:], True)))

    def check_path(self, path: np.ndarray, exempt: bool, p_WT: np.ndarray | None = None) -> bool:
        """`WholeBodyPlanner.path_is_valid` on the planner's environment, or
        with the gripper allowed the points of the target p_WT (`exempt`)."""
        checker = self.exempt_checker(p_WT) if exempt else None
        if exempt and checker is None:
            return False
        return self.planner.path_is_valid(path, checker=checker)

    def exempt_checker(self, p_WT: np.ndarray | None) -> SphereCollisionChecker | None:
        """The planner's checker whose environment lets the gripper touch the
        points near the target p_WT; None without a target. Cached for the
        planner's environment and the target."""
        env = self.planner.checker.env
        if p_WT is None:
            return None
        if self._exempt is None or self._exempt[0] is not env or not np.array_equal(self._exempt[2], p_WT):
            exempt_env = env.with_grasp_target(p_WT, self.config.target_clearance)
            self._exempt = (env, self.planner.checker.with_environment(exempt_env), np.array(p_WT))
        return self._exempt[1]

    def _plan_with(self, env: CollisionEnvironment, q: np.ndarray, q_goal: np.ndarray):
        """`WholeBodyPlanner.plan` in another environment (the planner's is restored)."""
        own = self.planner.checker.env
        self.planner.set_environment(env)
        try:
            return self.planner.plan(q, q_goal)
        finally:
            self.planner.set_environment(own)

    def _plan_via_approach(self, w: "_Work", q: np.ndarray, q_goal: np.ndarray) -> tuple | None:
        """(plan result, approach index, distance): a plan to the approach's
        entry (`_approach_entry`) followed by the straight approach; None
        without an entry or a plan to it. A robot already on the approach
        (`_on_approach`) goes straight in from where it is."""
        straight = self._on_approach(w, q, q_goal)
        if straight is not None:
            return PlanResult(True, "", straight, {"total": 0.0}), 0, 0.0
        entry = self._approach_entry(w, q_goal)
        if entry is None:
            return None
        to_entry = self.planner.plan(q, entry[0])
        if not to_entry.success:
            return None
        path = to_entry.trajectory
        last = linear_trajectory(path.q[-1], q_goal, path.times[-1], self.config.linear_speed_fraction)
        entry_index = path.q.shape[0] - 1
        # The entry is a stop for the tracker: the straight approach is only
        # straight if the robot is at its entry before it starts. The
        # look-ahead cuts a turn that is no corner (under `corner_angle`): by
        # 0.06 rad on a 45-degree arm turn (tests/test_tracker.py), which puts
        # the fingers a few cm off the approach line, beside the target.
        joined = TimedTrajectory(np.concatenate([path.times, last.times[1:]]), np.concatenate([path.q, last.q[1:]]),
                                 stops=(*path.stops, entry_index))
        return dc.replace(to_entry, trajectory=joined), entry_index, entry[1]

    def _plan_via_exit(self, w: "_Work", q: np.ndarray, q_goal: np.ndarray) -> tuple | None:
        """(plan result, approach index, exit index): from q, the gripper around the target,
        the straight motion back `approach_retreat` (or half as far) along
        the gripper's approach axis (valid with the gripper's exemption,
        ending free of every point), then a plan to q_goal (`_plan_via_approach` where
        q_goal touches the target). None when q_goal is the gripper's own
        pre-grasp, adjusted (`_SAME_PREGRASP`: no need to leave), or without
        such an exit or plan. Planned with the exemption, a motion between two
        pre-grasp poses around a cup swept the fingers through it and
        knocked it off its stand."""
        exempt = self.exempt_checker(w.inputs.p_WT)
        if exempt is None or self.config.approach_retreat <= 0.0 or self._ik is None:
            return None
        kinematics = FetchKinematics.instance()
        X_WG = kinematics.gripper_pose(q)
        X_WG_goal = kinematics.gripper_pose(q_goal)
        turn = RotationMatrix(X_WG[:3, :3].T @ X_WG_goal[:3, :3]).ToAngleAxis().angle()
        if np.linalg.norm(X_WG_goal[:3, 3] - X_WG[:3, 3]) <= self._SAME_PREGRASP[0] and turn <= self._SAME_PREGRASP[1]:
            return None  # the same pre-grasp, adjusted: no need to leave
        back = self._drawn_back(w, q, exempt, end_free=True)
        if back is None:
            return None
        exit_line = linear_trajectory(q, back[0], 0.0, self.config.linear_speed_fraction)
        # From the line's own end: it is q_exit with the continuous joints
        # unwrapped from q (IK wraps them into [-pi, pi)).
        q_out = exit_line.q[-1]
        onward = self.planner.plan(q_out, q_goal)
        approach_index = -1
        if not onward.success and onward.reason == FailureReason.GOAL_IN_COLLISION:
            via = self._plan_via_approach(w, q_out, q_goal)
            if via is not None:
                onward, approach_index, _ = via
        if not onward.success:
            return None
        path = onward.trajectory
        t_exit = exit_line.times[-1]
        joined = TimedTrajectory(np.concatenate([exit_line.times, t_exit + path.times[1:]]),
                                 np.concatenate([exit_line.q, path.q[1:]]),
                                 stops=(exit_line.q.shape[0] - 1,
                                        *(exit_line.q.shape[0] - 1 + i for i in path.stops if i > 0)))
        exit_index = exit_line.q.shape[0] - 1
        index = exit_index + approach_index if approach_index >= 0 else -1
        return dc.replace(onward, trajectory=joined), index, exit_index

    def _on_approach(self, w: "_Work", q: np.ndarray, q_goal: np.ndarray) -> TimedTrajectory | None:
        """The straight motion q -> q_goal when the robot is on its approach:
        base and torso at the goal's, the gripper within `approach_retreat`
        of the goal's, and the motion valid with the gripper's exemption. A
        replan from there (periodic, or the map's) continues the approach
        instead of backing out to its entry and starting it again."""
        exempt = self.exempt_checker(w.inputs.p_WT)
        if exempt is None or self.config.approach_retreat <= 0.0:
            return None
        offset = layout.wrap_configuration(np.asarray(q_goal, float) - q)
        if np.max(np.abs(offset[: layout.TORSO + 1])) > self._ON_APPROACH_TOLERANCE:
            return None
        kinematics = FetchKinematics.instance()
        gap = np.linalg.norm(kinematics.gripper_pose(q)[:3, 3] - kinematics.gripper_pose(q_goal)[:3, 3])
        if gap > self.config.approach_retreat + self._ON_APPROACH_TOLERANCE:
            return None
        return self._straight_motion(q, q_goal, exempt)

    def _straight_motion(self, q_from: np.ndarray, q_to: np.ndarray,
                         exempt: SphereCollisionChecker) -> TimedTrajectory | None:
        """The straight (joint-space) motion q_from -> q_to at the linear
        speed, if valid with the gripper's exemption; else None."""
        line = linear_trajectory(q_from, q_to, 0.0, self.config.linear_speed_fraction)
        return line if self.planner.path_is_valid(line.q, checker=exempt) else None

    #: Gripper offset [m] and turn [rad] within which a grasp-move goal is
    #: the pre-grasp the gripper is at (adjusted), not another one.
    _SAME_PREGRASP = (0.02, 0.2)

    #: Base (m, rad) and torso (m) offsets from the goal's, and gripper slack
    #: beyond `approach_retreat` [m], within which the robot is on its approach.
    _ON_APPROACH_TOLERANCE = 0.02

    def _approach_entry(self, w: "_Work", q_goal: np.ndarray) -> tuple[np.ndarray, float] | None:
        """(configuration, distance): the gripper `approach_retreat` (or, where
        the arm cannot reach that far back, half of it) back along its approach
        axis from q_goal (base and torso fixed), the straight approach from it
        to q_goal valid with the gripper's exemption; else None."""
        exempt = self.exempt_checker(w.inputs.p_WT)
        if exempt is None or self.config.approach_retreat <= 0.0 or self._ik is None:
            return None
        return self._drawn_back(w, q_goal, exempt)

    def _drawn_back(self, w: "_Work", q: np.ndarray, exempt: SphereCollisionChecker,
                    end_free: bool = False) -> tuple[np.ndarray, float] | None:
        """(configuration, distance): the gripper of q drawn back
        `approach_retreat` (or half of it) along its approach axis (IK, base
        and torso fixed), the straight motion between it and q valid with the
        gripper's exemption and, with `end_free`, the drawn-back configuration
        free of every point; else None."""
        X_WG = FetchKinematics.instance().gripper_pose(q)
        for distance in (self.config.approach_retreat, 0.5 * self.config.approach_retreat):
            X = X_WG.copy()
            X[:3, 3] -= distance * X[:3, 0]
            q_back, ok = self._solve_arm(w, X[None], q)
            if not ok[0] or (end_free and not self.planner.checker.is_free(q_back)[0]):
                continue
            if self._straight_motion(q_back[0], q, exempt) is not None:
                return q_back[0], distance
        return None

    def _solve_arm(self, w: "_Work", X_WG: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The approach IK with its random generator in the state of the tick."""
        self._ik.rng.bit_generator.state = w.ik_rng
        try:
            return self._ik.solve_arm(X_WG, q_seed)
        finally:
            w.ik_rng = self._ik.rng.bit_generator.state

    def _record(self, w: "_Work", q: np.ndarray, t: float) -> None:
        """Keeps the robot's configurations of the last `retreat_history_time` seconds."""
        horizon = self.config.retreat_history_time
        if horizon <= 0.0:
            return
        history = w.history
        if not history or np.max(np.abs(layout.wrap_configuration(q - history[-1][1]))) > 1e-3:
            q = np.array(q, dtype=float)
            q.flags.writeable = False
            history.append((t, q))
        first = 0
        while first < len(history) and history[first][0] < t - horizon:
            first += 1
        del history[:first]

    def _retreat(self, w: "_Work", goal: SubgoalCommand, q: np.ndarray) -> TimedTrajectory | None:
        """The robot's recent path backwards from q to the latest configuration
        the padded checker finds free (the robot was there, so the real
        geometry between was free), at `linear_speed_fraction` of the limits;
        None without one, or after two retreats for this goal."""
        if self.config.retreat_history_time <= 0.0 or w.retreats.get(goal.goal_id, 0) >= 2:
            return None
        if len(w.history) < 2:
            return None
        back = np.array([h for _, h in reversed(w.history)])
        path = [np.array(q, dtype=float)]
        for h in back:  # unwrapped continuous joints: no 2 pi jump between waypoints
            path.append(path[-1] + layout.wrap_configuration(h - path[-1]))
        path = np.array(path)
        free = np.asarray(self.planner.checker.is_free(path[1:]), dtype=bool)
        if not free.any():
            return None
        path = path[: int(np.argmax(free)) + 2]
        w.retreats[goal.goal_id] = w.retreats.get(goal.goal_id, 0) + 1
        return time_parametrize(path, layout.V_MAX * self.config.linear_speed_fraction)

    @staticmethod
    def _failure_event(plan: PlannedTrajectory) -> MotionEvent:
        """A goal that the map has put in collision is invalidated (the policy
        resamples without counting a motion failure); other failures are FAILED."""
        return MotionEvent.INVALIDATED if plan.reason == FailureReason.GOAL_IN_COLLISION else MotionEvent.FAILED

    def _start(self, w: "_Work", goal: SubgoalCommand, q: np.ndarray, t: float,
               revision: int) -> tuple[PlannedTrajectory, MotionEvent]:
        if goal.motion == "plan":
            plan = self._plan(w, goal, q, t, revision)
            return plan, (MotionEvent.NONE if plan.success else self._failure_event(plan))
        if goal.motion == "linear":
            try:
                traj = linear_trajectory(q, np.asarray(goal.q_goal, float), t, self.config.linear_speed_fraction)
            except ValueError as e:
                _log.error("motion t=%.2f: bad linear goal %d: %s", t, goal.goal_id, e)
                return PlannedTrajectory(goal.goal_id, None, False, FailureReason.INVALID_INPUT, revision,
                                         motion="linear"), MotionEvent.FAILED
            return PlannedTrajectory(goal.goal_id, traj, True, "", revision, motion="linear"), MotionEvent.NONE
        return PlannedTrajectory(goal.goal_id, None, True, "", revision, motion=goal.motion), MotionEvent.NONE

    def _plan(self, w: "_Work", goal: SubgoalCommand, q: np.ndarray, t: float, revision: int) -> PlannedTrajectory:
        w.last_replan_time = t
        t0 = time.perf_counter()
        wall_hits = self.planner.wall_limit_hits
        try:
            return self._plan_goal(w, goal, q, t, revision, t0)
        finally:
            if self.timings is not None:
                # Attempts the planner's wall-clock safety net stopped: the
                # episode is not reproducible when this module appears.
                for _ in range(self.planner.wall_limit_hits - wall_hits):
                    self.timings.add("planner_wall_limit", 1e3 * (time.perf_counter() - t0))

    def _plan_goal(self, w: "_Work", goal: SubgoalCommand, q: np.ndarray, t: float, revision: int,
                   t0: float) -> PlannedTrajectory:
        approach_index = exit_index = -1
        try:
            if w.inputs.before_planning is not None:
                w.inputs.before_planning()  # a bad map raises here: a recorded error
            q_goal = np.asarray(goal.q_goal, dtype=float)
            exempt = self.exempt_checker(w.inputs.p_WT) if goal.phase in (Phase.PREGRASP, Phase.GRASP_MOVE) else None
            if (exempt is not None and goal.phase == Phase.GRASP_MOVE
                    and not self.planner.unpadded_checker().is_free(q[None])[0]):
                # From the reached pre-grasp, the gripper already around the
                # target: out the way it came in, then to the goal without
                # touching the target; only where there is no such way (or
                # the goal is the same pre-grasp, adjusted) may the whole
                # (short) motion touch the target's points.
                via = self._plan_via_exit(w, q, q_goal)
                if via is not None:
                    result, approach_index, exit_index = via
                    _log.info("motion t=%.2f: goal %d: out along the approach, then to the new pre-grasp",
                              t, goal.goal_id)
                else:
                    result = self._plan_with(exempt.env, q, q_goal)
                    approach_index = 0
            else:
                result = self.planner.plan(q, q_goal)
            if (not result.success and result.reason == FailureReason.GOAL_IN_COLLISION
                    and exempt is not None and approach_index < 0):
                via = self._plan_via_approach(w, q, q_goal)
                if via is not None:
                    result, approach_index, distance = via
                    if distance > 0.0:
                        _log.info("motion t=%.2f: goal %d: planned to %.2f m back along the approach, then straight in",
                                  t, goal.goal_id, distance)
                    else:
                        _log.info("motion t=%.2f: goal %d: on the approach; straight in from here", t, goal.goal_id)
        except Exception:  # noqa: BLE001 - a planner bug ends the episode as a recorded error (the judge)
            _log.error("WholeBodyPlanner t=%.2f: planner raised on goal %d:\n%s", t, goal.goal_id, traceback.format_exc())
            return PlannedTrajectory(goal.goal_id, None, False, EXCEPTION_REASON, revision,
                                     1e3 * (time.perf_counter() - t0), motion="plan", error=traceback.format_exc())
        if self.timings is not None:
            self.timings.add("planner", result.timings["total"])
        if not result.success:
            _log.warning("WholeBodyPlanner t=%.2f: goal %d failed: %s (%s)", t, goal.goal_id, result.reason,
                         result.message)
            if result.reason == FailureReason.START_IN_COLLISION:
                retreat = self._retreat(w, goal, q)
                if retreat is not None:
                    _log.info("motion t=%.2f: goal %d: backing out %.2f m / %d waypoints along the robot's own path",
                              t, goal.goal_id, float(np.sum(np.hypot(*np.diff(retreat.q[:, :2], axis=0).T))),
                              retreat.q.shape[0])
                    return PlannedTrajectory(goal.goal_id, retreat.shifted(t), True, "", revision,
                                             result.timings["total"], motion="plan", retreat=True)
            return PlannedTrajectory(goal.goal_id, None, False, result.reason or FailureReason.TIMEOUT, revision,
                                     result.timings["total"], motion="plan")
        lowest = arm_floor_clearance(self.planner.checker, result.trajectory.q)
        if lowest < self.config.floor_clearance:
            _log.warning("WholeBodyPlanner t=%.2f: goal %d: the planned path takes the arm %.3f m from the floor "
                         "(needs %.3f); rejected", t, goal.goal_id, lowest, self.config.floor_clearance)
            return PlannedTrajectory(goal.goal_id, None, False, FLOOR_REASON, revision, result.timings["total"],
                                     motion="plan")
        return PlannedTrajectory(goal.goal_id, result.trajectory.shifted(t), True, "", revision,
                                 result.timings["total"], motion="plan", approach_index=approach_index,
                                 exit_index=exit_index)
