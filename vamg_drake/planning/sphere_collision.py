"""Batched, conservative collision checking of whole-body configurations.

The Fetch is a set of spheres (`vamg_drake.robot.spheres`) that cover its
collision geometry. A configuration is *free* when every sphere is free of the
environment (`vamg_drake.planning.collision_environment`), no two spheres of a
self-collision pair overlap, and every joint is inside its limits. The check
is one Numba kernel over a batch of configurations
(`vamg_drake.planning.sphere_checks`: forward kinematics fused with the
sphere tests, early exit).

Motion checks: configurations along a motion are checked at a spacing where no
sphere centre moves more than `motion_resolution` (a rigorous per-joint lever
bound, `SphereCollisionChecker.sphere_displacement_bound`), and every sphere is
inflated by half that spacing, so the straight-line motion between two free
checked states is free as well.
"""

import dataclasses
import functools
import math

import numba
import numpy as np

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.self_collision_pruning import reachable_self_tests
from vamg_drake.planning.sphere_checks import (TEST_CELLS, TEST_POINTS, TEST_TARGET_POINTS, batch_free, env_aabbs,
                                               held_poses_free, held_spheres)
from vamg_drake.robot import kinematics, layout
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.robot.spheres import ARM_LINKS, SphereModel, sphere_centres


@functools.lru_cache(maxsize=4096)
def bisection_order(n: int) -> np.ndarray:
    """Indices 0..n-1 in coarse-to-fine order (endpoints first, then midpoints).

    Cached per n; the returned array is read-only.
    """
    out = _bisection_order(n)
    out.flags.writeable = False
    return out


@numba.njit(cache=True)
def _bisection_order(n: int) -> np.ndarray:
    out = np.empty(n, dtype=np.int64)
    if n <= 2:
        for i in range(n):
            out[i] = i
        return out
    seen = np.zeros(n, dtype=np.bool_)
    out[0], out[1] = 0, n - 1
    seen[0] = seen[n - 1] = True
    m = 2
    step = float(n - 1)
    while step > 1.0:
        half = 0.5 * step
        j = 0
        while True:
            k = half + j * step
            if k >= n - 1:
                break
            i = int(math.floor(k + 0.5))
            if not seen[i]:
                seen[i] = True
                out[m] = i
                m += 1
            j += 1
        step = half
    for i in range(n):
        if not seen[i]:
            out[m] = i
            m += 1
    return out


@dataclasses.dataclass
class CollisionCheckerConfig:
    """Collision-check parameters.

    Attributes:
        motion_resolution: max sphere-centre displacement [m] between checked
            states along a motion; spheres are inflated by half of it.
        extra_padding: additional sphere inflation [m] (safety margin).
        head_pan, head_tilt: head pose assumed while planning [rad].
        self_padding: sphere inflation [m] for self-collision tests. Every
            checked configuration is exactly self-collision-free for the
            sphere model (which covers the URDF geometry with slack); between
            checked states the motion is covered by that slack rather than by
            the motion-resolution inflation, which would fragment the arm's
            free space (many tested sphere pairs sit a few cm apart). The
            1.5 cm default is the closed loop's margin: tracking the path
            deviates by up to ~1 cm in the arm, and the simulated Fetch
            touched its own base with no margin (the stow pose keeps 2 cm).
        base_extra_padding: further inflation [m] of the base's spheres
            against the environment while planning (not in the `unpadded`
            test of whether a configuration penetrates). The differential-
            drive base follows a curved path with a lateral error of a few
            centimetres, more than the arm's, so a base path planned at the
            motion-resolution padding from an obstacle can touch it.
        occupied_cells: the spheres of the arm, torso and head test a map's
            occupied cells as boxes, not the points in them: a cell keeps one
            point of the surface that crosses it, and the surface's other
            parts can lie up to the cell's diagonal from it along the surface
            (a TV screen's bottom edge 2.3 cm below the lowest point the map
            kept of it). Across a surface (a cell whose two neighbours along
            an axis are empty, with occupied neighbours beside it) the box is
            flat at its points: a table top is where the map saw it, so the
            wrist may pass above it as close as the points allow. The gripper
            and the base test the points: the gripper closes around the target
            beside its support (boxes there would rule out most grasps of low
            objects), and the base keeps its own clearance
            (`base_extra_padding`, the base costmap). Cells are the
            map's voxels where the field's resolution is the map's voxel size
            (`DistanceField.from_points` uses the same grid).
        arm_floor_clearance: the arm's spheres (`is_arm`; their padded radii)
            stay this far above the floor at z = 0 [m], so that between
            checked states (a sphere moves up to ``motion_resolution``) the
            unpadded ones keep at least this clearance. The map drops the
            floor's points (the base stands on them), so without it the
            planner routes the arm through the floor under a low target.
            None: no floor test.
    """

    motion_resolution: float = 0.03
    extra_padding: float = 0.0
    head_pan: float = 0.0
    head_tilt: float = 0.0
    self_padding: float = 0.015
    base_extra_padding: float = 0.0
    occupied_cells: bool = True
    arm_floor_clearance: float | None = 0.02


class SphereCollisionChecker:
    """Batched validity of whole-body configurations against an environment.

    Args:
        tree: the robot's `KinematicTree` (link order of the sphere model).
        link_index, center_L, radius: the sphere model (S,), (S, 3), (S,).
        self_collision_pairs: (P, 2) sphere index pairs that must not overlap.
        env: the `CollisionEnvironment`.
        config: `SphereCollisionCheckerConfig`.
        body_primitives: `vamg_drake.robot.spheres.BodyPrimitive`s tested
            against their spheres for self-collision.
        prune_self_tests: drop the self-collision tests that can never fail
            inside the joint limits (`unreachable_self_pairs`).
        is_gripper: (S,) the gripper's spheres (see `SphereModel.is_gripper`).
        is_base: (S,) the base's spheres (inflated by `base_extra_padding`).
    """

    def __init__(self, tree, link_index, center_L, radius, self_collision_pairs,
                 env: CollisionEnvironment, config: CollisionCheckerConfig | None = None,
                 body_primitives=(), prune_self_tests: bool = True, is_gripper: np.ndarray | None = None,
                 is_base: np.ndarray | None = None, is_arm: np.ndarray | None = None):
        self.tree = tree
        config = config or CollisionCheckerConfig()
        self.config = config
        self.sph_link = np.ascontiguousarray(link_index, dtype=np.int64)
        self.sph_c = np.ascontiguousarray(center_L, dtype=float)
        self.base_radius = np.ascontiguousarray(radius, dtype=float)
        self.pairs = np.ascontiguousarray(np.asarray(self_collision_pairs, dtype=np.int64).reshape(-1, 2))
        self.padding = 0.5 * config.motion_resolution + config.extra_padding
        self.is_base = (np.zeros(self.sph_link.shape[0], dtype=np.bool_) if is_base is None
                        else np.ascontiguousarray(is_base, dtype=np.bool_).reshape(self.sph_link.shape[0]))
        self.sph_r = self.base_radius + self.padding + config.base_extra_padding * self.is_base
        self.sph_rs = self.base_radius + config.self_padding
        self.is_arm = (np.zeros(self.sph_link.shape[0], dtype=np.bool_) if is_arm is None
                       else np.ascontiguousarray(is_arm, dtype=np.bool_).reshape(self.sph_link.shape[0]))
        self.lowest_centre = self._lowest_centres(self.sph_r)
        self.head = np.array([config.head_pan, config.head_tilt], dtype=float)
        self.q_lo = np.ascontiguousarray(layout.Q_LOWER, dtype=float)
        self.q_hi = np.ascontiguousarray(layout.Q_UPPER, dtype=float)
        self.check_env = np.ones(self.sph_link.shape[0], dtype=np.bool_)
        self.is_gripper = (np.zeros(self.sph_link.shape[0], dtype=np.bool_) if is_gripper is None
                           else np.ascontiguousarray(is_gripper, dtype=np.bool_).reshape(self.sph_link.shape[0]))
        # How each sphere tests a map (see `CollisionCheckerConfig.occupied_cells`).
        arm = TEST_CELLS if config.occupied_cells else TEST_POINTS
        self.env_test = np.select([self.is_gripper, self.is_base], [TEST_TARGET_POINTS, TEST_POINTS], arm).astype(np.int64)
        self._body = self._body_arrays(body_primitives)
        if prune_self_tests:
            keep_pairs, keep_body = reachable_self_tests(tree, self.sph_link, self.sph_c, self.base_radius,
                                                         self.pairs, self._body)
            self.pairs = np.ascontiguousarray(self.pairs[keep_pairs])
            link, kind, X, half, bp_prim, bp_sphere = self._body
            self._body = (link, kind, X, half, np.ascontiguousarray(bp_prim[keep_body]),
                          np.ascontiguousarray(bp_sphere[keep_body]))
        self._group_self_tests()
        self._self_cull = self._self_culling(self.sph_rs)
        self._self_cull_bare = self._self_culling(self.base_radius)  # for `unpadded`
        self.lever = self._joint_levers()
        # Forward kinematics only of the links with spheres or body primitives.
        self._fk_joint_type = tree.subtree_joint_types(np.concatenate([self.sph_link, self._body[0]]))
        self._planar = None
        self._planar_base()
        self.set_environment(env)

    def _lowest_centres(self, sph_r: np.ndarray) -> np.ndarray:
        """(S,) lowest world z allowed of each sphere's centre (radii `sph_r`):
        the arm's keep ``arm_floor_clearance`` above the floor, the rest any."""
        clearance = self.config.arm_floor_clearance
        if clearance is None:
            return np.full(sph_r.shape[0], -np.inf)
        return np.ascontiguousarray(np.where(self.is_arm, sph_r + clearance, -np.inf))

    @staticmethod
    def for_fetch(env: CollisionEnvironment, config: CollisionCheckerConfig | None = None) -> "SphereCollisionChecker":
        """The checker for the authored Fetch model and its sphere model."""
        spheres = SphereModel.load()
        tree = FetchKinematics.instance().tree
        links = np.asarray(spheres.link_names)[spheres.link_index]
        return SphereCollisionChecker(tree, spheres.link_index, spheres.center_L, spheres.radius,
                                spheres.self_collision_pairs, env, config,
                                body_primitives=spheres.body_primitives, is_gripper=spheres.is_gripper,
                                is_base=links == "base_link", is_arm=np.isin(links, ARM_LINKS))

    @staticmethod
    def _body_arrays(prims):
        """Flattens `vamg_drake.robot.spheres.BodyPrimitive`s for the kernel."""
        K = len(prims)
        link = np.array([p.link_index for p in prims], np.int64).reshape(K)
        kind = np.array([0 if p.kind == "box" else 1 for p in prims], np.int64).reshape(K)
        X = np.array([p.X_LS for p in prims], float).reshape(K, 4, 4)
        half = np.array([p.half for p in prims], float).reshape(K, 3)
        bp_prim = np.concatenate([np.full(len(p.spheres), k, np.int64) for k, p in enumerate(prims)] or [np.zeros(0, np.int64)])
        bp_sphere = np.concatenate([np.asarray(p.spheres, np.int64) for p in prims] or [np.zeros(0, np.int64)])
        return link, kind, X, half, bp_prim, bp_sphere

    def set_environment(self, env: CollisionEnvironment) -> None:
        """Replaces the environment (e.g. a new map)."""
        self.env = env
        f = env.field
        if f is None:
            self._field = (False, np.zeros((1, 1, 1), np.float32), np.zeros(3), 1.0, 0.0,
                           np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(1, np.int64))
        else:
            reach = float(np.max(self.sph_r, initial=0.0)) + f.margin
            if not reach < f.max_distance:
                raise ValueError(f"a sphere radius plus the field's bound ({reach:.3f} m) reaches past the distances "
                                 f"the field keeps ({f.max_distance:.3f} m, its pad): build the field with a larger pad")
            self._field = (True, f.dist, f.origin, f.resolution, f.margin, f.points, f.cell_keys, f.cell_start)
        self._field += (np.append(np.asarray(env.grasp_target, dtype=float), env.grasp_target_floor),
                        float(env.grasp_target_radius),
                        self.env_test)

    def with_environment(self, env: CollisionEnvironment) -> "SphereCollisionChecker":
        """A copy of this checker over another environment."""
        other = object.__new__(SphereCollisionChecker)
        other.__dict__.update(self.__dict__)
        other.set_environment(env)
        return other

    def unpadded(self) -> "SphereCollisionChecker":
        """A copy over the same environment whose spheres are *not* inflated
        for the motion resolution (radius + `extra_padding` only against the
        environment) nor by `self_padding` (the tracking margin) against each
        other: the test of whether a configuration actually penetrates
        something. Motions checked with it need a fine spacing of their own
        (see `densify`)."""
        other = object.__new__(SphereCollisionChecker)
        other.__dict__.update(self.__dict__)
        other.padding = self.config.extra_padding
        other.sph_r = self.base_radius + other.padding
        other.sph_rs = self.base_radius.copy()
        other.lowest_centre = other._lowest_centres(other.sph_r)
        other._self_cull = self._self_cull_bare
        return other

    def _group_self_tests(self) -> None:
        """Sorts the sphere pairs by their links and the body tests by
        primitive and link, so that each group is contiguous."""
        L = self.sph_link
        if self.pairs.shape[0]:
            order = np.lexsort((self.pairs[:, 1], self.pairs[:, 0], L[self.pairs[:, 1]], L[self.pairs[:, 0]]))
            self.pairs = np.ascontiguousarray(self.pairs[order])
        link, kind, X, half, bp_prim, bp_sphere = self._body
        if bp_prim.shape[0]:
            order = np.lexsort((bp_sphere, L[bp_sphere], bp_prim))
            self._body = (link, kind, X, half, np.ascontiguousarray(bp_prim[order]),
                          np.ascontiguousarray(bp_sphere[order]))

    def _self_culling(self, sph_rs: np.ndarray) -> tuple:
        """(lb_c (L, 3), lb_r (L,), pair_end (P,), bp_end (B,)):
        per link a bounding sphere (link frame) of its spheres at their
        self-collision radii `sph_rs` (-1: no spheres), and for every test the
        end of its group (see `_group_self_tests`). A group is free when the
        bounding spheres are apart, since every sphere lies inside its link's."""
        n_links = self.tree.parent.shape[0]
        L = self.sph_link
        lb_c = np.zeros((n_links, 3))
        lb_r = np.full(n_links, -1.0)
        for li in np.unique(L):
            m = L == li
            c = self.sph_c[m]
            lo, hi = c.min(axis=0), c.max(axis=0)
            lb_c[li] = 0.5 * (lo + hi)
            lb_r[li] = float(np.max(np.linalg.norm(c - lb_c[li], axis=1) + sph_rs[m])) + 1e-9

        def ends(keys: np.ndarray) -> np.ndarray:
            change = np.any(keys[1:] != keys[:-1], axis=1)
            group = np.concatenate([[0], np.cumsum(change)])
            return np.append(np.flatnonzero(change) + 1, keys.shape[0]).astype(np.int64)[group]

        pair_end = ends(L[self.pairs]) if self.pairs.shape[0] else np.zeros(0, np.int64)
        bp_prim, bp_sphere = self._body[4], self._body[5]
        bp_end = (ends(np.column_stack([bp_prim, L[bp_sphere]])) if bp_prim.shape[0]
                  else np.zeros(0, np.int64))
        return np.ascontiguousarray(lb_c), lb_r, pair_end, bp_end

    def _args(self):
        t = self.tree
        e = self.env
        return (self.head, t.parent, t.X_PJ, self._fk_joint_type, t.axis, t.var_index,
                self.sph_link, self.sph_c, self.sph_r, self.sph_rs, self.pairs, self.q_lo, self.q_hi,
                *self._field,
                e.box_p, e.box_R, e.box_half, e.cyl_p, e.cyl_R, e.cyl_radius, e.cyl_half_length,
                self.check_env, *self._body, *self._self_cull, self.lowest_centre)

    def base_pose_check_data(self, torso_arm: np.ndarray) -> tuple:
        """The arguments of `base_pose_free_exact` for the torso + arm (8,)
        held fixed, over the current environment (scratch arrays included:
        one user at a time). It ends with the torso + arm's sphere centres in
        the base frame and (limits and self-collision free, planar base):
        the torso + arm must not be changed afterwards for those checks."""
        torso_arm = np.asarray(torso_arm, dtype=float).reshape(layout.NQ - 3)
        Q = np.zeros((1, layout.NQ))
        Q[0, 3:] = torso_arm
        T = np.empty((self.tree.parent.shape[0], 3, 4))
        C = np.empty((self.sph_link.shape[0], 3))
        PW = np.empty((self._body[0].shape[0], 3, 5))
        e = self.env
        env_aabb = np.empty((e.box_p.shape[0] + e.cyl_p.shape[0], 6))
        env_aabbs(e.box_p, e.box_R, e.box_half, e.cyl_p, e.cyl_R, e.cyl_radius, e.cyl_half_length, env_aabb)
        near = np.empty(env_aabb.shape[0], dtype=np.int64)
        V = kinematics.extend_configuration(Q, self.head)[0]
        args = tuple(self._args())
        data = (Q, T, C, PW, env_aabb, near, V) + args[1:-1] + (np.empty((self.tree.parent.shape[0], 3)), args[-1])
        C0 = np.empty_like(C)
        flags = np.array([False, self._planar_base()])
        data += (C0, flags)
        flags[0] = held_spheres(data, C0)
        Q[0, 3:] = torso_arm
        return data

    def is_free(self, Q: np.ndarray) -> np.ndarray:
        """Validity (B,) of configurations Q (B, 11) (no early exit)."""
        Q = self._as_batch(Q)
        out = np.zeros(Q.shape[0], dtype=np.bool_)
        batch_free(Q, *self._args(), np.arange(Q.shape[0], dtype=np.int64), False, out)
        return out

    def drive_free(self, poses: np.ndarray, torso_arm: np.ndarray) -> np.ndarray:
        """Validity (M,) of the configurations (poses[m], torso_arm): the base
        at poses (M, 3) carrying the torso + arm (8,) held fixed. The same
        verdicts as `is_free` on those configurations, but forward
        kinematics and self-collision once: per pose only the spheres moved
        rigidly and tested against the environment."""
        poses = np.ascontiguousarray(np.asarray(poses, dtype=float).reshape(-1, 3))
        torso_arm = np.asarray(torso_arm, dtype=float).reshape(layout.NQ - 3)
        if not self._planar_base():
            return self.is_free(np.concatenate([poses, np.repeat(torso_arm[None], poses.shape[0], axis=0)], axis=1))
        out = np.zeros(poses.shape[0], dtype=np.bool_)
        held_poses_free(poses, self.base_pose_check_data(torso_arm), out)
        return out

    def _planar_base(self) -> bool:
        """Whether the base joints move every sphere rigidly in the plane:
        c(x, y, theta) = (x, y) + R_z(theta) c(0, 0, 0) (checked once)."""
        if self._planar is None:
            rng = np.random.default_rng(0)
            Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (4, layout.NQ))
            Q0 = Q.copy()
            Q0[:, :3] = 0.0
            c, c0 = self.sphere_centers(Q), self.sphere_centers(Q0)
            cos, sin = np.cos(Q[:, 2])[:, None], np.sin(Q[:, 2])[:, None]
            x = Q[:, 0:1] + cos * c0[..., 0] - sin * c0[..., 1]
            y = Q[:, 1:2] + sin * c0[..., 0] + cos * c0[..., 1]
            self._planar = bool(np.allclose(c, np.stack([x, y, c0[..., 2]], axis=-1), rtol=0.0, atol=1e-12))
        return self._planar

    def first_collision(self, Q: np.ndarray, order: np.ndarray | None = None) -> int:
        """Index of a configuration of Q in collision (coarse-to-fine search), or -1."""
        Q = self._as_batch(Q)
        if order is None:
            order = bisection_order(Q.shape[0])
        out = np.zeros(Q.shape[0], dtype=np.bool_)
        return int(batch_free(Q, *self._args(), order, True, out))

    def sphere_centers(self, Q: np.ndarray) -> np.ndarray:
        """World sphere centres (B, S, 3)."""
        V = kinematics.extend_configuration(self._as_batch(Q), self.head)
        out = np.empty((V.shape[0], self.sph_link.shape[0], 3))
        t = self.tree
        return sphere_centres(t.parent, t.X_PJ, self._fk_joint_type, t.axis, t.var_index, V,
                              self.sph_link, self.sph_c, np.empty((t.parent.shape[0], 3, 4)), out)

    def _joint_levers(self) -> np.ndarray:
        """Per-coordinate bound on sphere-centre motion per unit joint motion.

        For a revolute joint: the largest distance from the joint origin to a
        downstream sphere centre, bounded by the sum of the fixed offsets along
        the chain (the triangle inequality), so it holds for any configuration.
        """
        t = self.tree
        lever = np.zeros(layout.NQ)
        lever[0] = lever[1] = 1.0
        for s in range(self.sph_link.shape[0]):
            li = int(self.sph_link[s])
            reach = float(np.linalg.norm(self.sph_c[s]))
            i = li
            while i >= 0:
                k = int(t.var_index[i])
                if 0 <= k < layout.NQ and t.joint_type[i] == 1:
                    lever[k] = max(lever[k], reach)
                reach += float(np.linalg.norm(t.X_PJ[i, :3, 3]))
                i = int(t.parent[i])
        return lever

    def sphere_displacement_bound(self, dQ: np.ndarray) -> np.ndarray:
        """Upper bound (...,) on any sphere centre's motion for joint steps dQ (..., 11).

        Base x/y contribute their planar norm; every other joint |dq_j| times its lever.
        """
        dQ = np.asarray(dQ, dtype=float)
        planar = np.hypot(dQ[..., 0], dQ[..., 1])
        return planar + np.abs(dQ[..., 2:]) @ self.lever[2:]

    def _as_batch(self, Q: np.ndarray) -> np.ndarray:
        Q = np.ascontiguousarray(np.atleast_2d(np.asarray(Q, dtype=float)))
        if Q.ndim != 2 or Q.shape[1] != layout.NQ:
            raise ValueError(f"configurations must have shape (B, {layout.NQ}), got {Q.shape}")
        return Q

    def interpolate(self, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
        """States (n, 11) on the straight line qa->qb, both ends included, at the
        motion resolution."""
        d = float(self.sphere_displacement_bound(qb - qa))
        n = max(int(math.ceil(d / self.config.motion_resolution)), 1) + 1
        s = np.linspace(0.0, 1.0, n)[:, None]
        return qa + s * (qb - qa)

    def motion_free(self, qa: np.ndarray, qb: np.ndarray) -> bool:
        """True when the straight motion qa->qb is free (ends included)."""
        return self.first_collision(self.interpolate(qa, qb)) < 0

    def path_free(self, path: np.ndarray) -> bool:
        """True when every straight segment of path (N, 11) is free."""
        return self.first_collision(densify(path, self)) < 0


def densify(path: np.ndarray, checker: SphereCollisionChecker, resolution: float | None = None) -> np.ndarray:
    """Re-interpolates path (N, 11) so consecutive states move spheres <= resolution."""
    path = np.asarray(path, dtype=float)
    if path.shape[0] < 2:
        return path.copy()
    res = checker.config.motion_resolution if resolution is None else resolution
    return densify_indexed(np.ascontiguousarray(path), np.ascontiguousarray(checker.lever, dtype=float), float(res))[0]


@numba.njit(cache=True)
def densify_indexed(path, lever, res):
    """`densify` as a compiled kernel over levers (dim,): per segment
    max(ceil(bound / res), 1) steps, where bound is
    `SphereCollisionChecker.sphere_displacement_bound` (planar x, y norm plus the
    levers of the other coordinates). Returns the dense path and the dense
    index (N,) of every input state."""
    n, dim = path.shape
    counts = np.empty(n - 1, np.int64)
    index = np.zeros(n, np.int64)
    for k in range(n - 1):
        d = math.hypot(path[k + 1, 0] - path[k, 0], path[k + 1, 1] - path[k, 1])
        for j in range(2, dim):
            d += abs(path[k + 1, j] - path[k, j]) * lever[j]
        counts[k] = max(int(math.ceil(d / res)), 1)
        index[k + 1] = index[k] + counts[k]
    out = np.empty((index[n - 1] + 1, dim))
    out[0] = path[0]
    m = 1
    for k in range(n - 1):
        c = counts[k]
        for i in range(1, c + 1):
            f = i / c
            for a in range(dim):
                out[m, a] = path[k, a] + f * (path[k + 1, a] - path[k, a])
            m += 1
    return out, index
