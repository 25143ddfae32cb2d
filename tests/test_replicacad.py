"""ReplicaCAD scenes: loading, frames, rendering, scenarios, errors.

Runs on the ReplicaCAD sample beside the repository (``../shared/replicacad``)
or on ``$VAMG_REPLICACAD_DIR``; skipped with the reason when neither exists.
"""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import ClippingRange, DepthRange, DepthRenderCamera, MakeRenderEngineVtk, RenderCameraCore, RenderEngineVtkParams
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import CameraInfo

from vamg_drake.world.primitives import signed_distance_to_polygon
from vamg_drake.world.replicacad import (
    R_ZY,
    ReplicaCadError,
    find_replicacad_dir,
    list_replicacad_scenes,
    is_floor_covering_name,
    load_replicacad_layout,
    points_to_z_up,
    pose_to_z_up,
)
from vamg_drake.world.replicacad_generator import generate_replicacad_scenario
from vamg_drake.world.scenario import ReplicaCadScene, Scenario, ScenarioError, load_scenario, save_scenario, validate_scenario
from vamg_drake.world.scene_geometry import add_scene

SCENES = ("apt_0", "v3_sc0_staging_00", "v3_sc1_staging_00")
_SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "replicacad"


def _sample_dir() -> Path | None:
    root = os.environ.get("VAMG_REPLICACAD_DIR") or str(_SAMPLE)
    try:
        return find_replicacad_dir(root)
    except ReplicaCadError:
        return None


DATASET = _sample_dir()
pytestmark = pytest.mark.skipif(
    DATASET is None, reason=f"ReplicaCAD sample not found (set VAMG_REPLICACAD_DIR or provide {_SAMPLE})"
)


@pytest.fixture(autouse=True)
def _dataset_env(monkeypatch):
    if DATASET is not None:
        monkeypatch.setenv("VAMG_REPLICACAD_DIR", str(DATASET))


@pytest.fixture(scope="module")
def scenarios() -> dict[str, Scenario]:
    if DATASET is None:
        return {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("VAMG_REPLICACAD_DIR", str(DATASET))
        return {scene: generate_replicacad_scenario(scene, seed=0, dataset_dir=None) for scene in SCENES}


# ------------------------------------------------------------------ frames


def test_y_up_to_z_up_is_one_proper_rotation():
    assert np.allclose(R_ZY @ R_ZY.T, np.eye(3)) and np.isclose(np.linalg.det(R_ZY), 1.0)
    assert np.allclose(points_to_z_up(np.array([[0.0, 1.0, 0.0]])), [[0, 0, 1]])  # Y-up is Z-up
    assert np.allclose(points_to_z_up(np.array([[0.0, 0.0, 1.0]])), [[0, -1, 0]])  # Habitat's back is -y
    X = np.eye(4)
    X[:3, 3] = [1.0, 2.0, 3.0]
    assert np.allclose(pose_to_z_up(X)[:3, 3], [1.0, -3.0, 2.0])


@pytest.mark.parametrize("scene", SCENES)
def test_scene_loads_with_level_surfaces_and_floor_at_zero(scene):
    layout = load_replicacad_layout(scene)
    assert len(layout.bodies) > 20
    floor_z = np.concatenate([layout.navmesh.vertices[p, 2] for p in layout.navmesh.polygons])
    assert np.all(np.abs(floor_z) < 0.2), "navmesh floor must be at z ~ 0 (Y-up read as Z-up would not be)"
    assert layout.navmesh.boundary_edges.shape[1:] == (2, 3)
    # Table and counter tops: level, 0.6-1.0 m high, and the collision geometry is right below them.
    tops = [r for r in layout.receptacles if "table_01" in r.id or "counter_left" in r.id]
    assert tops, [r.id for r in layout.receptacles]
    for r in tops:
        assert 0.6 <= r.height <= 1.0, (r.id, r.height)
        assert np.allclose(r.box.R_WB[:, 2], [0, 0, 1])
    # Furniture stands on the floor (z = 0), nothing is below it.
    bottoms = np.array([min(p[:, 2].min() for p in b.pieces_W()) for b in layout.bodies if b.pieces_B])
    assert np.min(bottoms) > -0.15 and np.count_nonzero(np.abs(bottoms) < 0.06) >= 5
    # Everything sits in one horizontal slab: nothing above 3 m or under the floor.
    tops_z = np.array([max(p[:, 2].max() for p in b.pieces_W()) for b in layout.bodies if b.pieces_B])
    assert np.max(tops_z) < 3.0


def test_floor_coverings_by_name_rest_on_the_floor_and_are_not_obstacles():
    assert is_floor_covering_name("rc/020_frl_apartment_rug_01") and is_floor_covering_name("objects/frl_apartment_mat")
    assert not is_floor_covering_name("rc/030_frl_apartment_material_box") and not is_floor_covering_name("rc/001_frl_apartment_table_01")
    if "apt_1" not in list_replicacad_scenes(DATASET):
        pytest.skip(f"apt_1 not in {DATASET}")
    layout = load_replicacad_layout("apt_1")  # its rug_01 and mat float 3-5 cm above the floor in the scene file
    coverings = [b for b in layout.bodies if is_floor_covering_name(b.name)]
    assert len(coverings) == 3
    for body in coverings:
        z = np.concatenate(body.pieces_W())[:, 2]
        assert body.floor_covering and abs(z.min()) < 1e-6 and z.max() < 0.03, (body.name, z.min(), z.max())
    assert not any(is_floor_covering_name(box.name.rsplit("/", 1)[0]) for box in layout.obstacles)


def test_receptacle_surface_matches_collision_top():
    layout = load_replicacad_layout("v3_sc0_staging_00")
    r = next(r for r in layout.receptacles if "table_01" in r.id)
    body = next(b for b in layout.bodies if r.id.startswith(b.name + "/"))
    c = r.box.p_WB[:2]
    tops = [p[:, 2].max() for p in body.pieces_W() if np.all(np.abs(p[:, :2].mean(axis=0) - c) < 0.8)]
    assert abs(max(tops) - r.height) < 0.03


def test_visual_mesh_and_collision_pieces_coincide():
    """Drake's glTF import (y-up -> z-up) and our collision points share the body frame."""
    from pydrake.geometry import Mesh

    layout = load_replicacad_layout("v3_sc0_staging_00")
    body = next(b for b in layout.bodies if "table_01" in b.name)
    path, X_BG, scale = body.visuals[0]
    hull = Mesh(str(path), scale).GetConvexHull()
    v = np.array([hull.vertex(i) for i in range(hull.num_vertices())]) @ X_BG[:3, :3].T + X_BG[:3, 3]
    c = np.concatenate(body.pieces_B)
    assert np.allclose(v.min(axis=0), c.min(axis=0), atol=0.03)
    assert np.allclose(v.max(axis=0), c.max(axis=0), atol=0.03)


# -------------------------------------------------------------- scenarios


@pytest.mark.parametrize("scene", SCENES)
def test_generated_scenario_is_valid_and_round_trips(scene, scenarios, tmp_path):
    scenario = scenarios[scene]
    validate_scenario(scenario)
    assert scenario.replicacad.scene == scene and scenario.replicacad.dataset_dir == ""
    layout = scenario.replicacad_layout()
    start = np.array([[scenario.robot_start.x, scenario.robot_start.y]])
    assert layout.navmesh.contains_xy(start)[0]
    surfaces = {s.id: s for s in scenario.support_surfaces()}
    target = scenario.object(scenario.target)
    assert 0.4 <= surfaces[target.support].height <= 1.2
    for obj in scenario.objects:
        assert obj.support.startswith("rc/")
        assert -0.05 <= obj.xyz[2] - surfaces[obj.support].height <= 0.3
    path = tmp_path / "s.yaml"
    save_scenario(scenario, path)
    assert str(DATASET) not in path.read_text()  # no machine path in the file
    assert load_scenario(path) == scenario


def test_same_seed_same_scenario(scenarios):
    again = generate_replicacad_scenario("v3_sc1_staging_00", seed=0)
    assert again == scenarios["v3_sc1_staging_00"]


def test_start_off_the_navmesh_is_rejected(scenarios):
    scenario = scenarios["v3_sc0_staging_00"]
    bad = Scenario(**{**scenario.__dict__})
    lo = np.asarray(scenario.room.outline).min(axis=0)
    bad.robot_start = type(scenario.robot_start)(x=float(lo[0]) + 0.35, y=float(lo[1]) + 0.35, yaw=0.0)
    with pytest.raises(ScenarioError, match="robot_start"):
        validate_scenario(bad)


@pytest.mark.parametrize("scene", SCENES)
def test_scene_builds_and_depth_camera_sees_the_furniture(scene, scenarios):
    scenario = scenarios[scene]
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.005, discrete_contact_approximation="sap"), builder)
    handles = add_scene(plant, scenario)
    plant.Finalize()
    scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    assert any(name.startswith("wall/rc_") for name in (s.name for s in handles.static_shapes))
    # A camera 0.4 m above a bare spot of the target's receptacle, looking straight down.
    target = scenario.object(scenario.target)
    receptacle = next(r for r in scenario.replicacad_layout().receptacles if r.id == target.support)
    lo, hi = receptacle.top.min(axis=0), receptacle.top.max(axis=0)
    grid = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 25), np.linspace(lo[1], hi[1], 25)), axis=-1).reshape(-1, 2)
    ok = signed_distance_to_polygon(grid, receptacle.top) < -0.05
    for hull in receptacle.blocked:
        ok &= signed_distance_to_polygon(grid, hull) > 0.1
    for obj in scenario.objects:
        ok &= np.linalg.norm(grid - np.asarray(obj.xyz[:2]), axis=1) > 0.2
    assert np.any(ok)
    spot = grid[np.flatnonzero(ok)[0]]
    height = 0.4
    X_WC = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [spot[0], spot[1], receptacle.height + height])
    core = RenderCameraCore("vtk", CameraInfo(32, 24, np.pi / 12), ClippingRange(0.05, 10.0), RigidTransform())
    camera = DepthRenderCamera(core, DepthRange(0.1, 8.0))
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    depth = np.asarray(query.RenderDepthImage(camera, scene_graph.world_frame_id(), X_WC).data).squeeze()
    centre = depth[10:14, 14:18]
    assert np.all(np.isfinite(centre))
    # The furniture's surface, not the floor 0.4-1.2 m further down.
    assert abs(float(np.median(centre)) - height) < 0.04, float(np.median(centre))


# ------------------------------------------------------------------ errors


def _copy_dataset(tmp_path: Path) -> Path:
    """A writable copy of the configs + navmeshes; asset directories are symlinked."""
    copy = tmp_path / "replica_cad_dataset"
    copy.mkdir()
    for name in ("configs", "navmeshes"):
        shutil.copytree(DATASET / name, copy / name, copy_function=shutil.copyfile)
    for path in copy.rglob("*"):
        path.chmod(0o755 if path.is_dir() else 0o644)
    for name in ("urdf", "objects"):
        (copy / name).symlink_to(DATASET / name)
    shutil.copy(DATASET / "replicaCAD.scene_dataset_config.json", copy)
    return copy


def test_missing_collision_mesh_names_the_file(tmp_path, monkeypatch):
    monkeypatch.setenv("VAMG_CACHE", str(tmp_path / "cache"))
    copy = _copy_dataset(tmp_path)
    config = copy / "configs" / "objects" / "frl_apartment_table_01.object_config.json"
    doc = json.loads(config.read_text())
    doc["collision_asset"] = "../../objects/convex/no_such_table_cv_decomp.glb"
    config.write_text(json.dumps(doc))
    with pytest.raises(ReplicaCadError, match="no_such_table_cv_decomp.glb"):
        load_replicacad_layout("v3_sc0_staging_00", copy)


def test_missing_render_mesh_is_named_when_strict_and_drawn_from_collision_otherwise():
    # The sample lacks frl_apartment_bike_01.glb (apt_0 uses it).
    with pytest.raises(ReplicaCadError, match="frl_apartment_bike_01.glb"):
        load_replicacad_layout("apt_0", strict_assets=True)
    layout = load_replicacad_layout("apt_0")
    assert any("frl_apartment_bike_01.glb" in w for w in layout.warnings)
    bike = next(b for b in layout.bodies if "bike_01" in b.name)
    assert bike.visuals == () and bike.pieces_B


def test_missing_stage_is_an_error_only_when_required():
    with pytest.raises(ReplicaCadError, match="stage"):
        load_replicacad_layout("v3_sc0_staging_00", require_stage=True)
    scenario = Scenario(name="x", replicacad=ReplicaCadScene(scene="v3_sc0_staging_00", require_stage=True))
    assert not scenario.objects
    with pytest.raises(ScenarioError, match="replicacad: .*stage"):
        validate_scenario(scenario)


def test_unknown_scene_and_dataset_are_named(tmp_path):
    with pytest.raises(ReplicaCadError, match="'no_such_scene'.*known: apt_0"):
        load_replicacad_layout("no_such_scene")
    with pytest.raises(ReplicaCadError, match=str(tmp_path)):
        find_replicacad_dir(tmp_path)


# ------------------------------------------------------------------ caches


def test_layout_disk_cache_returns_the_same_layout_and_follows_the_dataset(tmp_path, monkeypatch):
    import vamg_drake.world.replicacad as replicacad

    monkeypatch.setenv("VAMG_CACHE", str(tmp_path / "cache"))
    copy = _copy_dataset(tmp_path)
    replicacad._load_cached.cache_clear()
    built = load_replicacad_layout("v3_sc0_staging_00", copy)
    stored = sorted((tmp_path / "cache").rglob("layouts/*.pickle"))
    assert len(stored) == 1
    replicacad._load_cached.cache_clear()  # as a new process would
    cached = load_replicacad_layout("v3_sc0_staging_00", copy)
    assert cached is not built
    assert [b.name for b in cached.bodies] == [b.name for b in built.bodies]
    assert all(np.array_equal(p, q) for a, b in zip(cached.bodies, built.bodies) for p, q in zip(a.pieces_B, b.pieces_B))
    assert [r.id for r in cached.all_receptacles()] == [r.id for r in built.all_receptacles()]
    # An edited dataset file is a new key: the layout is loaded again, not taken from the cache.
    config = copy / "configs" / "objects" / "frl_apartment_table_01.object_config.json"
    config.write_text(config.read_text() + "\n")
    replicacad._load_cached.cache_clear()
    load_replicacad_layout("v3_sc0_staging_00", copy)
    assert len(sorted((tmp_path / "cache").rglob("layouts/*.pickle"))) == 2
    # A corrupt cache file is rebuilt.
    stored = sorted((tmp_path / "cache").rglob("layouts/*.pickle"))
    for path in stored:
        path.write_bytes(b"not a pickle")
    replicacad._load_cached.cache_clear()
    again = load_replicacad_layout("v3_sc0_staging_00", copy)
    assert [b.name for b in again.bodies] == [b.name for b in built.bodies]
    replicacad._load_cached.cache_clear()


def test_depth_only_gltf_renders_the_same_depth_without_textures():
    from pydrake.geometry import GeometryInstance, Mesh, PerceptionProperties, RenderLabel

    from vamg_drake.world.replicacad import depth_only_gltf

    layout = load_replicacad_layout("apt_0")
    body = next(b for b in layout.bodies if b.visuals and "table" in b.name)
    gltf, X_BG, scale = body.visuals[0]
    stripped = depth_only_gltf(gltf)
    doc, full = json.loads(stripped.read_text()), json.loads(gltf.read_text())
    assert "images" in full and not {"images", "textures", "samplers"} & set(doc)
    assert doc["buffers"] == full["buffers"] and doc["meshes"] == full["meshes"]
    assert "Texture" not in json.dumps(doc.get("materials", []))

    def render(path):
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), builder)
        instance = GeometryInstance(RigidTransform(body.X_WB @ X_BG), Mesh(str(path), scale), "mesh")
        perception = PerceptionProperties()
        perception.AddProperty("label", "id", RenderLabel(1))
        instance.set_perception_properties(perception)
        plant.RegisterVisualGeometry(plant.world_body(), instance)
        plant.Finalize()
        scene_graph.AddRenderer("vtk", MakeRenderEngineVtk(RenderEngineVtkParams()))
        context = builder.Build().CreateDefaultContext()
        p_WB = body.X_WB[:3, 3]
        X_WC = RigidTransform(RotationMatrix.MakeXRotation(np.pi), [p_WB[0], p_WB[1], p_WB[2] + 2.0])
        core = RenderCameraCore("vtk", CameraInfo(64, 48, np.pi / 3), ClippingRange(0.05, 10.0), RigidTransform())
        query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
        return np.asarray(query.RenderDepthImage(DepthRenderCamera(core, DepthRange(0.1, 8.0)),
                                                 scene_graph.world_frame_id(), X_WC).data).squeeze()

    textured, depth_only = render(gltf), render(stripped)
    assert np.isfinite(textured).sum() > 50  # the table is in view
    np.testing.assert_array_equal(depth_only, textured)
