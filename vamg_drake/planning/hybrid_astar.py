"""Hybrid A* for the mobile base on a 2D clearance map, with Reeds-Shepp
analytic expansions and in-place rotations.

The robot's projection is covered by a few discs fixed in the base frame
(`Footprint2D`, e.g. the base disc against the obstacles of the low height
band and the torso/arm disc against those of the high band). A pose is free
when, for every disc, the 2D clearance of its band (`Costmap2D` layer) at the
disc centre's cell, minus the map's discretization bound, exceeds its radius.
Near a start or goal whose footprint touches an obstacle (the robot parked at
a table), poses are checked exactly instead: the whole-body sphere model
with the travel arm (`exact_pose_check`, see
`SphereCollisionChecker.base_pose_check_data`). The search runs
over (x, y, theta) bins with motion primitives (forward/backward arcs of the
minimum turning radius and straight segments, plus in-place turns); its
heuristic is the obstacle-aware 2D Dijkstra distance from the goal. Every few
expansions a Reeds-Shepp curve to the goal is tried (analytic expansion).
Costs are travel times at the base's speed limits.
"""

import dataclasses
import heapq
import math

import numba
import numpy as np

from vamg_drake.planning import reeds_shepp as rs
from vamg_drake.planning.sphere_checks import base_pose_free_exact
from vamg_drake.robot import layout


@dataclasses.dataclass(frozen=True, eq=False)
class Costmap2D:
    """Clearance [m] of 2D cell centres from the nearest obstacle cell centre.

    Attributes:
        clearance: (nx, ny) float32, or (bands, nx, ny): one layer per
            height band of obstacles.
        origin: (2,) centre of cell (0, 0).
        resolution: cell size [m].
        margin: discretization bound (sqrt(2) * resolution).
    """

    clearance: np.ndarray
    origin: np.ndarray
    resolution: float
    margin: float

    @property
    def layers(self) -> np.ndarray:
        """The clearance as (bands, nx, ny)."""
        c = self.clearance
        return c[None] if c.ndim == 2 else c

    @property
    def shape(self) -> tuple[int, int]:
        return self.layers.shape[1:]

    def cell(self, xy: np.ndarray) -> tuple[int, int]:
        i = int(math.floor((xy[0] - self.origin[0]) / self.resolution + 0.5))
        j = int(math.floor((xy[1] - self.origin[1]) / self.resolution + 0.5))
        return i, j


@dataclasses.dataclass(frozen=True, eq=False)
class Footprint2D:
    """Discs that cover the robot's projection, fixed in the base frame.

    Attributes:
        discs: (K, 3) rows (x, y, radius) [m], centre in the base frame.
        band: (K,) costmap layer each disc is tested against.
    """

    discs: np.ndarray
    band: np.ndarray

    @staticmethod
    def disc(radius: float) -> "Footprint2D":
        """One disc about the base origin, against layer 0."""
        return Footprint2D(np.array([[0.0, 0.0, float(radius)]]), np.zeros(1, np.int64))

    @staticmethod
    def covering(p_BS: np.ndarray, radius: np.ndarray) -> tuple[float, float]:
        """(x offset, radius) of the smallest disc centred on the base x axis
        that covers the xy projections of spheres (p_BS (N, 3), radius (N,))."""
        xs = np.linspace(p_BS[:, 0].min(), p_BS[:, 0].max(), 201)
        need = np.max(np.hypot(p_BS[None, :, 0] - xs[:, None], p_BS[None, :, 1]) + radius[None], axis=1)
        k = int(np.argmin(need))
        return float(xs[k]), float(need[k])

    @property
    def bounding_radius(self) -> float:
        return float(np.max(np.hypot(self.discs[:, 0], self.discs[:, 1]) + self.discs[:, 2]))


@dataclasses.dataclass
class HybridAStarConfig:
    """Search parameters.

    Attributes:
        turning_radius: minimum turning radius of arcs and Reeds-Shepp curves [m].
        step: arc length of one motion primitive [m].
        theta_bins: heading bins.
        reverse_penalty: cost multiplier when driving backwards, also the
            weight of backward segments when choosing Reeds-Shepp curves
            (`reeds_shepp.shortest_path`) and judging shortcuts: the head
            camera looks ahead (pan +-90 deg), so backing up drives into space
            the map has not seen; at 8, turning half a circle in place and
            driving forward wins over backing up more than ~0.6 m.
        max_analytic_reverse: a Reeds-Shepp curve to the goal (the one tried
            before the search, and the search's analytic expansions) is taken
            only if it drives at most this far backwards [m].
        allow_in_place_rotation: add in-place turns of one heading bin.
        analytic_every: try a Reeds-Shepp connection every n expansions.
        max_expansions: search limit.
        check_step: sampling step [m] of collision checks along curves.
        heuristic_weight: weight of the heuristic (> 1: greedier, fewer
            expansions, paths up to that factor longer before shortcutting).
        heuristic_cell: cell size [m] of the heuristic's distance grid (a
            whole multiple of the costmap's cells, the nearest).
        analytic_radius: within this distance [m] of the goal a Reeds-Shepp
            connection is tried at every expansion.
        exact_slack: with an exact pose check, a pose that the 2D discs
            block by less than this [m] is decided by the exact check.
    """

    turning_radius: float = 0.4
    step: float = 0.3
    theta_bins: int = 36
    reverse_penalty: float = 8.0
    max_analytic_reverse: float = 0.4
    allow_in_place_rotation: bool = True
    analytic_every: int = 8
    max_expansions: int = 20000
    check_step: float = 0.04
    exact_slack: float = 0.06
    heuristic_weight: float = 5.0
    heuristic_cell: float = 0.1
    analytic_radius: float = 1.0


@numba.njit(cache=True)
def _poses_2d(poses, layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact, has_exact, slack, need):
    """The 2D part of `_poses_free`: False when some pose (M, 3) is blocked;
    else True, with need[k] = 0 (pose k free), 1 (to check exactly with the
    travel arm), 2 + e (exactly with zone e's own arm). Without `has_exact`
    nothing is left to an exact check (zone poses are free then).

    (The exact checks' data tuples are not passed here: a compiled call
    costs ~25 ns per array in a tuple argument, 50 per tuple.)"""
    nx = layers.shape[1]
    ny = layers.shape[2]
    for k in range(poses.shape[0]):
        x, y, th = poses[k, 0], poses[k, 1], poses[k, 2]
        need[k] = 0
        zone = -1
        for e in range(exempt.shape[0]):
            if (x - exempt[e, 0]) ** 2 + (y - exempt[e, 1]) ** 2 < exempt_r * exempt_r:
                zone = e
                break
        if zone >= 0:
            if has_exact:
                if exempt_exact[zone] == 1:
                    need[k] = 1
                elif exempt_exact[zone] == 2:
                    need[k] = 2 + zone
            continue
        c = math.cos(th)
        s = math.sin(th)
        worst = -1.0
        for d in range(discs.shape[0]):
            px = x + c * discs[d, 0] - s * discs[d, 1]
            py = y + s * discs[d, 0] + c * discs[d, 1]
            i = int(math.floor((px - origin[0]) / h + 0.5))
            j = int(math.floor((py - origin[1]) / h + 0.5))
            if 0 <= i < nx and 0 <= j < ny:
                worst = max(worst, discs[d, 2] + margin - layers[band[d], i, j])
        if worst < 0.0:
            continue
        # Blocked in 2D by less than `slack`: the discs overestimate the
        # robot, let the exact check decide.
        if has_exact and worst < slack:
            need[k] = 1
            continue
        return False
    return True


@numba.njit(cache=True)
def _poses_exact(poses, need, exact, exact_zone):
    """The exact checks `_poses_2d` left (need[k] > 0)."""
    for k in range(poses.shape[0]):
        if need[k] == 0:
            continue
        x, y, th = poses[k, 0], poses[k, 1], poses[k, 2]
        if need[k] == 1:
            if not base_pose_free_exact(x, y, th, exact):
                return False
        elif need[k] == 2:
            if not base_pose_free_exact(x, y, th, exact_zone[0]):
                return False
        elif not base_pose_free_exact(x, y, th, exact_zone[1]):
            return False
    return True


@numba.njit(cache=True)
def _poses_free(poses, layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact, exact, exact_zone,
                slack):
    """True when every pose (M, 3) is free (see the module docstring).

    Poses within exempt_r of exempt point e (E, 2) are checked with the
    `exact` whole-body check (travel arm) where exempt_exact[e] == 1, with
    exact_zone[e] (the start's/goal's own arm) where it is 2; `exact` may be
    None (no zones then). Inside the search, `_poses_2d` first and
    `_poses_exact` only where needed.
    """
    need = np.empty(poses.shape[0], np.int64)
    if not _poses_2d(poses, layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact,
                     exact is not None, slack, need):
        return False
    if exact is None:
        return True
    return _poses_exact(poses, need, exact, exact_zone)


@numba.njit(cache=True)
def grid_distances(free, gi, gj, h):
    """8-connected grid distances [m] from cell (gi, gj) over the True cells of
    ``free`` with cell size ``h`` (inf where unreachable; all inf when the start
    lies outside the grid). A binary heap on flat arrays of (distance, cell),
    lazy deletion."""
    nx, ny = free.shape
    dist = np.full((nx, ny), np.inf)
    if not (0 <= gi < nx and 0 <= gj < ny):
        return dist
    dist[gi, gj] = 0.0
    cap = 8 * nx * ny + 1
    key = np.empty(cap)
    val = np.empty(cap, np.int64)
    key[0], val[0] = 0.0, gi * ny + gj
    n = 1
    diag = math.sqrt(2.0) * h
    while n > 0:
        d, c = key[0], val[0]
        # pop: the last element sifted down from the root
        n -= 1
        if n > 0:
            kk, vv = key[n], val[n]
            p = 0
            while True:
                ch = 2 * p + 1
                if ch >= n:
                    break
                if ch + 1 < n and key[ch + 1] < key[ch]:
                    ch += 1
                if key[ch] < kk:
                    key[p], val[p] = key[ch], val[ch]
                    p = ch
                else:
                    break
            key[p], val[p] = kk, vv
        i, j = c // ny, c % ny
        if d > dist[i, j]:
            continue
        for di in range(-1, 2):
            for dj in range(-1, 2):
                if di == 0 and dj == 0:
                    continue
                a = i + di
                b = j + dj
                if a < 0 or b < 0 or a >= nx or b >= ny or not free[a, b]:
                    continue
                nd = d + (diag if (di != 0 and dj != 0) else h)
                if nd < dist[a, b]:
                    dist[a, b] = nd
                    # push: sift up
                    p = n
                    n += 1
                    while p > 0:
                        q = (p - 1) // 2
                        if key[q] > nd:
                            key[p], val[p] = key[q], val[q]
                            p = q
                        else:
                            break
                    key[p], val[p] = nd, a * ny + b
    return dist


@numba.njit(cache=True)
def _footprint_free(layers, margin, thr, band, out):
    """out &= (layers[band[k]] - margin > thr[k] for every disc k)."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            for k in range(thr.shape[0]):
                if not layers[band[k], i, j] - margin > thr[k]:
                    out[i, j] = False
                    break
    return out


@numba.njit(cache=True)
def _coarse_footprint_free(layers, margin, thr, band, factor):
    """`_coarse_free(_footprint_free(...), factor)` in one pass (each block
    scanned until one of its cells is free)."""
    nx, ny = layers.shape[1], layers.shape[2]
    cx = (nx + factor - 1) // factor
    cy = (ny + factor - 1) // factor
    out = np.zeros((cx, cy), dtype=np.bool_)
    for a in range(cx):
        for b in range(cy):
            found = False
            for i in range(a * factor, min((a + 1) * factor, nx)):
                for j in range(b * factor, min((b + 1) * factor, ny)):
                    ok = True
                    for k in range(thr.shape[0]):
                        if not layers[band[k], i, j] - margin > thr[k]:
                            ok = False
                            break
                    if ok:
                        found = True
                        break
                if found:
                    break
            out[a, b] = found
    return out


@numba.njit(cache=True)
def _coarse_free(free, factor):
    """A grid `factor` times coarser: a coarse cell is free when any of its cells is."""
    nx, ny = free.shape
    cx = (nx + factor - 1) // factor
    cy = (ny + factor - 1) // factor
    out = np.zeros((cx, cy), dtype=np.bool_)
    for a in range(cx):
        for b in range(cy):
            found = False
            for i in range(a * factor, min((a + 1) * factor, nx)):
                for j in range(b * factor, min((b + 1) * factor, ny)):
                    if free[i, j]:
                        found = True
                        break
                if found:
                    break
            out[a, b] = found
    return out


@numba.njit(cache=True)
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@numba.njit(cache=True)
def _prim_poses(x, y, th, kappa, length, dth, n, out):
    """Fills out[:n] with poses along one motion primitive from (x, y, th)."""
    if dth != 0.0:
        out[0, 0], out[0, 1], out[0, 2] = x, y, th + dth
        return 1
    for k in range(n):
        s = length * (k + 1) / n
        if kappa == 0.0:
            out[k, 0] = x + s * math.cos(th)
            out[k, 1] = y + s * math.sin(th)
            out[k, 2] = th
        else:
            nth = th + kappa * s
            out[k, 0] = x + (math.sin(nth) - math.sin(th)) / kappa
            out[k, 1] = y - (math.cos(nth) - math.cos(th)) / kappa
            out[k, 2] = nth
    return n


@numba.njit(cache=True)
def _trace(start, node, poses, parents, prim_of, prims, counts, tail):
    """The poses from the start along the primitives of the tree path to
    `node`, then the analytic `tail` (its first pose is the node's)."""
    n_chain = 0
    i = node
    while i > 0:
        n_chain += 1
        i = parents[i]
    chain = np.empty(n_chain, np.int64)
    i = node
    for c in range(n_chain - 1, -1, -1):
        chain[c] = i
        i = parents[i]
    total = 1 + tail.shape[0] - 1
    for c in range(n_chain):
        total += counts[prim_of[chain[c]]]
    out = np.empty((total, 3))
    out[0] = start
    n = 1
    buf = np.empty((64, 3))
    for c in range(n_chain):
        i = chain[c]
        p = parents[i]
        k = prim_of[i]
        m = _prim_poses(poses[p, 0], poses[p, 1], poses[p, 2], prims[k, 0], prims[k, 1], prims[k, 2], counts[k], buf)
        out[n:n + m] = buf[:m]
        n += m
    out[n:] = tail[1:]
    return out


@numba.njit(cache=True)
def _any(need, m):
    for k in range(m):
        if need[k] != 0:
            return True
    return False


@numba.njit(cache=True)
def _search(start, goal, layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact, exact, exact_zone,
            slack,
            h2d, h2d_factor, h2d_slack, prims, prim_n, radius, check_step, theta_bins, xy_res, analytic_every, max_exp,
            v, heur_weight, near_goal, reverse_weight, max_reverse):
    """The Hybrid A* loop. Returns (status, node, poses, parents, prim ids, rs types, rs lengths, expansions).

    status: 1 found (node connects to the goal by the RS path), 0 exhausted, -1 limit.
    """
    nx = layers.shape[1]
    ny = layers.shape[2]
    # the search lattice covers the costmap
    x0 = origin[0] - 0.5 * h
    y0 = origin[1] - 0.5 * h
    gx = int(math.ceil(nx * h / xy_res)) + 1
    gy = int(math.ceil(ny * h / xy_res)) + 1
    closed = np.zeros((gx, gy, theta_bins), dtype=np.bool_)
    cap = 4096
    poses = np.empty((cap, 3))
    parents = np.empty(cap, dtype=np.int64)
    prim_of = np.empty(cap, dtype=np.int64)
    g_of = np.empty(cap)
    poses[0, 0], poses[0, 1], poses[0, 2] = start[0], start[1], start[2]
    parents[0] = -1
    prim_of[0] = -1
    g_of[0] = 0.0
    n_nodes = 1
    heap = [(0.0, 0)]
    has_exact = exact is not None
    need = np.empty(256, np.int64)
    buf = np.empty((64, 3))
    diag = math.sqrt(2.0)
    expansions = 0
    best_types = np.zeros(5, dtype=np.int64)
    best_lengths = np.zeros(5)
    while len(heap) > 0:
        f, idx = heapq.heappop(heap)
        x, y, th = poses[idx, 0], poses[idx, 1], poses[idx, 2]
        ci = int(math.floor((x - x0) / xy_res))
        cj = int(math.floor((y - y0) / xy_res))
        ct = int(math.floor((_wrap(th) + math.pi) / (2.0 * math.pi) * theta_bins)) % theta_bins
        if ci < 0 or cj < 0 or ci >= gx or cj >= gy:
            continue
        if closed[ci, cj, ct]:
            continue
        closed[ci, cj, ct] = True
        expansions += 1
        if expansions > max_exp:
            return -1, -1, poses[:n_nodes], parents[:n_nodes], prim_of[:n_nodes], best_types, best_lengths, expansions
        dgoal = math.hypot(x - goal[0], y - goal[1])
        if expansions % analytic_every == 1 or dgoal < near_goal:
            types, lengths, total = rs.shortest_path(poses[idx], goal, radius, reverse_weight)
            backward = 0.0
            for k in range(lengths.shape[0]):
                backward -= radius * min(lengths[k], 0.0)
            path = rs.sample_path(poses[idx], types, lengths, radius, check_step)
            if path.shape[0] > need.shape[0]:
                need = np.empty(2 * path.shape[0], np.int64)
            if backward <= max_reverse and _poses_2d(
                    path, layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact, has_exact, slack,
                    need) and (not has_exact or not _any(need, path.shape[0])
                               or _poses_exact(path, need, exact, exact_zone)):
                return 1, idx, poses[:n_nodes], parents[:n_nodes], prim_of[:n_nodes], types, lengths, expansions
        for p in range(prims.shape[0]):
            m = _prim_poses(x, y, th, prims[p, 0], prims[p, 1], prims[p, 2], prim_n[p], buf)
            qx, qy, qt = buf[m - 1, 0], buf[m - 1, 1], buf[m - 1, 2]
            ai = int(math.floor((qx - x0) / xy_res))
            aj = int(math.floor((qy - y0) / xy_res))
            at = int(math.floor((_wrap(qt) + math.pi) / (2.0 * math.pi) * theta_bins)) % theta_bins
            if ai < 0 or aj < 0 or ai >= gx or aj >= gy or closed[ai, aj, at]:
                continue
            if not _poses_2d(buf[:m], layers, origin, h, margin, discs, band, exempt, exempt_r, exempt_exact,
                             has_exact, slack, need):
                continue
            if has_exact and _any(need, m) and not _poses_exact(buf[:m], need, exact, exact_zone):
                continue
            # heuristic: obstacle-aware 2D distance on the coarse grid (minus
            # its grid slack) or Euclid
            i = int(math.floor((qx - origin[0]) / h + 0.5))
            j = int(math.floor((qy - origin[1]) / h + 0.5))
            e = math.hypot(qx - goal[0], qy - goal[1])
            if 0 <= i < nx and 0 <= j < ny:
                d2 = h2d[i // h2d_factor, j // h2d_factor]
                if d2 == np.inf:
                    continue
                e = max(e, d2 - h2d_slack)
            ng = g_of[idx] + prims[p, 3]
            if n_nodes == cap:
                cap *= 2
                poses2 = np.empty((cap, 3))
                poses2[:n_nodes] = poses[:n_nodes]
                poses = poses2
                par2 = np.empty(cap, dtype=np.int64)
                par2[:n_nodes] = parents[:n_nodes]
                parents = par2
                pr2 = np.empty(cap, dtype=np.int64)
                pr2[:n_nodes] = prim_of[:n_nodes]
                prim_of = pr2
                g2 = np.empty(cap)
                g2[:n_nodes] = g_of[:n_nodes]
                g_of = g2
            poses[n_nodes, 0], poses[n_nodes, 1], poses[n_nodes, 2] = qx, qy, qt
            parents[n_nodes] = idx
            prim_of[n_nodes] = p
            g_of[n_nodes] = ng
            heapq.heappush(heap, (ng + heur_weight * e / v, n_nodes))
            n_nodes += 1
    return 0, -1, poses[:n_nodes], parents[:n_nodes], prim_of[:n_nodes], best_types, best_lengths, expansions


@dataclasses.dataclass(frozen=True)
class BasePath:
    """Base poses (N, 3) (theta unwrapped) and the search's expansion count."""

    poses: np.ndarray
    expansions: int


class HybridAStar:
    """Hybrid A* planner for the base footprint on a `Costmap2D`.

    Args:
        costmap: the clearance layers.
        footprint: a `Footprint2D`, or a radius (one disc about the base origin).
        config: search parameters.
        checker: optional `SphereCollisionChecker` for exact whole-body pose
            checks with `travel_arm` (torso + arm (8,)): poses that the 2D
            discs block by less than `exact_slack`, and poses near a
            start/goal whose footprint touches an obstacle (there with the
            travel arm where it fits at that start/goal, else with the
            start's/goal's own arm). Without it such a start/goal is rejected.
        travel_arm: the torso + arm held while driving.
    """

    def __init__(self, costmap: Costmap2D, footprint: "Footprint2D | float",
                 config: HybridAStarConfig | None = None, checker=None, travel_arm: np.ndarray | None = None):
        self.costmap = costmap
        self.config = config or HybridAStarConfig()
        if not isinstance(footprint, Footprint2D):
            footprint = Footprint2D.disc(float(footprint))
        self.footprint = footprint
        self._discs = np.ascontiguousarray(footprint.discs, float)
        self._band = np.ascontiguousarray(footprint.band, np.int64)
        if self._band.size and self._band.max() >= costmap.layers.shape[0]:
            raise ValueError(f"footprint band {self._band.max()} but the costmap has {costmap.layers.shape[0]} layers")
        self.radius = footprint.bounding_radius
        self.checker = checker
        self.exact = None if checker is None else checker.base_pose_check_data(travel_arm)
        self._exact_zone = (self.exact, self.exact)
        self._slack = self.config.exact_slack if checker is not None else 0.0
        self.v = layout.TRACKER_BASE_V
        self.w = layout.TRACKER_BASE_W
        self._primitives = self._make_primitives()
        self._layers = np.ascontiguousarray(costmap.layers)
        self._exempt = np.zeros((0, 2))
        self._exempt_exact = np.zeros(0, np.bool_)
        self._exempt_r = 0.0
        self._free = None
        self._coarse = None

    def poses_free(self, poses: np.ndarray) -> bool:
        """Every pose (M, 3) is free (see the module docstring): the 2D test,
        then the exact checks it leaves (their data tuples are passed only
        then: ~150 arrays cost ~10 us per call from Python)."""
        cm = self.costmap
        poses = np.ascontiguousarray(poses, float)
        need = np.empty(poses.shape[0], np.int64)
        has_exact = self.exact is not None
        if not _poses_2d(poses, self._layers, cm.origin, cm.resolution, cm.margin, self._discs, self._band,
                         self._exempt, self._exempt_r, self._exempt_exact, has_exact, self._slack, need):
            return False
        if not has_exact or not need.any():
            return True
        return bool(_poses_exact(poses, need, self.exact, self._exact_zone))

    def warm_up(self) -> None:
        """Runs the compiled exact pose checks once (see `WholeBodyPlanner.warm_up`)."""
        if self.exact is not None:
            _poses_exact(np.zeros((1, 3)), np.ones(1, np.int64), self.exact, self._exact_zone)

    def reeds_shepp(self, a: np.ndarray, b: np.ndarray, max_reverse: float = np.inf) -> np.ndarray | None:
        """Sampled RS path a->b (M, 3) (backward segments weighted by
        `reverse_penalty`) if it backs up at most `max_reverse` [m] and its
        poses are free, else None."""
        R = self.config.turning_radius
        types, lengths, _ = rs.shortest_path(a, b, R, self.config.reverse_penalty)
        if -R * float(lengths[lengths < 0].sum()) > max_reverse:
            return None
        poses = rs.sample_path(a, types, lengths, R, self.config.check_step)
        return poses if self.poses_free(poses) else None

    def path_cost(self, poses: np.ndarray) -> float:
        """Length of a sampled base path [m], backward steps counted
        `reverse_penalty` times, plus 0.3 m per radian turned."""
        poses = np.ascontiguousarray(poses, float)
        return float(_path_cost(poses, 0, poses.shape[0] - 1, self.config.reverse_penalty))

    def _make_primitives(self):
        """Rows (kappa, signed length, in-place dtheta, cost [s]) and check counts."""
        c = self.config
        rows, counts = [], []
        n = max(int(math.ceil(c.step / c.check_step)), 1)
        for direction in (1.0, -1.0):
            for kappa in (-1.0 / c.turning_radius, 0.0, 1.0 / c.turning_radius):
                t = max(c.step / self.v, abs(kappa) * c.step / self.w)
                if direction < 0:
                    t *= c.reverse_penalty
                rows.append((kappa, direction * c.step, 0.0, t))
                counts.append(n)
        if c.allow_in_place_rotation:
            dth = 2.0 * math.pi / c.theta_bins
            for sgn in (1.0, -1.0):
                rows.append((0.0, 0.0, sgn * dth, dth / self.w))
                counts.append(1)
        return np.array(rows), np.array(counts, dtype=np.int64)

    def plan(self, start: np.ndarray, goal: np.ndarray, deadline_s: float | None = None,
             start_arm: np.ndarray | None = None, goal_arm: np.ndarray | None = None) -> tuple[BasePath | None, str]:
        """A base path start->goal (poses (x, y, theta), theta unwrapped), or (None, reason).

        The search is bounded by `HybridAStarConfig.max_expansions` (it runs
        compiled, without a clock, so the same inputs give the same path);
        `deadline_s` is accepted for symmetry.
        """
        c = self.config
        cm = self.costmap
        start = np.asarray(start, float)
        goal = np.asarray(goal, float)
        # A start/goal whose footprint touches an obstacle in 2D (e.g. parked
        # at a table, the arm over it) gets a zone around it where poses are
        # checked exactly (whole body, travel arm) instead.
        self._exempt = np.zeros((0, 2))
        self._exempt_exact = np.zeros(0, np.int64)
        self._exempt_r = self.radius + 2.0 * cm.margin
        exempt, exact, zone_data = [], [], []
        for name, p, arm in (("start", start, start_arm), ("goal", goal, goal_arm)):
            if self.poses_free(p[None]):
                continue
            if self.exact is None:
                return None, f"no base path ({name} footprint in collision in the 2D map)"
            exempt.append(p[:2])
            # Exactly free with the travel arm: check the zone with it; else
            # (the travel arm touches there) with the start's/goal's own arm,
            # which the robot then holds near it; else leave it to the 3D check.
            if base_pose_free_exact(p[0], p[1], p[2], self.exact):
                exact.append(1)
                zone_data.append(self.exact)
            elif arm is not None:
                data = self.checker.base_pose_check_data(arm)
                exact.append(2 if base_pose_free_exact(p[0], p[1], p[2], data) else 0)
                zone_data.append(data)
            else:
                exact.append(0)
                zone_data.append(self.exact)
        self._exempt = np.array(exempt, float).reshape(-1, 2)
        self._exempt_exact = np.array(exact, np.int64)
        while len(zone_data) < 2:
            zone_data.append(self.exact)
        self._exact_zone = tuple(zone_data)
        direct = self.reeds_shepp(start, goal, c.max_analytic_reverse)
        if direct is not None:
            return BasePath(direct, 0), ""
        nx, ny = cm.shape
        free = None  # no start/goal zones: the coarse grid straight from the layers (cached)
        if self._exempt.shape[0]:
            free = self._free_mask().copy()
            gx = cm.origin[0] + cm.resolution * np.arange(nx)
            gy = cm.origin[1] + cm.resolution * np.arange(ny)
            for ex, ey in self._exempt:
                free |= ((gx[:, None] - ex) ** 2 + (gy[None, :] - ey) ** 2) < self._exempt_r ** 2
        h2d, factor, h2d_slack = self._heuristic_grid(free, goal)
        si, sj = cm.cell(start)
        if 0 <= si < nx and 0 <= sj < ny and not np.isfinite(h2d[si // factor, sj // factor]):
            return None, "no base path (goal unreachable in the 2D map)"
        prims, counts = self._primitives
        xy_res = max(cm.resolution, 0.5 * c.step)
        status, node, poses, parents, prim_of, types, lengths, expansions = _search(
            start, goal, self._layers, cm.origin, cm.resolution, cm.margin, self._discs, self._band,
            self._exempt, self._exempt_r, self._exempt_exact, self.exact, self._exact_zone, self._slack,
            h2d, factor, h2d_slack, prims, counts, c.turning_radius, c.check_step, c.theta_bins, xy_res, c.analytic_every,
            c.max_expansions, self.v, c.heuristic_weight, c.analytic_radius, c.reverse_penalty,
            c.max_analytic_reverse)
        if status == -1:
            return None, "no base path (search limit)"
        if status == 0:
            return None, "no base path (search exhausted)"
        tail = rs.sample_path(poses[node], types, lengths, c.turning_radius, c.check_step)
        return BasePath(_trace(start, node, poses, parents, prim_of, prims, counts, tail), int(expansions)), ""

    def _free_mask(self) -> np.ndarray:
        """Cells where the footprint may fit at some heading (a relaxation:
        every disc centre lies within |offset| + h of the cell centre)."""
        if self._free is None:
            cm = self.costmap
            self._free = _footprint_free(self._layers, cm.margin, self._disc_thresholds(), self._band,
                                         np.ones(cm.shape, bool))
        return self._free

    def _disc_thresholds(self) -> np.ndarray:
        """Per disc the clearance a cell needs in `_free_mask`."""
        cm = self.costmap
        return np.array([r - math.hypot(x, y) - cm.resolution - self._slack for x, y, r in self._discs])

    def _heuristic_grid(self, free: np.ndarray | None, goal: np.ndarray) -> tuple[np.ndarray, int, float]:
        """Obstacle-aware distances to the goal on a grid `factor` times
        coarser than the costmap (cells of about `heuristic_cell` m; a coarse
        cell is free when any of its cells is in `free`, default
        `_free_mask`: an underestimate).

        Returns (distances (cx, cy) [m], factor, slack [m]): the distance of
        a fine cell (i, j) is at least dist[i // factor, j // factor] - slack
        (cell centres sit up to `slack` from their coarse cell's centre)."""
        cm = self.costmap
        factor = max(int(round(self.config.heuristic_cell / cm.resolution)), 1)
        if free is None:  # `_free_mask`, coarsened in one pass: the same for every goal
            if self._coarse is None or self._coarse[0] != factor:
                cm = self.costmap
                self._coarse = (factor, _coarse_footprint_free(self._layers, cm.margin, self._disc_thresholds(),
                                                               self._band, factor))
            coarse = self._coarse[1]
        else:
            coarse = _coarse_free(free, factor)
        gi, gj = cm.cell(goal)
        hc = factor * cm.resolution
        d = grid_distances(coarse, gi // factor, gj // factor, hc)
        return d, factor, 2.0 * math.sqrt(2.0) * 0.5 * (factor - 1) * cm.resolution + math.sqrt(2.0) * hc

    def shortcut(self, poses: np.ndarray, rng: np.random.Generator, iterations: int = 20) -> np.ndarray:
        """Randomized shortcutting of a base path with Reeds-Shepp connections
        (the random pairs of poses drawn up front: one generator call)."""
        R = self.config.turning_radius
        w = self.config.reverse_penalty
        poses = np.ascontiguousarray(poses, float)
        u = rng.random((iterations, 2))
        for it in range(iterations):
            n = poses.shape[0]
            if n < 4:
                break
            # Two distinct indices, uniformly (as rng.choice(n, 2, replace=False)).
            i, j = int(u[it, 0] * n), int(u[it, 1] * (n - 1))
            j += j >= i
            i, j = min(i, j), max(i, j)
            if j - i < 3:
                continue
            a, b = poses[i], poses[j]
            types, lengths, total = rs.shortest_path(a, b, R, w)
            seg = rs.sample_path(a, types, lengths, R, self.config.check_step)
            if (_path_cost(seg, 0, seg.shape[0] - 1, w) >= _path_cost(poses, i, j, w) - 1e-6
                    or not self.poses_free(seg)):
                continue
            # keep theta continuous: RS starts at a's unwrapped theta; shift the rest
            end_shift = seg[-1, 2] - b[2]
            rest = poses[j + 1:].copy()
            rest[:, 2] += end_shift
            seg[-1, 2] = b[2] + end_shift
            poses = np.concatenate([poses[:i], seg, rest])
        return poses


@numba.njit(cache=True)
def _path_cost(poses, i, j, reverse_weight):
    """`HybridAStar.path_cost` of poses[i..j]."""
    cost = 0.0
    for k in range(i, j):
        dx = poses[k + 1, 0] - poses[k, 0]
        dy = poses[k + 1, 1] - poses[k, 1]
        step = math.sqrt(dx * dx + dy * dy)
        if dx * math.cos(poses[k, 2]) + dy * math.sin(poses[k, 2]) < 0.0:
            step *= reverse_weight
        cost += step + 0.3 * abs(poses[k + 1, 2] - poses[k, 2])
    return cost
