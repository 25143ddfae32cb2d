"""The episode judge: collision, success, time limit (paper appendix "Evaluation Metrics").

`EpisodeJudge` is the plain core: it is fed, at each monitor tick, the time,
the robot's contacts and the target's height, and decides the outcome.
`vamg_drake.systems.episode_monitor_system.EpisodeMonitor` is its LeafSystem.
"""


import dataclasses as dc

#: Outcome statuses decided by the judge (the policy adds the other paper
#: categories: grasp, ik, reachability, perception, planning).
RUNNING = "running"
SUCCESS = "success"
COLLISION = "collision"
TIMEOUT = "timeout"


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
        status: RUNNING, SUCCESS, COLLISION or TIMEOUT.
        time: sim time of the verdict [s] (of the last tick while running).
        detail: human-readable detail (what collided with what, ...).
    """

    status: str = RUNNING
    time: float = 0.0
    detail: str = ""

    @property
    def done(self) -> bool:
        return self.status != RUNNING


#: Robot links allowed to touch anything (the fingers).
FINGER_LINKS = ("l_gripper_finger_link", "r_gripper_finger_link")
GRIPPER_LINKS = ("gripper_link",) + FINGER_LINKS


class EpisodeJudge:
    """Decides collision / success / time-out from what happened."""

    def __init__(self, target_rest_height: float, time_limit: float, config: EpisodeMonitorConfig | None = None):
        self.config = config or EpisodeMonitorConfig()
        self.target_rest_height = target_rest_height
        self.time_limit = time_limit
        self.outcome = EpisodeOutcome()
        self._lift_since: float | None = None
        self.max_lift = 0.0

    def update(self, time: float, contacts: list[Contact], target_height: float, grasp_started: bool) -> EpisodeOutcome:
        """Feeds one tick; returns the (possibly final) outcome."""
        if self.outcome.done:
            return self.outcome
        for c in contacts:
            if c.depth < self.config.penetration_tolerance or c.robot_link in FINGER_LINKS:
                continue
            if c.other_is_robot and (c.other in FINGER_LINKS):
                continue
            if grasp_started and c.other_is_target and c.robot_link in GRIPPER_LINKS:
                continue  # the palm may touch the target once the grasp has begun
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
        if time >= self.time_limit:
            self.outcome = EpisodeOutcome(TIMEOUT, time, f"time limit {self.time_limit} s reached")
            return self.outcome
        self.outcome = EpisodeOutcome(RUNNING, time, "")
        return self.outcome
