"""Base paths drive forward into what the head camera sees: backing up is
weighted by `HybridAStarConfig.reverse_penalty` everywhere (search primitives,
Reeds-Shepp curve choice, analytic expansions, shortcuts)."""

import numpy as np
import pytest

from vamg_drake.planning.hybrid_astar import Costmap2D, Footprint2D, HybridAStar, HybridAStarConfig


def _backward_length(poses: np.ndarray) -> float:
    d = np.diff(poses[:, :2], axis=0)
    back = d[:, 0] * np.cos(poses[:-1, 2]) + d[:, 1] * np.sin(poses[:-1, 2]) < 0.0
    return float(np.hypot(d[back, 0], d[back, 1]).sum())


@pytest.mark.parametrize("goal", [[-2.0, 0.0, 0.0], [-1.5, 0.8, 0.0], [-2.0, 0.5, np.pi], [-2.5, -1.0, np.pi / 2]])
def test_goals_behind_the_robot_are_reached_driving_forward(goal):
    costmap = Costmap2D(np.full((200, 200), 10.0, np.float32), np.array([-5.0, -5.0]), 0.05, 0.07)
    start = np.array([0.0, 0.0, 0.0])
    forward = HybridAStar(costmap, Footprint2D.disc(0.3), HybridAStarConfig())
    path, why = forward.plan(start, np.array(goal))
    assert path is not None, why
    np.testing.assert_allclose(path.poses[-1, :2], goal[:2], atol=1e-6)
    backward = _backward_length(path.poses)
    assert backward <= HybridAStarConfig().max_analytic_reverse + 1e-6
    shortened = forward.shortcut(path.poses, np.random.default_rng(0), 30)
    assert _backward_length(shortened) <= HybridAStarConfig().max_analytic_reverse + 1e-6
    # Unweighted, the shortest curve backs up farther.
    plain = HybridAStar(costmap, Footprint2D.disc(0.3),
                        HybridAStarConfig(reverse_penalty=1.0, max_analytic_reverse=np.inf))
    path, _ = plain.plan(start, np.array(goal))
    assert _backward_length(path.poses) > backward + 0.2
