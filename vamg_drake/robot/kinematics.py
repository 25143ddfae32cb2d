"""Forward kinematics of the Fetch, read from `models/fetch/fetch.urdf`.

The kinematic tree (joint origins, axes, types) is parsed from the URDF, the
one source of these facts, into flat arrays. One Numba kernel,
`link_transforms`, walks them for one configuration into a buffer the caller
owns, computing only the links of a subtree mask (`KinematicTree.subtree_joint_types`);
`tip_jacobian` adds the geometric Jacobian of a link from its output. Every
user of the robot's kinematics calls these two: the batched link poses here,
the sphere centres (`vamg_drake.robot.spheres`), the collision checks
(`vamg_drake.planning.sphere_checks`), the arm chain and its IK and kinematic
maps (`vamg_drake.policy`). `tests/test_robot_model.py` checks them against
Drake's `MultibodyPlant`.

The *extended* configuration used here is
``[q (11, see layout), head_pan, head_tilt, l_finger, r_finger]``.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import hashlib
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numba
import numpy as np

from vamg_drake.robot import layout

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
FETCH_URDF = MODELS_DIR / "fetch" / "fetch.urdf"

EXTENDED_JOINTS: tuple[str, ...] = (
    layout.WHOLE_BODY_JOINTS + layout.HEAD_JOINTS + layout.FINGER_JOINTS
)
NX = len(EXTENDED_JOINTS)  # 15
HEAD_SLICE = slice(layout.NQ, layout.NQ + 2)
FINGER_SLICE = slice(layout.NQ + 2, layout.NQ + 4)

JOINT_FIXED = 0
JOINT_REVOLUTE = 1
JOINT_PRISMATIC = 2
#: Joint type of a link outside a subtree mask: `link_transforms` skips it.
JOINT_SKIPPED = -1

CAMERA_FRAME = "head_camera_depth_optical_frame"
GRASP_FRAME = "gripper_link"
#: Default finger opening per finger [m] (fully open).
DEFAULT_FINGER = 0.05


def fetch_urdf_path() -> Path:
    """The authored Fetch URDF (primitive geometry, real kinematics)."""
    if not FETCH_URDF.exists():
        raise FileNotFoundError(f"Fetch model not found: {FETCH_URDF}")
    return FETCH_URDF


def model_hash() -> str:
    """SHA-256 (first 16 hex) of the URDF: the cache key for precomputed maps."""
    return hashlib.sha256(fetch_urdf_path().read_bytes()).hexdigest()[:16]


def _rpy_to_matrix(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _parse_origin(elem: ET.Element | None) -> np.ndarray:
    X = np.eye(4)
    if elem is None:
        return X
    xyz = [float(v) for v in elem.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in elem.get("rpy", "0 0 0").split()]
    X[:3, :3] = _rpy_to_matrix(*rpy)
    X[:3, 3] = xyz
    return X


@dc.dataclass(frozen=True)
class KinematicTree:
    """A kinematic tree as flat arrays, links in topological order.

    Attributes:
        link_names: body names; ``parent[i] < i``, -1 means the world.
        parent: (L,) parent link index.
        X_PJ: (L, 4, 4) pose of the joint frame in the parent link frame.
        joint_type: (L,) JOINT_FIXED / JOINT_REVOLUTE / JOINT_PRISMATIC.
        axis: (L, 3) unit joint axis in the joint frame.
        var_index: (L,) index into the extended configuration, -1 if fixed.
    """

    link_names: tuple[str, ...]
    parent: np.ndarray
    X_PJ: np.ndarray
    joint_type: np.ndarray
    axis: np.ndarray
    var_index: np.ndarray

    def index(self, name: str) -> int:
        try:
            return self.link_names.index(name)
        except ValueError:
            raise KeyError(f"{FETCH_URDF.name}: no link named '{name}'") from None

    def subtree_joint_types(self, links) -> np.ndarray:
        """The joint types with JOINT_SKIPPED for every link that is neither
        in `links` (indices) nor an ancestor of one: the subtree mask of
        `link_transforms`, which then computes only the links a caller needs."""
        needed = np.zeros(self.parent.shape[0], bool)
        needed[np.asarray(links, dtype=np.int64)] = True
        for i in range(self.parent.shape[0] - 1, -1, -1):  # parents come before children
            if needed[i] and self.parent[i] >= 0:
                needed[self.parent[i]] = True
        return np.ascontiguousarray(np.where(needed, self.joint_type, JOINT_SKIPPED), dtype=self.joint_type.dtype)


def parse_kinematic_tree(urdf_path: Path | None = None) -> KinematicTree:
    """Parses the URDF joints into a `KinematicTree` rooted at 'world'."""
    path = Path(urdf_path) if urdf_path else fetch_urdf_path()
    root = ET.parse(path).getroot()
    joints = root.findall("joint")
    by_child = {j.find("child").get("link"): j for j in joints}
    children: dict[str, list[str]] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j.find("child").get("link"))
    order: list[str] = []
    stack = list(reversed(children.get("world", [])))
    while stack:
        link = stack.pop()
        order.append(link)
        stack.extend(reversed(children.get(link, [])))
    L = len(order)
    parent = np.full(L, -1, dtype=np.int64)
    X_PJ = np.zeros((L, 4, 4))
    joint_type = np.zeros(L, dtype=np.int64)
    axis = np.zeros((L, 3))
    var_index = np.full(L, -1, dtype=np.int64)
    for i, link in enumerate(order):
        j = by_child[link]
        p = j.find("parent").get("link")
        parent[i] = -1 if p == "world" else order.index(p)
        X_PJ[i] = _parse_origin(j.find("origin"))
        kind = j.get("type")
        a = j.find("axis")
        axis[i] = [float(v) for v in (a.get("xyz") if a is not None else "1 0 0").split()]
        if kind in ("revolute", "continuous"):
            joint_type[i] = JOINT_REVOLUTE
        elif kind == "prismatic":
            joint_type[i] = JOINT_PRISMATIC
        elif kind == "fixed":
            joint_type[i] = JOINT_FIXED
        else:
            raise ValueError(f"{path.name}: joint '{j.get('name')}' has unsupported type '{kind}'")
        if joint_type[i] != JOINT_FIXED:
            name = j.get("name")
            if name not in EXTENDED_JOINTS:
                raise ValueError(f"{path.name}: joint '{name}' is not in the joint layout")
            var_index[i] = EXTENDED_JOINTS.index(name)
            axis[i] /= np.linalg.norm(axis[i])
    return KinematicTree(tuple(order), parent, X_PJ, joint_type, axis, var_index)


@numba.njit(cache=True, inline="always")
def link_transforms(parent, X_PJ, joint_type, axis, var_index, v, T):
    """T[i, :3, :] = X_W(link i) (rows of the pose) for the extended
    configuration v (NX,), for every link whose joint_type is not
    JOINT_SKIPPED (`KinematicTree.subtree_joint_types`); other rows are left
    as they are. T (L, 3, 4) or (L, 4, 4) is the caller's buffer: nothing is
    allocated, and no array views are taken (they cost reference counting)."""
    L = parent.shape[0]
    for i in range(L):
        jt = joint_type[i]
        if jt < 0:
            continue
        k = var_index[i]
        # Joint motion X_JC: rotation r about the axis, or translation t along it.
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
        t0, t1, t2 = 0.0, 0.0, 0.0
        if k >= 0:
            q = v[k]
            ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
            if jt == 1:
                c = math.cos(q)
                s = math.sin(q)
                tt = 1.0 - c
                r00 = tt * ax * ax + c
                r01 = tt * ax * ay - s * az
                r02 = tt * ax * az + s * ay
                r10 = tt * ax * ay + s * az
                r11 = tt * ay * ay + c
                r12 = tt * ay * az - s * ax
                r20 = tt * ax * az - s * ay
                r21 = tt * ay * az + s * ax
                r22 = tt * az * az + c
            elif jt == 2:
                t0, t1, t2 = q * ax, q * ay, q * az
        p = parent[i]
        # Row by row: A = X_WP @ X_PJ, then T[i] = A @ X_JC.
        for a in range(3):
            if p < 0:
                a0, a1, a2, a3 = X_PJ[i, a, 0], X_PJ[i, a, 1], X_PJ[i, a, 2], X_PJ[i, a, 3]
            else:
                w0, w1, w2, w3 = T[p, a, 0], T[p, a, 1], T[p, a, 2], T[p, a, 3]
                a0 = w0 * X_PJ[i, 0, 0] + w1 * X_PJ[i, 1, 0] + w2 * X_PJ[i, 2, 0]
                a1 = w0 * X_PJ[i, 0, 1] + w1 * X_PJ[i, 1, 1] + w2 * X_PJ[i, 2, 1]
                a2 = w0 * X_PJ[i, 0, 2] + w1 * X_PJ[i, 1, 2] + w2 * X_PJ[i, 2, 2]
                a3 = w0 * X_PJ[i, 0, 3] + w1 * X_PJ[i, 1, 3] + w2 * X_PJ[i, 2, 3] + w3
            if jt == 1:
                T[i, a, 0] = a0 * r00 + a1 * r10 + a2 * r20
                T[i, a, 1] = a0 * r01 + a1 * r11 + a2 * r21
                T[i, a, 2] = a0 * r02 + a1 * r12 + a2 * r22
            else:  # no rotation
                T[i, a, 0] = a0
                T[i, a, 1] = a1
                T[i, a, 2] = a2
            T[i, a, 3] = a0 * t0 + a1 * t1 + a2 * t2 + a3


@numba.njit(cache=True, inline="always")
def tip_jacobian(parent, joint_type, axis, var_index, T, tip, column, J):
    """J (6, n): the geometric Jacobian of link `tip`'s origin, rows (v, w)
    in W, from the link poses T that `link_transforms` computed. Column
    column[k] belongs to variable k of the extended configuration (-1: not a
    column); columns of joints off the path to `tip` are zero."""
    for c in range(J.shape[1]):
        for r in range(6):
            J[r, c] = 0.0
    px, py, pz = T[tip, 0, 3], T[tip, 1, 3], T[tip, 2, 3]
    i = tip
    while i >= 0:
        k = var_index[i]
        if k >= 0 and joint_type[i] > 0 and column[k] >= 0:
            c = column[k]
            ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
            wx = T[i, 0, 0] * ax + T[i, 0, 1] * ay + T[i, 0, 2] * az
            wy = T[i, 1, 0] * ax + T[i, 1, 1] * ay + T[i, 1, 2] * az
            wz = T[i, 2, 0] * ax + T[i, 2, 1] * ay + T[i, 2, 2] * az
            if joint_type[i] == 1:
                # The joint's origin is link i's origin (rotation moves neither).
                rx, ry, rz = px - T[i, 0, 3], py - T[i, 1, 3], pz - T[i, 2, 3]
                J[0, c] = wy * rz - wz * ry
                J[1, c] = wz * rx - wx * rz
                J[2, c] = wx * ry - wy * rx
                J[3, c] = wx
                J[4, c] = wy
                J[5, c] = wz
            else:
                J[0, c] = wx
                J[1, c] = wy
                J[2, c] = wz
        i = parent[i]


@numba.njit(cache=True)
def _link_poses(parent, X_PJ, joint_type, axis, var_index, V, out):
    """out[b] (L, 4, 4) = every link's pose for each configuration V[b]."""
    for b in range(V.shape[0]):
        link_transforms(parent, X_PJ, joint_type, axis, var_index, V[b], out[b])
        for i in range(parent.shape[0]):
            out[b, i, 3, 0] = 0.0
            out[b, i, 3, 1] = 0.0
            out[b, i, 3, 2] = 0.0
            out[b, i, 3, 3] = 1.0
    return out


def extend_configuration(
    q: np.ndarray, head: np.ndarray | None = None, fingers: np.ndarray | None = None
) -> np.ndarray:
    """Stacks q (B, 11), head (B, 2) and fingers (B, 2) into (B, NX)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.shape[-1] != layout.NQ:
        raise ValueError(f"q must have {layout.NQ} columns, got shape {q.shape}")
    B = q.shape[0]
    V = np.empty((B, NX))
    V[:, : layout.NQ] = q
    V[:, HEAD_SLICE] = 0.0 if head is None else np.broadcast_to(np.asarray(head, float), (B, 2))
    V[:, FINGER_SLICE] = DEFAULT_FINGER if fingers is None else np.broadcast_to(np.asarray(fingers, float), (B, 2))
    return V


class FetchKinematics:
    """Batched forward kinematics of the Fetch.

    Example:
        kin = FetchKinematics.instance()
        X_WL = kin.link_poses(q_batch)            # (B, L, 4, 4)
        X_WC = kin.camera_pose(q, pan, tilt)      # (4, 4), depth optical frame
        X_WG = kin.gripper_pose(q)                # (4, 4), grasp frame
    """

    def __init__(self, tree: KinematicTree | None = None):
        self.tree = tree or parse_kinematic_tree()
        self.link_names = self.tree.link_names
        self._camera = self.tree.index(CAMERA_FRAME)
        self._grasp = self.tree.index(GRASP_FRAME)

    @staticmethod
    @functools.cache
    def instance() -> "FetchKinematics":
        """A shared instance for the authored model."""
        return FetchKinematics()

    def link_index(self, name: str) -> int:
        return self.tree.index(name)

    def poses_extended(self, V: np.ndarray) -> np.ndarray:
        """Link poses (B, L, 4, 4) for extended configurations V (B, NX)."""
        V = np.ascontiguousarray(np.atleast_2d(V), dtype=float)
        if V.ndim != 2 or V.shape[1] != NX:
            raise ValueError(f"extended configurations must have shape (B, {NX}), got {V.shape}")
        out = np.empty((V.shape[0], len(self.link_names), 4, 4))
        t = self.tree
        return _link_poses(t.parent, t.X_PJ, t.joint_type, t.axis, t.var_index, V, out)

    def link_poses(
        self, q: np.ndarray, head: np.ndarray | None = None, fingers: np.ndarray | None = None
    ) -> np.ndarray:
        """World poses X_WL (B, L, 4, 4) of every link for q (B, 11) or (11,)."""
        return self.poses_extended(extend_configuration(q, head, fingers))

    def frame_pose(self, name: str, q: np.ndarray, head=None) -> np.ndarray:
        """X_WF for link/frame `name`; (4, 4) for one q, (B, 4, 4) for a batch."""
        X = self.link_poses(q, head)[:, self.tree.index(name)]
        return X[0] if np.ndim(q) == 1 else X

    def camera_pose(self, q: np.ndarray, pan: float = 0.0, tilt: float = 0.0) -> np.ndarray:
        """X_WC of the head depth optical frame (+z forward, +x right, +y down)."""
        X = self.link_poses(q, np.array([[pan, tilt]]))[:, self._camera]
        return X[0] if np.ndim(q) == 1 else X

    def camera_poses_for_gazes(self, q: np.ndarray, gazes: np.ndarray) -> np.ndarray:
        """X_WC (G, 4, 4) at configuration q (11,) for each (pan, tilt) row of gazes."""
        gazes = np.atleast_2d(gazes)
        Q = np.broadcast_to(np.asarray(q, float), (gazes.shape[0], layout.NQ))
        return self.link_poses(Q, gazes)[:, self._camera]

    def gripper_pose(self, q: np.ndarray) -> np.ndarray:
        """X_WG of the grasp frame (origin mid finger pads, +x approach, +y closing)."""
        X = self.link_poses(q)[:, self._grasp]
        return X[0] if np.ndim(q) == 1 else X
