"""The oracle grasp check: can a free parallel-jaw gripper lift the target?

The appendix ("Oracle Grasp Checking") keeps a benchmark object only if at
least one grasp lifts it in physics. Here:

* **Candidates** (instead of Contact-GraspNet, which is not available offline):
  geometric grasps on the object's collision hull as it rests in the scenario:
  top-down grasps (approach -z, closing axis at ``top_down_yaws`` angles) and
  side grasps (horizontal approach from ``side_azimuths`` directions, closing
  horizontally), each kept only if the hull's width across the closing axis
  (in the fingers' height band) fits the opening with ``width_margin`` to spare;
  narrowest first, at most ``max_candidates``.
* **Physics** (Drake, discrete SAP, the scene's contact parameters): the
  support part welded, the object free at its settled pose, and a gripper with
  no gravity: a palm and two box fingers (``finger_length`` 10 cm, opening
  up to ``max_opening`` 10 cm), moved by PD-controlled prismatic x, y, z joints
  (fixed orientation) and PD-closed fingers with a bounded force. Script: from
  10 cm back along the approach (pre-grasp), approach, close to 2 mm, retreat
  to the pre-grasp and lift 10 cm, hold.
* **Success** (appendix): both fingers touch the object at the end, the object
  rose at least ``min_lift`` (3 cm), and it moved less than ``max_slip`` (3 cm)
  relative to the gripper during the hold.

A candidate that starts in penetration is skipped. Nothing is cached here.
"""

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh
from pydrake.geometry import AddContactMaterial, AddRigidHydroelasticProperties, Box, ProximityProperties
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
from pydrake.multibody.tree import FixedOffsetFrame, PdControllerGains, PrismaticJoint, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.world.primitives import WorldPrimitive
from vamg_drake.world.scenario import Scenario
from vamg_drake.world.scene_geometry import SceneGeometryConfig, add_ycb_body, register_primitive
from vamg_drake.world.ycb import load_ycb_asset


@dataclass
class OracleGraspConfig:
    """Parameters of the oracle grasp check.

    Attributes:
        finger_length: finger box length along the approach [m] (paper: 0.10).
        finger_thickness: finger box size along the closing axis [m].
        finger_width: finger box size across the approach and closing axes [m].
        max_opening: widest opening [m] (paper: 0.10).
        closed_opening: commanded closed opening [m] (paper: 2 mm).
        width_margin: a candidate needs hull width <= max_opening - width_margin [m].
        pregrasp_offset: pre-grasp distance back along the approach [m] (paper: 0.10).
        lift_height: lift after the retreat [m] (paper: 0.10).
        grip_force: finger force limit [N].
        top_down_yaws: number of closing-axis angles of top-down grasps (over 180 deg).
        side_azimuths: number of side approach directions (over 360 deg).
        side_depth: side grasps put the fingertips this far past the centroid [m].
        table_clearance: fingertips stay this far above the support top [m].
        max_candidates: most candidates simulated.
        min_lift: success: object rise [m] (paper: 0.03).
        max_slip: success: object motion relative to the gripper during the hold [m] (paper: 0.03).
        hold_time: stability hold [s] (paper: 30 steps).
        time_step: plant time step [s].
        geometry: contact parameters (the scene's).
    """

    finger_length: float = 0.10
    finger_thickness: float = 0.012
    finger_width: float = 0.03
    max_opening: float = 0.10
    closed_opening: float = 0.002
    width_margin: float = 0.01
    pregrasp_offset: float = 0.10
    lift_height: float = 0.10
    grip_force: float = 40.0
    top_down_yaws: int = 4
    side_azimuths: int = 8
    side_depth: float = 0.01
    table_clearance: float = 0.012
    max_candidates: int = 12
    min_lift: float = 0.03
    max_slip: float = 0.03
    hold_time: float = 0.15
    time_step: float = 0.005
    geometry: SceneGeometryConfig = field(default_factory=SceneGeometryConfig)


@dataclass(frozen=True)
class GraspCandidate:
    """A grasp frame pose: origin between the fingertips, +x approach, +y closing.

    Attributes:
        kind: "top_down" or "side".
        p_WG: (3,) origin.
        R_WG: (3, 3) orientation.
        width: object hull width across the closing axis [m].
    """

    kind: str
    p_WG: np.ndarray
    R_WG: np.ndarray
    width: float


@dataclass(frozen=True)
class OracleGraspResult:
    """Outcome of the oracle check.

    Attributes:
        graspable: at least one candidate lifted the object.
        candidates: candidates that fit the opening.
        tried: candidates simulated.
        reason: why it is not graspable ("" if graspable).
        lift: rise of the object in the successful (or best) trial [m].
    """

    graspable: bool
    candidates: int
    tried: int
    reason: str
    lift: float


def hull_vertices_W(model: str, X_WO: RigidTransform) -> np.ndarray:
    """The convex hull's vertices (N, 3) of YCB object `model` at pose X_WO."""
    mesh = trimesh.load(str(load_ycb_asset(model).collision_path), force="mesh")
    return (X_WO.rotation().matrix() @ np.asarray(mesh.vertices).T).T + X_WO.translation()


def _hull_vertices_W(scenario: Scenario, name: str) -> np.ndarray:
    obj = scenario.object(name)
    return hull_vertices_W(obj.ycb_model, RigidTransform(RollPitchYaw(obj.rpy), obj.xyz))


def _frame(approach: np.ndarray, closing: np.ndarray) -> np.ndarray:
    x = approach / np.linalg.norm(approach)
    y = closing - x * (closing @ x)
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def grasp_candidates(scenario: Scenario, name: str, config: OracleGraspConfig | None = None) -> list[GraspCandidate]:
    """Geometric grasp candidates on object ``name`` at its scenario pose (narrowest first)."""
    return hull_grasp_candidates(_hull_vertices_W(scenario, name), scenario.object(name).support_height, config)


def hull_grasp_candidates(V: np.ndarray, support: float,
                          config: OracleGraspConfig | None = None) -> list[GraspCandidate]:
    """Geometric grasp candidates on an object whose hull vertices are V (N, 3)
    in W, resting on a support whose top is at height `support` (narrowest first)."""
    config = config or OracleGraspConfig()
    centre = V.mean(axis=0)
    centre[2] = 0.5 * (V[:, 2].min() + V[:, 2].max())
    top = V[:, 2].max()
    limit = config.max_opening - config.width_margin
    out = []
    for k in range(config.top_down_yaws):
        yaw = math.pi * k / config.top_down_yaws
        closing = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        R = _frame(np.array([0.0, 0.0, -1.0]), closing)
        tip_z = max(support + config.table_clearance + 0.5 * config.finger_width, top - config.finger_length + 0.02, centre[2] - 0.02)
        tip_z = min(tip_z, top - 0.01)
        band = V[(V[:, 2] >= tip_z - 0.5 * config.finger_width) & (V[:, 2] <= tip_z + config.finger_length)]
        if len(band) == 0:
            continue
        width = float(np.ptp(band @ closing))
        if width <= limit:
            out.append(GraspCandidate("top_down", np.array([centre[0], centre[1], tip_z]), R, width))
    z = max(centre[2], support + config.table_clearance + 0.5 * config.finger_width)
    band = V[np.abs(V[:, 2] - z) <= 0.5 * config.finger_width]
    for k in range(config.side_azimuths):
        phi = 2 * math.pi * k / config.side_azimuths
        approach = -np.array([math.cos(phi), math.sin(phi), 0.0])
        closing = np.array([-approach[1], approach[0], 0.0])
        if len(band) == 0:
            continue
        width = float(np.ptp(band @ closing))
        if width <= limit:
            p = np.array([centre[0], centre[1], z]) + config.side_depth * approach
            out.append(GraspCandidate("side", p, _frame(approach, closing), width))
    out.sort(key=lambda c: c.width)
    return out[: config.max_candidates]


def _gripper_props(config: OracleGraspConfig) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(config.geometry.static_friction, config.geometry.dynamic_friction), properties=props)
    if config.geometry.hydroelastic_modulus is not None:
        AddRigidHydroelasticProperties(0.01, props)
    return props


def _simulate(scenario: Scenario, name: str, candidate: GraspCandidate, config: OracleGraspConfig) -> tuple[bool, float, str]:
    obj = scenario.object(name)
    surfaces = {s.id: s for s in scenario.support_surfaces()}
    support = surfaces[obj.support].primitive if obj.support in surfaces else None
    return simulate_grasp(obj.model or name, RigidTransform(RollPitchYaw(obj.rpy), obj.xyz), support, candidate, config)


def simulate_grasp(model: str, X_WO: RigidTransform, support: WorldPrimitive | None, candidate: GraspCandidate,
                   config: OracleGraspConfig) -> tuple[bool, float, str]:
    """Executes one grasp of YCB object ``model`` resting at X_WO on ``support``
    (welded; None: no support) with the free gripper: approach from the
    pre-grasp pose, close, retreat, lift and hold.

    Returns:
        (success, lift [m], reason it failed or "").
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=config.time_step, discrete_contact_approximation="sap"), builder)
    support_body = plant.AddRigidBody("support", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.WeldFrames(plant.world_frame(), support_body.body_frame(), RigidTransform())
    if support is not None:
        register_primitive(plant, support_body, support, RigidTransform(), (0.6, 0.5, 0.4, 1.0), config.geometry)
    _, object_body = add_ycb_body(plant, "object", config.geometry, model)
    plant.SetDefaultFloatingBaseBodyPose(object_body, X_WO)

    gripper = plant.AddModelInstance("oracle_gripper")
    light = SpatialInertia.SolidSphereWithMass(0.05, 0.01)
    carriage_x = plant.AddRigidBody("carriage_x", gripper, light)
    carriage_y = plant.AddRigidBody("carriage_y", gripper, light)
    hand = plant.AddRigidBody("hand", gripper, SpatialInertia.SolidBoxWithMass(0.5, 0.04, 0.12, 0.06))
    joints = [
        plant.AddJoint(PrismaticJoint("gx", plant.world_frame(), carriage_x.body_frame(), [1, 0, 0])),
        plant.AddJoint(PrismaticJoint("gy", carriage_x.body_frame(), carriage_y.body_frame(), [0, 1, 0])),
    ]
    # The hand frame is G: the z joint carries it with the candidate's fixed orientation.
    hand_z = plant.AddFrame(_fixed_frame("z_parent", carriage_y.body_frame(), RigidTransform()))
    joints.append(plant.AddJoint(PrismaticJoint("gz", hand_z, plant.AddFrame(_fixed_frame("G_on_hand", hand.body_frame(), RigidTransform(RotationMatrix(candidate.R_WG).inverse()))), [0, 0, 1])))
    props = _gripper_props(config)
    palm_depth = 0.02
    span = config.max_opening + 2 * config.finger_thickness
    X_GPalm = RigidTransform([-config.finger_length - 0.5 * palm_depth, 0.0, 0.0])
    plant.RegisterCollisionGeometry(hand, X_GPalm, Box(palm_depth, span, config.finger_width), "palm", props)
    plant.RegisterVisualGeometry(hand, X_GPalm, Box(palm_depth, span, config.finger_width), "palm", np.array([0.3, 0.3, 0.3, 1.0]))
    fingers = []
    for side in (+1, -1):
        finger = plant.AddRigidBody(f"finger_{'l' if side > 0 else 'r'}", gripper, SpatialInertia.SolidBoxWithMass(0.05, config.finger_length, config.finger_thickness, config.finger_width))
        X_GF = RigidTransform([-0.5 * config.finger_length, side * 0.5 * config.finger_thickness, 0.0])
        plant.RegisterCollisionGeometry(finger, X_GF, Box(config.finger_length, config.finger_thickness, config.finger_width), finger.name(), props)
        plant.RegisterVisualGeometry(finger, X_GF, Box(config.finger_length, config.finger_thickness, config.finger_width), finger.name(), np.array([0.2, 0.2, 0.2, 1.0]))
        joints.append(plant.AddJoint(PrismaticJoint(f"{finger.name()}_slide", hand.body_frame(), finger.body_frame(), [0, side, 0], 0.0, 0.5 * config.max_opening)))
        fingers.append(finger)
    for joint in joints[:3]:
        actuator = plant.AddJointActuator(f"{joint.name()}_motor", joint)
        actuator.set_controller_gains(PdControllerGains(p=4000.0, d=150.0))
    for joint in joints[3:]:
        actuator = plant.AddJointActuator(f"{joint.name()}_motor", joint, config.grip_force)
        actuator.set_controller_gains(PdControllerGains(p=2000.0, d=20.0))
    plant.set_gravity_enabled(gripper, False)
    plant.Finalize()
    desired_port = plant.get_desired_state_input_port(gripper)
    diagram = builder.Build()

    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    pc = plant.GetMyContextFromRoot(context)
    a = candidate.R_WG[:, 0]
    p_pre = candidate.p_WG - config.pregrasp_offset * a
    p_up = p_pre + np.array([0.0, 0.0, config.lift_height])
    half_open, half_closed = 0.5 * config.max_opening, 0.5 * config.closed_opening
    for joint, value in zip(joints, [*p_pre, half_open, half_open]):
        joint.set_translation(pc, value)
    query = plant.get_geometry_query_input_port().Eval(pc)
    gripper_geoms = {g for b in plant.GetBodyIndices(gripper) for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))}
    if any({pair.id_A, pair.id_B} & gripper_geoms for pair in query.ComputePointPairPenetration()):
        return False, 0.0, "gripper starts in collision"

    # (time, position, half-opening) keyframes, linearly interpolated.
    keys = [
        (0.0, p_pre, half_open), (0.3, p_pre, half_open), (1.0, candidate.p_WG, half_open),
        (1.2, candidate.p_WG, half_open), (1.7, candidate.p_WG, half_closed), (2.4, p_pre, half_closed),
        (3.0, p_up, half_closed), (3.2, p_up, half_closed),
    ]
    t_hold = keys[-1][0]
    times = np.array([k[0] for k in keys])

    def desired(t: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(times, t) - 1, 0, len(keys) - 2))
        s = float(np.clip((t - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0))
        p = (1 - s) * keys[i][1] + s * keys[i + 1][1]
        w = (1 - s) * keys[i][2] + s * keys[i + 1][2]
        v = (keys[i + 1][1] - keys[i][1]) / (times[i + 1] - times[i]) if s < 1.0 else np.zeros(3)
        return np.concatenate([p, [w, w], v, [0.0, 0.0]])

    z0 = plant.EvalBodyPoseInWorld(pc, object_body).translation()[2]
    dt = 0.02
    t = 0.0
    p_GO_hold = None
    slip = 0.0
    while t < t_hold + config.hold_time - 1e-9:
        desired_port.FixValue(pc, desired(t))
        t = round(t + dt, 6)
        try:
            simulator.AdvanceTo(t)
        except RuntimeError as e:  # a diverging contact solve: this candidate fails, the check goes on
            return False, 0.0, f"simulation failed: {' '.join(str(e).split())[:120]}"
        if t >= t_hold:
            X_WH = plant.EvalBodyPoseInWorld(pc, hand)
            p_HO = X_WH.inverse() @ plant.EvalBodyPoseInWorld(pc, object_body).translation()
            p_GO_hold = p_HO if p_GO_hold is None else p_GO_hold
            slip = max(slip, float(np.linalg.norm(p_HO - p_GO_hold)))
    lift = float(plant.EvalBodyPoseInWorld(pc, object_body).translation()[2] - z0)
    contacts = plant.get_contact_results_output_port().Eval(pc)
    touching = set()
    object_geoms = set(plant.GetCollisionGeometriesForBody(object_body))
    finger_geoms = {g: f.name() for f in fingers for g in plant.GetCollisionGeometriesForBody(f)}
    for i in range(contacts.num_hydroelastic_contacts()):
        info = contacts.hydroelastic_contact_info(i)
        ids = {info.contact_surface().id_M(), info.contact_surface().id_N()}
        if ids & object_geoms:
            touching |= {finger_geoms[g] for g in ids if g in finger_geoms}
    for i in range(contacts.num_point_pair_contacts()):
        pair = contacts.point_pair_contact_info(i)
        ids = {pair.point_pair().id_A, pair.point_pair().id_B}
        if ids & object_geoms:
            touching |= {finger_geoms[g] for g in ids if g in finger_geoms}
    if len(touching) < 2:
        return False, lift, f"{len(touching)} finger(s) touch the object at the end"
    if lift < config.min_lift:
        return False, lift, f"object rose {lift:.3f} m (< {config.min_lift})"
    if slip >= config.max_slip:
        return False, lift, f"object slipped {slip:.3f} m in the hold (>= {config.max_slip})"
    return True, lift, ""


def _fixed_frame(name: str, parent, X_PF: RigidTransform):
    return FixedOffsetFrame(name, parent, X_PF)


def check_graspable(scenario: Scenario, name: str | None = None, config: OracleGraspConfig | None = None) -> OracleGraspResult:
    """Runs the oracle check on object ``name`` (default: the scenario's target)."""
    config = config or OracleGraspConfig()
    name = name or scenario.target
    return _check(name, grasp_candidates(scenario, name, config),
                  lambda candidate: _simulate(scenario, name, candidate, config), config)


def check_graspable_at(model: str, X_WO: RigidTransform, support: WorldPrimitive, support_top: float,
                       config: OracleGraspConfig | None = None) -> OracleGraspResult:
    """The oracle check of YCB object `model` resting at X_WO on `support`
    (whose top is at height `support_top`), outside any scenario."""
    config = config or OracleGraspConfig()
    candidates = hull_grasp_candidates(hull_vertices_W(model, X_WO), support_top, config)
    return _check(model, candidates, lambda candidate: simulate_grasp(model, X_WO, support, candidate, config), config)


def _check(name: str, candidates: list[GraspCandidate], simulate, config: OracleGraspConfig) -> OracleGraspResult:
    """Simulates `candidates` in turn (`simulate(candidate) -> (ok, lift,
    reason)`) until one lifts the object."""
    if not candidates:
        return OracleGraspResult(False, 0, 0, f"'{name}': no grasp fits the {config.max_opening:.2f} m opening", 0.0)
    best_lift, reasons = 0.0, []
    for tried, candidate in enumerate(candidates, start=1):
        ok, lift, reason = simulate(candidate)
        if ok:
            return OracleGraspResult(True, len(candidates), tried, "", lift)
        best_lift = max(best_lift, lift)
        reasons.append(f"{candidate.kind}: {reason}")
    summary = "; ".join(sorted(set(reasons)))[:300]
    return OracleGraspResult(False, len(candidates), len(candidates), f"'{name}': no candidate lifted it ({summary})", best_lift)
