"""The episode judge: outcome categories (paper appendix "Evaluation Metrics"
and "Failure Analysis").

`EpisodeJudge` is the plain core: it is fed, at each monitor tick, the time,
the robot's contacts, the target's height and what the policy and the planner
report, and decides the outcome. The statuses are the paper's categories:

* ``success``: the target lifted >= `lift_height` and held `hold_time`;
* ``collision``: a robot link other than the fingers touched something
  before the grasp was initiated (the paper: "any contact between the robot
  body (excluding gripper fingers) and environment obstacles or the target
  object before grasp initiation"). The grasp is initiated when the linear
  approach from the pre-grasp pose begins; from then on the gripper (palm and
  fingers) may touch the target and its support, since what it does to them
  is judged by the lift. Other links, and any self-contact, still count;
* ``grasp``: the policy finished its lift but the target was not held up
  within `grasp_verdict_time` (slipped, dropped, or never enclosed);
* ``ik``, ``reachability``, ``perception``: the subgoal policy gave up for
  that reason;
* ``planning``: the policy gave up after motion failures (kind ``timeout``),
  no subgoal could be sampled (kind ``subgoal``), or the episode's time limit
  passed (kind ``time_limit``).

``error`` is not a paper category: a component raised (the planner, a
sampler) or the simulation did. It carries the traceback
(`EpisodeOutcome.error`) so that a bug shows as a bug instead of inflating a
failure rate.

`vamg_drake.systems.episode_monitor_system.EpisodeMonitor` is its LeafSystem.
"""


import dataclasses as dc

from vamg_drake.robot.spheres import FINGER_LINKS

RUNNING = "running"
SUCCESS = "success"
COLLISION = "collision"
GRASP = "grasp"
IK = "ik"
REACHABILITY = "reachability"
PERCEPTION = "perception"
PLANNING = "planning"
#: A component or the simulation raised (not one of the paper's categories).
ERROR = "error"
#: Every final status, in the column order of the paper's results table.
CATEGORIES = (SUCCESS, COLLISION, GRASP, IK, REACHABILITY, PERCEPTION, PLANNING)
#: Kinds of planning failure (`EpisodeOutcome.kind`).
PLANNING_KINDS = ("timeout", "subgoal", "time_limit")

#: Policy failure category (`FailureCategory.value`) -> (status, kind).
_POLICY_FAILURES = {
    "reachability": (REACHABILITY, ""),
    "perception": (PERCEPTION, ""),
    "ik": (IK, ""),
    "planning": (PLANNING, "timeout"),
    "subgoal": (PLANNING, "subgoal"),
    "error": (ERROR, ""),
}


@dc.dataclass(frozen=True)
class PolicyReport:
    """What the policy and the motion layer report to the judge.

    Attributes:
        phase: the policy's phase value ("idle", "grasp_lift", "succeeded", "failed", ...).
        failure: its failure category value when failed ("reachability", ...).
        reason: its last reason.
        planner_error: the planner's exception (with traceback), if it raised.
    """

    phase: str = "idle"
    failure: str = ""
    reason: str = ""
    planner_error: str = ""


@dc.dataclass
class EpisodeMonitorConfig:
    """Success and collision criteria."""

    #: Lift above the target's resting height for success [m].
    lift_height: float = 0.10
    #: How long the lift must be held [s].
    hold_time: float = 2.0
    #: Contact depth below which a touch is ignored [m] (numerical noise).
    penetration_tolerance: float = 1e-4
    #: Monitor period [s].
    period: float = 0.05
    #: After the policy reports its lift done, the target must be held up
    #: within this long or the episode is a grasp failure [s].
    grasp_verdict_time: float = 4.0


@dc.dataclass(frozen=True)
class Contact:
    """A contact of a robot geometry with something.

    Attributes:
        robot_link: the robot link touching.
        other: the name of what it touches (body or geometry name).
        other_is_target: the other body is the target object.
        other_is_robot: a self-collision.
        depth: penetration depth [m].
    """

    robot_link: str
    other: str
    other_is_target: bool
    other_is_robot: bool
    depth: float


@dc.dataclass(frozen=True)
class EpisodeOutcome:
    """The judge's verdict so far.

    Attributes:
        status: RUNNING or one of CATEGORIES.
        time: sim time of the verdict [s] (of the last tick while running).
        detail: human-readable detail (what collided with what, ...).
        kind: for PLANNING, one of PLANNING_KINDS.
        error: for ERROR, the traceback of what raised.
    """

    status: str = RUNNING
    time: float = 0.0
    detail: str = ""
    kind: str = ""
    error: str = ""

    @property
    def done(self) -> bool:
        return self.status != RUNNING


#: Policy phases (`PolicyReport.phase`) at and after grasp initiation: the
#: linear approach from the pre-grasp pose, closing, lifting, backing off
#: from a grasp that closed on nothing (to try another), done.
GRASP_INITIATED_PHASES = ("grasp_approach", "grasp_close", "grasp_pull", "grasp_lift", "grasp_retreat", "succeeded")
#: Robot links allowed to touch anything are the fingers (`FINGER_LINKS`).
GRIPPER_LINKS = ("gripper_link",) + FINGER_LINKS


class EpisodeJudge:
    """Decides the outcome category from what happened."""

    def __init__(self, target_rest_height: float, time_limit: float, config: EpisodeMonitorConfig | None = None):
        self.config = config or EpisodeMonitorConfig()
        self.target_rest_height = target_rest_height
        self.time_limit = time_limit
        self.outcome = EpisodeOutcome()
        self._lift_since: float | None = None
        self._lift_done_at: float | None = None
        self.max_lift = 0.0

    def update(self, time: float, contacts: list[Contact], target_height: float, grasp_started: bool,
               policy: PolicyReport | None = None) -> EpisodeOutcome:
        """Feeds one tick; returns the (possibly final) outcome."""
        if self.outcome.done:
            return self.outcome
        for c in contacts:
            if c.depth < self.config.penetration_tolerance or c.robot_link in FINGER_LINKS:
                continue
            if c.other_is_robot and (c.other in FINGER_LINKS):
                continue
            if grasp_started and not c.other_is_robot and c.robot_link in GRIPPER_LINKS:
                continue  # after grasp initiation the palm's contacts are the grasp's business
            self.outcome = EpisodeOutcome(COLLISION, time, f"{c.robot_link} touched {c.other} ({c.depth * 1000:.1f} mm)")
            return self.outcome
        lift = target_height - self.target_rest_height
        self.max_lift = max(self.max_lift, lift)
        if lift >= self.config.lift_height:
            if self._lift_since is None:
                self._lift_since = time
            if time - self._lift_since >= self.config.hold_time - 1e-9:
                self.outcome = EpisodeOutcome(SUCCESS, time, f"target lifted {lift:.3f} m and held {self.config.hold_time} s")
                return self.outcome
        else:
            self._lift_since = None
        if policy is not None:
            verdict = self._policy_verdict(time, policy, lift)
            if verdict is not None:
                self.outcome = verdict
                return self.outcome
        if time >= self.time_limit:
            self.outcome = EpisodeOutcome(PLANNING, time, f"time limit {self.time_limit} s reached", "time_limit")
            return self.outcome
        self.outcome = EpisodeOutcome(RUNNING, time, "")
        return self.outcome

    def _policy_verdict(self, time: float, policy: PolicyReport, lift: float) -> EpisodeOutcome | None:
        if policy.planner_error:
            return EpisodeOutcome(ERROR, time, f"planner raised: {_last_line(policy.planner_error)}",
                                  error=policy.planner_error)
        if policy.phase == "failed":
            status, kind = _POLICY_FAILURES.get(policy.failure, (PLANNING, "subgoal"))
            if status == ERROR:
                return EpisodeOutcome(ERROR, time, _last_line(policy.reason), error=policy.reason)
            return EpisodeOutcome(status, time, policy.reason, kind)
        if policy.phase == "succeeded":
            if self._lift_done_at is None:
                self._lift_done_at = time
            if self._lift_since is None and time - self._lift_done_at >= self.config.grasp_verdict_time:
                return EpisodeOutcome(GRASP, time, f"lift finished but the target is not held up "
                                                   f"(lift {lift:.3f} m, max {self.max_lift:.3f} m)")
        return None


def _last_line(text: str) -> str:
    """The last non-empty line of a traceback (the exception itself)."""
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1].strip() if lines else text
