"""Which floor cells the head camera has seen, and the look-before-you-leave rule.

The ray-cast map only holds surfaces the camera has seen, so space it has not
seen looks free to the planner. Low furniture beside the start (a cabinet top
below the level head's view) is then driven into. The `SeenGrid` records, per
floor cell, when the camera first saw through it; the rule
`unseen_footprint` lists the cells the base footprint will cover on the next
stretch of its path that have not been seen yet, and the tracker does not
drive there until they have been (the gaze looks at them meanwhile).

A cell is seen when the ray from the camera to its probe point (the cell
centre at `probe_height`) reached the point: the probe lies in the image,
within the map's depth range and crop radius, and the measured depth at its
pixel is no shorter than the probe's depth minus `depth_tolerance` (or the
pixel has no return, +inf). An obstacle lower than the probe is met by the
same ray just past it and enters the map. A ray stopped farther than
`surface_radius` from the cell leaves it unseen (something in front hides
it); cells under the robot's base count as seen (it stands there).

A ray stopped on a surface within `surface_radius` of the cell (not the robot
itself) makes the cell seen but *hidden*: something stands over it whose
underside the head has not seen, e.g. a low cabinet whose top it sees from
above and whose sides are below the base's view. The map then holds only the
top, which the base's spheres pass under. The ring around the base that the
base and the stowed arm hide from the head (`robot_radius` to `ring_radius`)
is hidden where an obstacle is seen reaching it. `with_hidden_cells` adds
points in the hidden cells' columns to the planner's map until a ray reaches
their probes.
"""


import dataclasses as dc
import math

import numba
import numpy as np

from vamg_drake.perception.raycast_map import PointMapSnapshot, _encode_points, inside_any_sphere
from vamg_drake.robot.head_camera import CameraIntrinsics


@dc.dataclass
class SeenSpaceConfig:
    """Parameters of the seen-floor grid."""

    #: Cell edge [m].
    resolution: float = 0.05
    #: The grid covers a square of this half-width around its centre (the robot's start) [m];
    #: cells outside it count as seen.
    half_extent: float = 12.0
    #: Height of each cell's probe point [m]: below low furniture's tops, and high enough
    #: for the head's rays to it to clear the base's top edge (0.38 m) close to the base.
    probe_height: float = 0.25
    #: A probe counts as reached when the measured depth is at least its depth minus this [m].
    depth_tolerance: float = 0.05
    #: A ray stopped on a surface this close (horizontally) to the cell's centre sees the cell [m].
    surface_radius: float = 0.15
    #: Hits closer than this to the robot's base centre are on the robot itself, and the
    #: cells this close are seen (the robot stands on them) [m].
    robot_radius: float = 0.32
    #: Extra radius [m] of the robot's spheres when telling its own hits from obstacles.
    self_filter_margin: float = 0.03
    #: The ring from `robot_radius` to this around the base is hidden from the head by the
    #: base (and the stowed arm); its cells within `extend_radius` of an obstacle hit lower
    #: than `ring_max_height` are hidden cells (the obstacle may continue into the ring) [m].
    ring_radius: float = 0.45
    extend_radius: float = 0.15
    ring_max_height: float = 0.7
    #: Heights of the points `with_hidden_cells` adds in each hidden cell's column [m]
    #: (below the top of the base's spheres, 0.58 m).
    hidden_heights: list[float] = dc.field(default_factory=lambda: [0.1, 0.25, 0.4])
    #: The map's depth range and crop radius (what is not put into the map is not seen) [m].
    depth_min: float = 0.2
    depth_max: float = 3.0
    crop_radius: float = 2.5

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the first bad field."""
        if not (self.resolution > 0.0 and self.half_extent > self.resolution):
            raise ValueError("SeenSpaceConfig: need resolution > 0 and half_extent > resolution")
        if not 0.0 <= self.depth_min < self.depth_max:
            raise ValueError("SeenSpaceConfig: need 0 <= depth_min < depth_max")
        if not (self.crop_radius > 0.0 and self.depth_tolerance >= 0.0):
            raise ValueError("SeenSpaceConfig: need crop_radius > 0 and depth_tolerance >= 0")
        if not (self.surface_radius >= 0.0 and self.robot_radius >= 0.0 and self.extend_radius >= 0.0):
            raise ValueError("SeenSpaceConfig: need surface_radius, robot_radius and extend_radius >= 0")
        if not self.ring_radius >= self.robot_radius:
            raise ValueError("SeenSpaceConfig: need ring_radius >= robot_radius")
        if not all(math.isfinite(h) and h >= 0.0 for h in self.hidden_heights):
            raise ValueError(f"SeenSpaceConfig.hidden_heights must be finite and >= 0, got {self.hidden_heights}")


@dc.dataclass
class LookGateConfig:
    """The look-before-you-leave rule of the tracker.

    Attributes:
        enabled: hold the robot while the base would enter unseen cells.
        lookahead_distance: the stretch of base travel ahead that must be seen [m] ...
        max_turn: ... up to where the path's heading has turned this far from the
            robot's: a turn in place sweeps only the robot's own footprint, and
            the path after it lies ahead (and in view) once the robot has turned [rad].
        footprint_radius: radius of the base footprint (sphere model 0.30 m + margin) [m].
        blind_radius: cells this close to the base centre are not waited for: the base
            and the stowed arm hide the ring around the base from the head (an obstacle
            seen reaching into it makes its cells hidden, `SeenSpaceConfig.ring_radius`) [m].
        max_bearing: cells farther than this from the base heading are not waited for
            (the head, pan limits +-1.57 rad, cannot see behind the robot) [rad].
        settle_time: a cell counts as seen this long after it was first seen, so the
            map and the motion layer's re-check have had the image first [s].
        max_wait: the most the robot waits per trajectory (a cell may stay occluded) [s].
    """

    enabled: bool = True
    lookahead_distance: float = 0.8
    max_turn: float = 0.6
    footprint_radius: float = 0.35
    blind_radius: float = 0.45
    max_bearing: float = 1.75
    settle_time: float = 0.25
    max_wait: float = 2.0

    def validate(self) -> None:
        """Raises ValueError naming the first bad field."""
        for name in ("lookahead_distance", "max_turn", "footprint_radius", "blind_radius", "max_bearing",
                     "settle_time", "max_wait"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"LookGateConfig.{name} must be finite and >= 0, got {value}")


@dc.dataclass(frozen=True, eq=False)
class SeenGrid:
    """Floor cells, the time each was first seen (+inf: never) and which are hidden, immutable.

    Cell (i, j) has centre origin + (i + 0.5, j + 0.5) * resolution (x, y).
    `hidden_revision` counts the changes of the hidden set.
    """

    origin: np.ndarray
    resolution: float
    first_seen: np.ndarray  # (nx, ny) float64, +inf = unseen
    config: SeenSpaceConfig
    hidden: np.ndarray | None = None  # (nx, ny) bool; None = none hidden
    hidden_revision: int = 0

    def __post_init__(self):
        self.first_seen.flags.writeable = False
        if self.hidden is not None:
            self.hidden.flags.writeable = False

    def __deepcopy__(self, memo) -> "SeenGrid":
        return self  # immutable (`observe` returns a new grid): the Context's copies share it

    @staticmethod
    def around(center_xy: np.ndarray, config: SeenSpaceConfig | None = None) -> "SeenGrid":
        """An all-unseen grid centred on `center_xy`."""
        config = config or SeenSpaceConfig()
        n = int(math.ceil(2.0 * config.half_extent / config.resolution))
        origin = np.asarray(center_xy, float).reshape(2) - 0.5 * n * config.resolution
        return SeenGrid(origin, config.resolution, np.full((n, n), np.inf), config)

    @property
    def shape(self) -> tuple[int, int]:
        return self.first_seen.shape

    def cell_of(self, p_xy: np.ndarray) -> np.ndarray:
        """(M, 2) integer cells of points (M, 2) (may lie outside the grid)."""
        return np.floor((np.asarray(p_xy, float).reshape(-1, 2) - self.origin) / self.resolution).astype(np.int64)

    def centers(self, cells: np.ndarray) -> np.ndarray:
        """(M, 2) cell centres."""
        return self.origin + (np.asarray(cells, float) + 0.5) * self.resolution

    def seen_by(self, cells: np.ndarray, t: float) -> np.ndarray:
        """(M,) whether each cell was seen at or before time t (outside the grid: True)."""
        cells = np.asarray(cells, np.int64).reshape(-1, 2)
        inside = np.all((cells >= 0) & (cells < np.asarray(self.shape)), axis=1)
        out = np.ones(cells.shape[0], bool)
        out[inside] = self.first_seen[cells[inside, 0], cells[inside, 1]] <= t
        return out

    def observe(self, depth: np.ndarray, X_WC: np.ndarray, intrinsics: CameraIntrinsics, t: float,
                p_WB: np.ndarray | None = None,
                robot_spheres: tuple[np.ndarray, np.ndarray] | None = None) -> "SeenGrid":
        """The grid after one depth image (H, W) [m] from camera pose X_WC (4, 4) at time t.

        Args:
            p_WB: (2,) the robot's base position, or None (no robot).
            robot_spheres: the robot's sphere centres (S, 3) and radii (S,) now: hits in
                them (plus `self_filter_margin`) are the robot, not obstacles.

        Returns `self` when nothing changed.
        """
        c = self.config
        depth = np.asarray(depth, dtype=np.float32).reshape(intrinsics.height, intrinsics.width)
        X_WC = np.asarray(X_WC, float)
        p_WC = X_WC[:3, 3]
        reach = math.sqrt(max(c.crop_radius**2 - (p_WC[2] - c.probe_height) ** 2, 0.0))
        lo = np.maximum(self.cell_of(p_WC[:2] - reach)[0], 0)
        hi = np.minimum(self.cell_of(p_WC[:2] + reach)[0] + 1, np.asarray(self.shape))
        if np.any(hi <= lo):
            return self
        ii, jj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        todo = ~np.isfinite(self.first_seen[ii, jj])
        if self.hidden is not None:
            todo |= self.hidden[ii, jj]
        ii, jj = ii[todo], jj[todo]
        if ii.size == 0:
            return self
        xy = self.centers(np.column_stack([ii, jj]))
        p_W = np.column_stack([xy, np.full(ii.size, c.probe_height)])
        p_C = (p_W - p_WC) @ X_WC[:3, :3]  # R_CW (p_W - p_WC), row-wise
        z = p_C[:, 2]
        ok = (z >= c.depth_min) & (z <= c.depth_max) & (np.linalg.norm(p_W - p_WC, axis=1) <= c.crop_radius)
        u = np.full(z.shape, -1, np.int64)
        v = np.full(z.shape, -1, np.int64)
        u[ok] = np.floor(intrinsics.fx * p_C[ok, 0] / z[ok] + intrinsics.cx).astype(np.int64)
        v[ok] = np.floor(intrinsics.fy * p_C[ok, 1] / z[ok] + intrinsics.cy).astype(np.int64)
        ok &= (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
        measured = np.full(z.shape, np.nan)
        measured[ok] = depth[v[ok], u[ok]]
        with np.errstate(invalid="ignore"):
            reached = ok & (np.isposinf(measured) | (measured >= z - c.depth_tolerance))
            blocked = ok & ~reached & np.isfinite(measured) & (measured >= c.depth_min)
        d_B = None if p_WB is None else np.linalg.norm(xy - np.asarray(p_WB, float).reshape(2), axis=1)
        if d_B is not None:
            reached |= d_B <= c.robot_radius
        covered = np.zeros_like(reached)
        if np.any(blocked):
            rows = np.flatnonzero(blocked)
            hit = p_WC + (p_W[rows] - p_WC) * (measured[rows] / z[rows])[:, None]
            real = np.ones(rows.shape[0], bool)
            if p_WB is not None:
                real &= np.linalg.norm(hit[:, :2] - np.asarray(p_WB, float).reshape(2), axis=1) > c.robot_radius
            if robot_spheres is not None and real.any():
                centers, radii = robot_spheres
                real[real] = ~inside_any_sphere(np.ascontiguousarray(hit[real]), np.ascontiguousarray(centers, float),
                                                np.asarray(radii, float) + c.self_filter_margin)
            near = real & (np.linalg.norm(hit[:, :2] - xy[rows], axis=1) <= c.surface_radius)
            covered[rows[near]] = True
            # The ring around the base that the base hides from the head: an obstacle
            # seen reaching to within `extend_radius` of a ring cell may continue into it.
            low = hit[real & (hit[:, 2] <= c.ring_max_height), :2]
            if d_B is not None and low.shape[0]:
                ring = np.flatnonzero((d_B > c.robot_radius) & (d_B <= c.ring_radius) & ~reached)
                if ring.size:
                    d2 = ((xy[ring, None, :] - low[None, :, :]) ** 2).sum(axis=2).min(axis=1)
                    covered[ring[d2 <= c.extend_radius**2]] = True
        covered &= ~np.isfinite(self.first_seen[ii, jj])  # a cell once reached stays free
        hidden_now = np.zeros_like(reached) if self.hidden is None else self.hidden[ii, jj]
        newly_seen = (reached | covered) & ~np.isfinite(self.first_seen[ii, jj])
        hidden_change = (covered & ~hidden_now) | (reached & hidden_now)
        if not (np.any(newly_seen) or np.any(hidden_change)):
            return self
        first_seen = self.first_seen.copy()
        first_seen[ii[newly_seen], jj[newly_seen]] = t
        hidden, revision = self.hidden, self.hidden_revision
        if np.any(hidden_change):
            hidden = np.zeros(self.shape, bool) if hidden is None else hidden.copy()
            hidden[ii[covered], jj[covered]] = True
            hidden[ii[reached], jj[reached]] = False
            revision += 1
        return dc.replace(self, first_seen=first_seen, hidden=hidden, hidden_revision=revision)

    def hidden_points(self) -> np.ndarray:
        """(M, 3) points in the columns of the hidden cells, at `config.hidden_heights`."""
        if self.hidden is None:
            return np.empty((0, 3))
        xy = self.centers(np.argwhere(self.hidden))
        heights = np.asarray(self.config.hidden_heights, float)
        return np.column_stack([np.repeat(xy, heights.shape[0], axis=0), np.tile(heights, xy.shape[0])])


def unseen_footprint(grid: SeenGrid, path: np.ndarray, q_base: np.ndarray, t: float,
                     config: LookGateConfig) -> np.ndarray:
    """Probe points (M, 3) of the unseen cells the base will cover next.

    Args:
        grid: the seen-floor grid.
        path: (K, 3) base poses (x, y, theta) along the path from the robot's nearest point on.
        q_base: (3,) the robot's base pose (x, y, theta) now.
        t: the time now; cells first seen after t - config.settle_time do not count yet.
        config: the rule's parameters.

    The cells are those within `footprint_radius` of the path's base positions up
    to `lookahead_distance` of travel and `max_turn` of heading change, less the
    robot's own footprint now with the ring around it the head cannot see
    (`blind_radius`), and the cells more than `max_bearing` off its heading
    (the head cannot see behind the robot).
    """
    path = np.asarray(path, float).reshape(-1, 3)
    q_base = np.asarray(q_base, float).reshape(3)
    if path.shape[0] == 0:
        return np.empty((0, 3))
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1))])
    turn = np.abs((path[:, 2] - q_base[2] + np.pi) % (2.0 * np.pi) - np.pi)
    beyond = (travel > config.lookahead_distance + 1e-9) | (turn > config.max_turn)
    end = int(np.argmax(beyond)) if beyond.any() else path.shape[0]
    section = path[:max(end, 1), :2]
    r = config.footprint_radius
    lo = grid.cell_of(section.min(axis=0) - r)[0]
    hi = grid.cell_of(section.max(axis=0) + r)[0] + 1
    ii, jj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
    cells = np.column_stack([ii.ravel(), jj.ravel()])
    xy = grid.centers(cells)
    near = _within_radius_of_path(xy, np.ascontiguousarray(section), r * r)
    own = np.hypot(xy[:, 0] - q_base[0], xy[:, 1] - q_base[1])
    bearing = np.arctan2(xy[:, 1] - q_base[1], xy[:, 0] - q_base[0]) - q_base[2]
    bearing = np.abs((bearing + np.pi) % (2.0 * np.pi) - np.pi)
    wanted = near & (own > max(r, config.blind_radius)) & (bearing <= config.max_bearing)
    wanted[wanted] = ~grid.seen_by(cells[wanted], t - config.settle_time)
    return np.column_stack([xy[wanted], np.full(int(wanted.sum()), grid.config.probe_height)])


@numba.njit(cache=True)
def _within_radius_of_path(xy: np.ndarray, section: np.ndarray, r2: float) -> np.ndarray:
    """Whether each point of ``xy`` (C, 2) lies within sqrt(r2) of a point of ``section`` (K, 2).

    The squared distances are summed as NumPy's ``((a - b) ** 2).sum()`` does
    (dx*dx + dy*dy), so the verdicts equal the array expression's; the loop
    stops at the first path point close enough, without the (C, K, 2) array.
    """
    out = np.zeros(xy.shape[0], np.bool_)
    for c in range(xy.shape[0]):
        for k in range(section.shape[0]):
            dx = xy[c, 0] - section[k, 0]
            dy = xy[c, 1] - section[k, 1]
            if dx * dx + dy * dy <= r2:
                out[c] = True
                break
    return out


def with_hidden_cells(snapshot: PointMapSnapshot | None, grid: SeenGrid | None) -> PointMapSnapshot | None:
    """The map `snapshot` plus the points of the grid's hidden cells (`SeenGrid.hidden_points`).

    The revision is the sum of the map's and the hidden set's, so it changes
    whenever either does. Returns `snapshot` itself when no cell is hidden.
    """
    extra = np.empty((0, 3)) if grid is None else grid.hidden_points()
    if extra.shape[0] == 0:
        return snapshot
    if snapshot is None:
        voxel_size, points, keys, revision = grid.config.resolution, np.empty((0, 3)), np.empty(0, np.int64), 0
    else:
        voxel_size, points, keys, revision = (snapshot.voxel_size, snapshot.points, snapshot.voxel_keys,
                                              snapshot.revision)
    extra_keys = _encode_points(np.ascontiguousarray(extra), 1.0 / voxel_size)
    merged_points = np.concatenate([points, extra])
    merged_keys = np.concatenate([keys, extra_keys])
    merged_points.flags.writeable = False
    merged_keys.flags.writeable = False
    return PointMapSnapshot(merged_points, merged_keys, voxel_size, int(revision) + grid.hidden_revision)
