"""ReplicaCAD scenes (ManiSkill's asset layout) as rooms for the simulated world.

ManiSkill3 downloads ReplicaCAD (Meta, Habitat 2.0; CC BY-NC 4.0) into
``$MS_ASSET_DIR/scene_datasets/replica_cad_dataset``. ``load_replicacad_layout``
reads one scene instance (``configs/scenes/<scene>.scene_instance.json``) into
plain NumPy data that ``register_replicacad`` adds to a plant and that the
scenario generator, validation and plots use without Drake.

What is loaded, and how:

* **Frames.** ReplicaCAD is Y-up (Habitat, glTF); Drake is Z-up. The one
  conversion is ``R_ZY`` (+90 deg about x: (x, y, z) -> (x, -z, y)), applied
  by ``points_to_z_up`` and ``pose_to_z_up`` below and nowhere else. Every
  asset gets a body frame B that is its Habitat frame re-expressed Z-up
  (X_WB = R_ZY X_H R_ZY^T), so Drake's own glTF import (which rotates y-up
  files to z-up) and the collision points (``points_to_z_up`` of the raw
  vertices) agree.
* **Objects** (``object_instances``): one body each, welded at its instance
  pose, including those Habitat marks DYNAMIC (only the YCB targets move).
  Visual: the render ``.glb`` (converted byte-for-byte to ``.gltf`` + ``.bin``
  in the cache, because Drake reads ``.gltf`` but not ``.glb``), with the
  perception role, so the depth camera sees it. Collision: the convex
  decomposition, one ``Convex`` per mesh node (built from the node's points in
  memory); configs without one use the render mesh's bounding box.
  Floor coverings are visual only, so the base can drive over them (as
  ManiSkill's scene builder turns off the Fetch base's collisions with them):
  bodies whose template name has a token in ``FLOOR_COVERING_TOKENS`` (rugs,
  mats, carpets), lowered to rest on the floor where the scene file lets them
  float a few centimetres above it, and any body whose collision top is below
  ``FLOOR_COVERING_HEIGHT``.
* **Articulated furniture** (``articulated_object_instances``): the URDF is
  read here (not by Drake's parser: its meshes are ``.glb`` and its frames
  Y-up) and every link becomes a welded body at its pose with all joints at
  zero (closed doors and drawers). Fixed joints are a first version.
* **Receptacles** (``receptacle_aabb_*`` in object and ``.ao_config.json``
  files): the bottom face of the box, once in W, is a support surface
  ``rc/<body>/<receptacle>`` if it is level and open above (see
  ``ReplicaCadConfig``).
* **Stage** (the apartment shell): its render mesh is visual-only when the
  file is present. Collision walls always come from the navmesh: each
  boundary edge of the floor polygons that no furniture explains becomes a
  thin wall box, ``agent_radius`` outside the edge, reaching on by
  ``agent_radius`` at the ends that meet another wall edge (a corner). With
  ``require_stage=True`` a missing stage raises ``ReplicaCadError``.

Missing files raise ``ReplicaCadError`` naming the file, except a missing
render mesh of an object that still has a collision mesh: it is logged and the
collision pieces stand in as visuals (``strict_assets=True`` makes that an
error too). The ReplicaCAD sample in ``../shared/replicacad`` lacks stages and
three render meshes.
"""

import functools
import hashlib
import json
import logging
import math
import os
import pickle
import re
import struct
import tempfile
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from pydrake.geometry import (
    Convex,
    GeometryInstance,
    IllustrationProperties,
    Mesh,
    PerceptionProperties,
    ProximityProperties,
    RenderLabel,
)
from pydrake.math import RigidTransform
from pydrake.multibody.tree import SpatialInertia

from vamg_drake.world.primitives import WorldBox, convex_hull_2d, rotation_z, signed_distance_to_polygon
from vamg_drake.world.replicacad_navmesh import NavMesh, NavMeshError, read_navmesh

_log = logging.getLogger(__name__)

#: Where ManiSkill keeps the dataset below its asset directory.
MANISKILL_SUBDIR = Path("scene_datasets") / "replica_cad_dataset"
#: ManiSkill's default asset directory when MS_ASSET_DIR is unset.
MANISKILL_DEFAULT_ASSET_DIR = Path("~/.maniskill/data")
#: Environment variable naming the dataset (or a directory holding it); checked first.
DATASET_ENV = "VAMG_REPLICACAD_DIR"
#: A body whose collision top is below this [m] is a floor covering: visual only.
FLOOR_COVERING_HEIGHT = 0.03
#: Name tokens of floor coverings (ManiSkill's ``IGNORE_FETCH_COLLISION_STRS``).
FLOOR_COVERING_TOKENS = ("mat", "rug", "carpet")


def is_floor_covering_name(name: str) -> bool:
    """True when a body or template name has a floor-covering token ("frl_apartment_rug_01")."""
    tokens = re.split(r"[^a-z]+", Path(name).name.lower())
    return any(t in FLOOR_COVERING_TOKENS for t in tokens)

#: Y-up (Habitat, glTF) to Z-up (Drake): +90 degrees about x.
R_ZY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def points_to_z_up(p_Y: np.ndarray) -> np.ndarray:
    """Re-expresses (N, 3) points from a Y-up frame in the Z-up frame (x, -z, y)."""
    return np.asarray(p_Y, dtype=float) @ R_ZY.T


def pose_to_z_up(X_Y: np.ndarray) -> np.ndarray:
    """Re-expresses a (4, 4) pose between Y-up frames as the pose between their Z-up twins."""
    T = np.eye(4)
    T[:3, :3] = R_ZY
    return T @ np.asarray(X_Y, dtype=float) @ T.T


class ReplicaCadError(RuntimeError):
    """A ReplicaCAD dataset, scene or asset is missing or malformed (the message names it)."""


# ------------------------------------------------------------------ lookup


def _dataset_in(root: Path) -> Path | None:
    for candidate in (root, root / "replica_cad_dataset", root / MANISKILL_SUBDIR):
        if (candidate / "configs" / "scenes").is_dir():
            return candidate
    return None


def find_replicacad_dir(explicit: str | Path | None = None) -> Path | None:
    """Returns the ReplicaCAD dataset directory, or None if none is found.

    Looks in order at ``explicit`` (the dataset itself, a directory holding
    ``replica_cad_dataset``, or a ManiSkill asset dir), ``$VAMG_REPLICACAD_DIR``,
    ``$MS_ASSET_DIR/scene_datasets/replica_cad_dataset`` and ManiSkill's
    default ``~/.maniskill/data/scene_datasets/replica_cad_dataset``.

    Raises:
        ReplicaCadError: if ``explicit`` is given but holds no dataset.
    """
    if explicit:
        found = _dataset_in(Path(explicit).expanduser())
        if found is None:
            raise ReplicaCadError(f"{explicit}: no ReplicaCAD dataset here (expected configs/scenes/ in it or in {MANISKILL_SUBDIR} below it)")
        return found.resolve()
    roots = [os.environ.get(DATASET_ENV), os.environ.get("MS_ASSET_DIR"), str(MANISKILL_DEFAULT_ASSET_DIR)]
    for root in roots:
        if root:
            found = _dataset_in(Path(root).expanduser())
            if found is not None:
                return found.resolve()
    return None


def resolve_replicacad_dir(explicit: str | Path | None = None) -> Path:
    """Like ``find_replicacad_dir`` but raises ``ReplicaCadError`` saying where it looked."""
    found = find_replicacad_dir(explicit)
    if found is None:
        raise ReplicaCadError(
            "ReplicaCAD dataset not found: set VAMG_REPLICACAD_DIR or MS_ASSET_DIR, pass --replicacad-dir, or run "
            f"`python -m mani_skill.utils.download_asset ReplicaCAD` (looked in ${DATASET_ENV}, "
            f"$MS_ASSET_DIR/{MANISKILL_SUBDIR}, {MANISKILL_DEFAULT_ASSET_DIR / MANISKILL_SUBDIR})"
        )
    return found


def list_replicacad_scenes(dataset_dir: str | Path | None = None) -> list[str]:
    """Returns the scene instance names of a dataset."""
    root = resolve_replicacad_dir(dataset_dir)
    return sorted(p.name.removesuffix(".scene_instance.json") for p in (root / "configs" / "scenes").glob("*.scene_instance.json"))


# ------------------------------------------------------------ loaded data


@dataclass(frozen=True)
class SceneBody:
    """One welded body of a ReplicaCAD scene (an object or an articulated link).

    Attributes:
        name: unique, e.g. "rc/012_frl_apartment_table_01" or "rc/fridge_0/body".
        X_WB: (4, 4) pose of its Z-up body frame B.
        visuals: (gltf path, X_BG (4, 4), scale) per visual mesh.
        pieces_B: convex collision pieces as (N, 3) points in B.
        floor_covering: visual only (rugs, mats).
        source: the config or URDF it came from.
    """

    name: str
    X_WB: np.ndarray
    visuals: tuple[tuple[Path, np.ndarray, float], ...]
    pieces_B: tuple[np.ndarray, ...]
    floor_covering: bool
    source: Path

    def pieces_W(self) -> list[np.ndarray]:
        """Returns the collision pieces as (N, 3) points in W."""
        return [p @ self.X_WB[:3, :3].T + self.X_WB[:3, 3] for p in self.pieces_B]


@dataclass(frozen=True)
class Receptacle:
    """A ReplicaCAD receptacle box turned into a support surface.

    Attributes:
        id: "rc/<body>/<receptacle name>".
        height: z of the surface (the box's bottom face) [m].
        top: (k, 2) footprint polygon of the surface.
        box: the surface as a thin box whose top is at ``height`` (the drop-check support).
        blocked: (k, 2) polygons of scene geometry above the surface (keep clear).
        blocked_fraction: share of the surface under such geometry.
    """

    id: str
    height: float
    top: np.ndarray
    box: WorldBox
    blocked: tuple[np.ndarray, ...]
    blocked_fraction: float


@dataclass(frozen=True)
class ReplicaCadLayout:
    """A ReplicaCAD scene instance, loaded and converted to W (z up).

    Attributes:
        scene: the scene instance name.
        dataset_dir: the dataset directory.
        bodies: objects and articulated links.
        receptacles: usable support surfaces (level, open above).
        navmesh: the walkable floor.
        walls: wall boxes rebuilt from the navmesh boundary.
        obstacles: every collision piece as a vertical-axis bounding box (no floor coverings).
        stage_visual: the stage's converted render mesh, or None if absent.
        warnings: assets that were missing but not needed.
        covered_receptacles: level receptacles more than ``max_blocked_fraction``
            covered (objects may rest there, e.g. in the paper's task files,
            but generators place none there).
    """

    scene: str
    dataset_dir: Path
    bodies: tuple[SceneBody, ...]
    receptacles: tuple[Receptacle, ...]
    navmesh: NavMesh
    walls: tuple[WorldBox, ...]
    obstacles: tuple[WorldBox, ...]
    stage_visual: Path | None
    warnings: tuple[str, ...] = field(default=())
    covered_receptacles: tuple[Receptacle, ...] = field(default=())

    def all_receptacles(self) -> tuple[Receptacle, ...]:
        """Usable and covered receptacles (shelves inside cupboards, under other furniture)."""
        return self.receptacles + self.covered_receptacles

    def static_shapes(self) -> list[WorldBox]:
        """Returns walls and obstacle boxes (what ``static_obstacle_shapes`` adds)."""
        return list(self.walls) + list(self.obstacles)

    def xy_bounds(self) -> np.ndarray:
        """Returns (2, 2) [lower, upper] xy corners of the navmesh, walls and obstacles."""
        points = [self.navmesh.vertices[:, :2]] + [b.footprint() for b in self.walls + self.obstacles]
        points = np.concatenate(points)
        return np.stack([points.min(axis=0), points.max(axis=0)])


@dataclass
class ReplicaCadConfig:
    """How a ReplicaCAD scene is turned into a world.

    Attributes:
        wall_height: height of the navmesh walls [m].
        wall_thickness: [m].
        wall_clearance: a navmesh boundary edge is a wall unless scene geometry
            lies within this distance [m] of the point ``agent_radius``
            outside it.
        robot_height: geometry whose bottom is below this blocks the base [m].
        receptacle_clearance: geometry up to this far above a receptacle
            counts as covering it [m].
        max_blocked_fraction: receptacles more covered than this are unusable
            (closed cupboards, fridge shelves).
        receptacle_height_range: usable receptacle heights [m].
    """

    wall_height: float = 2.4
    wall_thickness: float = 0.1
    wall_clearance: float = 0.2
    robot_height: float = 1.5
    receptacle_clearance: float = 0.45
    max_blocked_fraction: float = 0.5
    receptacle_height_range: list[float] = field(default_factory=lambda: [0.05, 2.0])


# ------------------------------------------------------------- asset cache


def replicacad_cache_dir(dataset_dir: Path) -> Path:
    """Returns the cache directory for converted meshes of ``dataset_dir``."""
    root = os.environ.get("VAMG_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "vamg_drake"
    tag = re.sub(r"[^A-Za-z0-9]+", "_", str(dataset_dir.resolve())).strip("_")[-60:]
    return base / "replicacad" / tag


def glb_to_gltf(glb: Path, cache_dir: Path, dataset_dir: Path) -> Path:
    """Converts a ``.glb`` into ``.gltf`` + ``.bin`` in the cache (byte copy; reused if fresh).

    Raises:
        ReplicaCadError: naming the file if it is missing or not a glTF binary.
    """
    try:
        relative = glb.resolve().relative_to(dataset_dir.resolve())
    except ValueError:
        relative = Path(glb.name)
    out = (cache_dir / relative).with_suffix(".gltf")
    if out.exists() and out.stat().st_mtime >= glb.stat().st_mtime:
        return out
    data = glb.read_bytes()
    magic, _version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise ReplicaCadError(f"{glb}: not a binary glTF file")
    offset, doc, blob = 12, None, b""
    while offset < min(length, len(data)):
        size, kind = struct.unpack_from("<I4s", data, offset)
        chunk = data[offset + 8 : offset + 8 + size]
        offset += 8 + size
        if kind == b"JSON":
            doc = json.loads(chunk)
        elif kind == b"BIN\x00":
            blob = chunk
    if doc is None:
        raise ReplicaCadError(f"{glb}: glTF binary without a JSON chunk")
    out.parent.mkdir(parents=True, exist_ok=True)
    bin_name = out.with_suffix(".bin").name
    if doc.get("buffers"):
        doc["buffers"][0]["uri"] = bin_name
        _write_atomic(out.with_suffix(".bin"), blob)
    _write_atomic(out, json.dumps(doc).encode())
    return out


def depth_only_gltf(gltf: Path) -> Path:
    """A copy of a cached ``.gltf`` without images, textures or samplers, for the
    perception role (reused if fresh).

    The depth camera needs only the triangles; the textures (PNGs inside the
    ``.bin``) would be decoded by the renderer for nothing, which is most of
    the renderer's set-up time in an apartment. The copy shares the ``.bin``.
    """
    out = gltf.with_name(gltf.stem + ".depth.gltf")
    if out.exists() and out.stat().st_mtime >= gltf.stat().st_mtime:
        return out
    doc = json.loads(gltf.read_bytes())
    for key in ("images", "textures", "samplers"):
        doc.pop(key, None)
    for material in doc.get("materials", []):
        pbr = material.get("pbrMetallicRoughness", {})
        for key in [k for k in pbr if k.endswith("Texture")]:
            del pbr[key]
        for key in [k for k in material if k.endswith("Texture")]:
            del material[key]
    _write_atomic(out, json.dumps(doc).encode())
    return out


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _mesh_nodes(path: Path) -> list[np.ndarray]:
    """Returns the vertices (raw, Y-up asset frame) of every mesh node of a glTF binary."""
    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as e:  # trimesh raises many kinds
        raise ReplicaCadError(f"{path}: cannot read mesh ({e})") from e
    pieces = []
    for node in scene.graph.nodes_geometry:
        T, geometry = scene.graph[node]
        vertices = np.asarray(scene.geometry[geometry].vertices, dtype=float)
        if len(vertices) >= 4:
            pieces.append(trimesh.transform_points(vertices, T))
    return pieces


def _box_points(center: np.ndarray, half: np.ndarray, X: np.ndarray | None = None) -> np.ndarray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    p = center + signs * half
    return p if X is None else p @ X[:3, :3].T + X[:3, 3]


# -------------------------------------------------------------- transforms


def _pose(translation, rotation_wxyz) -> np.ndarray:
    X = np.eye(4)
    w, x, y, z = (float(v) for v in rotation_wxyz)
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    w, x, y, z = w / n, x / n, y / n, z / n
    X[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    X[:3, 3] = np.asarray(translation, dtype=float)
    return X


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.replace(",", " ").split()]


def _urdf_origin(element: ET.Element | None, scale: float) -> np.ndarray:
    X = np.eye(4)
    if element is None:
        return X
    xyz = _floats(element.get("xyz", "0 0 0"))
    r, p, y = _floats(element.get("rpy", "0 0 0"))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    X[:3, :3] = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    X[:3, 3] = scale * np.asarray(xyz)
    return X


# ------------------------------------------------------------------ loader


class _Loader:
    def __init__(self, dataset_dir: Path, scene: str, require_stage: bool, strict_assets: bool, config: ReplicaCadConfig):
        self.root = dataset_dir
        self.scene = scene
        self.require_stage = require_stage
        self.strict = strict_assets
        self.config = config
        self.cache = replicacad_cache_dir(dataset_dir)
        self.warnings: list[str] = []
        self.bodies: list[SceneBody] = []
        # (body name, receptacle name, box center, half extents) in the body's raw (Y-up) frame
        self.raw_receptacles: list[tuple[str, str, np.ndarray, np.ndarray, np.ndarray]] = []

    def _json(self, path: Path) -> dict:
        if not path.is_file():
            raise ReplicaCadError(f"{path}: file not found")
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ReplicaCadError(f"{path}: invalid JSON ({e})") from e

    def _visual(self, path: Path, owner: Path) -> Path | None:
        if path.is_file():
            return glb_to_gltf(path, self.cache, self.root)
        message = f"{path}: render mesh not found (referenced by {owner})"
        if self.strict:
            raise ReplicaCadError(message)
        self.warnings.append(message)
        _log.warning("%s; its collision pieces are drawn instead", message)
        return None

    def load(self) -> ReplicaCadLayout:
        scene_path = self.root / "configs" / "scenes" / f"{self.scene}.scene_instance.json"
        if not scene_path.is_file():
            known = ", ".join(list_replicacad_scenes(self.root)) or "none"
            raise ReplicaCadError(f"{scene_path}: scene instance {self.scene!r} not found (known: {known})")
        doc = self._json(scene_path)
        stage_visual = self._stage(doc.get("stage_instance") or {}, scene_path)
        for i, instance in enumerate(doc.get("object_instances", [])):
            self._object(i, instance, scene_path)
        for i, instance in enumerate(doc.get("articulated_object_instances", [])):
            self._articulated(i, instance, scene_path)
        navmesh = self._navmesh(doc, scene_path)
        obstacles = self._obstacles()
        walls = navmesh_walls(navmesh, self._blocking_footprints(obstacles), self.config)
        receptacles = self._receptacles()
        usable = tuple(r for r in receptacles if r.blocked_fraction <= self.config.max_blocked_fraction)
        covered = tuple(r for r in receptacles if r.blocked_fraction > self.config.max_blocked_fraction)
        return ReplicaCadLayout(
            scene=self.scene,
            dataset_dir=self.root,
            bodies=tuple(self.bodies),
            receptacles=usable,
            covered_receptacles=covered,
            navmesh=navmesh,
            walls=tuple(walls),
            obstacles=tuple(obstacles),
            stage_visual=stage_visual,
            warnings=tuple(self.warnings),
        )

    # -- stage and navmesh

    def _stage(self, instance: dict, scene_path: Path) -> Path | None:
        template = Path(instance.get("template_name", "")).name
        if not template:
            return None
        config_path = self.root / "configs" / "stages" / f"{template}.stage_config.json"
        render = None
        if config_path.is_file():
            render = (config_path.parent / self._json(config_path).get("render_asset", "")).resolve()
        if render is not None and render.is_file():
            return glb_to_gltf(render, self.cache, self.root)
        message = f"{render or config_path}: stage {template!r} not found (referenced by {scene_path})"
        if self.require_stage:
            raise ReplicaCadError(message)
        self.warnings.append(message)
        _log.info("%s; walls are rebuilt from the navmesh", message)
        return None

    def _navmesh(self, doc: dict, scene_path: Path) -> NavMesh:
        candidates = []
        name = doc.get("navmesh_instance")
        dataset_config = self.root / "replicaCAD.scene_dataset_config.json"
        if name and dataset_config.is_file():
            relative = self._json(dataset_config).get("navmesh_instances", {}).get(name)
            if relative:
                candidates.append(self.root / relative)
        candidates.append(self.root / "navmeshes" / f"{self.scene}.navmesh")
        for path in candidates:
            if path.is_file():
                try:
                    return read_navmesh(path, points_to_z_up)
                except NavMeshError as e:
                    raise ReplicaCadError(str(e)) from e
        raise ReplicaCadError(f"{candidates[-1]}: navmesh not found for scene {self.scene!r} ({scene_path})")

    # -- objects

    def _object(self, index: int, instance: dict, scene_path: Path) -> None:
        template = Path(instance.get("template_name", "")).name
        config_path = self.root / "configs" / "objects" / f"{template}.object_config.json"
        if not config_path.is_file():
            raise ReplicaCadError(f"{config_path}: object config not found (object_instances[{index}] of {scene_path})")
        config = self._json(config_path)
        render = (config_path.parent / config.get("render_asset", "")).resolve()
        visual = self._visual(render, config_path)
        if config.get("collision_asset"):
            collision = (config_path.parent / config["collision_asset"]).resolve()
            if not collision.is_file():
                raise ReplicaCadError(f"{collision}: collision mesh not found (referenced by {config_path})")
            raw_pieces = _mesh_nodes(collision)
        else:  # use_bounding_box_for_collision
            if not render.is_file():
                raise ReplicaCadError(f"{render}: render mesh not found and needed for the bounding-box collision of {config_path}")
            points = np.concatenate(_mesh_nodes(render))
            lo, hi = points.min(axis=0), points.max(axis=0)
            raw_pieces = [_box_points(0.5 * (lo + hi), 0.5 * (hi - lo))]
        X_H = _pose(instance.get("translation", [0, 0, 0]), instance.get("rotation", [1, 0, 0, 0]))
        name = f"rc/{index:03d}_{template}"
        visuals = () if visual is None else ((visual, np.eye(4), 1.0),)
        self._add_body(name, X_H, visuals, [points_to_z_up(p) for p in raw_pieces], config_path)
        for key, box in (config.get("user_defined") or {}).items():
            if key.startswith("receptacle_aabb"):
                self.raw_receptacles.append((name, box.get("name", key), X_H, np.asarray(box["position"], float), np.abs(np.asarray(box["scale"], float))))

    def _add_body(self, name, X_H, visuals, pieces_B, source) -> SceneBody:
        X_WB = pose_to_z_up(X_H)
        top = max((float((p @ X_WB[:3, :3].T)[:, 2].max() + X_WB[2, 3]) for p in pieces_B), default=0.0)
        floor_covering = top < FLOOR_COVERING_HEIGHT or is_floor_covering_name(name)
        if floor_covering and pieces_B:
            bottom = min(float((p @ X_WB[:3, :3].T)[:, 2].min() + X_WB[2, 3]) for p in pieces_B)
            if bottom > 0.0:  # floating rug: rest it on the floor
                X_WB = X_WB.copy()
                X_WB[2, 3] -= bottom
        body = SceneBody(name, X_WB, tuple(visuals), tuple(pieces_B), floor_covering, source)
        self.bodies.append(body)
        return body

    # -- articulated objects

    def _urdf_path(self, template: str, scene_path: Path) -> Path:
        matches = sorted((self.root / "urdf").glob(f"*/{template}.urdf"))
        if not matches:
            raise ReplicaCadError(f"{self.root / 'urdf' / '*' / (template + '.urdf')}: URDF of articulated object {template!r} not found (referenced by {scene_path})")
        return matches[0]

    def _articulated(self, index: int, instance: dict, scene_path: Path) -> None:
        template = instance.get("template_name", "")
        urdf = self._urdf_path(template, scene_path)
        s = float(instance.get("uniform_scale", 1.0))
        try:
            robot = ET.parse(urdf).getroot()
        except ET.ParseError as e:
            raise ReplicaCadError(f"{urdf}: invalid URDF ({e})") from e
        links = {link.get("name"): link for link in robot.findall("link")}
        parent_of = {}
        for joint in robot.findall("joint"):
            parent_of[joint.find("child").get("link")] = (joint.find("parent").get("link"), _urdf_origin(joint.find("origin"), s), joint.get("type"))
        X_H_root = _pose(instance.get("translation", [0, 0, 0]), instance.get("rotation", [1, 0, 0, 0]))

        @functools.cache
        def X_H_link(link: str) -> np.ndarray:
            if link not in parent_of:
                return X_H_root
            parent, X_PC, _ = parent_of[link]
            return X_H_link(parent) @ X_PC  # joints at zero

        ao_name = f"rc/{template}_{index}"
        for link_name, link in links.items():
            visuals, pieces = [], []
            for visual in link.findall("visual"):
                mesh = visual.find("geometry/mesh")
                if mesh is None:
                    continue
                path = (urdf.parent / mesh.get("filename")).resolve()
                gltf = self._visual(path, urdf)
                mesh_scale = _floats(mesh.get("scale", "1 1 1"))
                if gltf is not None:
                    X_LG = _urdf_origin(visual.find("origin"), s)
                    visuals.append((gltf, pose_to_z_up(X_LG), s * float(np.mean(mesh_scale))))
            for collision in link.findall("collision"):
                box = collision.find("geometry/box")
                if box is None:
                    continue
                size = s * np.array(_floats(box.get("size")))
                X_LG = _urdf_origin(collision.find("origin"), s)
                pieces.append(points_to_z_up(_box_points(np.zeros(3), 0.5 * size, X_LG)))
            if visuals or pieces:
                self._add_body(f"{ao_name}/{link_name}", X_H_link(link_name), visuals, pieces, urdf)
        ao_config = urdf.with_name(f"{template}.ao_config.json")
        if ao_config.is_file():
            for key, box in (self._json(ao_config).get("user_defined") or {}).items():
                link = box.get("parent_link", "")
                if not key.startswith("receptacle_aabb") or link not in links:
                    continue
                if parent_of.get(link, (None, None, "fixed"))[2] != "fixed":
                    continue  # inside a (closed) drawer or door
                self.raw_receptacles.append(
                    (f"{ao_name}/{link}", box.get("name", key), X_H_link(link), s * np.asarray(box["position"], float), s * np.abs(np.asarray(box["scale"], float)))
                )

    # -- derived geometry

    def _obstacles(self) -> list[WorldBox]:
        boxes = []
        for body in self.bodies:
            if body.floor_covering:
                continue
            for k, points in enumerate(body.pieces_W()):
                boxes.append(_vertical_box(f"{body.name}/{k}", points))
        return boxes

    def _blocking_footprints(self, obstacles: list[WorldBox]) -> list[np.ndarray]:
        return [b.footprint() for b in obstacles if b.z_range()[0] < self.config.robot_height]

    def _receptacles(self) -> list[Receptacle]:
        config = self.config
        pieces = [(b.name, p) for b in self.bodies if not b.floor_covering for p in b.pieces_W()]
        receptacles = []
        for body_name, name, X_H, center, half in self.raw_receptacles:
            X_W = pose_to_z_up(X_H)
            R = X_W[:3, :3] @ R_ZY  # raw (Y-up) box axes -> W
            up = R[:, 1]
            if up[2] < 0.99:
                continue  # not level
            corners = points_to_z_up(_box_points(center, half))  # raw box -> Z-up body frame
            corners_W = corners @ X_W[:3, :3].T + X_W[:3, 3]
            height = float(corners_W[:, 2].min())
            if not config.receptacle_height_range[0] <= height <= config.receptacle_height_range[1]:
                continue
            top = convex_hull_2d(corners_W[:, :2])
            x_axis = R[:, 0]
            yaw = math.atan2(x_axis[1], x_axis[0])
            c = corners_W.mean(axis=0)
            box = WorldBox(f"{body_name}/{name}", np.array([c[0], c[1], height - 0.01]), rotation_z(yaw), np.array([half[0], half[2], 0.01]))
            blocked = []
            for owner, points in pieces:
                z = points[:, 2]
                if z.max() <= height + 0.02 or z.min() >= height + config.receptacle_clearance:
                    continue
                # Only the part of the piece inside the clearance band covers the surface.
                band = points[(z > height + 0.02) & (z < height + config.receptacle_clearance)]
                hull_points = band if len(band) >= 3 else points
                hull = convex_hull_2d(hull_points[:, :2])
                if len(hull) >= 3 and np.any(signed_distance_to_polygon(top, hull) <= 0) | np.any(signed_distance_to_polygon(hull, top) <= 0):
                    blocked.append(hull)
            fraction = _covered_fraction(top, blocked)
            receptacles.append(Receptacle(f"{body_name}/{name}", height, top, box, tuple(blocked), fraction))
        return receptacles


def _covered_fraction(polygon: np.ndarray, covers: list[np.ndarray], spacing: float = 0.03) -> float:
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    xs = np.arange(lo[0] + 0.5 * spacing, hi[0], spacing)
    ys = np.arange(lo[1] + 0.5 * spacing, hi[1], spacing)
    if len(xs) == 0 or len(ys) == 0:
        return 1.0
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    grid = grid[signed_distance_to_polygon(grid, polygon) <= 0]
    if len(grid) == 0:
        return 1.0
    covered = np.zeros(len(grid), dtype=bool)
    for hull in covers:
        covered |= signed_distance_to_polygon(grid, hull) <= 0
    return float(np.count_nonzero(covered)) / len(grid)


def navmesh_walls(navmesh: NavMesh, footprints: list[np.ndarray], config: ReplicaCadConfig) -> list[WorldBox]:
    """The walls of a scene without its stage mesh, rebuilt from its navmesh.

    One thin box per navmesh boundary edge that no blocking `footprints`
    (furniture, (k, 2) polygons) explain, ``agent_radius`` outside the edge.
    An end that meets another wall edge reaches ``agent_radius`` further, so
    that the boxes close the room's corners; an end where the boundary turns
    around furniture stops at the edge's end (reaching on would push the wall
    into the furniture, and into an object resting on it there)."""
    centres = np.array([f.mean(axis=0) for f in footprints]).reshape(-1, 2)
    radii = np.array([np.max(np.linalg.norm(f - f.mean(axis=0), axis=1)) for f in footprints])
    r = navmesh.agent_radius
    edges = []
    for k, (a3, b3) in enumerate(navmesh.boundary_edges):
        a, b = a3[:2], b3[:2]
        length = float(np.linalg.norm(b - a))
        if length < 1e-6:
            continue
        u = (b - a) / length
        n = np.array([u[1], -u[0]])
        mid = 0.5 * (a + b)
        if navmesh.contains_xy((mid + 0.05 * n)[None])[0] and not navmesh.contains_xy((mid - 0.05 * n)[None])[0]:
            n = -n
        probe = mid + (r + 0.05) * n
        near = np.flatnonzero(np.linalg.norm(centres - probe, axis=1) <= radii + config.wall_clearance)
        if any(signed_distance_to_polygon(probe[None], footprints[i])[0] <= config.wall_clearance for i in near):
            continue
        if navmesh.contains_xy(probe[None])[0]:
            continue
        edges.append((k, a, b, u, n, length))
    ends = Counter(_vertex_key(p) for _, a, b, *_ in edges for p in (a, b))
    walls = []
    t = config.wall_thickness
    for k, a, b, u, n, length in edges:
        reach_a = r if ends[_vertex_key(a)] > 1 else 0.0
        reach_b = r if ends[_vertex_key(b)] > 1 else 0.0
        centre = 0.5 * (a + b) + 0.5 * (reach_b - reach_a) * u + (r + 0.5 * t) * n
        walls.append(
            WorldBox(
                f"wall/rc_{k}",
                np.array([centre[0], centre[1], 0.5 * config.wall_height]),
                rotation_z(math.atan2(u[1], u[0])),
                np.array([0.5 * (length + reach_a + reach_b), 0.5 * t, 0.5 * config.wall_height]),
            )
        )
    return walls


def _vertex_key(p_xy: np.ndarray) -> tuple[int, int]:
    """A navmesh vertex's identity in the plane (0.1 mm cells): edges that
    share it share the vertex."""
    return (int(round(float(p_xy[0]) * 1e4)), int(round(float(p_xy[1]) * 1e4)))


def _vertical_box(name: str, points_W: np.ndarray) -> WorldBox:
    """The smallest-area box with a vertical axis around (N, 3) points (a conservative obstacle)."""
    hull = convex_hull_2d(points_W[:, :2])
    z_lo, z_hi = float(points_W[:, 2].min()), float(points_W[:, 2].max())
    best = None
    if len(hull) < 3:
        hull = np.concatenate([hull, hull + 1e-4]) if len(hull) else np.zeros((2, 2))
    for i in range(len(hull)):
        edge = hull[(i + 1) % len(hull)] - hull[i]
        if np.linalg.norm(edge) < 1e-9:
            continue
        yaw = math.atan2(edge[1], edge[0])
        R = rotation_z(yaw)[:2, :2]
        local = hull @ R  # coordinates along the edge axes
        lo, hi = local.min(axis=0), local.max(axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            best = (area, yaw, R @ (0.5 * (lo + hi)), 0.5 * (hi - lo))
    _, yaw, c, h = best
    half = np.array([max(h[0], 1e-3), max(h[1], 1e-3), max(0.5 * (z_hi - z_lo), 1e-3)])
    return WorldBox(name, np.array([c[0], c[1], 0.5 * (z_lo + z_hi)]), rotation_z(yaw), half)


@functools.lru_cache(maxsize=8)
def _load_cached(dataset_dir: Path, scene: str, require_stage: bool, strict_assets: bool, config_key: str) -> ReplicaCadLayout:
    """The layout from the disk cache when its key matches, else loaded and stored.

    Loading an apartment (its meshes, navmesh walls and receptacles) takes
    seconds, and every benchmark episode runs in a fresh process. The key
    covers the arguments, this package's world-building sources, the mesh
    reader's version and the size and mtime of every dataset file, so any
    change to what the layout is made from loads it anew.
    """
    cache = replicacad_cache_dir(dataset_dir) / "layouts"
    digest = _layout_key(dataset_dir, scene, require_stage, strict_assets, config_key)
    path = cache / f"{scene}-{digest[:20]}.pickle"
    if path.is_file():
        try:
            layout = pickle.loads(path.read_bytes())
        except Exception as e:  # a corrupt or foreign file: rebuild it
            _log.warning("%s: unreadable layout cache (%s); loading the scene again", path, e)
        else:
            if isinstance(layout, ReplicaCadLayout) and all(p.is_file() for p in _layout_files(layout)):
                for message in layout.warnings:
                    _log.info("%s (cached layout)", message)
                return layout
    config = ReplicaCadConfig(**json.loads(config_key))
    layout = _Loader(dataset_dir, scene, require_stage, strict_assets, config).load()
    cache.mkdir(parents=True, exist_ok=True)
    _write_atomic(path, pickle.dumps(layout, protocol=pickle.HIGHEST_PROTOCOL))
    return layout


def _layout_key(dataset_dir: Path, scene: str, require_stage: bool, strict_assets: bool, config_key: str) -> str:
    h = hashlib.sha256(json.dumps([scene, require_stage, strict_assets, config_key, trimesh.__version__,
                                   np.__version__]).encode())
    for source in sorted(Path(__file__).parent.glob("*.py")):
        h.update(source.name.encode() + source.read_bytes())
    for path in sorted(dataset_dir.rglob("*")):
        if path.is_file():
            st = path.stat()
            h.update(f"{path.relative_to(dataset_dir)}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()


def _layout_files(layout: ReplicaCadLayout) -> list[Path]:
    """The converted meshes a layout refers to (in the asset cache)."""
    files = [path for body in layout.bodies for path, _, _ in body.visuals]
    return files + ([layout.stage_visual] if layout.stage_visual is not None else [])


def load_replicacad_layout(
    scene: str,
    dataset_dir: str | Path | None = None,
    require_stage: bool = False,
    strict_assets: bool = False,
    config: ReplicaCadConfig | None = None,
) -> ReplicaCadLayout:
    """Loads a ReplicaCAD scene instance (cached per process).

    Args:
        scene: scene instance name, e.g. "apt_0".
        dataset_dir: the dataset, or None to look it up (``find_replicacad_dir``).
        require_stage: raise if the stage mesh is missing (else walls come from the navmesh only).
        strict_assets: raise on any missing render mesh too.
        config: conversion parameters.

    Raises:
        ReplicaCadError: naming the dataset, scene or file that is missing or malformed.
    """
    root = resolve_replicacad_dir(dataset_dir)
    config = config or ReplicaCadConfig()
    key = json.dumps(config.__dict__, sort_keys=True)
    return _load_cached(root, scene, bool(require_stage), bool(strict_assets), key)


# ------------------------------------------------------------------ plant


def register_replicacad(plant, instance, layout: ReplicaCadLayout, proximity, visuals: bool = True,
                        anchored_owner: dict | None = None) -> dict[str, object]:
    """Adds a loaded layout's bodies (welded) to ``plant`` in model instance ``instance``.

    Visual meshes get the illustration role and, as an anchored copy without
    textures (`depth_only_gltf`), the perception role (the depth camera sees
    them); each convex piece is a ``Convex`` collision geometry with a copy of
    ``proximity``. Bodies without a render mesh show their collision pieces.
    The navmesh walls are not added here (``add_scene`` adds them with the
    room's walls). Call before ``plant.Finalize()``. ``visuals=False`` adds
    collision geometry only.

    With ``anchored_owner`` (a dict), the collision pieces are registered on the
    world body instead, at the same poses, and ``anchored_owner`` maps each
    piece's GeometryId to its body's name. SceneGraph treats geometry of the
    world body as anchored: it never enters the broad phase of the moving
    geometry, whereas the ~1,300 pieces of an apartment on welded bodies are
    "dynamic" and cost tens of milliseconds per contact query (measured:
    ``benchmarks/bench_episode.py``).

    Returns:
        body name -> RigidBody.
    """
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.1)
    bodies = {}
    gray = np.array([0.7, 0.7, 0.7, 1.0])
    entries = list(layout.bodies)
    if layout.stage_visual is not None:
        entries.append(SceneBody("rc/stage", np.eye(4), ((layout.stage_visual, np.eye(4), 1.0),), (), True, layout.stage_visual))
    for body_spec in entries:
        body = plant.AddRigidBody(body_spec.name, instance, inertia)
        plant.WeldFrames(plant.world_frame(), body.body_frame(), RigidTransform(body_spec.X_WB))
        bodies[body_spec.name] = body
        for k, (path, X_BG, scale) in enumerate(body_spec.visuals if visuals else ()):
            # Illustration: the glTF's own materials and textures (no diffuse
            # override). Perception (the depth camera): the same triangles
            # without textures.
            # The copy is anchored (on the world body, at the pose SceneGraph
            # would compute for it), so neither SceneGraph nor the renderer
            # updates its pose at every step.
            illustration = GeometryInstance(RigidTransform(X_BG), Mesh(str(path), scale), f"{body_spec.name}/visual_{k}")
            illustration.set_illustration_properties(IllustrationProperties())
            plant.RegisterVisualGeometry(body, illustration)
            X_WG = RigidTransform(body_spec.X_WB) @ RigidTransform(X_BG)
            depth = GeometryInstance(X_WG, Mesh(str(depth_only_gltf(path)), scale), f"{body_spec.name}/depth_{k}")
            perception = PerceptionProperties()
            perception.AddProperty("label", "id", RenderLabel(int(body.index())))
            depth.set_perception_properties(perception)
            plant.RegisterVisualGeometry(plant.world_body(), depth)
        for k, points in enumerate(body_spec.pieces_B):
            shape = Convex(np.ascontiguousarray(points.T), f"{body_spec.name}/{k}")
            if visuals and not body_spec.visuals:
                plant.RegisterVisualGeometry(body, RigidTransform(), shape, f"{body_spec.name}/proxy_{k}", gray)
            if body_spec.floor_covering:
                continue
            if anchored_owner is None:
                plant.RegisterCollisionGeometry(body, RigidTransform(), shape, f"{body_spec.name}/{k}", ProximityProperties(proximity))
            else:
                gid = plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(body_spec.X_WB), shape,
                                                      f"{body_spec.name}/{k}", ProximityProperties(proximity))
                anchored_owner[gid] = body_spec.name
    return bodies
