"""The authored Fetch model: Drake parses it, FK agrees, spheres cover it."""

import numpy as np
import pytest
import yaml
from pydrake.geometry import Box, Cylinder
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import (
    EXTENDED_JOINTS,
    JOINT_SKIPPED,
    NX,
    FetchKinematics,
    fetch_urdf_path,
    link_transforms,
    tip_jacobian,
)
from vamg_drake.robot.spheres import FINGER_LINKS, SPHERES_YAML, SphereModel, fit_spheres


@pytest.fixture(scope="module")
def drake_fetch():
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), builder)
    Parser(plant).AddModels(str(fetch_urdf_path()))
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    return plant, scene_graph, diagram, context


def _set_extended(plant, plant_context, V):
    x = np.zeros(plant.num_positions())
    for name, v in zip(EXTENDED_JOINTS, V):
        x[plant.GetJointByName(name).position_start()] = v
    plant.SetPositions(plant_context, x)


def _random_extended(rng, n):
    q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (n, layout.NQ))
    q[:, :2] = rng.uniform(-3, 3, (n, 2))
    head = np.c_[rng.uniform(*layout.HEAD_PAN_LIMITS, n), rng.uniform(*layout.HEAD_TILT_LIMITS, n)]
    fingers = rng.uniform(*layout.FINGER_LIMITS, (n, 2))
    return np.c_[q, head, fingers]


def test_joint_layout_matches_drake(drake_fetch):
    plant = drake_fetch[0]
    assert plant.num_positions() == len(EXTENDED_JOINTS) == 15
    for name, lo, hi in zip(layout.WHOLE_BODY_JOINTS, layout.Q_LOWER, layout.Q_UPPER):
        joint = plant.GetJointByName(name)
        if np.isfinite(lo):
            assert joint.position_lower_limits()[0] == pytest.approx(lo)
            assert joint.position_upper_limits()[0] == pytest.approx(hi)
    assert plant.num_actuators() == 15


def test_fk_agrees_with_drake(drake_fetch):
    plant, _, diagram, context = drake_fetch
    pc = plant.GetMyContextFromRoot(context)
    kin = FetchKinematics.instance()
    rng = np.random.default_rng(0)
    V = _random_extended(rng, 20)
    X_ours = kin.poses_extended(V)
    for b, v in enumerate(V):
        _set_extended(plant, pc, v)
        for i, name in enumerate(kin.link_names):
            X = plant.CalcRelativeTransform(pc, plant.world_frame(), plant.GetFrameByName(name)).GetAsMatrix4()
            np.testing.assert_allclose(X_ours[b, i], X, atol=1e-9, err_msg=name)


def test_kernel_agrees_with_drake_on_every_link_with_its_jacobian(drake_fetch):
    """The one kinematics kernel: every link's pose to 1e-12 of Drake's, the
    same bits when only a subtree is computed (other rows untouched), and
    each link's geometric Jacobian to 1e-12 of Drake's."""
    plant, _, diagram, context = drake_fetch
    pc = plant.GetMyContextFromRoot(context)
    tree = FetchKinematics.instance().tree
    L = len(tree.link_names)
    column = np.arange(NX, dtype=np.int64)  # every variable is a Jacobian column
    # Drake's velocity index of each extended-configuration variable.
    drake_v = [plant.GetJointByName(name).velocity_start() for name in EXTENDED_JOINTS]
    rng = np.random.default_rng(7)
    T = np.empty((L, 3, 4))
    J = np.empty((6, NX))
    for v in _random_extended(rng, 25):
        _set_extended(plant, pc, v)
        link_transforms(tree.parent, tree.X_PJ, tree.joint_type, tree.axis, tree.var_index, v, T)
        for i, name in enumerate(tree.link_names):
            frame = plant.GetFrameByName(name)
            X = plant.CalcRelativeTransform(pc, plant.world_frame(), frame).GetAsMatrix4()
            np.testing.assert_allclose(T[i], X[:3], rtol=0, atol=1e-12, err_msg=name)
            Jd = plant.CalcJacobianSpatialVelocity(pc, JacobianWrtVariable.kV, frame, np.zeros(3),
                                                   plant.world_frame(), plant.world_frame())
            tip_jacobian(tree.parent, tree.joint_type, tree.axis, tree.var_index, T, i, column, J)
            np.testing.assert_allclose(J[:3], Jd[3:, drake_v], rtol=0, atol=1e-12, err_msg=f"{name} v")
            np.testing.assert_allclose(J[3:], Jd[:3, drake_v], rtol=0, atol=1e-12, err_msg=f"{name} w")
        # A subtree: the same bits for its links, nothing written elsewhere.
        links = rng.choice(L, size=3, replace=False)
        masked = tree.subtree_joint_types(links)
        S = np.full((L, 3, 4), np.nan)
        link_transforms(tree.parent, tree.X_PJ, masked, tree.axis, tree.var_index, v, S)
        computed = masked != JOINT_SKIPPED
        assert computed[links].all()
        np.testing.assert_array_equal(S[computed], T[computed])
        assert np.isnan(S[~computed]).all()


def test_camera_frame_looks_forward_from_the_head():
    kin = FetchKinematics.instance()
    q = layout.stow_configuration(1.0, 2.0, np.pi / 2)
    X_WC = kin.camera_pose(q, 0.0, 0.0)
    # Optical axis +z_C points along the base heading (+y world here); +y_C down.
    np.testing.assert_allclose(X_WC[:3, 2], [0, 1, 0], atol=1e-9)
    np.testing.assert_allclose(X_WC[:3, 1], [0, 0, -1], atol=1e-9)
    assert 1.0 < X_WC[2, 3] < 1.2  # Fetch head camera height with the torso down.
    # Panning left turns the optical axis towards -x world.
    assert kin.camera_pose(q, 0.5, 0.0)[0, 2] < -0.4


def _surface_samples(shape, rng, n=200):
    """Points on the surface of a Drake Box or Cylinder, in the shape frame."""
    if isinstance(shape, Box):
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        p = rng.uniform(-1, 1, (n, 3))
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n))
        return p * half
    assert isinstance(shape, Cylinder)
    r, h = shape.radius(), shape.length() / 2
    t = rng.uniform(0, 2 * np.pi, n)
    side = np.c_[r * np.cos(t), r * np.sin(t), rng.uniform(-h, h, n)]
    rho = r * np.sqrt(rng.uniform(0, 1, n))
    caps = np.c_[rho * np.cos(t), rho * np.sin(t), np.where(rng.uniform(size=n) < 0.5, -h, h)]
    return np.where((rng.uniform(size=n) < 0.5)[:, None], side, caps)


def test_spheres_cover_collision_geometry(drake_fetch):
    plant, scene_graph, diagram, context = drake_fetch
    pc = plant.GetMyContextFromRoot(context)
    inspector = scene_graph.model_inspector()
    model = SphereModel.load()
    kin = FetchKinematics.instance()
    rng = np.random.default_rng(1)
    for v in _random_extended(rng, 8):
        _set_extended(plant, pc, v)
        centers = model.world_spheres(v[: layout.NQ], head=v[layout.NQ : layout.NQ + 2])
        for body_index in plant.GetBodyIndices(plant.GetModelInstanceByName("fetch")):
            body = plant.get_body(body_index)
            link = "gripper_link" if body.name() in FINGER_LINKS else body.name()
            mine = model.link_index == kin.link_index(link) if link in kin.link_names else None
            for gid in plant.GetCollisionGeometriesForBody(body):
                p_BS = _surface_samples(inspector.GetShape(gid), rng)
                X_BG = inspector.GetPoseInFrame(gid).GetAsMatrix4()
                X_WB = plant.EvalBodyPoseInWorld(pc, body).GetAsMatrix4()
                p_W = (X_WB @ X_BG @ np.c_[p_BS, np.ones(len(p_BS))].T)[:3].T
                d = np.linalg.norm(p_W[:, None] - centers[None, mine], axis=-1) - model.radius[mine]
                assert np.all(d.min(axis=1) <= 1e-9), f"{inspector.GetName(gid)} not covered by {link} spheres"


def test_sphere_self_collision_is_conservative(drake_fetch):
    plant, scene_graph, diagram, context = drake_fetch
    pc = plant.GetMyContextFromRoot(context)
    sc = scene_graph.GetMyContextFromRoot(context)
    model = SphereModel.load()
    rng = np.random.default_rng(2)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (600, layout.NQ))
    free = model.self_collision_free(Q)
    for q, f in zip(Q, free):
        _set_extended(plant, pc, np.r_[q, 0.0, 0.0, 0.05, 0.05])
        collides = scene_graph.get_query_output_port().Eval(sc).HasCollisions()
        assert not (f and collides), f"sphere model calls {q} free, Drake finds a collision"
    assert free.mean() > 0.6  # and it is not uselessly conservative


def test_stow_pose_is_self_collision_free():
    assert SphereModel.load().self_collision_free(layout.stow_configuration(0, 0, 0), margin=0.015)[0]


def test_sphere_yaml_is_up_to_date():
    stored = yaml.safe_load(SPHERES_YAML.read_text())
    fresh = fit_spheres()
    assert stored["model_hash"] == fresh["model_hash"], "fetch.urdf changed: run python -m vamg_drake.robot.spheres"
    assert len(stored["spheres"]) == len(fresh["spheres"])
    assert stored["self_collision_pairs"] == fresh["self_collision_pairs"]
