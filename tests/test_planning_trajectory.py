"""Tests for TimedTrajectory."""

import numpy as np
import pytest

from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout


def _line(n: int = 5) -> TimedTrajectory:
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    q1 = layout.stow_configuration(1.0, 0.5, 3.0)
    s = np.linspace(0.0, 1.0, n)[:, None]
    return TimedTrajectory(times=np.linspace(0.0, 2.0, n), q=q0 + s * (q1 - q0))


def test_sample_interpolates_and_holds_ends():
    traj = _line()
    assert traj.duration == pytest.approx(2.0)
    np.testing.assert_allclose(traj.sample(1.0)[:3], [0.5, 0.25, 1.5])
    np.testing.assert_allclose(traj.sample(-1.0), traj.q[0])
    np.testing.assert_allclose(traj.sample(5.0), traj.q[-1])
    np.testing.assert_allclose(traj.velocity(0.3)[:3], [0.5, 0.25, 1.5])
    assert traj.max_rate_ratio() == pytest.approx(1.5)


def test_arrays_are_read_only_copies():
    times = np.array([0.0, 1.0])
    q = np.zeros((2, layout.NQ))
    traj = TimedTrajectory(times=times, q=q)
    q[1, 0] = 5.0
    assert traj.q[1, 0] == 0.0
    with pytest.raises(ValueError):
        traj.q[0, 0] = 1.0


def test_rejects_bad_input():
    q = np.zeros((3, layout.NQ))
    with pytest.raises(ValueError, match="shape"):
        TimedTrajectory(times=np.arange(3.0), q=np.zeros((3, 7)))
    with pytest.raises(ValueError, match="strictly increasing"):
        TimedTrajectory(times=np.array([0.0, 1.0, 1.0]), q=q)
    bad = q.copy()
    bad[1, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        TimedTrajectory(times=np.arange(3.0), q=bad)
    jump = q.copy()
    jump[2, layout.THETA] = 4.0
    with pytest.raises(ValueError, match="base_theta"):
        TimedTrajectory(times=np.arange(3.0), q=jump)


def test_piecewise_polynomial_matches_sample():
    traj = _line()
    pp = traj.to_piecewise_polynomial()
    for t in [0.0, 0.7, 1.3, 2.0]:
        np.testing.assert_allclose(pp.value(t).ravel(), traj.sample(t), atol=1e-12)
