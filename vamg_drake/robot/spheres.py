"""The sphere model of the Fetch: the planner's and the map's view of the robot.

Spheres are fitted to the URDF's collision primitives (`fit_spheres`) so that
every collision surface lies inside some sphere of the same link (tested in
`tests/test_robot_model.py` at random configurations). The fingers are
covered at every opening by spheres on the gripper link, so the model does not
depend on the finger joints. The fitted model is stored in
`models/fetch/spheres.yaml` (regenerate with `python -m vamg_drake.robot.spheres`).

Self-collision pairs are the sphere pairs whose links Drake does not filter.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import itertools
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numba
import numpy as np
import yaml
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder
from scipy.spatial.transform import Rotation

from vamg_drake.robot import kinematics, layout
from vamg_drake.robot.kinematics import FetchKinematics, _parse_origin, link_transforms

SPHERES_YAML = kinematics.MODELS_DIR / "fetch" / "spheres.yaml"
FINGER_LINKS = ("l_gripper_finger_link", "r_gripper_finger_link")
#: Links whose spheres must stay above the floor (the arm; the base's own spheres reach below it).
ARM_LINKS = ("shoulder_pan_link", "shoulder_lift_link", "upperarm_roll_link", "elbow_flex_link",
             "forearm_roll_link", "wrist_flex_link", "wrist_roll_link", "gripper_link")
#: Links whose spheres move with the head joints (not part of the 11-D q).
HEAD_LINKS = ("head_pan_link", "head_tilt_link")


@dc.dataclass(frozen=True)
class SphereModel:
    """Spheres attached to links of the Fetch.

    Attributes:
        link_names: link name per sphere's `link_index`.
        link_index: (S,) index into `FetchKinematics.link_names`.
        center_L: (S, 3) centre in the link frame.
        radius: (S,) radius [m].
        self_collision_pairs: (P, 2) sphere index pairs to test for self-collision.
        is_gripper: (S,) spheres of the gripper and fingers (allowed to touch
            the target while grasping).
        is_head: (S,) spheres that move with the head joints.
    """

    link_names: tuple[str, ...]
    link_index: np.ndarray
    center_L: np.ndarray
    radius: np.ndarray
    self_collision_pairs: np.ndarray
    is_gripper: np.ndarray
    is_head: np.ndarray
    body_primitives: tuple["BodyPrimitive", ...]

    @property
    def num_spheres(self) -> int:
        return len(self.radius)

    @staticmethod
    @functools.cache
    def load(path: Path | None = None) -> "SphereModel":
        """Loads the sphere model (default `models/fetch/spheres.yaml`)."""
        path = Path(path) if path else SPHERES_YAML
        if not path.exists():
            raise FileNotFoundError(f"sphere model not found: {path} (run `python -m vamg_drake.robot.spheres`)")
        data = yaml.safe_load(path.read_text())
        kin = FetchKinematics.instance()
        rows = data["spheres"]
        link_names = tuple(kin.link_names)
        try:
            link_index = np.array([link_names.index(r["link"]) for r in rows], dtype=np.int64)
        except ValueError as e:
            raise ValueError(f"{path}: spheres[].link: {e}") from None
        center = np.array([r["center"] for r in rows], dtype=float)
        radius = np.array([r["radius"] for r in rows], dtype=float)
        pairs = np.array(data["self_collision_pairs"], dtype=np.int64).reshape(-1, 2)
        gripper_links = {"gripper_link", *FINGER_LINKS}
        is_gripper = np.array([r["link"] in gripper_links for r in rows])
        is_head = np.array([r["link"] in HEAD_LINKS for r in rows])
        body = tuple(
            BodyPrimitive(
                link_index=link_names.index(b["link"]),
                kind=b["kind"],
                X_LS=np.array(b["X_LS"], dtype=float).reshape(4, 4),
                half=np.array(b["half"], dtype=float),
                spheres=np.array(b["spheres"], dtype=np.int64),
            )
            for b in data["body_primitives"]
        )
        return SphereModel(link_names, link_index, center, radius, pairs, is_gripper, is_head, body)

    @functools.cached_property
    def joint_types(self) -> np.ndarray:
        """The tree's joint types masked to the links that carry spheres (and
        their ancestors): what `sphere_centres` needs computed."""
        return FetchKinematics.instance().tree.subtree_joint_types(self.link_index)

    def world_spheres(
        self, q: np.ndarray, head: np.ndarray | None = None, link_poses: np.ndarray | None = None
    ) -> np.ndarray:
        """Sphere centres p_WS (B, S, 3) for q (B, 11) or (11,) -> (S, 3);
        from `link_poses` (B, L, 4, 4) when the caller has them already."""
        if link_poses is not None:
            X = np.ascontiguousarray(link_poses, dtype=float)
            out = np.empty((X.shape[0], self.num_spheres, 3))
            _sphere_centres_from_poses(X, self.link_index, self.center_L, out)
        else:
            t = FetchKinematics.instance().tree
            V = kinematics.extend_configuration(q, head)
            out = np.empty((V.shape[0], self.num_spheres, 3))
            scratch = np.empty((t.parent.shape[0], 3, 4))
            sphere_centres(t.parent, t.X_PJ, self.joint_types, t.axis, t.var_index, V,
                           self.link_index, self.center_L, scratch, out)
        return out[0] if np.ndim(q) == 1 else out

    def self_collision_free(self, q: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """True where the robot is free of self-collision, (B,) for q (B, 11).

        Arm spheres are tested against each other, and against the exact
        primitives of the body (base, torso, head), whose covering spheres
        bulge too far past their flat faces for a self-collision test.
        """
        q = np.atleast_2d(q)
        X = FetchKinematics.instance().link_poses(q)
        c = self.world_spheres(q, link_poses=X)
        i, j = self.self_collision_pairs.T
        d = np.linalg.norm(c[:, i] - c[:, j], axis=-1)
        free = np.all(d > self.radius[i] + self.radius[j] + margin, axis=-1)
        for prim in self.body_primitives:
            free &= np.all(prim.distance(X, c) > self.radius[prim.spheres] + margin, axis=-1)
        return free


@dc.dataclass(frozen=True)
class BodyPrimitive:
    """An exact collision primitive of the robot body used for self-collision.

    Attributes:
        link_index: the link it is attached to.
        kind: "box" (half = half extents) or "cylinder" (half = radius,
            radius, half length; axis z of S).
        X_LS: (4, 4) pose of the shape frame S in the link frame.
        spheres: indices of the spheres allowed to collide with it.
    """

    link_index: int
    kind: str
    X_LS: np.ndarray
    half: np.ndarray
    spheres: np.ndarray

    def distance(self, X_WL: np.ndarray, p_WS: np.ndarray) -> np.ndarray:
        """Distance (B, K) from the centres p_WS[:, spheres] to this shape (0 inside)."""
        X_WS = X_WL[:, self.link_index] @ self.X_LS
        p = p_WS[:, self.spheres] - X_WS[:, None, :3, 3]
        p_S = np.einsum("bji,bkj->bki", X_WS[:, :3, :3], p)
        if self.kind == "box":
            excess = np.maximum(np.abs(p_S) - self.half, 0.0)
            return np.linalg.norm(excess, axis=-1)
        dr = np.maximum(np.linalg.norm(p_S[..., :2], axis=-1) - self.half[0], 0.0)
        dz = np.maximum(np.abs(p_S[..., 2]) - self.half[2], 0.0)
        return np.hypot(dr, dz)


#: Links whose self-collision is tested against their exact primitives.
BODY_LINKS = (
    "base_link",
    "torso_fixed_link",
    "torso_lift_link",
    "head_pan_link",
    "head_tilt_link",
    "shoulder_pan_link",
)


@numba.njit(cache=True, inline="always")
def sphere_centres_into(T, link_index, center_L, C):
    """C[s] = X_W(link_index[s]) @ center_L[s]: the world centres (S, 3) of the
    spheres from the link poses T (L, 3 or 4, 4) of `link_transforms`."""
    for s in range(link_index.shape[0]):
        li = link_index[s]
        px, py, pz = center_L[s, 0], center_L[s, 1], center_L[s, 2]
        C[s, 0] = T[li, 0, 0] * px + T[li, 0, 1] * py + T[li, 0, 2] * pz + T[li, 0, 3]
        C[s, 1] = T[li, 1, 0] * px + T[li, 1, 1] * py + T[li, 1, 2] * pz + T[li, 1, 3]
        C[s, 2] = T[li, 2, 0] * px + T[li, 2, 1] * py + T[li, 2, 2] * pz + T[li, 2, 3]


@numba.njit(cache=True)
def sphere_centres(parent, X_PJ, joint_type, axis, var_index, V, link_index, center_L, T, out):
    """out[b] (S, 3) = the sphere centres for each extended configuration
    V[b]; T (L, 3, 4) is the caller's scratch for the link poses."""
    for b in range(V.shape[0]):
        link_transforms(parent, X_PJ, joint_type, axis, var_index, V[b], T)
        sphere_centres_into(T, link_index, center_L, out[b])
    return out


@numba.njit(cache=True)
def _sphere_centres_from_poses(X, link_index, center_L, out):
    for b in range(X.shape[0]):
        sphere_centres_into(X[b], link_index, center_L, out[b])
    return out


# ----------------------------------------------------------------------------
# Fitting (run once when the URDF's collision geometry changes).


def _box_spheres(half: np.ndarray) -> tuple[np.ndarray, float]:
    """Covers a box with half extents `half` by a grid of equal spheres."""
    dims = 2.0 * half
    thin = int(np.argmin(dims))
    t = dims[thin]
    counts = np.maximum(1, np.ceil(dims / max(t, 0.04) - 1e-9)).astype(int)
    counts[thin] = 1
    cell = dims / counts
    radius = 0.5 * float(np.linalg.norm(cell))
    grids = [(-half[k] + cell[k] * (np.arange(counts[k]) + 0.5)) for k in range(3)]
    centers = np.array(list(itertools.product(*grids)))
    return centers, radius


def _cylinder_spheres(R: float, L: float) -> tuple[np.ndarray, float]:
    """Covers a z-axis cylinder (radius R, length L) by spheres along its axis."""
    n = max(1, math.ceil(L / R - 1e-9))
    s = L / n
    radius = math.hypot(R, 0.5 * s)
    z = -0.5 * L + s * (np.arange(n) + 0.5)
    return np.stack([np.zeros(n), np.zeros(n), z], axis=1), radius


def collision_primitives(urdf_path: Path | None = None) -> list[dict]:
    """The URDF's collision primitives: link, kind, X_LS and size."""
    path = Path(urdf_path) if urdf_path else kinematics.fetch_urdf_path()
    root = ET.parse(path).getroot()
    prims = []
    for link in root.findall("link"):
        for col in link.findall("collision"):
            X_LS = _parse_origin(col.find("origin"))
            geom = col.find("geometry")
            box, cyl = geom.find("box"), geom.find("cylinder")
            if box is not None:
                size = np.array([float(v) for v in box.get("size").split()])
                prims.append(dict(link=link.get("name"), name=col.get("name"), kind="box", X_LS=X_LS, half=size / 2))
            elif cyl is not None:
                prims.append(
                    dict(
                        link=link.get("name"),
                        name=col.get("name"),
                        kind="cylinder",
                        X_LS=X_LS,
                        radius=float(cyl.get("radius")),
                        length=float(cyl.get("length")),
                    )
                )
            else:
                raise ValueError(f"{path.name}: link {link.get('name')}: only box/cylinder collision is supported")
    return prims


def _finger_sweep_box(urdf_path: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half extents, in the gripper frame, of both fingers' sweep."""
    tree = kinematics.parse_kinematic_tree(urdf_path)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for prim in collision_primitives(urdf_path):
        if prim["link"] not in FINGER_LINKS:
            continue
        i = tree.index(prim["link"])
        for opening in (0.0, kinematics.DEFAULT_FINGER):
            X_GF = tree.X_PJ[i].copy()
            X_GF[:3, 3] += opening * tree.axis[i]
            corners = np.array(list(itertools.product(*[(-h, h) for h in prim["half"]])))
            p = (X_GF @ prim["X_LS"] @ np.c_[corners, np.ones(len(corners))].T)[:3].T
            lo, hi = np.minimum(lo, p.min(0)), np.maximum(hi, p.max(0))
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


#: The head links, replaced in self-collision by the cylinder they sweep over
#: the whole pan/tilt range (the gaze moves the head while the arm moves).
HEAD_LINKS = ("head_pan_link", "head_tilt_link")


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(4, 4) rotation about a unit axis."""
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(np.asarray(axis, float) * angle).as_matrix()
    return X


def _head_sweep_cylinder(urdf_path: Path | None = None, samples: int = 73, margin: float = 0.005) -> dict:
    """The cylinder about the pan axis, in the pan joint's parent link frame,
    that holds the head links' collision boxes at every pan and tilt."""
    tree = kinematics.parse_kinematic_tree(urdf_path)
    pan, tilt = tree.index("head_pan_link"), tree.index("head_tilt_link")
    lim = {"head_pan_link": layout.HEAD_PAN_LIMITS, "head_tilt_link": layout.HEAD_TILT_LIMITS}
    points = []
    for prim in collision_primitives(urdf_path):
        if prim["link"] not in HEAD_LINKS:
            continue
        half = prim["half"] if prim["kind"] == "box" else np.array([prim["radius"]] * 2 + [prim["length"] / 2])
        corners = np.array(list(itertools.product(*[(-h, h) for h in half])))
        p_L = (prim["X_LS"] @ np.c_[corners, np.ones(len(corners))].T)
        # Pan rotates about the axis (radius and height unchanged): sample tilt only.
        for a_tilt in np.linspace(*lim["head_tilt_link"], samples):
            X = tree.X_PJ[pan]
            if prim["link"] == "head_tilt_link":
                X = X @ tree.X_PJ[tilt] @ _rotation(tree.axis[tilt], a_tilt)
            points.append((X @ p_L)[:3].T)
            if prim["link"] == "head_pan_link":
                break
    p = np.concatenate(points)  # in the pan joint's parent frame, pan = 0
    axis_xy = tree.X_PJ[pan][:2, 3]
    radius = float(np.max(np.linalg.norm(p[:, :2] - axis_xy, axis=1))) + margin
    z_lo, z_hi = float(p[:, 2].min()) - margin, float(p[:, 2].max()) + margin
    X_LS = np.eye(4)
    X_LS[:3, 3] = [axis_xy[0], axis_xy[1], 0.5 * (z_lo + z_hi)]
    parent = tree.link_names[tree.parent[pan]]
    return dict(link=parent, kind="cylinder", X_LS=X_LS, half=[radius, radius, 0.5 * (z_hi - z_lo)])


def fit_spheres(urdf_path: Path | None = None) -> dict:
    """Fits spheres to the URDF collision primitives; returns the YAML document."""
    rows = []
    for prim in collision_primitives(urdf_path):
        if prim["link"] in FINGER_LINKS:
            continue
        if prim["kind"] == "box":
            centers, r = _box_spheres(prim["half"])
        else:
            centers, r = _cylinder_spheres(prim["radius"], prim["length"])
        p = (prim["X_LS"] @ np.c_[centers, np.ones(len(centers))].T)[:3].T
        rows += [dict(link=prim["link"], center=[round(float(v), 6) for v in c], radius=round(r + 1e-4, 6)) for c in p]
    centre, half = _finger_sweep_box(urdf_path)
    centers, r = _box_spheres(half)
    rows += [
        dict(link="gripper_link", center=[round(float(v), 6) for v in c + centre], radius=round(r + 1e-4, 6))
        for c in centers
    ]
    links = [r["link"] for r in rows]
    pairs = _self_collision_pairs(links, urdf_path)
    body = []

    def partners_of(link_names) -> list[int]:
        partners = sorted({b if links[a] in link_names else a for a, b in pairs
                           if links[a] in link_names or links[b] in link_names})
        return [k for k in partners if links[k] not in BODY_LINKS]

    for prim in collision_primitives(urdf_path):
        if prim["link"] not in BODY_LINKS or prim["link"] in HEAD_LINKS:
            continue
        if prim["kind"] == "box":
            half = [float(v) for v in prim["half"]]
        else:
            half = [prim["radius"], prim["radius"], prim["length"] / 2]
        body.append(
            dict(
                link=prim["link"],
                kind=prim["kind"],
                X_LS=[round(float(v), 9) for v in prim["X_LS"].ravel()],
                half=half,
                spheres=partners_of((prim["link"],)),
            )
        )
    head = _head_sweep_cylinder(urdf_path)
    body.append(dict(link=head["link"], kind="cylinder", X_LS=[round(float(v), 9) for v in head["X_LS"].ravel()],
                     half=[round(float(v), 6) for v in head["half"]], spheres=partners_of(HEAD_LINKS)))
    # Body-vs-arm pairs are tested on the exact primitives; body-vs-body
    # pairs are fixed relative to each other (apart from the head, filtered).
    pairs = [p for p in pairs if links[p[0]] not in BODY_LINKS and links[p[1]] not in BODY_LINKS]
    return dict(
        source=str(Path(urdf_path).name if urdf_path else kinematics.FETCH_URDF.name),
        model_hash=kinematics.model_hash(),
        spheres=rows,
        self_collision_pairs=pairs,
        body_primitives=body,
    )


def _self_collision_pairs(sphere_links: list[str], urdf_path: Path | None) -> list[list[int]]:
    """Sphere pairs on links whose collision Drake does not filter."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.01), builder)
    Parser(plant).AddModels(str(urdf_path or kinematics.fetch_urdf_path()))
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    inspector = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context)).inspector()

    def geoms(link: str) -> list:
        return plant.GetCollisionGeometriesForBody(plant.GetBodyByName(link))

    links = sorted(set(sphere_links))
    allowed = set()
    for a, b in itertools.combinations(links, 2):
        ga, gb = geoms(a), geoms(b)
        if a == "gripper_link" or b == "gripper_link":
            # Finger spheres live on the gripper link: test fingers' filters too.
            ga = ga + (sum((geoms(f) for f in FINGER_LINKS), []) if a == "gripper_link" else [])
            gb = gb + (sum((geoms(f) for f in FINGER_LINKS), []) if b == "gripper_link" else [])
        if any(not inspector.CollisionFiltered(x, y) for x in ga for y in gb):
            allowed.add((a, b))
    pairs = []
    for i, j in itertools.combinations(range(len(sphere_links)), 2):
        a, b = sorted((sphere_links[i], sphere_links[j]))
        if (a, b) in allowed:
            pairs.append([i, j])
    return pairs


def write_sphere_model(path: Path = SPHERES_YAML) -> Path:
    """Fits and writes `models/fetch/spheres.yaml`."""
    doc = fit_spheres()
    header = "# Fitted by `python -m vamg_drake.robot.spheres` from fetch.urdf collision primitives.\n"
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
    return path


if __name__ == "__main__":
    out = write_sphere_model()
    m = SphereModel.load(out)
    print(f"wrote {out}: {m.num_spheres} spheres, {len(m.self_collision_pairs)} self-collision pairs")
