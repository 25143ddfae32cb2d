"""The paper's drop check: is a sampled object placement physically stable?

The object is spawned ``drop_height`` above the sampled surface point (its
lowest point that far above the top, in its scanned resting orientation with a
sampled yaw) in a small Drake plant (discrete, SAP) holding the support part
welded and the objects already placed on it welded at their settled poses. It
falls for ``duration`` seconds, or less once it is at rest. It is accepted (paper, "Drop Checking") when

1. its centroid ends -5..+30 cm relative to the support top,
2. it moved less than 30 cm from its spawn point, and
3. it overlapped no existing object at spawn.

The settled pose is what the scenario stores. Nothing is cached between calls,
so the result depends only on the arguments.
"""


from dataclasses import dataclass, field

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.world.primitives import WorldPrimitive
from vamg_drake.world.scene_geometry import SceneGeometryConfig, add_ycb_body, register_primitive
from vamg_drake.world.ycb import load_ycb_asset


@dataclass
class DropCheckConfig:
    """Parameters of the drop check.

    Attributes:
        drop_height: gap between the object's lowest point and the top at spawn [m].
        duration: longest simulated time [s] (objects settle in ~0.5 s).
        settle_after: from this time on [s], the drop ends early once the
            object is at rest (checked every 50 ms; deterministic).
        settle_speed: "at rest" translational speed [m/s].
        settle_angular_speed: "at rest" angular speed [rad/s].
        time_step: plant time step [s]; 0.01 s lets the lightest (20 g)
            objects diverge under hydroelastic contact.
        height_band: accepted centroid height above the top [m] (paper: -5..+30 cm).
        max_displacement: accepted distance from spawn [m] (paper: 30 cm).
    """

    drop_height: float = 0.20
    duration: float = 1.0
    settle_after: float = 0.3
    settle_speed: float = 0.01
    settle_angular_speed: float = 0.2
    time_step: float = 0.005
    height_band: list[float] = field(default_factory=lambda: [-0.05, 0.30])
    max_displacement: float = 0.30


@dataclass(frozen=True)
class Neighbour:
    """An object already resting on the support: name and pose X_WO."""

    name: str
    xyz: np.ndarray
    rpy: np.ndarray


@dataclass(frozen=True)
class DropResult:
    """Outcome of one drop.

    Attributes:
        accepted: whether all three criteria hold.
        reason: "" if accepted, else which criterion failed.
        xyz: settled p_WO [m].
        rpy: settled R_WO [rad].
        height_above_support: settled centroid height above the top [m].
        displacement: distance from spawn to settled centroid [m].
    """

    accepted: bool
    reason: str
    xyz: np.ndarray
    rpy: np.ndarray
    height_above_support: float
    displacement: float


def drop_object(
    name: str,
    support: WorldPrimitive,
    support_height: float,
    p_xy: np.ndarray,
    yaw: float,
    neighbours: list[Neighbour] = (),
    config: DropCheckConfig | None = None,
    geometry: SceneGeometryConfig | None = None,
) -> DropResult:
    """Drops YCB object ``name`` onto ``support`` at ``p_xy`` and reports where it settles.

    Args:
        name: YCB object name.
        support: the support part (welded).
        support_height: z of its top [m].
        p_xy: (2,) sampled surface point.
        yaw: object yaw about W's z [rad].
        neighbours: objects already placed on this support (welded).
        config: drop-check parameters.
        geometry: contact parameters (the scene's, so the check sees the same friction).
    """
    config = config or DropCheckConfig()
    geometry = geometry or SceneGeometryConfig()
    asset = load_ycb_asset(name)

    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=config.time_step, discrete_contact_approximation="sap"),
        builder,
    )
    I_W = RigidTransform()
    support_body = plant.AddRigidBody("support", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.WeldFrames(plant.world_frame(), support_body.body_frame(), I_W)
    register_primitive(plant, support_body, support, I_W, (0.6, 0.5, 0.4, 1.0), geometry)
    for neighbour in neighbours:
        _, body = add_ycb_body(plant, neighbour.name, geometry)
        plant.WeldFrames(
            plant.world_frame(), body.body_frame(), RigidTransform(RollPitchYaw(neighbour.rpy), neighbour.xyz)
        )
    _, body = add_ycb_body(plant, name, geometry)
    p_spawn = np.array([p_xy[0], p_xy[1], support_height + asset.bottom_offset + config.drop_height])
    X_spawn = RigidTransform(RollPitchYaw(0.0, 0.0, yaw), p_spawn)
    plant.SetDefaultFloatingBaseBodyPose(body, X_spawn)
    plant.Finalize()
    diagram = builder.Build()

    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant_context = plant.GetMyContextFromRoot(context)
    query = plant.get_geometry_query_input_port().Eval(plant_context)
    overlaps = query.ComputePointPairPenetration()
    if overlaps:
        return DropResult(False, "overlaps an existing object at spawn", p_spawn, np.array([0.0, 0.0, yaw]), float(p_spawn[2] - support_height), 0.0)

    try:
        t = 0.0
        while t < config.duration:
            t = min(t + 0.05, config.duration)
            simulator.AdvanceTo(t)
            V = plant.EvalBodySpatialVelocityInWorld(plant_context, body)
            if t >= config.settle_after and np.linalg.norm(V.translational()) < config.settle_speed and np.linalg.norm(V.rotational()) < config.settle_angular_speed:
                break
    except RuntimeError as e:  # e.g. a diverging contact solve; reject, never crash
        message = " ".join(str(e).split())[:200]
        return DropResult(False, f"simulation failed: {message}", p_spawn, np.array([0.0, 0.0, yaw]), float("nan"), float("nan"))
    X_settled = plant.EvalBodyPoseInWorld(plant_context, body)
    xyz = np.asarray(X_settled.translation(), dtype=float)
    rpy = np.asarray(RollPitchYaw(X_settled.rotation()).vector(), dtype=float)
    height = float(xyz[2] - support_height)
    displacement = float(np.linalg.norm(xyz - p_spawn))
    reason = ""
    if not config.height_band[0] <= height <= config.height_band[1]:
        reason = f"settled {height:+.3f} m from the support top (band {list(config.height_band)})"
    elif displacement >= config.max_displacement:
        reason = f"moved {displacement:.3f} m from spawn (limit {config.max_displacement})"
    return DropResult(reason == "", reason, xyz, rpy, height, displacement)
