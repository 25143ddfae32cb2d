"""The ray-cast map M_t: a bounded world-frame point cloud with a voxel index.

Each depth observation updates the map in the paper's order (appendix
"Dynamic Environment Mapping"):

1. back-projection (`depth_points`): depth 0.2-3.0 m, 2.5 m crop sphere;
2. ground removal: new points with z < `ground_height` are dropped;
3. robot self-filtering: new points inside any robot sphere (radius +
   `self_filter_margin`) at the current configuration are dropped;
4. free-space carving: every map point that projects into the image and lies
   more than `carve_tolerance` (delta) in front of the measured depth is
   removed; points on or behind the surface (occluded) are kept;
5. voxel merge: a new point is added only if its voxel (edge `voxel_size`) is
   empty, so a voxel holds at most one point and the map stays bounded.

Carving details (choices not fixed by the paper):
* The measured depth used for a map point is the minimum over a
  (2 `carve_footprint_px` + 1)^2 pixel window, so a point on a silhouette edge
  is not carved because it rounds onto a background pixel.
* A pixel without a return (NaN, 0 = too close) carries no information and
  carves nothing; +inf ("too far" in Drake's RgbdSensor) means the ray is free
  up to the sensor's range, so it carves points up to `depth.depth_max`.
* Only map points with camera depth in [depth_min, depth_max] are carved: the
  map trusts the sensor only where it trusts it to add points.

The voxel index doubles as the planner-facing occupancy representation:
`occupied_voxels` (integer voxel coordinates) and `occupancy_grid` (a dense
bool grid with origin and resolution), always in step with the points.
"""


import dataclasses as dc
import functools
import logging

import numba
import numpy as np

from vamg_drake.perception.depth_points import DepthBackProjector, DepthToPointsConfig, validate_pose
from vamg_drake.robot.head_camera import CameraIntrinsics

_log = logging.getLogger(__name__)

#: Voxel coordinates are packed into one int64 key with 21 bits per axis.
_KEY_BITS = 21
_KEY_OFFSET = 1 << (_KEY_BITS - 1)
_KEY_MASK = (1 << _KEY_BITS) - 1
_EMPTY = np.int64(-1)


@dc.dataclass
class RayCastMapConfig:
    """Parameters of the ray-cast map (paper values unless noted)."""

    depth: DepthToPointsConfig = dc.field(default_factory=DepthToPointsConfig)
    #: New points below this height [m] are floor. The paper uses 0.3 m, which
    #: also hides low obstacles (chair legs, boxes on the floor); with exact
    #: simulated depth 0.05 m removes the floor and keeps them (see
    #: benchmarks/bench_perception.py, "ground_tradeoff").
    ground_height: float = 0.05
    #: Extra radius [m] added to every robot sphere when self-filtering.
    self_filter_margin: float = 0.03
    #: delta [m]: a point more than this in front of the measured depth is free space.
    carve_tolerance: float = 0.03
    #: Half-width [px] of the min-depth window used for carving (0 = single pixel).
    carve_footprint_px: int = 1
    #: Whether +inf pixels (no return within the sensor range) carve up to depth_max.
    carve_no_return: bool = True
    #: Voxel edge [m] of the merge grid; a voxel holds at most one point.
    voxel_size: float = 0.03
    #: Hard cap on the number of points; further new points are dropped (logged).
    max_points: int = 2_000_000

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the first bad field (yaml_load_typed skips __post_init__)."""
        self.depth.validate()
        if not self.voxel_size > 0.0:
            raise ValueError(f"RayCastMapConfig.voxel_size must be positive, got {self.voxel_size}")
        if not self.carve_tolerance >= 0.0:
            raise ValueError(f"RayCastMapConfig.carve_tolerance must be >= 0, got {self.carve_tolerance}")
        if not self.self_filter_margin >= 0.0:
            raise ValueError(f"RayCastMapConfig.self_filter_margin must be >= 0, got {self.self_filter_margin}")
        if self.carve_footprint_px < 0:
            raise ValueError(f"RayCastMapConfig.carve_footprint_px must be >= 0, got {self.carve_footprint_px}")
        if self.max_points <= 0:
            raise ValueError(f"RayCastMapConfig.max_points must be positive, got {self.max_points}")


@dc.dataclass(frozen=True)
class MapUpdateStats:
    """What one `PointMap.update` did. `ok` is False when the input was rejected."""

    ok: bool
    num_observed: int = 0
    num_ground: int = 0
    num_self: int = 0
    num_carved: int = 0
    num_added: int = 0
    num_points: int = 0
    message: str = ""


@dc.dataclass(frozen=True, eq=False)
class VoxelOccupancy:
    """A dense occupancy grid: cell (i, j, k) covers origin + voxel_size * [i, i+1) x ...

    Attributes:
        origin: (3,) world position of the grid's lower corner.
        voxel_size: cell edge [m].
        occupied: (nx, ny, nz) bool, read-only.
    """

    origin: np.ndarray
    voxel_size: float
    occupied: np.ndarray


@dc.dataclass(frozen=True, eq=False)
class PointMapSnapshot:
    """An immutable copy of the map, the value of the map output port.

    Attributes:
        points: (n, 3) world points p_WP, read-only.
        voxel_keys: (n,) int64 packed voxel keys of the points (see `voxel_indices`), read-only.
        voxel_size: voxel edge [m].
        revision: incremented by every update that changed the map.
    """

    points: np.ndarray
    voxel_keys: np.ndarray
    voxel_size: float
    revision: int

    @staticmethod
    def empty(voxel_size: float = RayCastMapConfig.voxel_size) -> "PointMapSnapshot":
        """A map without points (revision 0), the model value of map ports."""
        points, keys = np.empty((0, 3)), np.empty(0, dtype=np.int64)
        points.flags.writeable = False
        keys.flags.writeable = False
        return PointMapSnapshot(points, keys, voxel_size, 0)

    def __deepcopy__(self, memo) -> "PointMapSnapshot":
        return self  # immutable: the Context's copies of the map state share it

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])

    @functools.cached_property
    def voxel_indices(self) -> np.ndarray:
        """(n, 3) int64 voxel coordinates floor(p / voxel_size) of the points (decoded on first use)."""
        idx = _decode_keys(self.voxel_keys)
        idx.flags.writeable = False
        return idx


class PointMap:
    """The ray-cast map core: NumPy in, NumPy out, no Drake systems."""

    def __init__(self, intrinsics: CameraIntrinsics, config: RayCastMapConfig | None = None):
        self.config = config or RayCastMapConfig()
        self.config.validate()
        self.intrinsics = intrinsics
        self._projector = DepthBackProjector(intrinsics, self.config.depth)
        # Points live in the first `_n` rows of capacity-doubling buffers; the
        # open-addressing table maps voxel key -> row.
        self._buf_points = np.empty((1024, 3))
        self._buf_keys = np.empty(1024, dtype=np.int64)
        self._n = 0
        self._table_keys = np.full(1024, _EMPTY, dtype=np.int64)
        self._table_index = np.full(1024, -1, dtype=np.int64)
        self.revision = 0
        self._warned_full = False

    # ---- read access -------------------------------------------------------------
    @property
    def num_points(self) -> int:
        return self._n

    @property
    def _points(self) -> np.ndarray:
        return self._buf_points[: self._n]

    @property
    def _keys(self) -> np.ndarray:
        return self._buf_keys[: self._n]

    @property
    def points(self) -> np.ndarray:
        """(n, 3) world points (a read-only view, valid until the next update; copy to keep).

        Points added by the last update are the last `MapUpdateStats.num_added` rows.
        """
        view = self._points.view()
        view.flags.writeable = False
        return view

    def occupied_voxels(self) -> np.ndarray:
        """(n, 3) int64 voxel coordinates of the occupied voxels (row i holds point i)."""
        return _decode_keys(self._keys)

    def occupancy_grid(self, lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> VoxelOccupancy:
        """A dense bool grid of the occupied voxels inside [lower, upper] (default: the map's bounds)."""
        s = self.config.voxel_size
        idx = self.occupied_voxels()
        if lower is None or upper is None:
            if idx.shape[0] == 0:
                raise ValueError("occupancy_grid: the map is empty; pass lower and upper bounds")
            lo, hi = idx.min(axis=0), idx.max(axis=0)
        else:
            lo = np.floor(np.asarray(lower, dtype=float) / s).astype(np.int64)
            hi = np.floor(np.asarray(upper, dtype=float) / s).astype(np.int64)
            if np.any(hi < lo):
                raise ValueError(f"occupancy_grid: upper {upper} is below lower {lower}")
        shape = tuple((hi - lo + 1).tolist())
        grid = np.zeros(shape, dtype=bool)
        inside = np.all((idx >= lo) & (idx <= hi), axis=1)
        rel = idx[inside] - lo
        grid[rel[:, 0], rel[:, 1], rel[:, 2]] = True
        grid.flags.writeable = False
        return VoxelOccupancy(origin=lo * s, voxel_size=s, occupied=grid)

    def snapshot(self) -> PointMapSnapshot:
        """An immutable copy for output ports and other consumers."""
        pts = self._points.copy()
        keys = self._keys.copy()
        pts.flags.writeable = False
        keys.flags.writeable = False
        return PointMapSnapshot(points=pts, voxel_keys=keys, voxel_size=self.config.voxel_size, revision=self.revision)

    def contains_voxel_of(self, p_W: np.ndarray) -> np.ndarray:
        """(M,) True where the voxel of each point p_W (M, 3) holds a map point."""
        p = np.atleast_2d(np.asarray(p_W, dtype=float))
        keys = _encode_points(p, 1.0 / self.config.voxel_size)
        return _lookup_many(self._table_keys, self._table_index, keys) >= 0

    # ---- updates -----------------------------------------------------------------
    def clear(self) -> None:
        """Forgets every point."""
        self._n = 0
        self._table_keys[:] = _EMPTY
        self.revision += 1

    def add_points(self, p_W: np.ndarray) -> int:
        """Voxel-merges world points (M, 3) into the map without carving; returns the number added.

        Non-finite rows are skipped. Used for priors and tests; observations go through `update`.
        """
        p = np.asarray(p_W, dtype=float).reshape(-1, 3)
        p = np.ascontiguousarray(p[np.all(np.isfinite(p), axis=1)])
        n_before = self.num_points
        self._merge(p)
        if self.num_points != n_before:
            self.revision += 1
        return self.num_points - n_before

    def update(
        self,
        depth: np.ndarray,
        X_WC: np.ndarray,
        robot_sphere_centers_W: np.ndarray | None = None,
        robot_sphere_radii: np.ndarray | None = None,
    ) -> MapUpdateStats:
        """Integrates one depth image taken from camera pose X_WC.

        Args:
            depth: (H, W) or (H, W, 1) depth [m] along the optical axis.
            X_WC: (4, 4) pose of the camera optical frame C in the world W.
            robot_sphere_centers_W: (S, 3) robot sphere centres at the current
                configuration (self-filter); None disables self-filtering.
            robot_sphere_radii: (S,) sphere radii.

        Returns:
            MapUpdateStats. Bad input (wrong shapes, a non-finite or non-rigid pose,
            non-finite spheres) is logged and leaves the map unchanged (ok=False).
        """
        try:
            d = self._projector.check_depth(depth)
            X = validate_pose(X_WC, "camera pose X_WC")
            centers, radii = _check_spheres(robot_sphere_centers_W, robot_sphere_radii)
        except ValueError as e:
            _log.error("RayCastMap: observation rejected, map unchanged: %s", e)
            return MapUpdateStats(ok=False, num_points=self.num_points, message=str(e))

        c = self.config
        new_W = self._projector.points_W(d, X)
        n_obs = new_W.shape[0]
        if n_obs == 0 and not np.any(np.isposinf(d)):
            msg = "depth image has no valid pixel in range; nothing to add or carve"
            _log.warning("RayCastMap: %s", msg)
            return MapUpdateStats(ok=True, num_points=self.num_points, message=msg)

        # 2-3. Ground removal and self-filtering of the new points.
        above = new_W[:, 2] >= c.ground_height
        n_ground = int(n_obs - above.sum())
        new_W = new_W[above]
        n_self = 0
        if centers.shape[0] and new_W.shape[0]:
            robot = inside_any_sphere(new_W, centers, radii + c.self_filter_margin)
            n_self = int(robot.sum())
            new_W = new_W[~robot]

        # 4. Carve the existing map with this image.
        n_carved = 0
        if self.num_points:
            keep = points_not_seen_through(self._points, d, X, self.intrinsics, c.carve_tolerance,
                                           c.carve_footprint_px, c.carve_no_return, c.depth)
            removed = np.flatnonzero(~keep)
            n_carved = int(removed.size)
            if n_carved:
                self._n = _remove_rows(
                    self._table_keys, self._table_index, self._buf_points, self._buf_keys, self._n, removed
                )

        # 5. Voxel merge.
        n_before = self.num_points
        self._merge(np.ascontiguousarray(new_W))
        n_added = self.num_points - n_before
        if n_added or n_carved:
            self.revision += 1
        return MapUpdateStats(
            ok=True, num_observed=n_obs, num_ground=n_ground, num_self=n_self,
            num_carved=n_carved, num_added=n_added, num_points=self.num_points,
        )

    # ---- internals ---------------------------------------------------------------
    def _merge(self, p_W: np.ndarray) -> None:
        if p_W.shape[0] == 0:
            return
        keys = _encode_points(p_W, 1.0 / self.config.voxel_size)
        room = max(self.config.max_points - self._n, 0)
        n_total = self._n + min(p_W.shape[0], room)
        if n_total > self._buf_points.shape[0]:
            cap = self._buf_points.shape[0]
            while cap < n_total:
                cap *= 2
            cap = min(cap, self.config.max_points)
            points, keys_buf = np.empty((cap, 3)), np.empty(cap, dtype=np.int64)
            points[: self._n], keys_buf[: self._n] = self._points, self._keys
            self._buf_points, self._buf_keys = points, keys_buf
        if _table_capacity(n_total) > self._table_keys.shape[0]:
            cap = _table_capacity(n_total)
            self._table_keys = np.full(cap, _EMPTY, dtype=np.int64)
            self._table_index = np.full(cap, -1, dtype=np.int64)
            _table_insert_all(self._table_keys, self._table_index, self._keys)
        self._n, dropped = _merge_new(
            self._table_keys, self._table_index, self._buf_points, self._buf_keys, self._n, n_total, p_W, keys
        )
        if dropped and not self._warned_full:
            _log.warning(
                "RayCastMap: max_points=%d reached; %d new points dropped (further drops not logged)",
                self.config.max_points, dropped,
            )
            self._warned_full = True


def _check_spheres(centers, radii) -> tuple[np.ndarray, np.ndarray]:
    if centers is None:
        return np.empty((0, 3)), np.empty(0)
    c = np.ascontiguousarray(np.asarray(centers, dtype=float).reshape(-1, 3))
    r = np.ascontiguousarray(np.asarray(radii, dtype=float).reshape(-1))
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"robot spheres: {c.shape[0]} centres but {r.shape[0]} radii")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
        raise ValueError("robot spheres contain NaN or inf (robot configuration invalid?)")
    return c, r


def _table_capacity(n: int) -> int:
    cap = 1024
    while cap < 2 * n:
        cap *= 2
    return cap


def points_not_seen_through(points_W: np.ndarray, depth: np.ndarray, X_WC: np.ndarray, intrinsics: CameraIntrinsics,
                            tolerance: float, footprint_px: int, carve_no_return: bool,
                            depth_config: DepthToPointsConfig) -> np.ndarray:
    """(N,) bool: the points that this depth image does not see through.

    A point is seen through (free space now) when it projects into the image
    within the depth range and lies more than `tolerance` in front of the
    measured depth, taken as the minimum over a window of `footprint_px`
    pixels around it (so that a silhouette's edge does not carve the object);
    unknown pixels carve nothing, and no-return pixels carve up to the range's
    end when `carve_no_return`. Points outside the image, or behind what it
    sees, are kept."""
    z_meas = _carving_depth(depth, footprint_px, carve_no_return)
    X_CW = np.linalg.inv(X_WC)
    i = intrinsics
    return _carve_keep_mask(np.ascontiguousarray(points_W, dtype=float), X_CW, z_meas, i.fx, i.fy, i.cx, i.cy,
                            float(tolerance), float(depth_config.depth_min), float(depth_config.depth_max))


def _carving_depth(depth: np.ndarray, footprint: int, carve_no_return: bool) -> np.ndarray:
    """Per-pixel depth used for carving: unknown (NaN, <= 0) -> 0 (carves nothing), window minimum."""
    return _carving_depth_kernel(depth, footprint, carve_no_return)


@numba.njit(cache=True)
def _carving_depth_kernel(depth, r, carve_no_return):
    h, w = depth.shape
    z = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            d = depth[v, u]
            if not d > 0.0 or (not carve_no_return and d == np.inf):
                z[v, u] = 0.0
            else:
                z[v, u] = d
    if r == 0:
        return z
    tmp = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            m = z[v, u]
            for k in range(max(0, u - r), min(w, u + r + 1)):
                m = min(m, z[v, k])
            tmp[v, u] = m
    out = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            m = tmp[v, u]
            for k in range(max(0, v - r), min(h, v + r + 1)):
                m = min(m, tmp[k, u])
            out[v, u] = m
    return out


@numba.njit(cache=True)
def _carve_keep_mask(points, X_CW, z_meas, fx, fy, cx, cy, delta, depth_min, depth_max):
    n = points.shape[0]
    h, w = z_meas.shape
    keep = np.ones(n, dtype=np.bool_)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        z = X_CW[2, 0] * px + X_CW[2, 1] * py + X_CW[2, 2] * pz + X_CW[2, 3]
        if z < depth_min or z > depth_max:
            continue
        x = X_CW[0, 0] * px + X_CW[0, 1] * py + X_CW[0, 2] * pz + X_CW[0, 3]
        y = X_CW[1, 0] * px + X_CW[1, 1] * py + X_CW[1, 2] * pz + X_CW[1, 3]
        u = int(np.floor(fx * x / z + cx + 0.5))
        v = int(np.floor(fy * y / z + cy + 0.5))
        if u < 0 or u >= w or v < 0 or v >= h:
            continue
        if z < z_meas[v, u] - delta:
            keep[i] = False
    return keep


@numba.njit(cache=True)
def inside_any_sphere(points, centers, radii):
    """(N,) bool: whether each point (N, 3) lies in any sphere (S, 3), radii (S,)
    (boundary included), with a bounding-box early out per point."""
    n = points.shape[0]
    s = centers.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        lo[k] = np.min(centers[:, k] - radii)
        hi[k] = np.max(centers[:, k] + radii)
    r2 = radii * radii
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
            continue
        for j in range(s):
            dx = x - centers[j, 0]
            dy = y - centers[j, 1]
            dz = z - centers[j, 2]
            if dx * dx + dy * dy + dz * dz <= r2[j]:
                out[i] = True
                break
    return out


@numba.njit(cache=True)
def _encode_points(points, inv_size):
    n = points.shape[0]
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        key = np.int64(0)
        for k in range(3):
            c = np.int64(np.floor(points[i, k] * inv_size)) + _KEY_OFFSET
            if c < 0:
                c = 0
            elif c > _KEY_MASK:
                c = _KEY_MASK
            key = (key << _KEY_BITS) | c
        keys[i] = key
    return keys


@numba.njit(cache=True)
def _decode_keys(keys):
    n = keys.shape[0]
    out = np.empty((n, 3), dtype=np.int64)
    for i in range(n):
        key = keys[i]
        for k in range(2, -1, -1):
            out[i, k] = (key & _KEY_MASK) - _KEY_OFFSET
            key = key >> _KEY_BITS
    return out


@numba.njit(cache=True, inline="always")
def _slot(key, mask):
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64((h >> np.uint64(29)) & np.uint64(mask))


@numba.njit(cache=True)
def _table_insert_all(table_keys, table_index, keys):
    mask = table_keys.shape[0] - 1
    for i in range(keys.shape[0]):
        s = _slot(keys[i], mask)
        while table_keys[s] != -1:
            s = (s + 1) & mask
        table_keys[s] = keys[i]
        table_index[s] = i


@numba.njit(cache=True)
def _lookup_many(table_keys, table_index, keys):
    mask = table_keys.shape[0] - 1
    out = np.full(keys.shape[0], -1, dtype=np.int64)
    for i in range(keys.shape[0]):
        s = _slot(keys[i], mask)
        while table_keys[s] != -1:
            if table_keys[s] == keys[i]:
                out[i] = table_index[s]
                break
            s = (s + 1) & mask
    return out


@numba.njit(cache=True)
def _merge_new(table_keys, table_index, points, all_keys, n, cap, new_points, new_keys):
    """Appends each new point whose voxel is empty (up to `cap` rows); returns (count, dropped)."""
    mask = table_keys.shape[0] - 1
    dropped = 0
    for i in range(new_keys.shape[0]):
        key = new_keys[i]
        s = _slot(key, mask)
        found = False
        while table_keys[s] != -1:
            if table_keys[s] == key:
                found = True
                break
            s = (s + 1) & mask
        if found:
            continue
        if n >= cap:
            dropped += 1
            continue
        table_keys[s] = key
        table_index[s] = n
        points[n, 0] = new_points[i, 0]
        points[n, 1] = new_points[i, 1]
        points[n, 2] = new_points[i, 2]
        all_keys[n] = key
        n += 1
    return n, dropped


@numba.njit(cache=True)
def _table_delete(table_keys, table_index, key):
    """Removes `key` (backward-shift deletion keeps linear probing tombstone-free)."""
    mask = table_keys.shape[0] - 1
    s = _slot(key, mask)
    while table_keys[s] != key:
        if table_keys[s] == -1:
            return
        s = (s + 1) & mask
    j = s
    while True:
        j = (j + 1) & mask
        if table_keys[j] == -1:
            break
        home = _slot(table_keys[j], mask)
        # Leave entry j where it is if its home lies cyclically in (s, j].
        if s <= j:
            if s < home <= j:
                continue
        elif home > s or home <= j:
            continue
        table_keys[s] = table_keys[j]
        table_index[s] = table_index[j]
        s = j
    table_keys[s] = -1
    table_index[s] = -1


@numba.njit(cache=True)
def _set_index(table_keys, table_index, key, index):
    mask = table_keys.shape[0] - 1
    s = _slot(key, mask)
    while table_keys[s] != key:
        s = (s + 1) & mask
    table_index[s] = index


@numba.njit(cache=True)
def _remove_rows(table_keys, table_index, points, keys, n, removed):
    """Deletes rows `removed` (ascending) by moving the last rows into the holes; returns the new count."""
    for r in range(removed.shape[0] - 1, -1, -1):
        row = removed[r]
        _table_delete(table_keys, table_index, keys[row])
        last = n - 1
        if row != last:
            points[row, 0] = points[last, 0]
            points[row, 1] = points[last, 1]
            points[row, 2] = points[last, 2]
            keys[row] = keys[last]
            _set_index(table_keys, table_index, keys[row], row)
        n -= 1
    return n
