"""Does the remaining trajectory hit the map? (the 10 Hz execution-time check)

The robot at waypoint i is a set of spheres (centres (S, 3), radii (S,)); the
map is a point cloud. Waypoint i collides when any map point lies inside any of
its spheres (radius + margin).

* `SweptSphereIndex` (built once per trajectory): the spheres of all
  waypoints binned into a uniform grid over the trajectory's bounding box (CSR,
  entries sorted by waypoint). `first_collision(points, start)` then costs one
  cell lookup per map point plus a few sphere tests for the points near the
  path, so the full map can be re-checked every cycle; a cheaper incremental
  check passes only the points the last map update added.
* `first_colliding_waypoint`: the one-shot version (bins the points instead).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

#: The grid never has more cells than this (the cell edge grows instead).
_MAX_CELLS = 2_000_000


def first_colliding_waypoint(
    points_W: np.ndarray, sphere_centers_W: np.ndarray, sphere_radii: np.ndarray, margin: float = 0.0
) -> int:
    """Index of the first waypoint whose spheres contain a map point, or -1.

    Args:
        points_W: (M, 3) map points.
        sphere_centers_W: (N, S, 3) sphere centres per waypoint.
        sphere_radii: (S,) radii (the same spheres at every waypoint).
        margin: added to every radius [m].
    """
    p = np.ascontiguousarray(np.asarray(points_W, dtype=float).reshape(-1, 3))
    c = np.asarray(sphere_centers_W, dtype=float)
    r = np.ascontiguousarray(np.asarray(sphere_radii, dtype=float).reshape(-1)) + float(margin)
    if c.ndim != 3 or c.shape[2] != 3 or c.shape[1] != r.shape[0]:
        raise ValueError(
            f"first_colliding_waypoint: sphere_centers_W must be (N, S, 3) with S = len(sphere_radii) = "
            f"{r.shape[0]}, got {c.shape}"
        )
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
        raise ValueError("first_colliding_waypoint: sphere centres or radii contain NaN or inf")
    if p.shape[0] == 0 or c.shape[0] == 0 or r.shape[0] == 0:
        return -1
    c = np.ascontiguousarray(c)
    flat = c.reshape(-1, 3)
    rr = np.tile(r, c.shape[0])
    lo = (flat - rr[:, None]).min(axis=0)
    hi = (flat + rr[:, None]).max(axis=0)
    cell = max(2.0 * float(r.max()), 1e-3)
    extent = hi - lo
    while np.prod(np.floor(extent / cell) + 1.0) > _MAX_CELLS:
        cell *= 1.5
    dims = (np.floor(extent / cell) + 1).astype(np.int64)
    return int(_first_hit(p, c, r, lo, cell, dims))


class SweptSphereIndex:
    """Robot spheres along a trajectory, indexed for fast point queries.

    Args:
        sphere_centers_W: (N, S, 3) sphere centres per waypoint.
        sphere_radii: (S,) radii.
        margin: added to every radius [m].
        cell_size: grid cell edge [m].
    """

    def __init__(self, sphere_centers_W: np.ndarray, sphere_radii: np.ndarray, margin: float = 0.0, cell_size: float = 0.15):
        c = np.ascontiguousarray(np.asarray(sphere_centers_W, dtype=float))
        r = np.ascontiguousarray(np.asarray(sphere_radii, dtype=float).reshape(-1)) + float(margin)
        if c.ndim != 3 or c.shape[2] != 3 or c.shape[1] != r.shape[0]:
            raise ValueError(
                f"SweptSphereIndex: sphere_centers_W must be (N, S, 3) with S = len(sphere_radii) = "
                f"{r.shape[0]}, got {c.shape}"
            )
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
            raise ValueError("SweptSphereIndex: sphere centres or radii contain NaN or inf")
        if not cell_size > 0.0:
            raise ValueError(f"SweptSphereIndex.cell_size must be positive, got {cell_size}")
        self.num_waypoints = int(c.shape[0])
        self.centers, self.radii = c, r
        if c.shape[0] == 0 or r.shape[0] == 0:
            self.lo, self.cell, self.dims = np.zeros(3), float(cell_size), np.ones(3, dtype=np.int64)
            self.start = np.zeros(2, dtype=np.int64)
            self.entries = np.empty(0, dtype=np.int64)
            return
        flat = c.reshape(-1, 3)
        rr = np.tile(r, c.shape[0])
        self.lo = (flat - rr[:, None]).min(axis=0)
        hi = (flat + rr[:, None]).max(axis=0)
        cell = float(cell_size)
        while np.prod(np.floor((hi - self.lo) / cell) + 1.0) > _MAX_CELLS:
            cell *= 1.5
        self.cell = cell
        self.dims = (np.floor((hi - self.lo) / cell) + 1).astype(np.int64)
        self.start, self.entries = _bin_spheres(c, r, self.lo, cell, self.dims)

    def first_collision(self, points_W: np.ndarray, start_waypoint: int = 0) -> int:
        """The first waypoint >= start_waypoint whose spheres contain one of points_W (M, 3), or -1."""
        p = np.ascontiguousarray(np.asarray(points_W, dtype=float).reshape(-1, 3))
        if p.shape[0] == 0 or self.entries.shape[0] == 0:
            return -1
        return int(
            _query_points(p, self.centers, self.radii, self.lo, self.cell, self.dims, self.start, self.entries, int(start_waypoint))
        )


def first_colliding_waypoint_reference(
    points_W: np.ndarray, sphere_centers_W: np.ndarray, sphere_radii: np.ndarray, margin: float = 0.0
) -> int:
    """A straightforward SciPy reference: a k-d tree over the points, one ball query per sphere."""
    p = np.asarray(points_W, dtype=float).reshape(-1, 3)
    if p.shape[0] == 0:
        return -1
    tree = cKDTree(p)
    r = np.asarray(sphere_radii, dtype=float) + margin
    for i, centers in enumerate(np.asarray(sphere_centers_W, dtype=float)):
        for center, radius in zip(centers, r):
            if tree.query_ball_point(center, radius, return_length=True) > 0:
                return i
    return -1


@numba.njit(cache=True)
def _first_hit(points, centers, radii, lo, cell, dims):
    nx, ny, nz = dims[0], dims[1], dims[2]
    ncell = nx * ny * nz
    m = points.shape[0]
    cell_of = np.full(m, -1, dtype=np.int64)
    counts = np.zeros(ncell + 1, dtype=np.int64)
    inv = 1.0 / cell
    for i in range(m):
        ix = int(np.floor((points[i, 0] - lo[0]) * inv))
        iy = int(np.floor((points[i, 1] - lo[1]) * inv))
        iz = int(np.floor((points[i, 2] - lo[2]) * inv))
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            continue
        k = (ix * ny + iy) * nz + iz
        cell_of[i] = k
        counts[k + 1] += 1
    for k in range(ncell):
        counts[k + 1] += counts[k]
    if counts[ncell] == 0:
        return -1
    fill = counts[:-1].copy()
    order = np.empty(counts[ncell], dtype=np.int64)
    for i in range(m):
        k = cell_of[i]
        if k >= 0:
            order[fill[k]] = i
            fill[k] += 1
    n_way = centers.shape[0]
    n_sph = centers.shape[1]
    for w in range(n_way):
        for s in range(n_sph):
            cx, cy, cz, r = centers[w, s, 0], centers[w, s, 1], centers[w, s, 2], radii[s]
            r2 = r * r
            x0 = max(int(np.floor((cx - r - lo[0]) * inv)), 0)
            x1 = min(int(np.floor((cx + r - lo[0]) * inv)), nx - 1)
            y0 = max(int(np.floor((cy - r - lo[1]) * inv)), 0)
            y1 = min(int(np.floor((cy + r - lo[1]) * inv)), ny - 1)
            z0 = max(int(np.floor((cz - r - lo[2]) * inv)), 0)
            z1 = min(int(np.floor((cz + r - lo[2]) * inv)), nz - 1)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    for iz in range(z0, z1 + 1):
                        k = (ix * ny + iy) * nz + iz
                        for j in range(counts[k], counts[k + 1]):
                            q = order[j]
                            dx = points[q, 0] - cx
                            dy = points[q, 1] - cy
                            dz = points[q, 2] - cz
                            if dx * dx + dy * dy + dz * dz <= r2:
                                return w
    return -1


@numba.njit(cache=True)
def _sphere_cells(center, r, lo, inv, dims):
    x0 = max(int(np.floor((center[0] - r - lo[0]) * inv)), 0)
    x1 = min(int(np.floor((center[0] + r - lo[0]) * inv)), dims[0] - 1)
    y0 = max(int(np.floor((center[1] - r - lo[1]) * inv)), 0)
    y1 = min(int(np.floor((center[1] + r - lo[1]) * inv)), dims[1] - 1)
    z0 = max(int(np.floor((center[2] - r - lo[2]) * inv)), 0)
    z1 = min(int(np.floor((center[2] + r - lo[2]) * inv)), dims[2] - 1)
    return x0, x1, y0, y1, z0, z1


@numba.njit(cache=True)
def _bin_spheres(centers, radii, lo, cell, dims):
    """CSR (start (cells+1,), entries = waypoint * S + sphere) of the cells each sphere's box overlaps."""
    ny, nz = dims[1], dims[2]
    n_way, n_sph = centers.shape[0], centers.shape[1]
    inv = 1.0 / cell
    n_cells = dims[0] * ny * nz
    counts = np.zeros(n_cells + 1, dtype=np.int64)
    for w in range(n_way):
        for s in range(n_sph):
            x0, x1, y0, y1, z0, z1 = _sphere_cells(centers[w, s], radii[s], lo, inv, dims)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    for iz in range(z0, z1 + 1):
                        counts[(ix * ny + iy) * nz + iz + 1] += 1
    for k in range(n_cells):
        counts[k + 1] += counts[k]
    fill = counts[:-1].copy()
    entries = np.empty(counts[n_cells], dtype=np.int64)
    for w in range(n_way):  # waypoint-major, so each cell's entries are sorted by waypoint
        for s in range(n_sph):
            x0, x1, y0, y1, z0, z1 = _sphere_cells(centers[w, s], radii[s], lo, inv, dims)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    for iz in range(z0, z1 + 1):
                        k = (ix * ny + iy) * nz + iz
                        entries[fill[k]] = w * n_sph + s
                        fill[k] += 1
    return counts, entries


@numba.njit(cache=True)
def _query_points(points, centers, radii, lo, cell, dims, start, entries, first_waypoint):
    nx, ny, nz = dims[0], dims[1], dims[2]
    n_sph = centers.shape[1]
    inv = 1.0 / cell
    best = -1
    for i in range(points.shape[0]):
        fx = (points[i, 0] - lo[0]) * inv
        fy = (points[i, 1] - lo[1]) * inv
        fz = (points[i, 2] - lo[2]) * inv
        if fx < 0.0 or fy < 0.0 or fz < 0.0 or fx >= nx or fy >= ny or fz >= nz:
            continue
        k = (int(fx) * ny + int(fy)) * nz + int(fz)
        for j in range(start[k], start[k + 1]):
            e = entries[j]
            w = e // n_sph
            if w < first_waypoint:
                continue
            if best >= 0 and w >= best:
                break  # entries are sorted by waypoint
            s = e - w * n_sph
            dx = points[i, 0] - centers[w, s, 0]
            dy = points[i, 1] - centers[w, s, 1]
            dz = points[i, 2] - centers[w, s, 2]
            if dx * dx + dy * dy + dz * dz <= radii[s] * radii[s]:
                best = w
                break
    return best
