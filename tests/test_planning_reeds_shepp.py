"""Reeds-Shepp curves: lengths against OMPL, endpoints by integration."""

import numpy as np
import pytest

from vamg_drake.planning import reeds_shepp as rs

ob = pytest.importorskip("ompl.base")


@pytest.mark.parametrize("radius", [1.0, 0.4])
def test_lengths_match_ompl_and_paths_reach_the_goal(radius):
    space = ob.ReedsSheppStateSpace(radius)
    a, b = space.allocState(), space.allocState()
    rng = np.random.default_rng(7)
    for i in range(1500):
        s = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)])
        g = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)])
        if i % 3 == 0:  # short, turning-dominated connections
            g[:2] = s[:2] + rng.uniform(-0.3, 0.3, 2)
        a.setX(s[0]), a.setY(s[1]), a.setYaw(s[2])
        b.setX(g[0]), b.setY(g[1]), b.setYaw(g[2])
        types, lengths, total = rs.shortest_path(s, g, radius)
        assert total == pytest.approx(space.distance(a, b), abs=1e-7)
        end = rs.end_pose(s, types, lengths, radius)
        np.testing.assert_allclose(end[:2], g[:2], atol=1e-7)
        assert np.angle(np.exp(1j * (end[2] - g[2]))) == pytest.approx(0.0, abs=1e-7)


def test_sampled_path_is_continuous_and_ends_at_goal():
    s, g = np.array([0.0, 0.0, 0.0]), np.array([0.5, 1.0, 2.5])
    types, lengths, total = rs.shortest_path(s, g, 0.4)
    poses = rs.sample_path(s, types, lengths, 0.4, 0.02)
    np.testing.assert_allclose(poses[0], s)
    np.testing.assert_allclose(poses[-1, :2], g[:2], atol=1e-9)
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    assert steps.max() <= 0.02 + 1e-9
    assert np.sum(steps) == pytest.approx(total, rel=1e-3)


def test_reverse_weight_trades_length_for_forward_driving():
    """A goal behind the robot: the plain shortest path backs up all the way;
    with backward segments weighted 3x the chosen path drives less backwards
    (and is longer), and still ends at the goal."""
    start, goal, R = np.array([0.0, 0.0, 0.0]), np.array([-1.5, 0.8, 0.0]), 0.4

    def backward(lengths):
        return -R * lengths[lengths < 0].sum()

    t1, l1, total1 = rs.shortest_path(start, goal, R)
    t3, l3, total3 = rs.shortest_path(start, goal, R, 3.0)
    assert backward(l1) == pytest.approx(total1)
    assert backward(l3) < 0.6 * backward(l1) and total3 > total1
    np.testing.assert_allclose(rs.end_pose(start, t3, l3, R), goal, atol=1e-9)
    # Weight 1 is the plain shortest path.
    assert rs.shortest_path(start, goal, R, 1.0)[2] == pytest.approx(total1)
