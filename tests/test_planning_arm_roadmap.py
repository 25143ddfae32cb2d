"""The arm roadmap: self-collision-free paths to the travel pose, lazy fixed-base queries."""

import numpy as np
import pytest

from vamg_drake.planning.arm_roadmap import ArmRoadmap, ArmRoadmapConfig
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker, densify
from vamg_drake.planning.whole_body_planner import PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout
from vamg_drake.world.primitives import WorldBox, rotation_z

TRAVEL = np.asarray(PlannerConfig().travel_torso_arm, float)


@pytest.fixture(scope="module")
def checker():
    return SphereCollisionChecker.for_fetch(CollisionEnvironment())


def _wrapped(x):
    return layout.wrap_configuration(np.concatenate([np.zeros(3), x]))[3:]


def _free_samples(checker, n, seed):
    rng = np.random.default_rng(seed)
    X = rng.uniform(layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:], (20 * n, 8))
    return X[checker.is_free(np.concatenate([np.zeros((X.shape[0], 3)), X], axis=1))][:n]


def _path_free(checker, base, W):
    Q = np.concatenate([np.repeat(np.asarray(base, float)[None], W.shape[0], axis=0), W], axis=1)
    return checker.first_collision(densify(Q, checker)) < 0


def test_small_roadmap_is_self_free_deterministic_and_rooted_at_the_carry(checker):
    config = ArmRoadmapConfig(nodes=80, neighbours=6)
    a = ArmRoadmap.build(checker, TRAVEL, config)
    b = ArmRoadmap.build(checker, TRAVEL, config)
    np.testing.assert_array_equal(a.nodes, b.nodes)
    np.testing.assert_array_equal(a.edges, b.edges)
    np.testing.assert_allclose(a.nodes[0], _wrapped(TRAVEL))
    assert a.nodes.shape == (80, 8) and a.num_edges > 80
    Q = np.concatenate([np.zeros((80, 3)), a.nodes], axis=1)
    assert checker.is_free(Q).all()
    for i, j in a.edges[:: max(a.num_edges // 40, 1)]:
        assert _path_free(checker, np.zeros(3), a.nodes[[i, j]])
    # The tree toward the carry: costs decrease along it.
    connected = np.flatnonzero(np.isfinite(a.cost_to_carry))[1:]
    assert np.all(a.cost_to_carry[a.next_toward_carry[connected]] < a.cost_to_carry[connected])


def test_paths_to_the_carry_start_at_the_query_and_are_self_free(checker):
    roadmap = ArmRoadmap.for_checker(checker, TRAVEL)
    X = _free_samples(checker, 25, seed=3)
    X[:, layout.IS_CONTINUOUS[3:]] += 2 * np.pi  # unwrapped rolls: the path keeps them
    found = 0
    for x in X:
        W = roadmap.to_carry(x)
        if W is None:
            continue
        found += 1
        np.testing.assert_array_equal(W[0], x)
        np.testing.assert_allclose(_wrapped(W[-1]), _wrapped(TRAVEL), atol=1e-9)
        assert _path_free(checker, np.array([1.0, -2.0, 0.7]), W)  # self-collision does not depend on the base
    assert found >= 23


def test_lazy_query_at_a_fixed_base_avoids_the_table(checker):
    table = [WorldBox("table/top", np.array([0.75, 0.0, 0.72]), rotation_z(0.0), np.array([0.3, 0.6, 0.02])),
             WorldBox("table/base", np.array([0.75, 0.0, 0.35]), rotation_z(0.0), np.array([0.15, 0.3, 0.35]))]
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(table))
    cc = planner.checker
    base = np.zeros(3)
    goals = [x for x in _free_samples(cc.with_environment(cc.env), 200, seed=5)
             if cc.is_free(np.concatenate([base, x])[None])[0]][:10]
    roadmap = planner._arm_roadmap()

    def state_free(X):
        return cc.is_free(np.concatenate([np.zeros((X.shape[0], 3)), X], axis=1))

    from vamg_drake.planning.whole_body_rrt import WholeBodySearchSpace

    space = WholeBodySearchSpace.fixed_base(cc, base)
    found = 0
    for g in goals:
        W = roadmap.connect(planner.travel, g, state_free, space.motion_free)
        if W is None:
            continue
        found += 1
        np.testing.assert_array_equal(W[0], planner.travel)
        np.testing.assert_allclose(_wrapped(W[-1]), _wrapped(g), atol=1e-9)
        assert _path_free(cc, base, W)
    assert found >= 5


def test_bad_config_and_a_colliding_carry_are_errors(checker):
    with pytest.raises(ValueError, match="nodes"):
        ArmRoadmap.build(checker, TRAVEL, ArmRoadmapConfig(nodes=1))
    self_colliding = np.array([0.246, -0.739, -1.109, -3.038, 1.41, 2.593, 0.461, 1.442])
    assert not checker.is_free(np.concatenate([np.zeros(3), self_colliding])[None])[0]
    with pytest.raises(ValueError, match="carry"):
        ArmRoadmap.build(checker, self_colliding, ArmRoadmapConfig(nodes=10))


def test_remembered_queries_answer_as_fresh_ones(checker):
    """`to_carry` and `self_free` answers are remembered; a remembered path is
    the fresh one, and changing a returned path does not change the next."""
    roadmap = ArmRoadmap.for_checker(checker, TRAVEL)
    fresh = ArmRoadmap(checker, roadmap.nodes, roadmap.cost_to_carry, roadmap.next_toward_carry, roadmap.edges,
                       roadmap.config)  # the same roadmap, nothing remembered
    answers = []
    for x in _free_samples(checker, 6, 31):
        first = roadmap.to_carry(x)
        if first is not None:
            first[:] = 0.0  # the caller's copy
        again = roadmap.to_carry(x)
        want = fresh.to_carry(x)
        assert (again is None) == (want is None)
        if want is not None:
            np.testing.assert_array_equal(again, want)
        line = np.stack([x, TRAVEL])
        assert roadmap.self_free(line) == roadmap.self_free(line) == fresh.self_free(line)
        answers.append(want is not None)
    assert any(answers)
