"""Procedural rooms: a seeded generator of whole scenarios.

``generate_scenario(seed, config)`` builds a rectangular or L-shaped room of
15-50 m^2 with one or two doorways, places 3-12 pieces of furniture without
overlap while keeping the floor navigable, drops YCB objects onto the support
surfaces (each accepted by the drop check, settled pose stored), picks a target
at 0.4-1.2 m that a base can approach, and a robot start in free space.

Decisions:

* Navigability is judged on a 2D grid (``grid_resolution``): a cell is a free
  base position when its distance to every wall and furniture footprint is at
  least the footprint radius plus one cell. A new piece of furniture is only
  accepted if the free base positions stay one connected region (>= 90 % of
  them in the largest component, and the doorways reachable), and every support
  surface stays approachable (a free base position within ``reach_radius``).
* The start distance is the *Euclidean* distance in the plane between the start
  and the target point, in [3, 10] m, and the start lies in the same connected
  free region as a base position within ``reach_radius`` of the target (so a
  path exists).
* Same seed, same config -> the same scenario, bit for bit: one
  ``np.random.default_rng(seed)`` drives everything, iterated in list order,
  and the drop check is a deterministic simulation. Generated numbers are
  rounded to 1e-5 so the YAML is exact and readable.
"""


import copy
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from vamg_drake.world.drop_check import DropCheckConfig, Neighbour, drop_object
from vamg_drake.world.furniture import AGAINST_WALL, footprint_size, sample_furniture
from vamg_drake.world.primitives import points_in_polygon, polygon_area, rotation_z, signed_distance_to_polygon
from vamg_drake.world.scenario import (
    ROBOT_FOOTPRINT_RADIUS,
    AppearAtDistance,
    AppearAtPhase,
    Cylinder,
    Doorway,
    Furniture,
    MoveAlongPath,
    PlacedObject,
    PlanarPose,
    Room,
    Scenario,
    SupportSurface,
    validate_scenario,
)
from vamg_drake.world.scene_geometry import SceneGeometryConfig
from vamg_drake.world.ycb import YCB_OBJECTS, load_ycb_asset

_KINDS = ("table", "counter", "shelf", "chair", "sofa", "cabinet")
_KIND_WEIGHTS = np.array([0.25, 0.15, 0.15, 0.2, 0.1, 0.15])


class GenerationError(RuntimeError):
    """The generator found no valid scenario for a seed within its attempts."""


@dataclass
class RoomGeneratorConfig:
    """Parameters of the procedural room generator.

    Attributes:
        area_range: floor area [m^2].
        min_side: shortest room side [m].
        l_shape_probability: chance of an L-shaped room.
        wall_thickness: [m].
        wall_height: [m].
        doorway_width: [m].
        max_doorways: 1 or 2 doorways are cut.
        furniture_count: pieces of furniture (inclusive range).
        area_per_furniture: at most one piece per this much floor [m^2].
        furniture_gap: minimum gap between pieces of furniture [m].
        object_count: YCB objects (inclusive range).
        min_object_separation: between object centres in the plane [m] (paper: 0.2).
        target_height_range: support height of the target [m].
        reach_radius: a free base position must exist this close (horizontally)
            to the target [m].
        start_distance_range: Euclidean start-target distance [m].
        robot_radius: base footprint radius [m].
        grid_resolution: navigability grid cell [m].
        dynamic: add the paper's dynamic events (a pedestrian on the path and a
            table-top box near the target at pre-grasp).
        moving_obstacle: add an obstacle moving at 0.2 m/s across the room.
        time_limit: episode time limit [s].
        max_room_attempts: rooms tried before giving up.
        max_drop_attempts: drops per object before giving up on it (paper: 100).
        drop_check: drop-check parameters.
        geometry: contact parameters used by the drop check.
    """

    area_range: list[float] = field(default_factory=lambda: [15.0, 50.0])
    min_side: float = 3.0
    l_shape_probability: float = 0.35
    wall_thickness: float = 0.1
    wall_height: float = 2.4
    doorway_width: float = 0.9
    max_doorways: int = 2
    furniture_count: list[int] = field(default_factory=lambda: [3, 12])
    area_per_furniture: float = 4.0
    furniture_gap: float = 0.05
    object_count: list[int] = field(default_factory=lambda: [3, 8])
    min_object_separation: float = 0.20
    target_height_range: list[float] = field(default_factory=lambda: [0.4, 1.2])
    reach_radius: float = 0.8
    start_distance_range: list[float] = field(default_factory=lambda: [3.0, 10.0])
    robot_radius: float = ROBOT_FOOTPRINT_RADIUS
    grid_resolution: float = 0.05
    dynamic: bool = False
    moving_obstacle: bool = False
    time_limit: float = 120.0
    max_room_attempts: int = 30
    max_drop_attempts: int = 100
    drop_check: DropCheckConfig = field(default_factory=DropCheckConfig)
    geometry: SceneGeometryConfig = field(default_factory=SceneGeometryConfig)


def _r(x: float) -> float:
    return round(float(x), 5)


# ------------------------------------------------------------------ grid


class FloorGrid:
    """A 2D grid over the room: blocked cells and where the base fits.

    Attributes:
        origin: (2,) xy of cell (0, 0)'s centre.
        resolution: cell size [m].
        inside: (nx, ny) cells whose centre is inside the room outline.
        occupied: (nx, ny) cells covered by furniture footprints.
    """

    def __init__(self, room: Room, resolution: float, margin: float = 0.2):
        poly = room.polygon()
        lo = poly.min(axis=0) - margin
        hi = poly.max(axis=0) + margin
        self.resolution = resolution
        self.origin = lo
        n = np.ceil((hi - lo) / resolution).astype(int) + 1
        xs = lo[0] + resolution * np.arange(n[0])
        ys = lo[1] + resolution * np.arange(n[1])
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        self.centers = np.stack([gx, gy], axis=-1)
        self.inside = points_in_polygon(self.centers.reshape(-1, 2), poly).reshape(gx.shape)
        self.occupied = np.zeros_like(self.inside)

    def cells_in_polygon(self, polygon: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """Returns a mask of cells whose centres are inside ``polygon`` grown by ``inflate``."""
        lo = polygon.min(axis=0) - inflate - self.resolution
        hi = polygon.max(axis=0) + inflate + self.resolution
        i0, j0 = np.maximum(np.floor((lo - self.origin) / self.resolution).astype(int), 0)
        i1, j1 = np.minimum(np.ceil((hi - self.origin) / self.resolution).astype(int) + 1, self.inside.shape)
        mask = np.zeros_like(self.inside)
        if i1 <= i0 or j1 <= j0:
            return mask
        pts = self.centers[i0:i1, j0:j1].reshape(-1, 2)
        hit = signed_distance_to_polygon(pts, polygon) <= inflate
        mask[i0:i1, j0:j1] = hit.reshape(i1 - i0, j1 - j0)
        return mask

    def clearance(self, occupied: np.ndarray | None = None) -> np.ndarray:
        """Distance [m] from each cell centre to the nearest blocked cell centre."""
        occupied = self.occupied if occupied is None else occupied
        free = self.inside & ~occupied
        return ndimage.distance_transform_edt(free) * self.resolution

    def base_free(self, robot_radius: float, occupied: np.ndarray | None = None) -> np.ndarray:
        """Cells where the base footprint fits, with one cell of discretization margin."""
        return self.clearance(occupied) >= robot_radius + self.resolution

    def index(self, p_xy: np.ndarray) -> tuple[int, int]:
        """Returns the cell containing ``p_xy``."""
        i, j = np.round((np.asarray(p_xy) - self.origin) / self.resolution).astype(int)
        return int(i), int(j)


def _components(free: np.ndarray) -> tuple[np.ndarray, int]:
    labels, count = ndimage.label(free, structure=np.ones((3, 3)))
    if count == 0:
        return labels, 0
    sizes = np.bincount(labels.ravel())[1:]
    return labels, int(np.argmax(sizes)) + 1


# ------------------------------------------------------------------ room


def _sample_room(rng: np.random.Generator, config: RoomGeneratorConfig) -> Room:
    area = rng.uniform(*config.area_range)
    aspect = rng.uniform(1.0, 2.0)
    l_shape = rng.uniform() < config.l_shape_probability
    if l_shape:
        fx, fy = rng.uniform(0.3, 0.5, size=2)  # cut-out fraction of the bounding box
        scale = math.sqrt(area / (aspect * (1.0 - fx * fy)))
        W, H = aspect * scale, scale
        cw, ch = fx * W, fy * H
        if min(H - ch, W - cw) < config.min_side * 0.8 or H < config.min_side:
            l_shape = False
    if not l_shape:
        H = max(math.sqrt(area / aspect), config.min_side)
        W = area / H
        outline = [[0, 0], [W, 0], [W, H], [0, H]]
    else:
        outline = [[0, 0], [W, 0], [W, H - ch], [W - cw, H - ch], [W - cw, H], [0, H]]
    outline = [[_r(x), _r(y)] for x, y in outline]
    room = Room(outline=outline, wall_thickness=config.wall_thickness, wall_height=config.wall_height)
    poly = np.asarray(outline)
    lengths = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)
    edges = [i for i in range(len(poly)) if lengths[i] >= config.doorway_width + 0.6]
    count = int(rng.integers(1, config.max_doorways + 1))
    for edge in rng.permutation(edges)[:count]:
        half = 0.5 * config.doorway_width
        center = rng.uniform(half + 0.3, lengths[edge] - half - 0.3)
        room.doorways.append(Doorway(edge=int(edge), center=_r(center), width=config.doorway_width))
    return room


def _doorway_zones(room: Room, depth: float) -> list[np.ndarray]:
    """Keep-clear rectangles just inside each doorway."""
    poly = np.asarray(room.outline, dtype=float)
    sign = 1.0 if polygon_area(poly) >= 0 else -1.0
    zones = []
    for door in room.doorways:
        a, b = poly[door.edge], poly[(door.edge + 1) % len(poly)]
        u = (b - a) / np.linalg.norm(b - a)
        inward = sign * np.array([-u[1], u[0]])
        c = a + door.center * u
        h = 0.5 * door.width
        zones.append(np.array([c - h * u, c + h * u, c + h * u + depth * inward, c - h * u + depth * inward]))
    return zones


# ------------------------------------------------------------- furniture


def _candidate_pose(
    furniture: Furniture, size: np.ndarray, room: Room, rng: np.random.Generator
) -> PlanarPose | None:
    if furniture.kind in AGAINST_WALL:
        pieces = room.wall_segments()
        poly = np.asarray(room.outline, dtype=float)
        sign = 1.0 if polygon_area(poly) >= 0 else -1.0  # inward = left of a CCW edge
        _, a, b = pieces[int(rng.integers(len(pieces)))]
        length = float(np.linalg.norm(b - a))
        if length < size[0] + 0.02:
            return None
        u = (b - a) / length
        inward = sign * np.array([-u[1], u[0]])
        s = rng.uniform(0.5 * size[0] + 0.01, length - 0.5 * size[0] - 0.01)
        c = a + s * u + (0.5 * size[1] + 0.01) * inward
        # F's +y (the back) points at the wall, i.e. along -inward.
        yaw = math.atan2(-inward[1], -inward[0]) - 0.5 * math.pi
        return PlanarPose(_r(c[0]), _r(c[1]), _r(math.atan2(math.sin(yaw), math.cos(yaw))))
    poly = room.polygon()
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    c = rng.uniform(lo, hi)
    if furniture.kind == "chair":
        yaw = rng.uniform(-math.pi, math.pi)
    else:
        yaw = 0.5 * math.pi * int(rng.integers(4)) + rng.normal(0.0, 0.05)
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    return PlanarPose(_r(c[0]), _r(c[1]), _r(yaw))


def _support_surfaces(furniture: Furniture) -> list[SupportSurface]:
    return Scenario(furniture=[furniture]).support_surfaces()


def _approachable(grid: FloorGrid, reachable: np.ndarray, polygon: np.ndarray, reach: float) -> bool:
    return bool(np.any(reachable & grid.cells_in_polygon(polygon, inflate=reach)))


def _place_furniture(
    room: Room, grid: FloorGrid, rng: np.random.Generator, config: RoomGeneratorConfig
) -> list[Furniture]:
    area = room.area()
    n_max = int(min(config.furniture_count[1], max(config.furniture_count[0], area // config.area_per_furniture)))
    n_target = int(rng.integers(config.furniture_count[0], n_max + 1))
    keep_clear = np.zeros_like(grid.inside)
    for zone in _doorway_zones(room, depth=1.0):
        keep_clear |= grid.cells_in_polygon(zone)
    door_cells = [grid.index(zone.mean(axis=0)) for zone in _doorway_zones(room, depth=1.0)]

    placed: list[Furniture] = []
    supports: list[np.ndarray] = []
    for k in range(n_target):
        # The first piece carries the target: a table or a counter.
        kind = ("table", "counter")[int(rng.integers(2))] if k == 0 else _KINDS[int(rng.choice(len(_KINDS), p=_KIND_WEIGHTS))]
        piece = sample_furniture(kind, f"{kind}_{k}", rng)
        size = footprint_size(piece)
        for _ in range(40):
            pose = _candidate_pose(piece, size, room, rng)
            if pose is None:
                continue
            piece.pose = pose
            footprint = _rectangle(pose, size)
            cells = grid.cells_in_polygon(footprint, inflate=config.furniture_gap)
            if np.any(cells & (grid.occupied | keep_clear | ~grid.inside)):
                continue
            occupied = grid.occupied | grid.cells_in_polygon(footprint)
            free = grid.base_free(config.robot_radius, occupied)
            labels, main = _components(free)
            if main == 0 or np.count_nonzero(labels == main) < 0.9 * np.count_nonzero(free):
                continue
            reachable = labels == main
            if not all(reachable[i, j] for i, j in door_cells):
                continue
            new_supports = [s.primitive.footprint() for s in _support_surfaces(piece)]
            if not all(_approachable(grid, reachable, s, config.reach_radius) for s in supports + new_supports):
                continue
            grid.occupied = occupied
            placed.append(piece)
            supports.extend(new_supports)
            break
    return placed


def _rectangle(pose: PlanarPose, size: np.ndarray) -> np.ndarray:
    half = 0.5 * np.asarray(size)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    R = rotation_z(pose.yaw)[:2, :2]
    return corners @ R.T + np.array([pose.x, pose.y])


# --------------------------------------------------------------- objects


def _reach_mask(grid: FloorGrid, reachable: np.ndarray, p_xy: np.ndarray, reach: float) -> np.ndarray:
    d = np.linalg.norm(grid.centers - p_xy, axis=-1)
    return reachable & (d <= reach)


def _drop(
    name: str,
    surface: SupportSurface,
    placed: list[PlacedObject],
    rng: np.random.Generator,
    config: RoomGeneratorConfig,
    accept_xy=None,
) -> PlacedObject | None:
    asset = load_ycb_asset(name)
    margin = 0.7 * asset.xy_radius + 0.02
    poly = surface.primitive.footprint()
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    neighbours = [Neighbour(o.name, np.asarray(o.xyz), np.asarray(o.rpy)) for o in placed if o.support == surface.id]
    centres = np.array([o.xyz[:2] for o in placed]).reshape(-1, 2)
    for _ in range(config.max_drop_attempts):
        p_xy = rng.uniform(lo, hi)
        yaw = rng.uniform(-math.pi, math.pi)
        if not surface.contains_xy(p_xy[None], margin)[0]:
            continue
        if len(centres) and np.min(np.linalg.norm(centres - p_xy, axis=1)) < config.min_object_separation:
            continue
        if accept_xy is not None and not accept_xy(p_xy):
            continue
        result = drop_object(name, surface.primitive, surface.height, p_xy, yaw, neighbours, config.drop_check, config.geometry)
        if not result.accepted:
            continue
        xyz = [_r(v) for v in result.xyz]
        if not surface.contains_xy(np.array([xyz[:2]]))[0]:
            continue
        if len(centres) and np.min(np.linalg.norm(centres - np.array(xyz[:2]), axis=1)) < config.min_object_separation:
            continue
        return PlacedObject(name=name, xyz=xyz, rpy=[_r(v) for v in result.rpy], support=surface.id, support_height=_r(surface.height))
    return None


# ---------------------------------------------------------------- events


def _grid_path(grid: FloorGrid, free: np.ndarray, start: tuple[int, int], goals: np.ndarray) -> np.ndarray | None:
    """Shortest 8-connected path over ``free`` cells from start to any goal cell -> (N, 2) xy."""
    ids = -np.ones(free.shape, dtype=np.int64)
    ids[free] = np.arange(np.count_nonzero(free))
    rows, cols, weights = [], [], []
    nx, ny = free.shape
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        # Pair every cell (a) with its neighbour at (+di, +dj) (b); di >= 0.
        a = ids[: nx - di, :]
        b = ids[di:, :]
        a, b = (a[:, : ny - dj], b[:, dj:]) if dj >= 0 else (a[:, -dj:], b[:, : ny + dj])
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        weights.append(np.full(np.count_nonzero(ok), math.hypot(di, dj)))
    n = int(np.count_nonzero(free))
    graph = csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    if ids[start] < 0:
        return None
    dist, pred = dijkstra(graph, directed=False, indices=int(ids[start]), return_predecessors=True)
    goal_ids = ids[goals & free]
    if len(goal_ids) == 0 or not np.isfinite(dist[goal_ids]).any():
        return None
    node = int(goal_ids[np.argmin(dist[goal_ids])])
    cells = np.argwhere(free)
    path = [node]
    while pred[node] >= 0:
        node = int(pred[node])
        path.append(node)
    return grid.centers[tuple(cells[path[::-1]].T)]


def shortest_grid_path(grid: FloorGrid, free: np.ndarray, start: tuple[int, int], goals: np.ndarray) -> np.ndarray | None:
    """Shortest 8-connected path (diagonal steps cost sqrt 2) over ``free`` cells.

    Args:
        grid: the floor grid.
        free: (nx, ny) passable cells.
        start: start cell index.
        goals: (nx, ny) goal cells; the path ends at the nearest one.

    Returns:
        (N, 2) xy of the cell centres along the path, or None if no goal is reachable.
    """
    return _grid_path(grid, free, start, goals)


def _pedestrian(
    grid: FloorGrid, free: np.ndarray, start: np.ndarray, goal_mask: np.ndarray, target_xy: np.ndarray, rng: np.random.Generator, config: RoomGeneratorConfig
) -> AppearAtDistance | None:
    event = AppearAtDistance(name="pedestrian")
    radius = event.shape.radius
    path = _grid_path(grid, free, grid.index(start), goal_mask)
    if path is None or len(path) < 3:
        return None
    for fraction in rng.permutation(np.linspace(0.35, 0.75, 9)):
        p = path[int(fraction * (len(path) - 1))]
        if np.linalg.norm(p - start) < event.trigger_distance + radius + 0.2:
            continue
        if np.linalg.norm(p - target_xy) < config.reach_radius + radius + 0.2:
            continue
        blocked = grid.occupied | (np.linalg.norm(grid.centers - p, axis=-1) <= radius)
        free_with = grid.base_free(config.robot_radius, blocked)
        if _grid_path(grid, free_with, grid.index(start), goal_mask & free_with) is None:
            continue  # no alternative route
        event.xyz = [_r(p[0]), _r(p[1]), _r(0.5 * event.shape.length)]
        return event
    return None


def _table_top_box(surface: SupportSurface, target: PlacedObject, objects: list[PlacedObject], rng: np.random.Generator) -> AppearAtPhase | None:
    event = AppearAtPhase(name="table_top_box")
    size = np.asarray(event.shape.size)
    others = np.array([o.xyz[:2] for o in objects])
    for _ in range(50):
        angle = rng.uniform(-math.pi, math.pi)
        p = np.asarray(target.xyz[:2]) + rng.uniform(0.12, 0.2) * np.array([math.cos(angle), math.sin(angle)])
        if not surface.contains_xy(p[None], 0.5 * np.linalg.norm(size[:2]) + 0.01)[0]:
            continue
        if np.min(np.linalg.norm(others - p, axis=1)) < 0.1:
            continue
        event.xyz = [_r(p[0]), _r(p[1]), _r(surface.height + 0.5 * size[2] + 0.002)]
        return event
    return None


def _moving_obstacle(grid: FloorGrid, free: np.ndarray, start: np.ndarray, rng: np.random.Generator) -> MoveAlongPath | None:
    event = MoveAlongPath(name="walker", shape=Cylinder(0.25, 1.7))
    cells = np.argwhere(free & (grid.clearance() >= event.shape.radius + 0.1))
    for _ in range(50):
        a, b = grid.centers[tuple(cells[rng.integers(len(cells), size=2)].T)]
        if np.linalg.norm(b - a) < 2.0:
            continue
        samples = a + np.linspace(0.0, 1.0, 40)[:, None] * (b - a)
        ij = np.round((samples - grid.origin) / grid.resolution).astype(int)
        if not np.all(free[ij[:, 0], ij[:, 1]]):
            continue
        d_start = np.min(np.linalg.norm(samples - start, axis=1))
        if d_start < 1.0:
            continue
        z = 0.5 * event.shape.length
        event.waypoints = [[_r(a[0]), _r(a[1]), _r(z)], [_r(b[0]), _r(b[1]), _r(z)]]
        return event
    return None


# -------------------------------------------------------------- generator


def generate_scenario(seed: int, config: RoomGeneratorConfig | None = None) -> Scenario:
    """Generates a validated scenario from ``seed`` (deterministic).

    Raises:
        GenerationError: if no valid room was found in ``max_room_attempts``.
    """
    config = config or RoomGeneratorConfig()
    rng = np.random.default_rng(seed)
    for _ in range(config.max_room_attempts):
        scenario = _try_generate(seed, rng, config)
        if scenario is not None:
            validate_scenario(scenario, f"generate_scenario(seed={seed})")
            return scenario
    raise GenerationError(f"generate_scenario(seed={seed}): no valid room in {config.max_room_attempts} attempts")


def _try_generate(seed: int, rng: np.random.Generator, config: RoomGeneratorConfig) -> Scenario | None:
    room = _sample_room(rng, config)
    grid = FloorGrid(room, config.grid_resolution)
    furniture = _place_furniture(room, grid, rng, config)
    if len(furniture) < config.furniture_count[0]:
        return None
    free = grid.base_free(config.robot_radius)
    labels, main = _components(free)
    reachable = labels == main
    surfaces = Scenario(furniture=furniture).support_surfaces()
    lo_h, hi_h = config.target_height_range
    target_surfaces = [s for s in surfaces if lo_h <= s.height <= hi_h]
    if not target_surfaces:
        return None

    names = list(YCB_OBJECTS)
    count = int(rng.integers(config.object_count[0], config.object_count[1] + 1))
    chosen = [names[i] for i in rng.choice(len(names), size=count, replace=False)]

    # The target first, on a reachable-height surface, within reach of a free base cell.
    surface = target_surfaces[int(rng.integers(len(target_surfaces)))]
    target = _drop(chosen[0], surface, [], rng, config, accept_xy=lambda p: bool(np.any(_reach_mask(grid, reachable, p, config.reach_radius))))
    if target is None:
        return None
    objects = place_clutter(target, chosen[1:], surfaces, rng, lambda name, s, objs: _drop(name, s, objs, rng, config))
    start = sample_start_pose(grid, reachable, target.xyz[:2], config.start_distance_range, rng)
    if start is None:
        return None
    target_xy = np.asarray(target.xyz[:2])
    start_xy = np.array([start.x, start.y])

    events = []
    if config.dynamic:
        goal_mask = _reach_mask(grid, reachable, target_xy, config.reach_radius)
        pedestrian = _pedestrian(grid, free, start_xy, goal_mask, target_xy, rng, config)
        if pedestrian is not None:
            events.append(pedestrian)
        box = _table_top_box(surface, target, objects, rng)
        if box is not None:
            events.append(box)
    if config.moving_obstacle:
        walker = _moving_obstacle(grid, free, start_xy, rng)
        if walker is not None:
            events.append(walker)

    return Scenario(
        name=f"procedural_{seed:05d}",
        seed=int(seed),
        room=room,
        furniture=furniture,
        objects=objects,
        target=target.name,
        robot_start=start,
        dynamic_events=events,
        time_limit=config.time_limit,
    )


# ------------------------------------------------------------- re-targeting


def floor_grid_of(scenario: Scenario, config: RoomGeneratorConfig | None = None) -> tuple[FloorGrid, np.ndarray]:
    """The generator's grid of a scenario: (grid with furniture footprints, reachable base cells)."""
    config = config or RoomGeneratorConfig()
    grid = FloorGrid(scenario.room, config.grid_resolution)
    for piece in scenario.furniture:
        grid.occupied |= grid.cells_in_polygon(_rectangle(piece.pose, footprint_size(piece)))
    free = grid.base_free(config.robot_radius)
    labels, main = _components(free)
    return grid, (labels == main) if main else np.zeros_like(free)


def target_candidates(scenario: Scenario, config: RoomGeneratorConfig | None = None) -> list[str]:
    """Objects the generator would accept as a target (height band, approachable base)."""
    config = config or RoomGeneratorConfig()
    grid, reachable = floor_grid_of(scenario, config)
    lo, hi = config.target_height_range
    names = []
    for obj in scenario.objects:
        if lo <= obj.support_height <= hi and np.any(_reach_mask(grid, reachable, np.asarray(obj.xyz[:2]), config.reach_radius)):
            names.append(obj.name)
    return names


def retarget_scenario(scenario: Scenario, target: str, seed: int, config: RoomGeneratorConfig | None = None) -> Scenario | None:
    """The same room and objects with another target, a new start and new dynamic events.

    The start and events are drawn as ``generate_scenario`` draws them, from
    ``np.random.default_rng(seed)``. Returns None when no start or event fits.
    """
    config = config or RoomGeneratorConfig()
    rng = np.random.default_rng(seed)
    grid, reachable = floor_grid_of(scenario, config)
    free = grid.base_free(config.robot_radius)
    obj = scenario.object(target)
    target_xy = np.asarray(obj.xyz[:2])
    d = np.linalg.norm(grid.centers - target_xy, axis=-1)
    lo_d, hi_d = config.start_distance_range
    start_cells = np.argwhere(reachable & (d >= lo_d) & (d <= hi_d))
    if len(start_cells) == 0:
        return None
    i, j = start_cells[int(rng.integers(len(start_cells)))]
    start_xy = grid.centers[i, j]
    out = copy.deepcopy(scenario)
    out.target = target
    out.robot_start = PlanarPose(_r(start_xy[0]), _r(start_xy[1]), _r(rng.uniform(-math.pi, math.pi)))
    out.dynamic_events = []
    if config.dynamic:
        goal_mask = _reach_mask(grid, reachable, target_xy, config.reach_radius)
        pedestrian = _pedestrian(grid, free, start_xy, goal_mask, target_xy, rng, config)
        if pedestrian is not None:
            out.dynamic_events.append(pedestrian)
        surface = next((s for s in scenario.support_surfaces() if s.id == obj.support), None)
        box = _table_top_box(surface, obj, scenario.objects, rng) if surface is not None else None
        if box is not None:
            out.dynamic_events.append(box)
    if config.moving_obstacle:
        walker = _moving_obstacle(grid, free, start_xy, rng)
        if walker is not None:
            out.dynamic_events.append(walker)
    validate_scenario(out, f"retarget_scenario({scenario.name}, {target})")
    return out


def place_clutter(target, names, surfaces, rng: np.random.Generator, place) -> list:
    """[target] plus each of ``names`` dropped by ``place(name, surface, objects)``
    on a support surface drawn in proportion to its area (None = not placed)."""
    objects = [target]
    areas = np.array([abs(np.prod(s.primitive.footprint().max(0) - s.primitive.footprint().min(0))) for s in surfaces])
    for name in names:
        s = surfaces[int(rng.choice(len(surfaces), p=areas / areas.sum()))]
        placed = place(name, s, objects)
        if placed is not None:
            objects.append(placed)
    return objects


def sample_start_pose(grid, reachable: np.ndarray, target_xy, distance_range, rng: np.random.Generator):
    """A random-heading start on a reachable cell within ``distance_range`` of the target, or None."""
    d = np.linalg.norm(grid.centers - np.asarray(target_xy, float), axis=-1)
    lo_d, hi_d = distance_range
    start_cells = np.argwhere(reachable & (d >= lo_d) & (d <= hi_d))
    if len(start_cells) == 0:
        return None
    i, j = start_cells[int(rng.integers(len(start_cells)))]
    start_xy = grid.centers[i, j]
    return PlanarPose(_r(start_xy[0]), _r(start_xy[1]), _r(rng.uniform(-math.pi, math.pi)))
