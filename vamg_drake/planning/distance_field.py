"""A Euclidean distance field on a voxel grid, with the points it was built from.

Built from map points (N, 3) or from a boolean occupancy grid (the map's
0.03 m voxels) by an exact separable distance transform (`edt_3d`).

Conservativeness (the bound `DistanceField.margin`): every obstacle point p
lies in an occupied cell whose centre v is within (sqrt(3)/2) h of p; a query
centre c is looked up at its nearest cell centre g, within (sqrt(3)/2) h of
c; the field stores D(g) = min_v |g - v| exactly. By the triangle inequality
    D(g) - sqrt(3) h <= |c - p| <= D(g) + sqrt(3) h,
so a sphere (c, r) is certainly free when D(g) - sqrt(3) h > r and certainly
hits an occupied cell's point when D(g) + sqrt(3) h <= r. A field built from
points (`DistanceField.from_points`, the map) keeps them, indexed by cell, and
settles the shell in between exactly: the sphere is free iff no point lies
within r of c (the obstacle set is the map's points; the motion padding covers
the surface between samples). A field built from bare occupancy (no points)
counts the whole shell as collision. Cells outside the grid are free: the grid
is padded by more than the largest sphere radius plus the bound around every
obstacle cell. For the same reason the field stores distances only up to the
pad (`DistanceField.max_distance`): a cell farther than that from every
obstacle holds +inf, which answers every test as the exact distance would,
and the transform skips the parabolas of such cells.
"""

import dataclasses
import math

import numba
import numpy as np

SQRT3 = math.sqrt(3.0)


@dataclasses.dataclass(frozen=True, eq=False)
class DistanceField:
    """Distances [m] from voxel centres to the nearest occupied voxel centre.

    Attributes:
        dist: (nx, ny, nz) float32 distance per cell.
        origin: (3,) world position of the centre of cell (0, 0, 0).
        resolution: cell size h [m].
        margin: the conservative discretization bound sqrt(3) h.
        occupancy: (nx, ny, nz) bool occupied cells.
        points: (N, 3) the obstacle points grouped by cell (empty for a field
            built from bare occupancy), for exact tests near obstacles.
        cell_keys: (M,) sorted flat indices of the cells holding points.
        cell_start: (M + 1,) points[cell_start[m]:cell_start[m + 1]] lie in
            cell cell_keys[m].
        max_distance: distances above this [m] are stored as +inf; a sphere
            test is exact while its radius plus `margin` is below it.
    """

    dist: np.ndarray
    origin: np.ndarray
    resolution: float
    margin: float
    occupancy: np.ndarray
    points: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    cell_keys: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    cell_start: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(1, np.int64))
    max_distance: float = math.inf

    @property
    def has_points(self) -> bool:
        """Whether near-obstacle tests are exact against the points."""
        return self.points.shape[0] > 0

    @property
    def num_occupied(self) -> int:
        return int(self.occupancy.sum())

    @staticmethod
    def from_occupancy(
        occupied: np.ndarray, origin: np.ndarray, resolution: float, pad: float = 0.5
    ) -> "DistanceField":
        """Builds the field from a bool grid whose cell (0,0,0) is centred at origin.

        The grid is padded by `pad` metres on each side so that spheres near the
        boundary see the obstacles; beyond the padded grid everything is free,
        and inside it distances above `pad` are +inf (`max_distance`).
        """
        occupied = np.asarray(occupied)
        if occupied.ndim != 3 or occupied.dtype != bool:
            raise ValueError(f"occupancy must be a 3D bool array, got {occupied.dtype} {occupied.shape}")
        if not resolution > 0:
            raise ValueError(f"resolution must be positive, got {resolution}")
        origin = np.asarray(origin, dtype=float).reshape(3)
        if not np.all(np.isfinite(origin)):
            raise ValueError("occupancy origin contains NaN or inf")
        n_pad = int(math.ceil(pad / resolution))
        occ = np.pad(occupied, n_pad, mode="constant", constant_values=False)
        origin = origin - n_pad * resolution
        if not occ.any():  # no obstacle: every distance is "none"
            return DistanceField(np.full(occ.shape, np.float32(1e6)), origin, float(resolution), SQRT3 * resolution, occ)
        dist = edt_3d(occ, float(resolution), max_distance=float(pad))
        return DistanceField(dist, origin, float(resolution), SQRT3 * resolution, occ, max_distance=float(pad))

    @staticmethod
    def from_points(points: np.ndarray, resolution: float = 0.03, pad: float = 0.5) -> "DistanceField":
        """Bins obstacle points (N, 3) into a grid of cell size `resolution`."""
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {points.shape}")
        finite = np.all(np.isfinite(points), axis=1)
        points = points[finite]
        if points.shape[0] == 0:
            # An empty map: a single free cell; everything is free.
            return DistanceField.from_occupancy(np.zeros((1, 1, 1), bool), np.zeros(3), resolution, pad=0.0)
        lo = np.floor(points.min(axis=0) / resolution) * resolution
        idx = np.floor((points - lo) / resolution).astype(np.int64)
        shape = idx.max(axis=0) + 1
        occ = np.zeros(shape, dtype=bool)
        occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        f = DistanceField.from_occupancy(occ, lo + 0.5 * resolution, resolution, pad)
        # Index the points by their cell of the padded grid.
        n_pad = int(round((lo[0] + 0.5 * resolution - f.origin[0]) / resolution))
        idx += n_pad
        ny, nz = f.dist.shape[1], f.dist.shape[2]
        flat = (idx[:, 0] * ny + idx[:, 1]) * nz + idx[:, 2]
        order = np.argsort(flat, kind="stable")
        flat = flat[order]
        keys, start = np.unique(flat, return_index=True)
        cell_start = np.append(start, flat.shape[0]).astype(np.int64)
        return dataclasses.replace(f, points=np.ascontiguousarray(points[order]),
                                   cell_keys=np.ascontiguousarray(keys, np.int64), cell_start=cell_start)


@numba.njit(cache=True)
def _edt_1d(f, n, d, v, z):
    """Squared distance transform of samples f[:n] (Felzenszwalb-Huttenlocher
    lower envelope of parabolas) into d[:n]; v, z are scratch."""
    k = 0
    v[0] = 0
    z[0] = -np.inf
    z[1] = np.inf
    for q in range(1, n):
        if f[q] == np.inf:
            continue
        if f[v[k]] == np.inf:
            v[k] = q
            continue
        while True:
            p = v[k]
            sp = ((f[q] + q * q) - (f[p] + p * p)) / (2.0 * q - 2.0 * p)
            if sp <= z[k]:
                k -= 1
                if k < 0:
                    k = 0
                    v[0] = q
                    z[0] = -np.inf
                    z[1] = np.inf
                    break
                continue
            k += 1
            v[k] = q
            z[k] = sp
            z[k + 1] = np.inf
            break
    k = 0
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        p = v[k]
        d[q] = (q - p) * (q - p) + f[p]


def edt_2d(occupied: np.ndarray, h: float) -> np.ndarray:
    """Euclidean distance [m] from every cell centre of a 2D bool grid to the
    nearest occupied cell centre (cell size h); inf where nothing is occupied."""
    return edt_3d(np.ascontiguousarray(occupied)[:, :, None], float(h))[:, :, 0]


def edt_3d(occupied: np.ndarray, h: float, max_distance: float = math.inf) -> np.ndarray:
    """Euclidean distance [m] from every cell centre of a 3D bool grid to the
    nearest occupied cell centre (cell size h), float32; inf where nothing is
    occupied, or nothing within `max_distance`. Exact (separable
    squared-distance transform, one pass per axis), O(cells), no index arrays:
    5.7x faster than SciPy's `distance_transform_edt` on 6M-cell room grids,
    with the same float32 distances (as measured by
    benchmarks/bench_motion_layer.py on an idle machine). The first pass reads
    the occupancy and the last writes the metric distance, so no whole-grid
    NumPy pass runs in between.

    With a finite `max_distance` every pass drops the partial squared
    distances above it (the nearest obstacle of a cell within reach is within
    reach along each axis on its own), so the later passes skip those
    samples; the distances up to `max_distance` are unchanged."""
    occupied = np.ascontiguousarray(occupied, dtype=bool)
    if occupied.ndim != 3:
        raise ValueError(f"occupancy must be a 3D bool array, got shape {occupied.shape}")
    if not max_distance > 0.0:
        raise ValueError(f"edt_3d: max_distance must be positive, got {max_distance}")
    g = np.empty(occupied.shape)
    out = np.empty(occupied.shape, dtype=np.float32)
    m = max(g.shape)
    f, d, v, z = np.empty(m), np.empty(m), np.empty(m, dtype=np.int64), np.empty(m + 1)
    # Squared distances in cells; +inf keeps every one (the test is d > cut).
    cut = (max_distance / h) ** 2 if math.isfinite(max_distance) else math.inf
    _edt_first_lines(occupied, g, f, d, v, z, cut)  # along z
    _edt_lines(g.transpose((0, 2, 1)), out.transpose((0, 2, 1)), False, float(h), f, d, v, z, cut)  # along y
    _edt_lines(g.transpose((1, 2, 0)), out.transpose((1, 2, 0)), True, float(h), f, d, v, z, cut)  # along x
    return out


@numba.njit(cache=True)
def _edt_first_lines(occ, g, f, d, v, z, cut):
    """Squared distance transform along the last axis of the bool grid occ into
    g; values above `cut` become +inf."""
    a, b, n = occ.shape
    for i in range(a):
        for j in range(b):
            for k in range(n):
                f[k] = 0.0 if occ[i, j, k] else np.inf
            _edt_1d(f, n, d, v, z)
            for k in range(n):
                g[i, j, k] = d[k] if d[k] <= cut else np.inf


@numba.njit(cache=True)
def _edt_lines(g, out, metric, h, f, d, v, z, cut):
    """Squared distance transform along the last axis of g (3D); values above
    `cut` become +inf. They go back into g, or with `metric` into out as the
    float32 distance h sqrt(.) (the last pass)."""
    a, b, n = g.shape
    for i in range(a):
        for j in range(b):
            seen = False
            for k in range(n):
                f[k] = g[i, j, k]
                seen = seen or f[k] != np.inf
            if seen:
                _edt_1d(f, n, d, v, z)
            for k in range(n):
                inside = seen and d[k] <= cut
                if metric:
                    out[i, j, k] = np.float32(math.sqrt(d[k]) * h) if inside else np.float32(np.inf)
                elif seen:  # an all-inf line stays so
                    g[i, j, k] = d[k] if inside else np.inf
