"""The compiled RRT-Connect: its motion checks agree with the checker's, its
paths are valid and the same seed gives the same path."""

import numpy as np
import pytest

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.testing.planning_problems import room_problem
from vamg_drake.planning.whole_body_rrt import KernelRRTConfig, WholeBodySearchSpace
from vamg_drake.robot import layout

LO, HI = layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:]
W = np.r_[5.0, np.ones(7)]


@pytest.fixture(scope="module")
def room():
    base = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    p = room_problem(3, base)
    return p, base.with_environment(CollisionEnvironment.from_primitives(p.obstacles))


def _arm(rng, around, sigma):
    return np.clip(around + rng.normal(0, sigma, 8) * np.r_[0.1, np.ones(7)], layout.Q_LOWER[3:], layout.Q_UPPER[3:])


def test_fixed_base_motion_check_agrees_with_checker(room):
    p, cc = room
    space = WholeBodySearchSpace.fixed_base(cc, p.q_start[:3])
    rng = np.random.default_rng(0)
    results = []
    for _ in range(300):
        a = _arm(rng, p.q_start[3:], 0.3)
        b = _arm(rng, a, 0.5)
        mine = space.motion_free(a, b)
        assert mine == cc.motion_free(np.r_[p.q_start[:3], a], np.r_[p.q_start[:3], b])
        results.append(mine)
    assert 0 < sum(results) < len(results)  # both outcomes exercised


def test_along_path_states_follow_the_base_path_and_check_like_the_checker(room):
    p, cc = room
    poses = np.array([p.q_start[:3], p.q_start[:3] + [0.4, 0.0, 0.3], p.q_start[:3] + [0.8, 0.2, 0.6]])
    space = WholeBodySearchSpace.along_path(cc, poses)
    Q = space.to_configurations(np.array([np.r_[0.0, p.q_start[3:]], np.r_[space.duration, p.q_start[3:]]]))
    np.testing.assert_allclose(Q[:, :3], poses[[0, -1]])
    rng = np.random.default_rng(1)
    for _ in range(100):
        xa = np.r_[rng.uniform(0, space.duration), _arm(rng, p.q_start[3:], 0.3)]
        xb = np.r_[rng.uniform(0, space.duration), _arm(rng, xa[1:], 0.5)]
        dense = space.states(xa, xb)
        assert space.motion_free(xa, xb) == (cc.first_collision(dense) < 0)


def test_fixed_base_rrt_connect_plans_valid_deterministic_paths(room):
    p, cc = room
    space = WholeBodySearchSpace.fixed_base(cc, p.q_start[:3])
    rng = np.random.default_rng(2)
    goal = next(g for g in (rng.uniform(LO, HI) for _ in range(2000))
                if cc.is_free(np.r_[p.q_start[:3], g][None])[0] and not space.motion_free(p.q_start[3:], g))
    cfg = KernelRRTConfig(max_iterations=2000)
    a, why = space.rrt_connect(p.q_start[3:], goal, LO, HI, W, np.random.default_rng(5), cfg)
    b, _ = space.rrt_connect(p.q_start[3:], goal, LO, HI, W, np.random.default_rng(5), cfg)
    assert a is not None, why
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[0], p.q_start[3:])
    np.testing.assert_array_equal(a[-1], goal)
    assert cc.path_free(space.to_configurations(a))


def test_rrt_connect_reports_the_iteration_limit(room):
    p, cc = room
    space = WholeBodySearchSpace.fixed_base(cc, p.q_start[:3])
    blocked = p.q_start[3:].copy()
    blocked[0] = 10.0  # torso far outside its limits: every motion to it fails
    path, why = space.rrt_connect(p.q_start[3:], blocked, LO, HI, W, np.random.default_rng(0),
                                  KernelRRTConfig(max_iterations=50))
    assert path is None and why == "iteration limit"


def test_a_paused_and_resumed_search_finds_the_same_path(room):
    """`RRTConnectSearch` stopped after a few iterations (reporting the
    iteration limit) and resumed gives the path of one uninterrupted run."""
    from vamg_drake.planning.whole_body_rrt import RRTConnectSearch

    p, cc = room
    space = WholeBodySearchSpace.fixed_base(cc, p.q_start[:3])
    rng = np.random.default_rng(2)
    cfg = KernelRRTConfig(max_iterations=2000, chunk=1)
    needed = 0
    for _ in range(200):  # a goal the search needs a few iterations for
        goal = rng.uniform(LO, HI)
        if not cc.is_free(np.r_[p.q_start[:3], goal][None])[0] or space.motion_free(p.q_start[3:], goal):
            continue
        probe = RRTConnectSearch(space, p.q_start[3:], goal, LO, HI, W, np.random.default_rng(5), cfg)
        if probe.run(None)[0] is not None and probe.iteration >= 4:
            needed = probe.iteration  # chunk=1: the iteration that connected
            break
    assert needed >= 4
    whole, why = space.rrt_connect(p.q_start[3:], goal, LO, HI, W, np.random.default_rng(5), cfg)
    assert whole is not None, why
    search = RRTConnectSearch(space, p.q_start[3:], goal, LO, HI, W, np.random.default_rng(5),
                              KernelRRTConfig(max_iterations=2000, chunk=4))
    paused, why = search.run(needed - 1)
    assert paused is None and why == "iteration limit" and search.iteration == needed - 1
    resumed, why = search.run(None)
    assert resumed is not None, why
    np.testing.assert_array_equal(resumed, whole)
    np.testing.assert_array_equal(search.run(5)[0], whole)  # finished: the same answer
