"""Self-collision tests that can never fail inside the joint limits are dropped."""

import numpy as np

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import CollisionCheckerConfig, SphereCollisionChecker
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.robot.spheres import SphereModel


def _checker(prune: bool, self_padding: float = 0.0) -> SphereCollisionChecker:
    sm = SphereModel.load()
    return SphereCollisionChecker(FetchKinematics.instance().tree, sm.link_index, sm.center_L, sm.radius,
                            sm.self_collision_pairs, CollisionEnvironment(),
                            CollisionCheckerConfig(self_padding=self_padding),
                            body_primitives=sm.body_primitives, prune_self_tests=prune)


def test_pruned_self_collision_tests_agree_with_all_tests():
    full, pruned = _checker(False), _checker(True)
    assert 0 < pruned.pairs.shape[0] < full.pairs.shape[0]
    rng = np.random.default_rng(11)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (50_000, layout.NQ))
    np.testing.assert_array_equal(pruned.is_free(Q), full.is_free(Q))


def test_dropped_pairs_keep_their_distance_at_random_configurations():
    """Every dropped pair stays apart (unpadded) at random configurations."""
    full, pruned = _checker(False), _checker(True)
    kept = {tuple(p) for p in pruned.pairs.tolist()}
    dropped = np.array([p for p in full.pairs.tolist() if tuple(p) not in kept])
    assert dropped.shape[0] > 0
    rng = np.random.default_rng(12)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (20_000, layout.NQ))
    c = full.sphere_centers(Q)
    gap = np.linalg.norm(c[:, dropped[:, 0]] - c[:, dropped[:, 1]], axis=-1) \
        - full.base_radius[dropped[:, 0]] - full.base_radius[dropped[:, 1]]
    assert gap.min() > 0.0


def test_self_padding_keeps_most_of_the_arm_free():
    """A 1.5 cm self-collision padding on pairs that can never touch (elbow and
    wrist spheres around the forearm, 2-6 cm apart everywhere) would cut the
    free space; after pruning most random configurations stay free."""
    rng = np.random.default_rng(13)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (20_000, layout.NQ))
    free0 = _checker(True, 0.0).is_free(Q).mean()
    free15 = _checker(True, 0.015).is_free(Q).mean()
    assert free15 > 0.8 * free0


def test_link_bounding_sphere_culling_agrees_with_every_test():
    """Self-collision groups skipped by their links' bounding spheres
    (`SphereCollisionChecker._self_culling`) never hide a collision: the same
    verdicts as testing every pair, padded and unpadded."""
    def no_culling(checker):
        lb_c, lb_r, pair_end, bp_end = checker._self_cull
        checker._self_cull = (lb_c, np.where(lb_r < 0, lb_r, 1e3), pair_end, bp_end)
        return checker

    rng = np.random.default_rng(14)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (50_000, layout.NQ))
    for padding in (0.0, 0.015):
        culled = _checker(True, padding)
        free = culled.is_free(Q)
        assert 0.05 < free.mean() < 0.95
        np.testing.assert_array_equal(free, no_culling(_checker(True, padding)).is_free(Q))
        np.testing.assert_array_equal(culled.unpadded().is_free(Q),
                                      no_culling(_checker(True, padding).unpadded()).is_free(Q))
