"""The whole-body path tracker (paper appendix "Whole-Body Path Tracker").

A 20 Hz velocity controller that follows the planner's `TimedTrajectory`.
State x = [x, y, theta, h, q_arm(7)] (`layout` order), input
u = [v, w, h_dot, q_arm_dot(7)]. Each cycle:

1. **Nearest waypoint.** The trajectory is resampled on a fixed time grid
   (`TrackerConfig.resample_dt`, plus the original waypoint times). The
   nearest sample to the current q by the weighted distance
   ``w_p |dp_xy|^2 + w_h wrap(dtheta)^2 + w_j |wrap(dq_joints)|^2`` is searched
   forward only, inside ``[previous nearest, previous nearest +
   search_window_time]`` and never past the next cusp, so progress is monotone
   and a path that crosses or folds back on itself never snaps back. Ties (a
   pause in the path) go to the latest sample, so a pause never stalls it.
2. **Look-ahead.** The reference is the sample `lookahead_time` seconds after
   the nearest one (the look-ahead is in seconds of the planner's own time
   parametrization, i.e. a fixed number of resampled waypoints). With the
   paper's gain the default 0.4 s makes the steady-state speed match the
   trajectory's (2.5 * 20 / 20.5 * 0.4 ~= 0.98).
3. **One-step MPC.** u* = gain (B'QB + R)^-1 B'Q dx with B(theta) the unicycle
   + identity input matrix linearized at the current heading. B'QB is diagonal
   for a diagonal Q, so the solve is closed-form per input (`one_step_mpc`);
   `one_step_mpc_reference` is the literal matrix formula (tests, benchmark).
   Reverse motion (v < 0) comes out of it wherever the reference lies behind.
4. **Clamps.** |v| <= TRACKER_BASE_V, |w| <= TRACKER_BASE_W, torso and arm
   rates <= V_MAX (all from `vamg_drake.robot.layout`). By default the whole
   command is scaled down uniformly so that it keeps its direction in joint
   space (`uniform_clamp`); otherwise each input is clipped.

Additions to the paper, each documented and switchable:

* **Cusps.** A Reeds-Shepp path reverses at cusps, where the look-ahead would
  fold back onto the path and stall the robot short of the cusp. The path is
  split at base direction reversals; the reference never passes the next cusp
  until the robot is within `cusp_position_tolerance` along its heading,
  `cusp_lateral_tolerance` across it and `cusp_heading_tolerance`
  of it.
* **Corners.** A whole-body path turns sharply in joint space where its
  pieces meet (a base drive, then the arm unfolding): the look-ahead chord
  cuts such a corner, and seed 0's gripper swept into the target it was
  meant to stop 5 cm before. A turn of the direction of motion (in units of
  each coordinate's rate limit) by more than `corner_angle` is a stop like a
  cusp: the reference waits there until the robot is within the cusp
  tolerances and every torso/arm joint within `corner_joint_tolerance`.
* **Lateral correction.** B(theta) has no lateral direction, so the paper's law
  leaves a cross-track offset uncorrected. With ``lateral_gain > 0`` the
  reference heading is turned towards the path by ``atan(lateral_gain *
  e_lateral)`` (Stanley-like, signed by the travel direction, bounded by
  `max_lateral_correction`, off while the reference is a stop point).
  ``lateral_gain = 0`` is the paper's law unchanged.
* **Path-error gain.** The law's error splits as dx = (q_ref - q_nearest) +
  (q_nearest - q): the chord along the path ahead and the robot's deviation
  from it. On a curved whole-body path the chord points inside the curve, and
  with equal weights the robot settles where the deviation cancels it: the
  gripper cut corners by up to 12.6 cm on seed 0's pre-grasp motion and
  touched the wall the planner had kept 4 cm away. The deviation of the
  heading and joints (a unicycle cannot move across its heading, x and y are
  left alone) is weighted by `path_error_gain`; with 3, the corner stops and
  the stop gain 2 the gripper stays within 2.3-6.6 cm of five recorded plans
  (4-14 cm with the paper's law) and each finishes sooner. Gains of 4-5 made
  the shoulder pan oscillate in the simulated plant, whose PD-driven joints lag
  the commanded state. ``path_error_gain = 1`` is the paper's law.

A trajectory is validated before it is accepted (`set_trajectory`): shapes,
NaN/inf, increasing times, wrap-around jumps of continuous joints, jumps
between consecutive waypoints (distance and implied rate) and a start far from
the current q. A rejected trajectory stops the robot (zero command) with the
reason in `TrackerCommand.reason`. Accepting a new trajectory mid-execution
restarts the nearest-waypoint search on it, so a new path through the current
state continues the motion without a jump in the command.
"""

import dataclasses as dc
import math

import numpy as np

from vamg_drake.robot import layout

#: Number of inputs u = [v, w, h_dot, q_arm_dot(7)].
NU = 10
#: Continuous joints among the 8 torso + arm joints.
_JOINT_CONTINUOUS = layout.IS_CONTINUOUS[layout.TORSO_ARM]
#: |u| limits in input order, from the layout (one place for each fact).
U_LIMITS = np.concatenate(
    [[layout.TRACKER_BASE_V, layout.TRACKER_BASE_W], layout.V_MAX[layout.TORSO_ARM]]
)
#: Coordinates whose deviation `TrackerConfig.path_error_gain` weights
#: (not x, y: a unicycle cannot move across its heading, and an amplified
#: cross-track offset held the robot still on a curve).
_AMPLIFIED = slice(2, None)
#: Share of the normalized motion the torso/arm must carry for a turn to be a corner.
_CORNER_ARM_SHARE = 0.3
#: An arm joint this far from `layout.Q_ARM_STOW` [rad] makes every sharp turn a corner.
_CORNER_UNFOLDED = 0.3
#: Forward displacements below this [m] count as no base motion (cusp detection).
_MOTION_EPS = 1e-6
#: A run of base motion in one direction shorter than this [m] is jitter (cusp detection).
_MIN_RUN_TRAVEL = 0.005


@dc.dataclass
class TrackerConfig:
    """Parameters of the whole-body tracker (loadable with `yaml_load_typed`).

    Attributes:
        period: control period [s] (20 Hz in the paper).
        q_diag: diagonal of Q over x = [x, y, theta, h, q_arm(7)] (11 values).
        r_diag: diagonal of R over u = [v, w, h_dot, q_arm_dot(7)] (10 values).
        gain: the paper's gain alpha applied to u*.
        lookahead_time: look-ahead from the nearest waypoint [s of trajectory time].
        resample_dt: time spacing of the resampled reference [s].
        max_resampled_waypoints: the resampling spacing grows beyond this many samples.
        search_window_time: forward window of the nearest-waypoint search [s].
        position_weight: weight of |dp_xy|^2 [1/m^2] in the nearest-waypoint metric.
        heading_weight: weight of wrap(dtheta)^2 [1/rad^2].
        joint_weight: weight of each torso/arm joint's squared error.
        lateral_gain: cross-track heading correction [1/m]; 0 = the paper's law.
        path_error_gain: weight of the deviation from the nearest point of the
            path against the chord to the look-ahead reference; 1 = the paper's law.
        max_lateral_correction: bound of the heading correction [rad].
        lateral_stop_distance: no lateral correction this close to the next stop
            (cusp or final waypoint), whose heading must be met [m].
        uniform_clamp: scale the whole command into the limits (True) or clip each input.
        goal_position_tolerance: done when the base is this close to the final waypoint [m]...
        goal_heading_tolerance: ...its heading this close [rad]...
        goal_joint_tolerance: ...and every torso/arm joint this close [m or rad]
            (0.03 rad on each of 7 joints left the gripper 1.5-2 cm off a grasp pose).
        cusp_position_tolerance: a cusp is passed within this distance along
            the robot's heading [m]...
        cusp_lateral_tolerance: ...this distance across it (a unicycle cannot
            remove a lateral offset at the cusp itself: seed 0 stopped 3.3 cm
            from a cusp, 0.7 cm across, and crept until the motion timed out) [m]...
        cusp_heading_tolerance: ...and this heading error [rad].
        corner_angle: a turn of the path's direction of motion sharper than
            this is a stop [rad]; >= pi: only cusps are stops.
        corner_joint_tolerance: a stop is passed with every torso/arm joint this
            close [m or rad].
        stop_gain: the error is scaled by this while the reference is a stop
            (cusp, corner, final waypoint): the paper's law closes the last
            0.3 rad to a 0.02 rad tolerance in about 1.2 s, at every stop;
            1 = the paper's law.
        stall_command_ratio: with the reference at a stop and the command below
            this fraction of every limit, the robot has stalled (a unicycle
            cannot remove a lateral offset in place): a cusp is passed anyway;
            at the final waypoint the command is zeroed with status STALLED.
        max_start_position_error: reject a trajectory whose nearest waypoint (in the
            first search window) is farther than this from the current base [m]...
        max_start_heading_error: ...or whose heading differs more [rad]...
        max_start_joint_error: ...or any torso/arm joint differs more [m or rad].
        max_waypoint_step_position: reject when consecutive waypoints are farther
            apart in the base plane [m]...
        max_waypoint_step_joint: ...or in heading / any torso/arm joint [rad or m].
        max_rate_ratio: reject when a segment's implied rate exceeds the layout's
            limits by this factor (a jump in time).
    """

    period: float = 0.05
    q_diag: list[float] = dc.field(default_factory=lambda: [20.0, 20.0, 15.0] + [12.0] * 8)
    r_diag: list[float] = dc.field(default_factory=lambda: [0.5, 0.8] + [1.0] * 8)
    gain: float = 2.5
    lookahead_time: float = 0.3
    resample_dt: float = 0.02
    max_resampled_waypoints: int = 20000
    search_window_time: float = 2.0
    position_weight: float = 1.0
    heading_weight: float = 0.05
    joint_weight: float = 0.1
    lateral_gain: float = 4.0
    path_error_gain: float = 3.0
    max_lateral_correction: float = 0.5
    lateral_stop_distance: float = 0.1
    uniform_clamp: bool = True
    goal_position_tolerance: float = 0.03
    goal_heading_tolerance: float = 0.05
    goal_joint_tolerance: float = 0.01
    cusp_position_tolerance: float = 0.03
    cusp_lateral_tolerance: float = 0.08
    cusp_heading_tolerance: float = 0.05
    corner_angle: float = 1.2
    corner_joint_tolerance: float = 0.02
    stop_gain: float = 2.0
    stall_command_ratio: float = 0.01
    max_start_position_error: float = 0.3
    max_start_heading_error: float = 0.5
    max_start_joint_error: float = 0.3
    max_waypoint_step_position: float = 0.5
    max_waypoint_step_joint: float = 1.0
    max_rate_ratio: float = 3.0

    def validate(self) -> None:
        """Raises ValueError naming the first bad field."""
        if len(self.q_diag) != layout.NQ:
            raise ValueError(f"TrackerConfig.q_diag needs {layout.NQ} values, got {len(self.q_diag)}")
        if len(self.r_diag) != NU:
            raise ValueError(f"TrackerConfig.r_diag needs {NU} values, got {len(self.r_diag)}")
        if not all(math.isfinite(v) and v >= 0.0 for v in self.q_diag):
            raise ValueError("TrackerConfig.q_diag must be finite and >= 0")
        if not all(math.isfinite(v) and v > 0.0 for v in self.r_diag):
            raise ValueError("TrackerConfig.r_diag must be finite and > 0")
        positive = ("period", "gain", "path_error_gain", "stop_gain", "resample_dt", "search_window_time", "goal_position_tolerance",
                    "goal_heading_tolerance", "goal_joint_tolerance", "cusp_position_tolerance", "cusp_lateral_tolerance",
                    "cusp_heading_tolerance", "corner_angle", "corner_joint_tolerance", "max_start_position_error", "max_start_heading_error",
                    "max_start_joint_error", "max_waypoint_step_position", "max_waypoint_step_joint",
                    "max_rate_ratio")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"TrackerConfig.{name} must be finite and > 0, got {value}")
        non_negative = ("lookahead_time", "position_weight", "heading_weight", "joint_weight",
                        "lateral_gain", "max_lateral_correction", "lateral_stop_distance",
                        "stall_command_ratio")
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"TrackerConfig.{name} must be finite and >= 0, got {value}")
        if self.max_resampled_waypoints < 2:
            raise ValueError("TrackerConfig.max_resampled_waypoints must be >= 2")


class TrackerStatus:
    """Values of `TrackerCommand.status`."""

    IDLE = "idle"  # no trajectory (zero command)
    TRACKING = "tracking"
    DONE = "done"  # final waypoint reached within tolerance (zero command)
    STALLED = "stalled"  # at the final waypoint's reference, outside tolerance, not moving (zero command)
    REJECTED = "rejected"  # the last trajectory was rejected (zero command)
    INVALID_STATE = "invalid_state"  # q_now malformed (zero command)
    WAITING = "waiting"  # holding until the base's next stretch of path has been seen (zero command)


@dc.dataclass(frozen=True, eq=False)
class TrackerCommand:
    """One tracker output (the `tracking` port's value).

    Attributes:
        base_velocity: (v [m/s], w [rad/s]) in the base frame.
        joint_velocity: torso + 7 arm joint rates.
        nearest_index: index of the original waypoint at or before the nearest
            point of the path (-1 without a trajectory).
        reference_index: the same for the look-ahead reference.
        nearest_time: trajectory time of the nearest point [s] (NaN without one).
        reference_time: trajectory time of the reference [s].
        done: the final waypoint is reached within the goal tolerances.
        status: a `TrackerStatus` value.
        reason: why the trajectory was rejected or the command zeroed ("" otherwise).
        position_error: base distance to the nearest point of the path [m].
    """

    base_velocity: np.ndarray = dc.field(default_factory=lambda: np.zeros(2))
    joint_velocity: np.ndarray = dc.field(default_factory=lambda: np.zeros(layout.NQ - 3))
    nearest_index: int = -1
    reference_index: int = -1
    nearest_time: float = math.nan
    reference_time: float = math.nan
    done: bool = False
    status: str = TrackerStatus.IDLE
    reason: str = ""
    position_error: float = math.nan

    @property
    def u(self) -> np.ndarray:
        """The input vector u = [v, w, h_dot, q_arm_dot(7)] (10,)."""
        return np.concatenate([self.base_velocity, self.joint_velocity])


def state_error(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """dx = q_ref - q (..., 11) with wrapped differences on continuous joints."""
    dx = np.asarray(q_ref, float) - np.asarray(q, float)
    dx[..., layout.IS_CONTINUOUS] = layout.wrap_angle(dx[..., layout.IS_CONTINUOUS])
    return dx


def one_step_mpc(dx: np.ndarray, theta: float, q_diag: np.ndarray, r_diag: np.ndarray) -> np.ndarray:
    """u* = (B'QB + R)^-1 B'Q dx for diagonal Q (11,) and R (10,), closed form.

    With B(theta) = [[cos, 0, 0], [sin, 0, 0], [0, 1, 0], [0, 0, I_8]] and a
    diagonal Q, B'QB is diagonal, so each input decouples.
    """
    c, s = math.cos(theta), math.sin(theta)
    u = np.empty(NU)
    u[0] = (q_diag[0] * c * dx[0] + q_diag[1] * s * dx[1]) / (q_diag[0] * c * c + q_diag[1] * s * s + r_diag[0])
    u[1] = q_diag[2] * dx[2] / (q_diag[2] + r_diag[1])
    u[2:] = q_diag[3:] * dx[3:] / (q_diag[3:] + r_diag[2:])
    return u


def input_matrix(theta: float) -> np.ndarray:
    """The paper's B(theta) (11, 10)."""
    B = np.zeros((layout.NQ, NU))
    B[0, 0], B[1, 0] = math.cos(theta), math.sin(theta)
    B[2, 1] = 1.0
    B[3:, 2:] = np.eye(NU - 2)
    return B


def one_step_mpc_reference(dx: np.ndarray, theta: float, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The literal formula u* = (B'QB + R)^-1 B'Q dx with full matrices Q (11, 11), R (10, 10)."""
    B = input_matrix(theta)
    return np.linalg.solve(B.T @ Q @ B + R, B.T @ Q @ dx)


def clamp_command(u: np.ndarray, uniform: bool) -> np.ndarray:
    """u within `U_LIMITS`: scaled as a whole (uniform) or clipped per input."""
    if uniform:
        ratio = float(np.max(np.abs(u) / U_LIMITS))
        return u / ratio if ratio > 1.0 else u
    return np.clip(u, -U_LIMITS, U_LIMITS)


def _resample(times: np.ndarray, q: np.ndarray, dt: float, max_samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ts, qs, source) the path on a uniform time grid plus the original times.

    `source[k]` is the original waypoint at or before sample k.
    """
    t = times - times[0]
    if t.shape[0] == 1:
        return t.copy(), q.copy(), np.zeros(1, dtype=int)
    dt = max(dt, t[-1] / (max_samples - 1))
    grid = np.union1d(np.arange(0.0, t[-1], dt), t)
    keep = np.r_[True, np.diff(grid) > 1e-9]
    grid = grid[keep]
    grid[-1] = t[-1]
    k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.shape[0] - 2)
    s = np.clip((grid - t[k]) / (t[k + 1] - t[k]), 0.0, 1.0)
    qs = q[k] + s[:, None] * (q[k + 1] - q[k])
    source = np.where(s >= 1.0, k + 1, k)
    return grid, qs, source


def _corners(qs: np.ndarray, angle: float) -> np.ndarray:
    """Samples where the direction of motion (dq / V_MAX) turns by more than
    `angle` [rad] between the segments before and after them (pauses
    skipped), where the torso/arm carry at least `_CORNER_ARM_SHARE` of
    either segment's motion or an arm joint is `_CORNER_UNFOLDED` from stow."""
    if angle >= np.pi or qs.shape[0] < 3:
        return np.zeros(0, dtype=int)
    d = state_error(qs[1:], qs[:-1]) / layout.V_MAX[None, :]
    norm = np.linalg.norm(d, axis=1)
    moving = np.flatnonzero(norm > 1e-9)
    if moving.size < 2:
        return np.zeros(0, dtype=int)
    u = d[moving] / norm[moving, None]
    cos = np.sum(u[:-1] * u[1:], axis=1)
    # Only turns that move the arm or carry it unfolded: with the arm stowed,
    # the base's own turns (a drive into an in-place turn, a straight line into
    # an arc) are the unicycle tracking's business, and a stop only costs time.
    arm_share = np.linalg.norm(u[:, 3:], axis=1)
    corner = moving[1:]  # the sample where the next moving segment starts
    unfolded = np.max(np.abs(layout.wrap_angle(qs[corner][:, layout.ARM] - layout.Q_ARM_STOW)), axis=1)
    involves_arm = (np.maximum(arm_share[:-1], arm_share[1:]) > _CORNER_ARM_SHARE) | (unfolded > _CORNER_UNFOLDED)
    return corner[(cos < math.cos(angle)) & involves_arm]


def _direction_and_stops(qs: np.ndarray, corner_angle: float = np.pi,
                         required: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(direction (N,), stops) per sample: +1 forward, -1 reverse, 0 no base
    travel on the segment leaving it; stops: cusp and corner sample indices
    (`_corners`), the `required` sample indices, then N-1.

    A run of samples in one direction that travels less than
    `_MIN_RUN_TRAVEL` in all is jitter, not travel (direction 0): an in-place
    turn whose base position wobbles by 0.1 mm otherwise splits into dozens of
    cusps, each to be reached within the cusp tolerances, and the robot
    stopped short of the turn (seed 0: 0.79 rad of heading left after 3 s).
    """
    n = qs.shape[0]
    direction = np.zeros(n, dtype=int)
    if n > 1:
        d = np.diff(qs[:, :2], axis=0)
        mid = 0.5 * (qs[:-1, 2] + qs[1:, 2])
        forward = d[:, 0] * np.cos(mid) + d[:, 1] * np.sin(mid)
        step = np.where(forward > _MOTION_EPS, 1, np.where(forward < -_MOTION_EPS, -1, 0))
        start = 0
        for k in range(1, n):  # runs of equal sign; short runs are jitter
            if k == n - 1 or step[k] != step[start]:
                if step[start] != 0 and np.sum(np.abs(forward[start:k])) < _MIN_RUN_TRAVEL:
                    step[start:k] = 0
                start = k
        direction[:-1] = step
        direction[-1] = direction[-2]
    moving = np.flatnonzero(direction[:-1] != 0) if n > 1 else np.zeros(0, dtype=int)
    stops = []
    for a, b in zip(moving[:-1], moving[1:]):
        if direction[a] != direction[b]:
            stops.append(a + 1)  # the end of the last segment in the old direction
    stops.extend(int(k) for k in _corners(qs, corner_angle) if 0 < k < n - 1)
    if required is not None:
        stops.extend(int(k) for k in required if 0 < k < n - 1)
    stops.append(n - 1)
    return direction, np.unique(np.asarray(stops, dtype=int))


class WholeBodyTrackerCore:
    """The tracker's state machine over plain NumPy (no Drake).

    Usage: `set_trajectory(times, q, q_now)` (returns "" or the rejection
    reason), then `command(q_now)` every `config.period` seconds.
    """

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self.config.validate()
        self._q_diag = np.asarray(self.config.q_diag, float)
        self._r_diag = np.asarray(self.config.r_diag, float)
        self._reason = ""
        self._status = TrackerStatus.IDLE
        self._clear_path()

    def _clear_path(self) -> None:
        self._ts = None
        self._t0 = 0.0
        self._qs = None
        self._source = None
        self._direction = None
        self._stops = None
        self._segment = 0
        self._nearest = 0
        self._done = False

    @property
    def status(self) -> str:
        return self._status

    @property
    def reason(self) -> str:
        return self._reason

    @property
    def resampled(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(times (M,), q (M, 11)) of the resampled reference, or None."""
        return None if self._qs is None else (self._ts, self._qs)

    def base_path_ahead(self) -> np.ndarray:
        """(K, 3) base poses (x, y, theta) of the resampled path from the nearest sample on (empty without a path)."""
        return np.empty((0, 3)) if self._qs is None else self._qs[self._nearest:, :3]

    def clear(self) -> None:
        """Drops the trajectory; the command is zero until a new one arrives."""
        self._clear_path()
        self._status = TrackerStatus.IDLE
        self._reason = ""

    def reject(self, reason: str) -> str:
        """Drops the trajectory and stops (zero command, status REJECTED) with `reason`."""
        self._clear_path()
        self._status = TrackerStatus.REJECTED
        self._reason = reason
        return reason

    def validate_trajectory(self, times, q, q_now) -> str:
        """The reason why (times, q) cannot be tracked from q_now, or ""."""
        cfg = self.config
        try:
            times = np.asarray(times, dtype=float)
            q = np.asarray(q, dtype=float)
            q_now = np.asarray(q_now, dtype=float)
        except (TypeError, ValueError) as e:
            return f"trajectory arrays are not numeric: {e}"
        if q.ndim != 2 or q.shape[1] != layout.NQ:
            return f"trajectory q must have shape (N, {layout.NQ}), got {q.shape}"
        if times.ndim != 1 or times.shape[0] != q.shape[0]:
            return f"trajectory times must have shape ({q.shape[0]},), got {times.shape}"
        if q.shape[0] < 1:
            return "trajectory has no waypoints"
        if q_now.shape != (layout.NQ,) or not np.all(np.isfinite(q_now)):
            return f"current configuration must be a finite ({layout.NQ},) vector"
        if not np.all(np.isfinite(times)):
            return "trajectory times contain NaN or inf"
        bad = np.flatnonzero(~np.all(np.isfinite(q), axis=1))
        if bad.size:
            return f"trajectory q contains NaN or inf at waypoint(s) {bad[:5].tolist()}"
        if np.any(np.diff(times) <= 0.0):
            i = int(np.flatnonzero(np.diff(times) <= 0.0)[0])
            return f"trajectory times must increase strictly (times[{i}]={times[i]}, times[{i + 1}]={times[i + 1]})"
        if q.shape[0] > 1:
            step = np.abs(np.diff(q, axis=0))
            cont = step[:, layout.IS_CONTINUOUS]
            if np.any(cont > np.pi):
                i, j = np.argwhere(cont > np.pi)[0]
                name = np.asarray(layout.WHOLE_BODY_JOINTS)[layout.IS_CONTINUOUS][j]
                return (f"continuous joint {name} jumps by {cont[i, j]:.3f} rad between waypoints "
                        f"{i} and {i + 1} (wrap-around; the path must be unwrapped)")
            dxy = np.hypot(step[:, 0], step[:, 1])
            if np.any(dxy > cfg.max_waypoint_step_position):
                i = int(np.argmax(dxy))
                return (f"base jumps by {dxy[i]:.3f} m between waypoints {i} and {i + 1} "
                        f"(max_waypoint_step_position {cfg.max_waypoint_step_position})")
            joint_step = step[:, 2:]
            if np.any(joint_step > cfg.max_waypoint_step_joint):
                i, j = np.argwhere(joint_step > cfg.max_waypoint_step_joint)[0]
                return (f"joint {layout.WHOLE_BODY_JOINTS[j + 2]} jumps by {joint_step[i, j]:.3f} between "
                        f"waypoints {i} and {i + 1} (max_waypoint_step_joint {cfg.max_waypoint_step_joint})")
            rate = step / np.diff(times)[:, None]
            rate[:, 0] = dxy / np.diff(times)
            rate[:, 1] = 0.0
            ratio = rate / layout.V_MAX[None, :]
            if np.any(ratio > cfg.max_rate_ratio):
                i, j = np.argwhere(ratio > cfg.max_rate_ratio)[0]
                return (f"segment {i}->{i + 1} moves {layout.WHOLE_BODY_JOINTS[j]} at {ratio[i, j]:.1f} x its "
                        f"rate limit (max_rate_ratio {cfg.max_rate_ratio}): a jump in time")
        return ""

    def set_trajectory(self, times, q, q_now, stops=()) -> str:
        """Loads a trajectory (times (N,), q (N, 11)) to track from q_now (11,).

        `stops` are waypoint indices that are stops like cusps and corners
        (`TimedTrajectory.stops`): the reference waits at each until the robot
        is within the stop tolerances.

        Returns:
            "" when accepted; otherwise the rejection reason (the tracker then
            stops: zero command, status REJECTED, until a valid trajectory).
        """
        reason = self.validate_trajectory(times, q, q_now)
        if reason:
            return self.reject(reason)
        cfg = self.config
        times = np.asarray(times, dtype=float)
        q = np.asarray(q, dtype=float)
        q_now = np.asarray(q_now, dtype=float)
        ts, qs, source = _resample(times, q, cfg.resample_dt, cfg.max_resampled_waypoints)
        # The original waypoint times are on the grid: waypoint k is the first sample sourced from it.
        required = np.searchsorted(source, np.asarray(stops, dtype=int), side="left")
        direction, stops = _direction_and_stops(qs, cfg.corner_angle, required)
        self._ts, self._qs, self._source, self._t0 = ts, qs, source, float(times[0])
        self._direction, self._stops = direction, stops
        self._segment, self._nearest, self._done = 0, 0, False
        nearest = self._search(q_now)
        dx = state_error(qs[nearest], q_now)
        dxy = float(np.hypot(dx[0], dx[1]))
        joint = float(np.max(np.abs(dx[3:])))
        if dxy > cfg.max_start_position_error:
            return self.reject(f"trajectory starts {dxy:.3f} m from the robot's base "
                                f"(max_start_position_error {cfg.max_start_position_error})")
        if abs(dx[2]) > cfg.max_start_heading_error:
            return self.reject(f"trajectory starts {abs(dx[2]):.3f} rad from the robot's heading "
                                f"(max_start_heading_error {cfg.max_start_heading_error})")
        if joint > cfg.max_start_joint_error:
            j = int(np.argmax(np.abs(dx[3:]))) + 3
            return self.reject(f"trajectory starts {joint:.3f} from the robot's {layout.WHOLE_BODY_JOINTS[j]} "
                                f"(max_start_joint_error {cfg.max_start_joint_error})")
        self._status = TrackerStatus.TRACKING
        self._reason = ""
        return ""

    def _search(self, q_now: np.ndarray) -> int:
        """The nearest sample in the forward window of the current segment (updates state)."""
        cfg = self.config
        ts, qs = self._ts, self._qs
        lo = self._nearest
        seg_end = int(self._stops[self._segment])
        hi = int(np.searchsorted(ts, ts[lo] + cfg.search_window_time, side="right")) - 1
        hi = max(lo, min(hi, seg_end))
        window = qs[lo:hi + 1]
        dx = state_error(window, q_now)
        d2 = (cfg.position_weight * (dx[:, 0] ** 2 + dx[:, 1] ** 2)
              + cfg.heading_weight * dx[:, 2] ** 2
              + cfg.joint_weight * np.sum(dx[:, 3:] ** 2, axis=1))
        # Ties (a pause in the path) go to the latest sample so progress never stalls.
        self._nearest = lo + (d2.shape[0] - 1 - int(np.argmin(d2[::-1])))
        return self._nearest

    def _reference(self, nearest: int) -> int:
        seg_end = int(self._stops[self._segment])
        j = int(np.searchsorted(self._ts, self._ts[nearest] + self.config.lookahead_time - 1e-9, side="left"))
        return min(max(j, nearest), seg_end)

    def _zero(self, status: str, reason: str = "", nearest: int = -1, reference: int = -1,
              done: bool = False, position_error: float = math.nan) -> TrackerCommand:
        has = self._qs is not None and nearest >= 0
        return TrackerCommand(
            nearest_index=int(self._source[nearest]) if has else -1,
            reference_index=int(self._source[reference]) if has and reference >= 0 else -1,
            nearest_time=self._t0 + float(self._ts[nearest]) if has else math.nan,
            reference_time=self._t0 + float(self._ts[reference]) if has and reference >= 0 else math.nan,
            done=done, status=status, reason=reason, position_error=position_error)

    def command(self, q_now) -> TrackerCommand:
        """The velocity command for the current configuration q_now (11,)."""
        cfg = self.config
        try:
            q_now = np.asarray(q_now, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            q_now = np.full(1, np.nan)
        if q_now.shape != (layout.NQ,) or not np.all(np.isfinite(q_now)):
            return self._zero(TrackerStatus.INVALID_STATE,
                              f"robot configuration must be a finite ({layout.NQ},) vector")
        if self._qs is None:
            return self._zero(self._status, self._reason)
        qs, last = self._qs, self._qs.shape[0] - 1
        if self._done:
            return self._zero(TrackerStatus.DONE, nearest=self._nearest, reference=last, done=True,
                              position_error=float(np.hypot(*(qs[last, :2] - q_now[:2]))))
        nearest = self._search(q_now)
        reference = self._reference(nearest)
        seg_end = int(self._stops[self._segment])
        if reference == seg_end and seg_end < last:
            dx_stop = state_error(qs[seg_end], q_now)
            c, s = math.cos(q_now[2]), math.sin(q_now[2])
            along, across = c * dx_stop[0] + s * dx_stop[1], -s * dx_stop[0] + c * dx_stop[1]
            at_cusp = (abs(along) <= cfg.cusp_position_tolerance and abs(across) <= cfg.cusp_lateral_tolerance
                       and abs(dx_stop[2]) <= cfg.cusp_heading_tolerance
                       and float(np.max(np.abs(dx_stop[3:]))) <= cfg.corner_joint_tolerance)
            if at_cusp or self._stalled(self._control(q_now, nearest, reference, seg_end)):
                self._segment += 1
                self._nearest = seg_end
                nearest = self._search(q_now)
                reference = self._reference(nearest)
                seg_end = int(self._stops[self._segment])
        position_error = float(np.hypot(*(qs[nearest, :2] - q_now[:2])))
        u = self._control(q_now, nearest, reference, seg_end)
        if reference == last:
            dx_goal = state_error(qs[last], q_now)
            xy, heading, joint = math.hypot(dx_goal[0], dx_goal[1]), abs(dx_goal[2]), float(np.max(np.abs(dx_goal[3:])))
            if (xy <= cfg.goal_position_tolerance and heading <= cfg.goal_heading_tolerance
                    and joint <= cfg.goal_joint_tolerance):
                self._done = True
                self._status = TrackerStatus.DONE
                return self._zero(TrackerStatus.DONE, nearest=nearest, reference=reference, done=True,
                                  position_error=position_error)
            if self._stalled(u):
                reason = (f"stalled {xy:.3f} m / {heading:.3f} rad / {joint:.3f} (joints) from the final "
                          "waypoint, outside the goal tolerances")
                return self._zero(TrackerStatus.STALLED, reason, nearest=nearest, reference=reference,
                                  position_error=position_error)
        u = clamp_command(u, cfg.uniform_clamp)
        return TrackerCommand(
            base_velocity=u[:2].copy(), joint_velocity=u[2:].copy(),
            nearest_index=int(self._source[nearest]), reference_index=int(self._source[reference]),
            nearest_time=self._t0 + float(self._ts[nearest]),
            reference_time=self._t0 + float(self._ts[reference]),
            done=False, status=TrackerStatus.TRACKING, reason="", position_error=position_error)

    def _stalled(self, u: np.ndarray) -> bool:
        return float(np.max(np.abs(u) / U_LIMITS)) < self.config.stall_command_ratio

    def _deviation(self, q_now: np.ndarray, nearest: int) -> np.ndarray:
        """q_nearest - q without its component along the path's direction at
        the nearest sample: the samples are discrete, and an amplified
        along-track error would brake the robot short of every pause."""
        qs = self._qs
        e = state_error(qs[nearest], q_now)
        k = min(nearest + 1, qs.shape[0] - 1)
        tangent = state_error(qs[k], qs[nearest]) if k > nearest else state_error(qs[nearest], qs[max(nearest - 1, 0)])
        norm2 = float(tangent @ tangent)
        if norm2 > 1e-18:
            e -= (float(e @ tangent) / norm2) * tangent
        return e

    def _control(self, q_now: np.ndarray, nearest: int, reference: int, seg_end: int) -> np.ndarray:
        """The paper's gain * one-step MPC toward the reference (before clamping)."""
        cfg, qs = self.config, self._qs
        dx = state_error(qs[reference], q_now)
        if reference == seg_end:
            dx *= cfg.stop_gain
        elif cfg.path_error_gain != 1.0:
            dx[_AMPLIFIED] += (cfg.path_error_gain - 1.0) * self._deviation(q_now, nearest)[_AMPLIFIED]
        direction = int(self._direction[nearest])
        if (cfg.lateral_gain > 0.0 and direction != 0
                and math.hypot(*(qs[seg_end, :2] - q_now[:2])) > cfg.lateral_stop_distance):
            theta_path = qs[nearest, 2]
            e_left = (-math.sin(theta_path) * (q_now[0] - qs[nearest, 0])
                      + math.cos(theta_path) * (q_now[1] - qs[nearest, 1]))
            correction = math.atan(cfg.lateral_gain * direction * e_left)
            dx[2] -= float(np.clip(correction, -cfg.max_lateral_correction, cfg.max_lateral_correction))
        return cfg.gain * one_step_mpc(dx, float(q_now[layout.THETA]), self._q_diag, self._r_diag)
