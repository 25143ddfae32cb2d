"""Scenarios in ReplicaCAD scenes: YCB targets on receptacles, a start on the navmesh.

``generate_replicacad_scenario(scene, seed)`` follows the procedural generator
(``vamg_drake.world.rooms``) with the room replaced by a ReplicaCAD scene:

* free base positions: cells of a 2D grid that lie on the navmesh's floor
  polygons and keep the base footprint radius (+ one cell) from every wall and
  obstacle box lower than ``ReplicaCadConfig.robot_height``; the largest
  8-connected region is "reachable";
* support surfaces: the scene's usable receptacles; the target goes on one
  0.4-1.2 m high with a reachable cell within ``reach_radius``;
* every object is sampled clear of the scene geometry above its receptacle,
  accepted by the same drop check as procedural rooms (spawned 20 cm above the
  receptacle, settled pose stored), and then checked against the whole scene
  in Drake (penetration at most ``max_penetration``, i.e. resting contact);
* the start is a reachable cell 3-10 m (Euclidean) from the target.

The scenario stores the scene *name* (``Scenario.replicacad``); the dataset is
found again at build time (``find_replicacad_dir``). Same seed, same dataset,
same config -> the same scenario.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.geometry import ProximityProperties
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from scipy import ndimage

from vamg_drake.world.primitives import signed_distance_to_polygon
from vamg_drake.world.replicacad import (
    ReplicaCadError,
    ReplicaCadLayout,
    find_replicacad_dir,
    load_replicacad_layout,
    register_replicacad,
    resolve_replicacad_dir,
)
from vamg_drake.world.rooms import (
    FloorGrid,
    GenerationError,
    RoomGeneratorConfig,
    _components,
    _drop,
    _r,
    _reach_mask,
    place_clutter,
    sample_start_pose,
)
from vamg_drake.world.scenario import PlacedObject, ReplicaCadScene, Room, Scenario, SupportSurface, validate_scenario
from vamg_drake.world.scene_geometry import SceneGeometryConfig, add_ycb_body
from vamg_drake.world.ycb import YCB_OBJECTS, load_ycb_asset


@dataclass
class ReplicaCadGeneratorConfig:
    """Parameters of the ReplicaCAD scenario generator.

    Attributes:
        objects: the procedural generator's object, target, start, drop-check
            and contact parameters (its room and furniture fields are unused).
        room_margin: the room outline is the scene's bounding rectangle grown by this [m].
        max_attempts: whole-scenario attempts before giving up.
        max_placements: drop-checked placements tried per object before giving up on it.
        max_penetration: deepest accepted contact with the scene after settling [m].
    """

    objects: RoomGeneratorConfig = field(default_factory=RoomGeneratorConfig)
    room_margin: float = 0.3
    max_attempts: int = 10
    max_placements: int = 5
    max_penetration: float = 0.01


class SceneContactCheck:
    """The whole ReplicaCAD scene in a Drake plant, to check placed YCB objects against it."""

    def __init__(self, layout: ReplicaCadLayout, names: list[str], models: list[str] | None = None):
        builder = DiagramBuilder()
        plant, self._scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.0), builder)
        register_replicacad(plant, plant.AddModelInstance("scene"), layout, ProximityProperties(), visuals=False)
        geometry = SceneGeometryConfig(hydroelastic_modulus=None)
        self._bodies = {}
        for name, model in zip(names, models or names):
            _, body = add_ycb_body(plant, name, geometry, model)
            self._bodies[name] = body
        plant.Finalize()
        self._plant = plant
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._parked = {name: RigidTransform([0.0, 3.0 * i, -100.0]) for i, name in enumerate(names)}
        for name, body in self._bodies.items():
            plant.SetFreeBodyPose(self._plant_context, body, self._parked[name])
        self._geometry_ids = {
            name: set(plant.GetCollisionGeometriesForBody(body)) for name, body in self._bodies.items()
        }

    def penetration(self, obj: PlacedObject) -> float:
        """Deepest penetration [m] of ``obj`` at its pose into the scene (0 if none)."""
        body = self._bodies[obj.name]
        self._plant.SetFreeBodyPose(self._plant_context, body, RigidTransform(RollPitchYaw(obj.rpy), np.asarray(obj.xyz, float)))
        query = self._plant.get_geometry_query_input_port().Eval(self._plant_context)
        ids = self._geometry_ids[obj.name]
        depth = 0.0
        for pair in query.ComputePointPairPenetration():
            if pair.id_A in ids or pair.id_B in ids:
                depth = max(depth, float(pair.depth))
        self._plant.SetFreeBodyPose(self._plant_context, body, self._parked[obj.name])
        return depth


def apartment_room(layout: ReplicaCadLayout, margin: float = 0.3, wall_thickness: float = 0.1, wall_height: float = 2.4) -> Room:
    """The room of a ReplicaCAD scene: its bounding rectangle grown by ``margin`` [m]."""
    lo, hi = layout.xy_bounds()
    lo, hi = lo - margin, hi + margin
    outline = [[_r(lo[0]), _r(lo[1])], [_r(hi[0]), _r(lo[1])], [_r(hi[0]), _r(hi[1])], [_r(lo[0]), _r(hi[1])]]
    return Room(outline=outline, wall_thickness=wall_thickness, wall_height=wall_height)


def replicacad_floor_grid(layout: ReplicaCadLayout, room: Room, config: RoomGeneratorConfig, robot_height: float = 1.5) -> tuple[FloorGrid, np.ndarray]:
    """Returns (grid, reachable base cells) of a scene: on the navmesh, clear of walls and obstacles."""
    grid = FloorGrid(room, config.grid_resolution)
    centers = grid.centers.reshape(-1, 2)
    grid.inside = layout.navmesh.contains_xy(centers).reshape(grid.inside.shape)
    occupied = np.zeros_like(grid.inside)
    for shape in layout.static_shapes():
        if shape.z_range()[0] < robot_height:
            occupied |= grid.cells_in_polygon(shape.footprint())
    grid.occupied = occupied
    clearance = ndimage.distance_transform_edt(~occupied) * grid.resolution
    free = grid.inside & (clearance >= config.robot_radius + grid.resolution)
    labels, main = _components(free)
    return grid, (labels == main) if main else np.zeros_like(free)


def generate_replicacad_scenario(
    scene: str, seed: int, dataset_dir: str | Path | None = None, config: ReplicaCadGeneratorConfig | None = None
) -> Scenario:
    """Generates a validated scenario in ReplicaCAD scene ``scene`` from ``seed``.

    Args:
        scene: scene instance name, e.g. "apt_0".
        seed: the generator seed.
        dataset_dir: the dataset, or None to look it up. An explicit directory
            is stored in the scenario (so the file loads again on this machine);
            a looked-up one is not.
        config: generator parameters.

    Raises:
        ReplicaCadError: if the dataset, scene or an asset is missing.
        GenerationError: if no valid scenario was found in ``max_attempts``.
    """
    config = config or ReplicaCadGeneratorConfig()
    explicit = str(resolve_replicacad_dir(dataset_dir)) if dataset_dir else ""
    layout = load_replicacad_layout(scene, explicit or None)
    rng = np.random.default_rng(seed)
    room = apartment_room(layout, config.room_margin, config.objects.wall_thickness, config.objects.wall_height)
    grid, reachable = replicacad_floor_grid(layout, room, config.objects)
    if not np.any(reachable):
        raise GenerationError(f"replicacad {scene!r}: no free base position on the navmesh")
    for _ in range(config.max_attempts):
        scenario = _try_generate(scene, seed, layout, room, grid, reachable, rng, config)
        if scenario is not None:
            scenario.replicacad.dataset_dir = explicit
            validate_scenario(scenario, f"generate_replicacad_scenario({scene!r}, seed={seed})")
            return scenario
    raise GenerationError(f"generate_replicacad_scenario({scene!r}, seed={seed}): no valid scenario in {config.max_attempts} attempts")


def _try_generate(scene, seed, layout, room, grid, reachable, rng, config: ReplicaCadGeneratorConfig) -> Scenario | None:
    objects_config = config.objects
    receptacles = {r.id: r for r in layout.receptacles}
    surfaces = [SupportSurface(r.id, r.height, r.box) for r in layout.receptacles]
    lo_h, hi_h = objects_config.target_height_range
    reach = objects_config.reach_radius
    target_surfaces = [
        s for s in surfaces
        if lo_h <= s.height <= hi_h and np.any(reachable & grid.cells_in_polygon(s.primitive.footprint(), inflate=reach))
    ]
    if not target_surfaces:
        raise GenerationError(f"replicacad {scene!r}: no receptacle {lo_h}-{hi_h} m high within {reach} m of a free base position")

    names = list(YCB_OBJECTS)
    count = int(rng.integers(objects_config.object_count[0], objects_config.object_count[1] + 1))
    chosen = [names[i] for i in rng.choice(len(names), size=count, replace=False)]
    checker = SceneContactCheck(layout, chosen)

    def clear_of_scene(surface: SupportSurface, name: str):
        margin = 0.7 * load_ycb_asset(name).xy_radius + 0.02
        blocked = receptacles[surface.id].blocked

        def accept(p_xy: np.ndarray) -> bool:
            return all(signed_distance_to_polygon(p_xy[None], hull)[0] > margin for hull in blocked)

        return accept

    def place(name: str, surface: SupportSurface, placed: list[PlacedObject], extra=None) -> PlacedObject | None:
        base_accept = clear_of_scene(surface, name)
        accept = base_accept if extra is None else (lambda p: base_accept(p) and extra(p))
        for _ in range(config.max_placements):
            obj = _drop(name, surface, placed, rng, objects_config, accept_xy=accept)
            if obj is None:
                return None
            if checker.penetration(obj) <= config.max_penetration:
                return obj
        return None

    surface = target_surfaces[int(rng.integers(len(target_surfaces)))]
    target = place(chosen[0], surface, [], extra=lambda p: bool(np.any(_reach_mask(grid, reachable, p, reach))))
    if target is None:
        return None
    objects = place_clutter(target, chosen[1:], surfaces, rng, place)
    start = sample_start_pose(grid, reachable, target.xyz[:2], objects_config.start_distance_range, rng)
    if start is None:
        return None
    return Scenario(
        name=f"replicacad_{scene}_{seed:05d}",
        seed=int(seed),
        room=room,
        objects=objects,
        target=target.name,
        robot_start=start,
        time_limit=objects_config.time_limit,
        replicacad=ReplicaCadScene(scene=scene),
    )


__all__ = [
    "ReplicaCadError",
    "apartment_room",
    "ReplicaCadGeneratorConfig",
    "SceneContactCheck",
    "find_replicacad_dir",
    "generate_replicacad_scenario",
    "replicacad_floor_grid",
]
