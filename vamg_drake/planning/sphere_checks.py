"""The compiled whole-body checks of `SphereCollisionChecker`: forward
kinematics (the robot's kernel, `vamg_drake.robot.kinematics.link_transforms`)
fused with the sphere tests against the environment and against the robot
itself, with early exit. The checks take one tuple of arrays (see
`_config_free`); the tuple's layout is `SphereCollisionChecker._args`.
"""

import math

import numba
import numpy as np

from vamg_drake.robot.kinematics import DEFAULT_FINGER, NX, link_transforms
from vamg_drake.robot.spheres import sphere_centres_into


@numba.njit(cache=True, inline="always")
def _checked_link_transforms(Q, b, data):
    """The link poses data[1] and sphere centres data[2] of configuration
    Q[b], through the extended configuration data[6] (head and fingers set)."""
    V, T, C = data[6], data[1], data[2]
    for j in range(Q.shape[1]):
        V[j] = Q[b, j]
    link_transforms(data[7], data[8], data[9], data[10], data[11], V, T)
    sphere_centres_into(T, data[12], data[13], C)


@numba.njit(cache=True)
def extended_scratch(nq, head):
    """An extended configuration (NX,) with the head at `head` (2,) and the
    fingers open (the sphere model covers the gripper at any opening); the
    first nq entries are the caller's."""
    V = np.zeros(NX)
    V[nq] = head[0]
    V[nq + 1] = head[1]
    for k in range(nq + 2, NX):
        V[k] = DEFAULT_FINGER
    return V


@numba.njit(cache=True)
def env_aabbs(box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, out):
    """out[k] = (lo xyz, hi xyz) world AABB of primitive k (boxes, then cylinders)."""
    nb = box_p.shape[0]
    for k in range(nb + cyl_p.shape[0]):
        for a in range(3):
            if k < nb:
                e = 0.0
                for c in range(3):
                    e += abs(box_R[k, a, c]) * box_half[k, c]
                m = box_p[k, a]
            else:
                j = k - nb
                ax = abs(cyl_R[j, a, 2])
                e = ax * cyl_hl[j] + math.sqrt(max(1.0 - ax * ax, 0.0)) * cyl_r[j]
                m = cyl_p[j, a]
            out[k, a] = m - e
            out[k, 3 + a] = m + e
    return out


#: How a sphere tests a map (`SphereCollisionChecker.env_test`): against its
#: points; against its occupied cells as boxes (`_sphere_hits_map`); against its points but
#: those of the grasp target (the gripper).
TEST_POINTS, TEST_CELLS, TEST_TARGET_POINTS = 0, 1, 2


@numba.njit(cache=True)
def _body_prim_d2(PW, k, kind, half, cx, cy, cz):
    """Squared distance from point (cx, cy, cz) to body primitive k (world pose PW[k])."""
    dx = cx - PW[k, 0, 3]
    dy = cy - PW[k, 1, 3]
    dz = cz - PW[k, 2, 3]
    sx = PW[k, 0, 0] * dx + PW[k, 1, 0] * dy + PW[k, 2, 0] * dz
    sy = PW[k, 0, 1] * dx + PW[k, 1, 1] * dy + PW[k, 2, 1] * dz
    sz = PW[k, 0, 2] * dx + PW[k, 1, 2] * dy + PW[k, 2, 2] * dz
    if kind == 0:
        ex = max(abs(sx) - half[k, 0], 0.0)
        ey = max(abs(sy) - half[k, 1], 0.0)
        ez = max(abs(sz) - half[k, 2], 0.0)
        return ex * ex + ey * ey + ez * ez
    er = max(math.sqrt(sx * sx + sy * sy) - half[k, 0], 0.0)
    ez = max(abs(sz) - half[k, 2], 0.0)
    return er * er + ez * ez


@numba.njit(cache=True, inline="always")
def _env_free(C, data):
    """The spheres at world centres C (S, 3) (radii `sph_r`, those with
    `check_env`) are free of the environment of the checker tuple `data`
    (see `_config_free`)."""
    env_aabb, near = data[4], data[5]
    sph_r = data[14]
    has_field, dist, origin, h, margin = data[19], data[20], data[21], data[22], data[23]
    pts, cell_keys, cell_start, tgt_c, tgt_r, sph_test = data[24], data[25], data[26], data[27], data[28], data[29]
    box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, check_env = (data[30], data[31], data[32], data[33],
                                                                     data[34], data[35], data[36], data[37])
    lowest_centre = data[49]
    S = C.shape[0]
    lx0, ly0, lz0 = 1e300, 1e300, 1e300
    hx0, hy0, hz0 = -1e300, -1e300, -1e300
    for s in range(S):
        if not check_env[s]:
            continue
        cx, cy, cz = C[s, 0], C[s, 1], C[s, 2]
        if cz < lowest_centre[s]:  # below the floor (the map keeps no floor points)
            return False
        r = sph_r[s]
        lx0 = min(lx0, cx - r)
        ly0 = min(ly0, cy - r)
        lz0 = min(lz0, cz - r)
        hx0 = max(hx0, cx + r)
        hy0 = max(hy0, cy + r)
        hz0 = max(hz0, cz + r)
        if has_field:
            ix = int(math.floor((cx - origin[0]) / h + 0.5))
            iy = int(math.floor((cy - origin[1]) / h + 0.5))
            iz = int(math.floor((cz - origin[2]) / h + 0.5))
            if 0 <= ix < dist.shape[0] and 0 <= iy < dist.shape[1] and 0 <= iz < dist.shape[2]:
                d = dist[ix, iy, iz]
                if d - margin <= r:
                    if pts.shape[0] == 0:
                        return False
                    # A gripper sphere near the grasp target ignores its points.
                    test = sph_test[s]
                    exempt = False
                    if test == TEST_TARGET_POINTS and tgt_r > 0.0:
                        ex, ey, ez = cx - tgt_c[0], cy - tgt_c[1], cz - tgt_c[2]
                        exempt = ex * ex + ey * ey + ez * ez <= (tgt_r + r) ** 2
                    if not exempt and d + margin <= r:
                        return False
                    if _sphere_hits_map(cx, cy, cz, r, dist, origin, h, pts, cell_keys, cell_start,
                                           exempt, tgt_c, tgt_r, test == TEST_CELLS):
                        return False
    # Broad phase: primitives whose AABB overlaps the robot's.
    n_near = 0
    for k in range(env_aabb.shape[0]):
        if (env_aabb[k, 0] <= hx0 and env_aabb[k, 3] >= lx0 and env_aabb[k, 1] <= hy0
                and env_aabb[k, 4] >= ly0 and env_aabb[k, 2] <= hz0 and env_aabb[k, 5] >= lz0):
            near[n_near] = k
            n_near += 1
    nb = box_p.shape[0]
    if n_near > 0:
        for s in range(S):
            if not check_env[s]:
                continue
            cx, cy, cz = C[s, 0], C[s, 1], C[s, 2]
            r = sph_r[s]
            for n in range(n_near):
                k = near[n]
                if (cx + r < env_aabb[k, 0] or cx - r > env_aabb[k, 3] or cy + r < env_aabb[k, 1]
                        or cy - r > env_aabb[k, 4] or cz + r < env_aabb[k, 2] or cz - r > env_aabb[k, 5]):
                    continue
                if k < nb:
                    dx = cx - box_p[k, 0]
                    dy = cy - box_p[k, 1]
                    dz = cz - box_p[k, 2]
                    d2 = 0.0
                    for a in range(3):
                        lc = box_R[k, 0, a] * dx + box_R[k, 1, a] * dy + box_R[k, 2, a] * dz
                        e = abs(lc) - box_half[k, a]
                        if e > 0:
                            d2 += e * e
                    if d2 <= r * r:
                        return False
                else:
                    m = k - nb
                    dx = cx - cyl_p[m, 0]
                    dy = cy - cyl_p[m, 1]
                    dz = cz - cyl_p[m, 2]
                    lx = cyl_R[m, 0, 0] * dx + cyl_R[m, 1, 0] * dy + cyl_R[m, 2, 0] * dz
                    ly = cyl_R[m, 0, 1] * dx + cyl_R[m, 1, 1] * dy + cyl_R[m, 2, 1] * dz
                    lz = cyl_R[m, 0, 2] * dx + cyl_R[m, 1, 2] * dy + cyl_R[m, 2, 2] * dz
                    er = math.sqrt(lx * lx + ly * ly) - cyl_r[m]
                    ez = abs(lz) - cyl_hl[m]
                    d2 = 0.0
                    if er > 0:
                        d2 += er * er
                    if ez > 0:
                        d2 += ez * ez
                    if d2 <= r * r:
                        return False
    return True


@numba.njit(cache=True, inline="always")
def _self_free(T, C, data):
    """No self-collision for link poses T and sphere centres C (see
    `_config_free`)."""
    PW = data[3]
    sph_link, sph_rs, pairs = data[12], data[15], data[16]
    prim_link, prim_kind, prim_X, prim_half, bp_prim, bp_sphere = (data[38], data[39], data[40], data[41],
                                                                  data[42], data[43])
    lb_c, lb_r, pair_end, bp_end, LB = data[44], data[45], data[46], data[47], data[48]
    # Self-collision tests are grouped by link (pairs by their two links,
    # body tests by primitive and link); a group is skipped when the links'
    # bounding spheres (`SphereCollisionChecker._self_culling`) are apart.
    for li in range(lb_r.shape[0]):
        if lb_r[li] < 0.0:
            continue
        px, py, pz = lb_c[li, 0], lb_c[li, 1], lb_c[li, 2]
        for a in range(3):
            LB[li, a] = T[li, a, 0] * px + T[li, a, 1] * py + T[li, a, 2] * pz + T[li, a, 3]
    k = 0
    while k < pairs.shape[0]:
        a = pairs[k, 0]
        b = pairs[k, 1]
        la = sph_link[a]
        lb = sph_link[b]
        dx = LB[la, 0] - LB[lb, 0]
        dy = LB[la, 1] - LB[lb, 1]
        dz = LB[la, 2] - LB[lb, 2]
        rr = lb_r[la] + lb_r[lb]
        if dx * dx + dy * dy + dz * dz > rr * rr:
            k = pair_end[k]
            continue
        end = pair_end[k]
        while k < end:
            a = pairs[k, 0]
            b = pairs[k, 1]
            dx = C[a, 0] - C[b, 0]
            dy = C[a, 1] - C[b, 1]
            dz = C[a, 2] - C[b, 2]
            rr = sph_rs[a] + sph_rs[b]
            if dx * dx + dy * dy + dz * dz <= rr * rr:
                return False
            k += 1
    # Spheres against the exact primitives of the robot body (self-collision).
    # World poses of the primitives first: PW[k] = T[link] @ X_LS (3x4).
    for k in range(prim_link.shape[0]):
        li = prim_link[k]
        for a in range(3):
            for c in range(4):
                v = T[li, a, 0] * prim_X[k, 0, c] + T[li, a, 1] * prim_X[k, 1, c] + T[li, a, 2] * prim_X[k, 2, c]
                if c == 3:
                    v += T[li, a, 3]
                PW[k, a, c] = v
        # PW[k, a, 4]: half extent of the primitive's world AABB along axis a.
        for a in range(3):
            if prim_kind[k] == 0:
                e = 0.0
                for c in range(3):
                    e += abs(PW[k, a, c]) * prim_half[k, c]
            else:
                u = abs(PW[k, a, 2])
                e = u * prim_half[k, 2] + math.sqrt(max(1.0 - u * u, 0.0)) * prim_half[k, 0] + 1e-12
            PW[k, a, 4] = e
    n = 0
    while n < bp_prim.shape[0]:
        k = bp_prim[n]
        li = sph_link[bp_sphere[n]]
        rb = lb_r[li]
        # The link's bounding sphere outside the primitive's AABB (first) or
        # apart from the primitive: the whole group is free.
        if (abs(LB[li, 0] - PW[k, 0, 3]) > PW[k, 0, 4] + rb or abs(LB[li, 1] - PW[k, 1, 3]) > PW[k, 1, 4] + rb
                or abs(LB[li, 2] - PW[k, 2, 3]) > PW[k, 2, 4] + rb
                or _body_prim_d2(PW, k, prim_kind[k], prim_half, LB[li, 0], LB[li, 1], LB[li, 2]) > rb * rb):
            n = bp_end[n]
            continue
        end = bp_end[n]
        while n < end:
            sidx = bp_sphere[n]
            if _body_prim_d2(PW, k, prim_kind[k], prim_half, C[sidx, 0], C[sidx, 1], C[sidx, 2]) <= \
                    sph_rs[sidx] * sph_rs[sidx]:
                return False
            n += 1
    return True


@numba.njit(cache=True, inline="always")
def _config_free(Q, b, data):
    """Validity of configuration Q[b] for the checker tuple `data` (see
    `SphereCollisionChecker.base_pose_check_data`: scratch arrays T, C, PW, the
    environment's AABBs, `near` and the extended configuration V (head and
    fingers set, in place of the head that `SphereCollisionChecker._args`
    starts with), then the rest of `_args` but its last (the lowest sphere
    centres allowed), a scratch LB, and that last). One tuple
    instead of ~45 array arguments: a compiled call costs ~20 ns per array
    argument (reference counting), as much as the check itself.

    Environment primitives are culled per configuration: only those whose
    world AABB (`env_aabb`, see `env_aabbs`) overlaps the AABB of the
    robot's inflated spheres are tested, each first against the sphere's own
    box.
    """
    q_lo, q_hi = data[17], data[18]
    for j in range(Q.shape[1]):
        if not (Q[b, j] >= q_lo[j] and Q[b, j] <= q_hi[j]):  # also rejects NaN
            return False
    _checked_link_transforms(Q, b, data)
    if not _env_free(data[2], data):
        return False
    return _self_free(data[1], data[2], data)


@numba.njit(cache=True)
def batch_free(Q, head, parent, X_PJ, joint_type, axis, var_index,
               sph_link, sph_c, sph_r, sph_rs, pairs, q_lo, q_hi,
               has_field, dist, origin, h, margin, pts, cell_keys, cell_start, tgt_c, tgt_r, sph_test,
               box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, check_env,
               prim_link, prim_kind, prim_X, prim_half, bp_prim, bp_sphere, lb_c, lb_r, pair_end, bp_end,
               lowest_centre, order, stop_at_first, out):
    """out[b] = config Q[b] free; visits rows in `order`; optional early exit.

    Returns the first row found in collision (in visiting order) or -1.
    """
    T = np.empty((parent.shape[0], 3, 4))
    C = np.empty((sph_link.shape[0], 3))
    PW = np.empty((prim_link.shape[0], 3, 5))
    env_aabb = np.empty((box_p.shape[0] + cyl_p.shape[0], 6))
    env_aabbs(box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, env_aabb)
    near = np.empty(env_aabb.shape[0], dtype=np.int64)
    LB = np.empty((parent.shape[0], 3))
    V = extended_scratch(Q.shape[1], head)
    data = (Q, T, C, PW, env_aabb, near, V, parent, X_PJ, joint_type, axis, var_index,
            sph_link, sph_c, sph_r, sph_rs, pairs, q_lo, q_hi,
            has_field, dist, origin, h, margin, pts, cell_keys, cell_start, tgt_c, tgt_r, sph_test,
            box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, check_env,
            prim_link, prim_kind, prim_X, prim_half, bp_prim, bp_sphere, lb_c, lb_r, pair_end, bp_end, LB,
            lowest_centre)
    first = -1
    for n in range(order.shape[0]):
        b = order[n]
        ok = _config_free(Q, b, data)
        out[b] = ok
        if not ok and first < 0:
            first = b
            if stop_at_first:
                return first
    return first


@numba.njit(cache=True)
def held_spheres(data, C0):
    """Fills C0 (S, 3) with the sphere centres in the base frame for the
    torso + arm data[0][0, 3:] and returns whether that torso + arm is inside
    its limits and free of self-collision (both independent of the base)."""
    Q, T = data[0], data[1]
    q_lo, q_hi = data[17], data[18]
    Q[0, 0] = Q[0, 1] = Q[0, 2] = 0.0
    for j in range(3, Q.shape[1]):
        if not (Q[0, j] >= q_lo[j] and Q[0, j] <= q_hi[j]):
            return False
    _checked_link_transforms(Q, 0, data)
    C0[:] = data[2]
    return _self_free(T, C0, data)


@numba.njit(cache=True, inline="always")
def _held_pose_free(x, y, th, data):
    """Configuration (x, y, th, held torso + arm) free, from the tuple's
    base-frame sphere centres data[50] (see `held_spheres`): the base moves
    them rigidly (planar joints: x, y, then yaw about z); only the
    environment is tested."""
    q_lo, q_hi = data[17], data[18]
    if not (x >= q_lo[0] and x <= q_hi[0] and y >= q_lo[1] and y <= q_hi[1] and th >= q_lo[2]
            and th <= q_hi[2]):
        return False
    C, C0 = data[2], data[50]
    c = math.cos(th)
    sn = math.sin(th)
    for s in range(C0.shape[0]):
        C[s, 0] = x + c * C0[s, 0] - sn * C0[s, 1]
        C[s, 1] = y + sn * C0[s, 0] + c * C0[s, 1]
        C[s, 2] = C0[s, 2]
    return _env_free(C, data)


@numba.njit(cache=True)
def held_poses_free(poses, data, out):
    """out[m] = configuration (poses[m] (x, y, theta), held torso + arm) is
    free, for a tuple of `SphereCollisionChecker.base_pose_check_data` on a planar
    base: self-collision and joint limits of the torso + arm were tested once
    (data[51][0]); per pose only the environment."""
    if not data[51][0]:
        out[:] = False
        return
    for m in range(poses.shape[0]):
        out[m] = _held_pose_free(poses[m, 0], poses[m, 1], poses[m, 2], data)


@numba.njit(cache=True, inline="always")
def config_free_data(data):
    """Validity of data[0][0] (the (1, 11) scratch configuration of a tuple
    made by `SphereCollisionChecker.base_pose_check_data`; numba-callable)."""
    return _config_free(data[0], 0, data)


@numba.njit(cache=True, inline="always")
def base_pose_free_exact(x, y, theta, data):
    """Whole-body validity at base pose (x, y, theta) with the torso/arm of
    `SphereCollisionChecker.base_pose_check_data` (a tuple it made; numba-callable)."""
    th = (theta + math.pi) % (2.0 * math.pi) - math.pi
    if data[51][1]:  # planar base: the held torso + arm's spheres moved rigidly
        return data[51][0] and _held_pose_free(x, y, th, data)
    Q = data[0]
    Q[0, 0] = x
    Q[0, 1] = y
    Q[0, 2] = th
    return config_free_data(data)


@numba.njit(cache=True, inline="always")
def _occupied(dist, i, j, k):
    """Whether cell (i, j, k) is occupied (outside the grid: not)."""
    return (0 <= i < dist.shape[0] and 0 <= j < dist.shape[1] and 0 <= k < dist.shape[2]
            and dist[i, j, k] == 0.0)


@numba.njit(cache=True, inline="always")
def _surface_normals(dist, idx, out):
    """out[a]: whether occupied cell idx (3,) holds a piece of a surface with
    its normal along axis a: both of its neighbours along a are empty and at
    least two of its four neighbours across a are occupied. Such a cell's
    surface lies at its points' coordinate along a, not anywhere in the cell."""
    i, j, k = idx[0], idx[1], idx[2]
    n0 = int(_occupied(dist, i - 1, j, k)) + int(_occupied(dist, i + 1, j, k))
    n1 = int(_occupied(dist, i, j - 1, k)) + int(_occupied(dist, i, j + 1, k))
    n2 = int(_occupied(dist, i, j, k - 1)) + int(_occupied(dist, i, j, k + 1))
    out[0] = n0 == 0 and n1 + n2 >= 2
    out[1] = n1 == 0 and n0 + n2 >= 2
    out[2] = n2 == 0 and n0 + n1 >= 2


@numba.njit(cache=True)
def _sphere_hits_map(cx, cy, cz, r, dist, origin, h, pts, cell_keys, cell_start, exempt, tgt_c, tgt_r,
                     cells=False):
    """Whether the map reaches within r of (cx, cy, cz): some point of the
    occupied cells (dist == 0) that the sphere's bounding box overlaps,
    except, when `exempt`, those within tgt_r of tgt_c[:3] and above tgt_c[3];
    with `cells`, whether an occupied cell's box does. A cell's box spans the
    cell, except across a surface (`_surface_normals`): there it spans its
    points' extent (a table top's cell is the slab at the top's height, a TV
    screen's bottom cell still reaches to the cell's lower face)."""
    eps = 1e-9
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    idx = np.empty(3, np.int64)
    normal = np.empty(3, np.bool_)
    c = (cx, cy, cz)
    for a in range(3):
        lo[a] = max(int(math.floor((c[a] - r - eps - origin[a]) / h + 0.5)), 0)
        hi[a] = min(int(math.floor((c[a] + r + eps - origin[a]) / h + 0.5)), dist.shape[a] - 1)
    ny, nz = dist.shape[1], dist.shape[2]
    r2 = r * r
    half = 0.5 * h
    for i in range(lo[0], hi[0] + 1):
        ex = max(abs(origin[0] + h * i - cx) - half, 0.0)
        for j in range(lo[1], hi[1] + 1):
            ey = max(abs(origin[1] + h * j - cy) - half, 0.0)
            exy = ex * ex + ey * ey
            if exy > r2:
                continue
            for k in range(lo[2], hi[2] + 1):
                if dist[i, j, k] != 0.0:
                    continue
                ez = max(abs(origin[2] + h * k - cz) - half, 0.0)
                if exy + ez * ez > r2:
                    continue
                key = (i * ny + j) * nz + k
                m = np.searchsorted(cell_keys, key)
                has_points = m < cell_keys.shape[0] and cell_keys[m] == key
                if cells:
                    if not has_points:
                        return True
                    idx[0], idx[1], idx[2] = i, j, k
                    _surface_normals(dist, idx, normal)
                    d2 = 0.0
                    for a in range(3):
                        b_lo = origin[a] + h * idx[a] - half
                        b_hi = b_lo + h
                        if normal[a]:
                            b_lo, b_hi = math.inf, -math.inf
                            for n in range(cell_start[m], cell_start[m + 1]):
                                b_lo = min(b_lo, pts[n, a])
                                b_hi = max(b_hi, pts[n, a])
                        e = max(b_lo - c[a], c[a] - b_hi, 0.0)
                        d2 += e * e
                    if d2 <= r2:
                        return True
                    continue
                if not has_points:
                    continue
                for n in range(cell_start[m], cell_start[m + 1]):
                    dx = pts[n, 0] - cx
                    dy = pts[n, 1] - cy
                    dz = pts[n, 2] - cz
                    if dx * dx + dy * dy + dz * dz <= r2:
                        if exempt:
                            tx = pts[n, 0] - tgt_c[0]
                            ty = pts[n, 1] - tgt_c[1]
                            tz = pts[n, 2] - tgt_c[2]
                            if tx * tx + ty * ty + tz * tz <= tgt_r * tgt_r and pts[n, 2] > tgt_c[3]:
                                continue
                        return True
    return False
