"""Self-collision tests that can never fail inside the joint limits, found
once per robot model and dropped from the checks (`unreachable_self_pairs`)."""

import math

import numba
import numpy as np

from vamg_drake.planning.sphere_checks import extended_scratch
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import link_transforms


@numba.njit(cache=True)
def _min_self_gaps(Q, head, parent, X_PJ, joint_type, axis, var_index, sph_link, sph_c, radius,
                   pair_a, pair_b, prim_link, prim_kind, prim_X, prim_half, body_k, body_s, gap_pair, gap_body):
    """Smallest gaps over configurations Q (B, 11) of the unpadded sphere pairs
    (pair_a[n], pair_b[n]) and of spheres body_s[n] vs body primitives body_k[n]."""
    T = np.empty((parent.shape[0], 3, 4))
    V = extended_scratch(Q.shape[1], head)
    gap_pair[:] = np.inf
    gap_body[:] = np.inf
    for b in range(Q.shape[0]):
        for j in range(Q.shape[1]):
            V[j] = Q[b, j]
        link_transforms(parent, X_PJ, joint_type, axis, var_index, V, T)
        for n in range(pair_a.shape[0] + body_s.shape[0]):
            s = pair_a[n] if n < pair_a.shape[0] else body_s[n - pair_a.shape[0]]
            li = sph_link[s]
            c = np.empty(3)
            for a in range(3):
                c[a] = (T[li, a, 0] * sph_c[s, 0] + T[li, a, 1] * sph_c[s, 1] + T[li, a, 2] * sph_c[s, 2]
                        + T[li, a, 3])
            if n < pair_a.shape[0]:
                t = pair_b[n]
                lt = sph_link[t]
                d2 = 0.0
                for a in range(3):
                    e = c[a] - (T[lt, a, 0] * sph_c[t, 0] + T[lt, a, 1] * sph_c[t, 1] + T[lt, a, 2] * sph_c[t, 2]
                                + T[lt, a, 3])
                    d2 += e * e
                g = math.sqrt(d2) - radius[s] - radius[t]
                if g < gap_pair[n]:
                    gap_pair[n] = g
                continue
            m = n - pair_a.shape[0]
            k = body_k[m]
            lk = prim_link[k]
            # Shape frame S in W: R = T[lk] R_LS, p = T[lk] p_LS.
            loc = np.zeros(3)
            for a in range(3):
                for cc in range(3):
                    r_wa = (T[lk, cc, 0] * prim_X[k, 0, a] + T[lk, cc, 1] * prim_X[k, 1, a]
                            + T[lk, cc, 2] * prim_X[k, 2, a])
                    p_w = (T[lk, cc, 0] * prim_X[k, 0, 3] + T[lk, cc, 1] * prim_X[k, 1, 3]
                           + T[lk, cc, 2] * prim_X[k, 2, 3] + T[lk, cc, 3])
                    loc[a] += r_wa * (c[cc] - p_w)
            if prim_kind[k] == 0:
                d2 = 0.0
                for a in range(3):
                    e = max(abs(loc[a]) - prim_half[k, a], 0.0)
                    d2 += e * e
                d = math.sqrt(d2)
            else:
                er = max(math.sqrt(loc[0] * loc[0] + loc[1] * loc[1]) - prim_half[k, 0], 0.0)
                ez = max(abs(loc[2]) - prim_half[k, 2], 0.0)
                d = math.sqrt(er * er + ez * ez)
            g = d - radius[s]
            if g < gap_body[m]:
                gap_body[m] = g


def _chain_joints(parent: np.ndarray, var_index: np.ndarray, a: int, b: int) -> list[int] | None:
    """Links whose (moving) joints lie on the tree path between links a and b
    (the joint of link i connects it to its parent), or None when one of them
    is not a whole-body coordinate (head, fingers)."""
    up_a, i = [], a
    while i >= 0:
        up_a.append(i)
        i = int(parent[i])
    up_b, i = [], b
    while i >= 0:
        up_b.append(i)
        i = int(parent[i])
    common = next(i for i in up_a if i in up_b)
    links = up_a[:up_a.index(common)] + up_b[:up_b.index(common)]
    moving = [i for i in links if var_index[i] >= 0]
    if any(var_index[i] >= layout.NQ for i in moving):
        return None
    return moving


def _lever_below(tree, link: int, joint_link: int, point_L: np.ndarray) -> float:
    """Bound on the distance from the joint origin of `joint_link` to a point
    fixed in `link` (a descendant): the point's offset plus the fixed offsets
    of the chain (triangle inequality), for any configuration."""
    reach, i = float(np.linalg.norm(point_L)), link
    while i != joint_link:
        reach += float(np.linalg.norm(tree.X_PJ[i, :3, 3]))
        i = int(tree.parent[i])
    return reach


def unreachable_self_pairs(tree, sph_link, sph_c, radius, pairs, body, grid_error: float = 0.005,
                           max_grid: int = 60_000) -> tuple[np.ndarray, np.ndarray]:
    """Which self-collision tests can never fail inside the joint limits.

    For the two links of a sphere pair (or of a sphere and a body primitive)
    only the joints on the tree path between them change their distance. When
    there are few, the distance is evaluated on a grid over those joints'
    limits (continuous joints: one turn) fine enough that between grid points
    it changes by at most `grid_error` (per joint: lever bound x half the
    spacing, levers from the chain's fixed offsets). A test whose smallest
    gap on the grid exceeds `grid_error` is certainly never violated by the
    unpadded spheres, and is dropped. (Such pairs, e.g. the elbow and wrist
    spheres around the forearm, sit 2-6 cm apart at every configuration: a
    self-collision padding on them would only cut the arm's free space.)

    Returns (keep_pairs (P,), keep_body_tests (K,)) bool masks.
    """
    link_c, kind, X, half, bp_prim, bp_sphere = body
    tests = [(int(sph_link[a]), int(sph_link[b]), ("pair", n)) for n, (a, b) in enumerate(pairs)]
    tests += [(int(link_c[bp_prim[n]]), int(sph_link[bp_sphere[n]]), ("body", n)) for n in range(bp_prim.shape[0])]
    keep_pairs = np.ones(pairs.shape[0], bool)
    keep_body = np.ones(bp_prim.shape[0], bool)
    groups: dict[tuple[int, int], list] = {}
    for la, lb, t in tests:
        groups.setdefault((la, lb), []).append(t)
    lo = np.where(layout.IS_CONTINUOUS, -np.pi, layout.Q_LOWER)
    hi = np.where(layout.IS_CONTINUOUS, np.pi, layout.Q_UPPER)
    for (la, lb), items in groups.items():
        joints = _chain_joints(tree.parent, tree.var_index, la, lb)
        if joints is None or len(joints) == 0 or len(joints) > 3:
            continue
        # Levers: the largest bound over the points tested on either side.
        points = []
        for what, n in items:
            if what == "pair":
                a, b = pairs[n]
                points += [(int(sph_link[a]), sph_c[a]), (int(sph_link[b]), sph_c[b])]
            else:
                k = bp_prim[n]
                s = bp_sphere[n]
                points += [(int(sph_link[s]), sph_c[s])]
                # Every point of the primitive is within its centre's offset
                # plus its bounding radius of the link origin.
                r_k = float(np.linalg.norm(half[k])) if kind[k] == 0 else math.hypot(half[k, 0], half[k, 2])
                points += [(int(link_c[k]), np.array([np.linalg.norm(X[k, :3, 3]) + r_k, 0.0, 0.0]))]
        axes, err_each = [], grid_error / len(joints)
        for j in joints:
            k = int(tree.var_index[j])
            if tree.joint_type[j] == 1:
                lever = max([_lever_below(tree, l, j, p) for l, p in points if _is_below(tree, l, j)] or [0.0])
            else:
                lever = 1.0
            spacing = 2.0 * err_each / max(lever, 1e-9)
            n = max(int(math.ceil((hi[k] - lo[k]) / spacing)), 1) + 1
            axes.append((k, np.linspace(lo[k], hi[k], n)))
        if np.prod([len(a[1]) for a in axes]) > max_grid:
            continue
        grids = np.meshgrid(*[a[1] for a in axes], indexing="ij")
        Q = np.tile(0.5 * (np.where(np.isfinite(lo), lo, 0) + np.where(np.isfinite(hi), hi, 0)), (grids[0].size, 1))
        Q[:, :3] = 0.0
        for (k, _), g in zip(axes, grids):
            Q[:, k] = g.ravel()
        ip = np.array([n for what, n in items if what == "pair"], np.int64)
        ib = np.array([n for what, n in items if what == "body"], np.int64)
        gap_pair, gap_body = np.empty(ip.shape[0]), np.empty(ib.shape[0])
        _min_self_gaps(np.ascontiguousarray(Q), np.zeros(2), tree.parent, tree.X_PJ, tree.joint_type, tree.axis,
                       tree.var_index, sph_link, sph_c, radius, pairs[ip, 0].copy(), pairs[ip, 1].copy(),
                       link_c, kind, X, half, bp_prim[ib].copy(), bp_sphere[ib].copy(), gap_pair, gap_body)
        keep_pairs[ip] = gap_pair <= grid_error
        keep_body[ib] = gap_body <= grid_error
    return keep_pairs, keep_body


def _is_below(tree, link: int, joint_link: int) -> bool:
    i = link
    while i >= 0:
        if i == joint_link:
            return True
        i = int(tree.parent[i])
    return False


_SELF_TESTS_CACHE: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}


def reachable_self_tests(tree, sph_link, sph_c, radius, pairs, body) -> tuple[np.ndarray, np.ndarray]:
    """The masks of `unreachable_self_pairs`, computed once per robot model."""
    parts = [tree.X_PJ, tree.parent, tree.var_index, tree.axis, sph_link, sph_c, radius, pairs, *body]
    key = b"".join(np.ascontiguousarray(a).tobytes() for a in parts)
    if key not in _SELF_TESTS_CACHE:
        _SELF_TESTS_CACHE[key] = unreachable_self_pairs(tree, sph_link, sph_c, radius, pairs, body)
    return _SELF_TESTS_CACHE[key]
