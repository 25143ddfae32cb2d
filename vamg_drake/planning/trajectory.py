"""Timed whole-body trajectories: the planner's output, consumed by the tracker
and the gaze optimizer.

A `TimedTrajectory` is a piecewise-linear path through whole-body
configurations ``q`` (see `vamg_drake.robot.layout`) at strictly increasing
times. Continuous joints (base yaw, the roll joints) are stored *unwrapped*
along the path, so linear interpolation never takes the long way round; a
step of more than pi in a continuous joint is rejected as a wrap-around jump.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from vamg_drake.robot import layout

#: A continuous joint moving more than this between two consecutive waypoints
#: is a wrap-around bug (the waypoints must be unwrapped along the path).
MAX_CONTINUOUS_STEP = np.pi


@dataclasses.dataclass(frozen=True, eq=False)
class TimedTrajectory:
    """Whole-body waypoints q (N, 11) at times (N,) [s], linearly interpolated.

    The planner emits times starting at 0 (relative to the moment the plan was
    requested); use `shifted` to move it onto the simulation clock.
    The arrays are copied and made read-only on construction. `stops` are
    waypoint indices the tracker must reach (within its stop tolerances)
    before it follows the path on, e.g. the entry of a straight grasp
    approach, which a look-ahead chord would otherwise cut.
    """

    times: np.ndarray
    q: np.ndarray
    stops: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        times = np.array(self.times, dtype=float, copy=True).reshape(-1)
        q = np.array(self.q, dtype=float, copy=True)
        if q.ndim != 2 or q.shape[1] != layout.NQ:
            raise ValueError(
                f"TimedTrajectory.q must have shape (N, {layout.NQ}), got {q.shape}"
            )
        if times.shape[0] != q.shape[0]:
            raise ValueError(
                f"TimedTrajectory.times has {times.shape[0]} entries but q has "
                f"{q.shape[0]} rows"
            )
        if times.shape[0] < 1:
            raise ValueError("TimedTrajectory needs at least one waypoint")
        if not np.all(np.isfinite(times)):
            raise ValueError("TimedTrajectory.times contains NaN or inf")
        bad_rows = np.flatnonzero(~np.all(np.isfinite(q), axis=1))
        if bad_rows.size:
            raise ValueError(
                f"TimedTrajectory.q contains NaN or inf at waypoint(s) {bad_rows[:5].tolist()}"
            )
        if np.any(np.diff(times) <= 0.0):
            i = int(np.flatnonzero(np.diff(times) <= 0.0)[0])
            raise ValueError(
                f"TimedTrajectory.times must be strictly increasing "
                f"(times[{i}]={times[i]}, times[{i + 1}]={times[i + 1]})"
            )
        if q.shape[0] > 1:
            step = np.abs(np.diff(q[:, layout.IS_CONTINUOUS], axis=0))
            if np.any(step > MAX_CONTINUOUS_STEP):
                i, j = np.argwhere(step > MAX_CONTINUOUS_STEP)[0]
                joint = np.asarray(layout.WHOLE_BODY_JOINTS)[layout.IS_CONTINUOUS][j]
                raise ValueError(
                    f"TimedTrajectory.q jumps by {step[i, j]:.3f} rad in continuous "
                    f"joint {joint} between waypoints {i} and {i + 1}; unwrap it"
                )
        stops = tuple(sorted({int(k) for k in self.stops}))
        if stops and not 0 <= stops[0] <= stops[-1] < q.shape[0]:
            raise ValueError(f"TimedTrajectory.stops must index waypoints 0..{q.shape[0] - 1}, got {list(stops)}")
        times.flags.writeable = False
        q.flags.writeable = False
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "stops", stops)

    def __copy__(self) -> "TimedTrajectory":
        return self  # immutable (frozen, read-only arrays): copies may share it

    def __deepcopy__(self, memo) -> "TimedTrajectory":
        # Drake copies abstract port and state values; sharing keeps the
        # trajectory's identity, which consumers use to notice a new plan.
        return self

    @property
    def num_waypoints(self) -> int:
        return int(self.times.shape[0])

    @property
    def start_time(self) -> float:
        return float(self.times[0])

    @property
    def end_time(self) -> float:
        return float(self.times[-1])

    @property
    def duration(self) -> float:
        """end_time - start_time [s]."""
        return float(self.times[-1] - self.times[0])

    def sample(self, t: float) -> np.ndarray:
        """The configuration (11,) at time t, held constant outside the span."""
        return self.sample_many(np.array([t], dtype=float))[0]

    def sample_many(self, t: np.ndarray) -> np.ndarray:
        """Configurations (M, 11) at times t (M,), held constant outside the span."""
        t = np.asarray(t, dtype=float).reshape(-1)
        if not np.all(np.isfinite(t)):
            raise ValueError("TimedTrajectory.sample: time is NaN or inf")
        if self.num_waypoints == 1:
            return np.repeat(self.q, t.shape[0], axis=0)
        tc = np.clip(t, self.times[0], self.times[-1])
        k = np.clip(np.searchsorted(self.times, tc, side="right") - 1, 0, self.num_waypoints - 2)
        s = (tc - self.times[k]) / (self.times[k + 1] - self.times[k])
        return self.q[k] + s[:, None] * (self.q[k + 1] - self.q[k])

    def velocity(self, t: float) -> np.ndarray:
        """The (piecewise-constant) rate q_dot (11,) at time t; zero outside the span."""
        if self.num_waypoints == 1 or t < self.times[0] or t > self.times[-1]:
            return np.zeros(layout.NQ)
        k = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.num_waypoints - 2))
        return (self.q[k + 1] - self.q[k]) / (self.times[k + 1] - self.times[k])

    def segment_velocities(self) -> np.ndarray:
        """Rates (N-1, 11) on each segment."""
        return np.diff(self.q, axis=0) / np.diff(self.times)[:, None]

    def max_rate_ratio(self, v_max: np.ndarray = layout.V_MAX) -> float:
        """max over segments and joints of |q_dot| / v_max (<= 1 means within limits).

        Base x and y share the linear speed limit v_max[0] (the planar speed is
        used, not the per-axis one).
        """
        if self.num_waypoints == 1:
            return 0.0
        qd = self.segment_velocities()
        ratio = np.abs(qd) / np.asarray(v_max)[None, :]
        ratio[:, 0] = np.hypot(qd[:, 0], qd[:, 1]) / v_max[0]
        ratio[:, 1] = 0.0
        return float(ratio.max())

    def shifted(self, t0: float) -> "TimedTrajectory":
        """A copy whose times start at t0."""
        return TimedTrajectory(times=self.times - self.times[0] + t0, q=self.q, stops=self.stops)

    def to_piecewise_polynomial(self):
        """The same trajectory as a Drake first-order-hold PiecewisePolynomial."""
        if self.num_waypoints == 1:
            return PiecewisePolynomial(self.q[0].reshape(-1, 1))
        return PiecewisePolynomial.FirstOrderHold(self.times, self.q.T)
