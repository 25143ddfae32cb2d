"""Scenario: what is in the room, as dataclasses loaded from YAML.

A scenario is one YAML file read with ``pydrake.common.yaml.yaml_load_typed``
(the format is described in ``vamg_drake/world/README.md``). Shapes and dynamic
events are tagged unions (``!Box``, ``!Cylinder``, ``!AppearAtDistance``, ...).

Frames: W is the world (z up, floor top at z = 0). A furniture frame F sits on
the floor at (x, y) with yaw; its parts are given in F. An object's frame O has
its origin at the object's centroid (see ``vamg_drake.world.ycb``), so the
target point p is the translation of X_WO of the target object.

Every malformed, incomplete or inconsistent scenario raises ``ScenarioError``
whose lines name the file and the field, e.g.
``scenario.yaml: objects[2].name: unknown YCB object 'foo' (known: ...)``.
"""


import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from vamg_drake.config_validation import InputError, load_typed_text, read_yaml_text
from vamg_drake.provenance import atomic_write_text

from vamg_drake.world.primitives import (
    WorldBox,
    WorldCylinder,
    WorldPrimitive,
    distance_to_polygon_boundary,
    footprint_clearance,
    points_in_polygon,
    polygon_area,
    rotation_from_rpy,
    rotation_z,
    signed_distance_to_polygon,
)
from vamg_drake.world.replicacad import ReplicaCadError, load_replicacad_layout
from vamg_drake.world.ycb import YCB_MODELS

FURNITURE_KINDS = ("table", "counter", "shelf", "chair", "sofa", "cabinet")
#: Subgoal-policy phases an ``AppearAtPhase`` event may name.
POLICY_PHASES = ("observe", "pre_grasp", "grasp")
#: The Fetch base footprint radius [m] used for start-pose checks.
ROBOT_FOOTPRINT_RADIUS = 0.32
#: The paper's drop-check band for an object above its support [m].
SUPPORT_HEIGHT_BAND = (-0.05, 0.30)
#: The largest extent [m] of any shape (a part, an obstacle): beyond it a
#: number is a typo, and Drake's geometry would accept it.
MAX_SHAPE_EXTENT = 20.0
#: The longest episode [s] a scenario may ask for (a day: beyond it, a typo).
MAX_TIME_LIMIT = 86400.0
#: The fastest a moving obstacle may go [m/s] (a running person; the paper's 0.2).
MAX_OBSTACLE_SPEED = 5.0
#: How far [m] a furniture part may reach through the room's outline, or
#: hover above the floor or the part beneath it, before it is an error.
GEOMETRY_TOLERANCE = 0.03
#: ReplicaCAD receptacles are axis-aligned boxes that approximate seats,
#: cushions and shelves; an object's centroid may lie this far [m] outside one
#: (a bowl on a chair seat) and still rest on the furniture under it.
RECEPTACLE_EDGE_TOLERANCE = 0.12


class ScenarioError(ValueError):
    """A scenario is malformed or inconsistent.

    Attributes:
        problems: one "<source>: <field>: <message>" line per problem.
    """

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


# ---------------------------------------------------------------- shapes


@dataclass
class Box:
    """A box with full side lengths ``size`` = [x, y, z] (like Drake's Box)."""

    size: list[float] = field(default_factory=lambda: [0.1, 0.1, 0.1])


@dataclass
class Cylinder:
    """A cylinder along its frame's z axis (like Drake's Cylinder)."""

    radius: float = 0.3
    length: float = 1.7


Shape = Box | Cylinder


def _shape_top_half_height(shape: Shape) -> float:
    return 0.5 * (shape.size[2] if isinstance(shape, Box) else shape.length)


def world_primitive(name: str, shape: Shape, p_W: np.ndarray, R_W: np.ndarray) -> WorldPrimitive:
    """Returns the world primitive for ``shape`` at (p_W, R_W)."""
    if isinstance(shape, Box):
        return WorldBox(name, p_W, R_W, 0.5 * np.asarray(shape.size, dtype=float))
    return WorldCylinder(name, p_W, R_W, float(shape.radius), float(shape.length))


# ------------------------------------------------------------------ room


@dataclass
class PlanarPose:
    """A pose on the floor: position (x, y) [m] and heading ``yaw`` [rad]."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


@dataclass
class Doorway:
    """A gap in the wall along outline edge ``edge`` (vertex edge -> edge+1).

    Attributes:
        edge: index of the outline edge.
        center: distance [m] of the gap centre from the edge's first vertex.
        width: gap width [m].
    """

    edge: int = 0
    center: float = 0.5
    width: float = 0.9


@dataclass
class Room:
    """The room: a simple floor polygon bounded by walls outside it.

    Attributes:
        outline: floor polygon vertices [[x, y], ...] (rectangle: 4, L: 6).
        wall_thickness: walls are built outside the outline [m].
        wall_height: [m].
        doorways: gaps in the walls.
    """

    outline: list[list[float]] = field(default_factory=list)
    wall_thickness: float = 0.1
    wall_height: float = 2.4
    doorways: list[Doorway] = field(default_factory=list)

    def polygon(self) -> np.ndarray:
        """Returns the (k, 2) outline, counter-clockwise."""
        poly = np.asarray(self.outline, dtype=float).reshape(-1, 2)
        return poly if polygon_area(poly) >= 0 else poly[::-1]

    def area(self) -> float:
        """Returns the floor area [m^2]."""
        return abs(polygon_area(np.asarray(self.outline, dtype=float).reshape(-1, 2)))

    def wall_segments(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Returns the wall pieces (edge index, start xy, end xy) along the outline.

        Edges follow the ``outline`` as written (so ``Doorway.edge`` indexes it);
        doorway gaps are cut out.
        """
        poly = np.asarray(self.outline, dtype=float).reshape(-1, 2)
        pieces = []
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            length = float(np.linalg.norm(b - a))
            u = (b - a) / length
            gaps = sorted(
                (d.center - 0.5 * d.width, d.center + 0.5 * d.width)
                for d in self.doorways
                if d.edge == i
            )
            s = 0.0
            for lo, hi in gaps + [(length, length)]:
                if lo - s > 1e-6:
                    pieces.append((i, a + s * u, a + lo * u))
                s = max(s, hi)
        return pieces

    def wall_primitives(self) -> list[WorldBox]:
        """Returns the walls as boxes just outside the outline (corners overlap)."""
        poly = np.asarray(self.outline, dtype=float).reshape(-1, 2)
        sign = 1.0 if polygon_area(poly) >= 0 else -1.0  # outward = right of a CCW edge
        t = self.wall_thickness
        boxes = []
        for k, (i, a, b) in enumerate(self.wall_segments()):
            u = (b - a) / np.linalg.norm(b - a)
            outward = sign * np.array([u[1], -u[0]])
            # Extend by t at ends that are outline corners, so corners close.
            edge_a, edge_b = poly[i], poly[(i + 1) % len(poly)]
            ext_a = t if np.allclose(a, edge_a) else 0.0
            ext_b = t if np.allclose(b, edge_b) else 0.0
            a2, b2 = a - ext_a * u, b + ext_b * u
            center = 0.5 * (a2 + b2) + 0.5 * t * outward
            yaw = math.atan2(u[1], u[0])
            size = [float(np.linalg.norm(b2 - a2)), t, self.wall_height]
            boxes.append(
                WorldBox(
                    f"wall/{k}",
                    np.array([center[0], center[1], 0.5 * self.wall_height]),
                    rotation_z(yaw),
                    0.5 * np.asarray(size),
                )
            )
        return boxes


# ------------------------------------------------------------- furniture


@dataclass
class Part:
    """A primitive part of a piece of furniture, posed in the furniture frame F.

    Attributes:
        name: unique within its furniture.
        shape: ``!Box`` or ``!Cylinder``.
        xyz: part centre in F [m].
        rpy: part orientation in F [rad].
        support: whether the part's top face is a support surface.
        rgba: colour.
    """

    name: str = ""
    shape: Box | Cylinder = field(default_factory=Box)
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    support: bool = False
    rgba: list[float] = field(default_factory=lambda: [0.6, 0.5, 0.4, 1.0])


@dataclass
class Furniture:
    """A piece of furniture welded to the world.

    Attributes:
        name: unique in the scenario, e.g. "table_0".
        kind: one of FURNITURE_KINDS.
        pose: frame F on the floor.
        parts: its primitives.
    """

    name: str = ""
    kind: str = "table"
    pose: PlanarPose = field(default_factory=PlanarPose)
    parts: list[Part] = field(default_factory=list)

    def X_WF(self) -> tuple[np.ndarray, np.ndarray]:
        """Returns (p_WF, R_WF)."""
        return np.array([self.pose.x, self.pose.y, 0.0]), rotation_z(self.pose.yaw)

    def part_pose(self, part: Part) -> tuple[np.ndarray, np.ndarray]:
        """Returns (p_WP, R_WP) of a part."""
        p_WF, R_WF = self.X_WF()
        return p_WF + R_WF @ np.asarray(part.xyz, float), R_WF @ rotation_from_rpy(part.rpy)

    def primitives(self) -> list[WorldPrimitive]:
        """Returns the parts as world primitives named "<furniture>/<part>"."""
        return [
            world_primitive(f"{self.name}/{p.name}", p.shape, *self.part_pose(p))
            for p in self.parts
        ]


@dataclass(frozen=True)
class SupportSurface:
    """The top face of a support part, in W.

    Attributes:
        id: "<furniture>/<part>".
        height: z of the top face [m].
        primitive: the part; its footprint is the usable top.
    """

    id: str
    height: float
    primitive: WorldPrimitive

    def contains_xy(self, p_xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether (N, 2) points lie on the top at least ``margin`` inside its edge."""
        return signed_distance_to_polygon(p_xy, self.primitive.footprint()) <= -margin


# --------------------------------------------------------------- objects


@dataclass
class PlacedObject:
    """A YCB object resting on a support surface.

    Attributes:
        name: unique per scenario; also the YCB model (a key of
            ``ycb.YCB_MODELS``) unless ``model`` is given.
        xyz: p_WO, the object centroid [m].
        rpy: R_WO as roll, pitch, yaw [rad].
        support: id of the support surface, "<furniture>/<part>".
        support_height: z of that surface [m].
        model: the YCB model when ``name`` is not one, e.g. two "cups_a" in
            one room named "cups_a" and "cups_a_2".
    """

    name: str = ""
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rpy: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    support: str = ""
    support_height: float = 0.0
    model: str = ""

    @property
    def ycb_model(self) -> str:
        """The YCB model this object is an instance of."""
        return self.model or self.name


# -------------------------------------------------------- dynamic events


@dataclass
class AppearAtDistance:
    """An obstacle that appears when the robot base comes within a distance.

    Defaults are the paper's pedestrian: a cylinder r 0.3 m, h 1.7 m, appearing
    when the horizontal distance from the base origin to ``xyz`` is <= 1.7 m.

    Attributes:
        name: unique among the events.
        shape: obstacle shape, centred at ``xyz`` when visible.
        xyz: shape centre in W when visible [m].
        yaw: shape yaw about its centre [rad].
        trigger_distance: [m].
        rgba: colour.
        heading_towards: also require the base to head towards the obstacle
            (positive dot product of the base's heading and the direction
            to ``xyz``), the rule of the paper authors' released tasks.
    """

    name: str = ""
    shape: Cylinder | Box = field(default_factory=Cylinder)
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.85])
    yaw: float = 0.0
    trigger_distance: float = 1.7
    rgba: list[float] = field(default_factory=lambda: [0.9, 0.3, 0.2, 1.0])
    heading_towards: bool = False


@dataclass
class AppearAtPhase:
    """A (small, table-top) obstacle that appears when the policy enters a phase.

    Attributes:
        name: unique among the events.
        shape: obstacle shape, centred at ``xyz`` when visible.
        xyz: shape centre in W when visible [m].
        yaw: [rad].
        phase: one of POLICY_PHASES.
        rgba: colour.
        alternatives: further shape centres, tried in order after ``xyz``
            when the robot is too close to it (see ``min_robot_clearance``).
        min_robot_clearance: the obstacle appears at the first of ``xyz`` and
            ``alternatives`` whose centre lies at least this far [m] from every
            robot link origin; where none does, it does not appear (0: always
            at ``xyz``).
    """

    name: str = ""
    shape: Box | Cylinder = field(default_factory=lambda: Box([0.08, 0.08, 0.12]))
    xyz: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw: float = 0.0
    phase: str = "pre_grasp"
    rgba: list[float] = field(default_factory=lambda: [0.9, 0.6, 0.1, 1.0])
    alternatives: list[list[float]] = field(default_factory=list)
    min_robot_clearance: float = 0.0

    def candidates(self) -> np.ndarray:
        """(K, 3) shape centres in the order they are tried."""
        return np.asarray([self.xyz, *self.alternatives], dtype=float).reshape(-1, 3)


@dataclass
class MoveAlongPath:
    """An obstacle moving through waypoints at constant speed from ``start_time``.

    Attributes:
        name: unique among the events.
        shape: obstacle shape, centred on the path.
        waypoints: [[x, y, z], ...] shape centres in W (at least 2).
        speed: [m/s] (the paper's moving obstacles: 0.2).
        start_time: [s]; before it the obstacle waits at the first waypoint.
        loop: at the end, run the path backwards and forwards again; else stop.
        yaw: [rad].
        rgba: colour.
    """

    name: str = ""
    shape: Cylinder | Box = field(default_factory=Cylinder)
    waypoints: list[list[float]] = field(default_factory=list)
    speed: float = 0.2
    start_time: float = 0.0
    loop: bool = True
    yaw: float = 0.0
    rgba: list[float] = field(default_factory=lambda: [0.2, 0.4, 0.9, 1.0])

    def position_at(self, t: float) -> np.ndarray:
        """Returns the shape centre in W at time ``t`` [s]."""
        points = np.asarray(self.waypoints, dtype=float)
        seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
        total = float(seg.sum())
        s = max(0.0, t - self.start_time) * self.speed
        if total <= 0.0:
            return points[0].copy()
        if self.loop:
            s = s % (2.0 * total)
            s = 2.0 * total - s if s > total else s
        else:
            s = min(s, total)
        cumulative = np.concatenate([[0.0], np.cumsum(seg)])
        i = int(np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(seg) - 1))
        u = 0.0 if seg[i] == 0 else (s - cumulative[i]) / seg[i]
        return points[i] + u * (points[i + 1] - points[i])


DynamicEvent = AppearAtDistance | AppearAtPhase | MoveAlongPath


# ------------------------------------------------------------- ReplicaCAD


@dataclass
class ReplicaCadScene:
    """A ReplicaCAD scene instance as the room (``vamg_drake.world.replicacad``).

    Attributes:
        scene: scene instance name, e.g. "apt_0".
        dataset_dir: leave empty in committed files: the dataset is found via
            ``$VAMG_REPLICACAD_DIR``, ``$MS_ASSET_DIR`` or ``~/.maniskill/data``.
        require_stage: fail if the apartment shell (stage mesh) is missing.
    """

    scene: str = ""
    dataset_dir: str = ""
    require_stage: bool = False


# --------------------------------------------------------------- scenario


@dataclass
class Scenario:
    """One grasping task in one room.

    Attributes:
        name: scenario name.
        seed: the generator seed (or any number for hand-written scenarios).
        room: walls and doorways.
        furniture: welded furniture.
        objects: YCB objects on support surfaces.
        target: name of the object to grasp.
        robot_start: base pose (x, y, yaw = theta).
        dynamic_events: obstacles that appear or move during the episode.
        time_limit: episode time limit [s].
        replicacad: a ReplicaCAD scene loaded in addition to room and
            furniture (its receptacles are support surfaces), or None.
    """

    name: str = ""
    seed: int = 0
    room: Room = field(default_factory=Room)
    furniture: list[Furniture] = field(default_factory=list)
    objects: list[PlacedObject] = field(default_factory=list)
    target: str = ""
    robot_start: PlanarPose = field(default_factory=PlanarPose)
    dynamic_events: list[AppearAtDistance | AppearAtPhase | MoveAlongPath] = field(
        default_factory=list
    )
    time_limit: float = 120.0
    replicacad: ReplicaCadScene | None = None

    def replicacad_layout(self):
        """Returns the loaded ``ReplicaCadLayout``, or None without ``replicacad``.

        Raises:
            ReplicaCadError: if the dataset, scene or an asset is missing.
        """
        if self.replicacad is None:
            return None
        return load_replicacad_layout(
            self.replicacad.scene, self.replicacad.dataset_dir or None, self.replicacad.require_stage
        )

    def object(self, name: str) -> PlacedObject:
        """Returns the placed object called ``name`` (KeyError if absent)."""
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise KeyError(f"no object {name!r} in scenario {self.name!r}")

    def target_point(self) -> np.ndarray:
        """Returns p, the target object's centroid in W."""
        return np.asarray(self.object(self.target).xyz, dtype=float)

    def support_surfaces(self) -> list[SupportSurface]:
        """Returns every support surface (parts with ``support: true``)."""
        surfaces = []
        for furniture in self.furniture:
            for part in furniture.parts:
                if not part.support:
                    continue
                p_WP, R_WP = furniture.part_pose(part)
                top = float(p_WP[2] + _shape_top_half_height(part.shape))
                surfaces.append(
                    SupportSurface(
                        f"{furniture.name}/{part.name}",
                        top,
                        world_primitive(f"{furniture.name}/{part.name}", part.shape, p_WP, R_WP),
                    )
                )
        layout = self.replicacad_layout()
        if layout is not None:
            surfaces.extend(SupportSurface(r.id, r.height, r.box) for r in layout.all_receptacles())
        return surfaces


def static_obstacle_shapes(scenario: Scenario) -> list[WorldPrimitive]:
    """Returns walls and furniture as world primitives (no floor, no objects).

    A ReplicaCAD scene adds its navmesh walls and one vertical-axis box around
    each collision piece (``ReplicaCadLayout.static_shapes``).
    """
    shapes: list[WorldPrimitive] = list(scenario.room.wall_primitives())
    for furniture in scenario.furniture:
        shapes.extend(furniture.primitives())
    layout = scenario.replicacad_layout()
    if layout is not None:
        shapes.extend(layout.static_shapes())
    return shapes


# ---------------------------------------------------------------- YAML IO


def scenario_to_yaml(scenario: Scenario) -> str:
    """Returns the YAML text of a scenario (Drake's yaml_dump_typed)."""
    return yaml_dump_typed(scenario)


def scenario_from_yaml(text: str, source: str = "<string>") -> Scenario:
    """Parses and validates YAML text; ``source`` names it in errors."""
    try:
        scenario = load_typed_text(text, Scenario, None, source)
    except InputError as e:  # wrong types, unknown fields, not YAML, not a mapping
        raise ScenarioError(e.problems) from None
    validate_scenario(scenario, source)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Loads and validates a scenario file.

    Raises:
        ScenarioError: naming the file and the field.
    """
    path = Path(path)
    try:
        text = read_yaml_text(path, path.name if path.is_file() else str(path))
    except InputError as e:  # missing, a directory, binary, empty
        raise ScenarioError(e.problems) from None
    return scenario_from_yaml(text, source=path.name)


def save_scenario(scenario: Scenario, path: str | Path) -> None:
    """Writes a scenario as YAML (validated first, so only good files are written)."""
    validate_scenario(scenario, str(path))
    atomic_write_text(path, scenario_to_yaml(scenario))


# ------------------------------------------------------------- validation


def _finite_vector(value, n: int) -> bool:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return v.shape == (n,) and bool(np.all(np.isfinite(v)))


def _check_shape(shape: Shape, where: str, problems: list[str]) -> None:
    if isinstance(shape, Box):
        if not _finite_vector(shape.size, 3) or min(shape.size) <= 0:
            problems.append(f"{where}.size: needs 3 positive lengths, got {shape.size}")
        elif max(shape.size) > MAX_SHAPE_EXTENT:
            problems.append(f"{where}.size: {shape.size} exceeds {MAX_SHAPE_EXTENT} m")
    elif not (math.isfinite(shape.radius) and math.isfinite(shape.length) and shape.radius > 0 and shape.length > 0):
        problems.append(f"{where}: radius and length must be positive, got {shape.radius}, {shape.length}")
    elif max(2 * shape.radius, shape.length) > MAX_SHAPE_EXTENT:
        problems.append(f"{where}: radius {shape.radius}, length {shape.length} exceed {MAX_SHAPE_EXTENT} m")


def _segments_cross(a, b, c, d) -> bool:
    def orient(p, q, r):
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    return orient(a, b, c) * orient(a, b, d) < 0 and orient(c, d, a) * orient(c, d, b) < 0


def _check_room(room: Room, problems: list[str]) -> bool:
    if len(room.outline) < 3:
        problems.append("room.outline: needs at least 3 [x, y] vertices")
        return False
    if not all(_finite_vector(v, 2) for v in room.outline):
        problems.append("room.outline: every vertex must be a finite [x, y]")
        return False
    poly = np.asarray(room.outline, dtype=float)
    n = len(poly)
    lengths = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)
    if np.any(lengths < 1e-6):
        problems.append(f"room.outline: edge {int(np.argmin(lengths))} has zero length (repeated vertex)")
        return False
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            if _segments_cross(poly[i], poly[(i + 1) % n], poly[j], poly[(j + 1) % n]):
                problems.append(f"room.outline: edges {i} and {j} cross (not a simple polygon)")
                return False
    if room.area() <= 0.0:
        problems.append("room.outline: zero area")
        return False
    if not (room.wall_thickness > 0 and room.wall_height > 0):
        problems.append("room: wall_thickness and wall_height must be positive")
    for k, door in enumerate(room.doorways):
        where = f"room.doorways[{k}]"
        if not 0 <= door.edge < n:
            problems.append(f"{where}.edge: {door.edge} is not an outline edge (0..{n - 1})")
            continue
        length = float(np.linalg.norm(poly[(door.edge + 1) % n] - poly[door.edge]))
        if door.width <= 0 or door.center - 0.5 * door.width < 0 or door.center + 0.5 * door.width > length:
            problems.append(f"{where}: gap [{door.center} +- {door.width / 2}] does not fit edge of length {length:.3f}")
    return True


def validate_scenario(scenario: Scenario, source: str = "<scenario>") -> None:
    """Checks a scenario for completeness and consistency.

    Checks: required fields present; room outline a simple polygon with valid
    doorways; furniture kinds, names, shapes; objects are known YCB names,
    unique, on an existing support surface (inside its top, within the
    drop-check height band); the target is one of the objects; the robot start
    footprint (r = ROBOT_FOOTPRINT_RADIUS) inside the room and clear of walls
    and furniture; dynamic events well formed.

    Raises:
        ScenarioError: listing every problem as "<source>: <field>: <message>".
    """
    problems: list[str] = []
    if not scenario.name:
        problems.append("name: missing")
    if not (math.isfinite(scenario.time_limit) and 0 < scenario.time_limit <= MAX_TIME_LIMIT):
        problems.append(f"time_limit: must be a positive number of seconds up to {MAX_TIME_LIMIT:g}, "
                        f"got {scenario.time_limit}")
    room_ok = _check_room(scenario.room, problems)
    _check_numbers(scenario, problems)
    replicacad_ok = _check_replicacad(scenario, problems)

    furniture_names: set[str] = set()
    problems_before_furniture = len(problems)
    for i, furniture in enumerate(scenario.furniture):
        where = f"furniture[{i}]"
        if not furniture.name:
            problems.append(f"{where}.name: missing")
        elif furniture.name in furniture_names:
            problems.append(f"{where}.name: duplicate furniture name {furniture.name!r}")
        furniture_names.add(furniture.name)
        if furniture.kind not in FURNITURE_KINDS:
            problems.append(f"{where}.kind: unknown kind {furniture.kind!r} (known: {', '.join(FURNITURE_KINDS)})")
        if not furniture.parts:
            problems.append(f"{where}.parts: a piece of furniture needs at least one part")
        part_names: set[str] = set()
        for j, part in enumerate(furniture.parts):
            pw = f"{where}.parts[{j}]"
            if not part.name or part.name in part_names:
                problems.append(f"{pw}.name: missing or duplicate part name {part.name!r}")
            part_names.add(part.name)
            _check_shape(part.shape, f"{pw}.shape", problems)
            if not (_finite_vector(part.xyz, 3) and _finite_vector(part.rpy, 3)):
                problems.append(f"{pw}: xyz and rpy must be 3 finite numbers each")
            elif part.support and (abs(part.rpy[0]) > 1e-6 or abs(part.rpy[1]) > 1e-6):
                problems.append(f"{pw}.support: a support part must be level (roll = pitch = 0)")

    if len(problems) == problems_before_furniture:
        _check_furniture_geometry(scenario, problems, room_ok)
    furniture_ok = len(problems) == problems_before_furniture and replicacad_ok
    surfaces = {s.id: s for s in scenario.support_surfaces()} if furniture_ok else {}
    seen: set[str] = set()
    for i, obj in enumerate(scenario.objects):
        where = f"objects[{i}]"
        if obj.ycb_model not in YCB_MODELS:
            field_name = "model" if obj.model else "name"
            problems.append(f"{where}.{field_name}: unknown YCB object {obj.ycb_model!r} (known: {', '.join(YCB_MODELS)})")
        if not obj.name:
            problems.append(f"{where}.name: missing")
        elif obj.name in seen:
            problems.append(f"{where}.name: object {obj.name!r} appears twice")
        seen.add(obj.name)
        if not (_finite_vector(obj.xyz, 3) and _finite_vector(obj.rpy, 3)):
            problems.append(f"{where}: xyz and rpy must be 3 finite numbers each")
            continue
        if not surfaces:
            continue
        surface = surfaces.get(obj.support)
        if surface is None:
            problems.append(f"{where}.support: no support surface {obj.support!r} (have: {', '.join(surfaces) or 'none'})")
            continue
        if abs(surface.height - obj.support_height) > 0.01:
            problems.append(f"{where}.support_height: {obj.support_height} but {obj.support!r} is at {surface.height:.3f}")
        dz = obj.xyz[2] - surface.height
        edge = -RECEPTACLE_EDGE_TOLERANCE if obj.support.startswith("rc/") else 0.0
        if not (SUPPORT_HEIGHT_BAND[0] <= dz <= SUPPORT_HEIGHT_BAND[1]) or not surface.contains_xy(np.array([obj.xyz[:2]]), edge)[0]:
            problems.append(f"{where}.xyz: {obj.name!r} at {obj.xyz} is not on support {obj.support!r} (top at z = {surface.height:.3f})")

    if not scenario.target:
        problems.append("target: missing")
    elif scenario.target not in seen:
        problems.append(f"target: {scenario.target!r} is not one of the objects ({', '.join(o.name for o in scenario.objects) or 'none'})")

    if room_ok and furniture_ok:
        _check_start(scenario, problems)

    event_names: set[str] = set()
    for i, event in enumerate(scenario.dynamic_events):
        where = f"dynamic_events[{i}]"
        if not event.name or event.name in event_names:
            problems.append(f"{where}.name: missing or duplicate event name {event.name!r}")
        event_names.add(event.name)
        _check_shape(event.shape, f"{where}.shape", problems)
        if isinstance(event, MoveAlongPath):
            if len(event.waypoints) < 2 or not all(_finite_vector(w, 3) for w in event.waypoints):
                problems.append(f"{where}.waypoints: needs at least 2 finite [x, y, z] points")
            if not event.speed > 0:
                problems.append(f"{where}.speed: must be positive, got {event.speed}")
        else:
            if not _finite_vector(event.xyz, 3):
                problems.append(f"{where}.xyz: must be 3 finite numbers")
        if isinstance(event, AppearAtDistance) and not event.trigger_distance > 0:
            problems.append(f"{where}.trigger_distance: must be positive")
        if isinstance(event, AppearAtPhase):
            if event.phase not in POLICY_PHASES:
                problems.append(f"{where}.phase: unknown phase {event.phase!r} (known: {', '.join(POLICY_PHASES)})")
            if not all(_finite_vector(a, 3) for a in event.alternatives):
                problems.append(f"{where}.alternatives: each must be 3 finite numbers")
            if not (np.isfinite(event.min_robot_clearance) and event.min_robot_clearance >= 0):
                problems.append(f"{where}.min_robot_clearance: must be a finite number >= 0, got {event.min_robot_clearance}")

    if problems:
        raise ScenarioError([f"{source}: {p}" for p in problems])


def _check_replicacad(scenario: Scenario, problems: list[str]) -> bool:
    if scenario.replicacad is None:
        return True
    if not scenario.replicacad.scene:
        problems.append("replicacad.scene: missing")
        return False
    try:
        scenario.replicacad_layout()
    except ReplicaCadError as e:
        problems.append(f"replicacad: {e}")
        return False
    return True


def _check_start(scenario: Scenario, problems: list[str]) -> None:
    start = scenario.robot_start
    if not _finite_vector([start.x, start.y, start.yaw], 3):
        return  # reported by _check_numbers
    p = np.array([[start.x, start.y]])
    r = ROBOT_FOOTPRINT_RADIUS
    poly = scenario.room.polygon()
    if not points_in_polygon(p, poly)[0]:
        problems.append(f"robot_start: ({start.x}, {start.y}) is outside the room")
        return
    if distance_to_polygon_boundary(p, poly)[0] < r:
        # Doorway gaps are walls the robot may cross, but not a place to start.
        problems.append(f"robot_start: footprint (r = {r} m) at ({start.x}, {start.y}) crosses the room's walls")
    for furniture in scenario.furniture:
        clearance = footprint_clearance(p, furniture.primitives())[0]
        if clearance < r:
            problems.append(
                f"robot_start: footprint (r = {r} m) at ({start.x}, {start.y}) overlaps furniture {furniture.name!r}"
                f" ({'centre inside it' if clearance < 0 else f'clearance {clearance:.2f} m'})"
            )
    layout = scenario.replicacad_layout()
    if layout is not None:
        if not layout.navmesh.contains_xy(p)[0]:
            problems.append(f"robot_start: ({start.x}, {start.y}) is not on the navmesh of {layout.scene!r}")
        clearance = footprint_clearance(p, layout.static_shapes())[0]
        if clearance < r:
            problems.append(
                f"robot_start: footprint (r = {r} m) at ({start.x}, {start.y}) overlaps {layout.scene!r} geometry (clearance {clearance:.2f} m)"
            )


def _check_numbers(scenario: Scenario, problems: list[str]) -> None:
    """Finite numbers and sane ranges where a bad value would pass the other
    checks (a NaN compares false everywhere) and break the simulation."""
    start = scenario.robot_start
    for name in ("x", "y", "yaw"):
        if not math.isfinite(getattr(start, name)):
            problems.append(f"robot_start.{name}: must be a finite number, got {getattr(start, name)}")
    room = scenario.room
    for name in ("wall_thickness", "wall_height"):
        if not math.isfinite(getattr(room, name)):
            problems.append(f"room.{name}: must be a finite number, got {getattr(room, name)}")
    for k, door in enumerate(room.doorways):
        if not _finite_vector([door.center, door.width], 2):
            problems.append(f"room.doorways[{k}]: center and width must be finite numbers")
    for i, furniture in enumerate(scenario.furniture):
        for j, part in enumerate(furniture.parts):
            _check_rgba(part.rgba, f"furniture[{i}].parts[{j}].rgba", problems)
    for i, event in enumerate(scenario.dynamic_events):
        _check_rgba(event.rgba, f"dynamic_events[{i}].rgba", problems)
    for i, obj in enumerate(scenario.objects):
        if not math.isfinite(obj.support_height):
            problems.append(f"objects[{i}].support_height: must be a finite number, got {obj.support_height}")
    for i, event in enumerate(scenario.dynamic_events):
        where = f"dynamic_events[{i}]"
        if not math.isfinite(event.yaw):
            problems.append(f"{where}.yaw: must be a finite number, got {event.yaw}")
        if isinstance(event, MoveAlongPath):
            if math.isfinite(event.speed) and event.speed > MAX_OBSTACLE_SPEED:
                problems.append(f"{where}.speed: {event.speed} m/s exceeds {MAX_OBSTACLE_SPEED} m/s")
            elif not math.isfinite(event.speed):
                problems.append(f"{where}.speed: must be a finite number, got {event.speed}")
            if not (math.isfinite(event.start_time) and event.start_time >= 0):
                problems.append(f"{where}.start_time: must be a finite number >= 0, got {event.start_time}")
        if isinstance(event, AppearAtDistance) and not math.isfinite(event.trigger_distance):
            problems.append(f"{where}.trigger_distance: must be a finite number, got {event.trigger_distance}")


def _check_rgba(rgba, where: str, problems: list[str]) -> None:
    if not _finite_vector(rgba, 4) or not all(0.0 <= c <= 1.0 for c in rgba):
        problems.append(f"{where}: needs 4 numbers in [0, 1], got {rgba}")


def _check_furniture_geometry(scenario: Scenario, problems: list[str], room_ok: bool) -> None:
    """Each piece of furniture: a finite pose, inside the room's walls, and
    every part resting on the floor or on another part (nothing hovers)."""
    posed = []
    for i, furniture in enumerate(scenario.furniture):
        pose = furniture.pose
        bad = [n for n in ("x", "y", "yaw") if not math.isfinite(getattr(pose, n))]
        for name in bad:
            problems.append(f"furniture[{i}].pose.{name}: must be a finite number, got {getattr(pose, name)}")
        if not bad:
            posed.append((i, furniture))
    poly = scenario.room.polygon() if room_ok else None
    tol = GEOMETRY_TOLERANCE
    for i, furniture in posed:
        primitives = furniture.primitives()
        boxes, outside = [], []
        for prim in primitives:
            footprint = prim.footprint()
            z_lo, z_hi = prim.z_range()
            boxes.append((footprint.min(axis=0), footprint.max(axis=0), z_lo, z_hi))
            if poly is not None and scenario.replicacad is None:
                depth = float(np.max(signed_distance_to_polygon(footprint, poly)))
                # A wall corner of a concave room inside the part: the part spans the corner.
                corners = points_in_polygon(poly, footprint)
                if np.any(corners):
                    depth = max(depth, float(np.max(-signed_distance_to_polygon(poly[corners], footprint))))
                outside.append(depth)
        if outside and max(outside) > tol:
            worst = int(np.argmax(outside))
            problems.append(f"furniture[{i}].pose: {furniture.name} reaches {outside[worst]:.2f} m through the "
                            f"room's walls (part {furniture.parts[worst].name!r})")
        for j, (_, _, z_lo, _) in enumerate(boxes):
            if z_lo < -tol:
                problems.append(f"furniture[{i}].parts[{j}]: {furniture.name}/{furniture.parts[j].name} reaches "
                                f"{-z_lo:.2f} m below the floor")
        grounded = {j for j, (_, _, z_lo, _) in enumerate(boxes) if z_lo <= tol}
        changed = True
        while changed:
            changed = False
            for j, (lo, hi, z_lo, z_hi) in enumerate(boxes):
                if j in grounded:
                    continue
                for k in list(grounded):
                    lo2, hi2, z_lo2, z_hi2 = boxes[k]
                    if (np.all(lo <= hi2 + tol) and np.all(lo2 <= hi + tol)
                            and z_lo <= z_hi2 + tol and z_lo2 <= z_hi + tol):
                        grounded.add(j)
                        changed = True
                        break
        for j, (_, _, z_lo, _) in enumerate(boxes):
            if j not in grounded:
                below = [boxes[k][3] for k in grounded if boxes[k][3] <= z_lo + tol]
                gap = z_lo - max(below, default=0.0)
                problems.append(f"furniture[{i}].parts[{j}]: {furniture.name}/{furniture.parts[j].name} floats "
                                f"{gap:.2f} m above the floor or the part beneath it (touches no other part)")
