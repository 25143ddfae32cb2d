"""The torso + arm serial chain of the Fetch in its base frame: batched FK and Jacobian.

The chain runs from ``base_link`` (frame B) to the grasp frame G
(``gripper_link``) through the 8 joints ``q[TORSO_ARM]`` (torso lift and the 7
arm joints). Its joint origins and axes come from the same parsed URDF as
``FetchKinematics`` (`vamg_drake.robot.kinematics.parse_kinematic_tree`).
Kinematic maps and the fast IK need the pose *and* the geometric Jacobian for
millions of configurations, hence this dedicated Numba kernel.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import math

import numba
import numpy as np

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import GRASP_FRAME, JOINT_FIXED, JOINT_REVOLUTE, KinematicTree, parse_kinematic_tree

#: Number of chain joints (torso + 7 arm).
N_CHAIN = 8
CHAIN_LOWER = layout.Q_LOWER[layout.TORSO_ARM]
CHAIN_UPPER = layout.Q_UPPER[layout.TORSO_ARM]
CHAIN_CONTINUOUS = layout.IS_CONTINUOUS[layout.TORSO_ARM]


@dc.dataclass(frozen=True)
class ArmChain:
    """Flat arrays of the chain from base_link to the grasp frame.

    Attributes:
        X_PJ: (n, 4, 4) joint frame in the previous chain link's frame.
        joint_type: (n,) JOINT_FIXED / JOINT_REVOLUTE / JOINT_PRISMATIC.
        axis: (n, 3) joint axis in the joint frame.
        column: (n,) index into the 8 chain variables, -1 for fixed joints.
    """

    X_PJ: np.ndarray
    joint_type: np.ndarray
    axis: np.ndarray
    column: np.ndarray

    @staticmethod
    @functools.cache
    def load() -> "ArmChain":
        """The chain of the authored Fetch model."""
        return ArmChain.from_tree(parse_kinematic_tree())

    @staticmethod
    def from_tree(tree: KinematicTree, tip: str = GRASP_FRAME, root: str = "base_link") -> "ArmChain":
        path = []
        i = tree.index(tip)
        root_index = tree.index(root)
        while i != root_index:
            if i < 0:
                raise ValueError(f"'{tip}' is not below '{root}' in the kinematic tree")
            path.append(i)
            i = int(tree.parent[i])
        path.reverse()
        column = np.full(len(path), -1, dtype=np.int64)
        for c, i in enumerate(path):
            if tree.joint_type[i] != JOINT_FIXED:
                v = int(tree.var_index[i])
                if not layout.TORSO <= v < layout.NQ:
                    raise ValueError(f"chain joint of link '{tree.link_names[i]}' is not a torso/arm joint")
                column[c] = v - layout.TORSO
        if sorted(column[column >= 0].tolist()) != list(range(N_CHAIN)):
            raise ValueError("the chain base_link -> gripper must contain exactly the torso and 7 arm joints")
        return ArmChain(
            np.ascontiguousarray(tree.X_PJ[path]),
            np.ascontiguousarray(tree.joint_type[path]),
            np.ascontiguousarray(tree.axis[path]),
            column,
        )

    def forward(self, q_chain: np.ndarray, with_jacobian: bool = False):
        """X_BG (B, 4, 4) [and the geometric Jacobian J (B, 6, 8), rows (v, w) in B].

        Args:
            q_chain: (B, 8) torso + arm joint values.
        """
        q_chain = np.ascontiguousarray(np.atleast_2d(q_chain), dtype=float)
        if q_chain.shape[1] != N_CHAIN:
            raise ValueError(f"q_chain must have {N_CHAIN} columns, got shape {q_chain.shape}")
        X = np.empty((q_chain.shape[0], 4, 4))
        J = np.empty((q_chain.shape[0], 6, N_CHAIN))
        chain_fk_jacobian(self.X_PJ, self.joint_type, self.axis, self.column, q_chain, X, J, with_jacobian)
        return (X, J) if with_jacobian else X


def base_poses(q: np.ndarray) -> np.ndarray:
    """X_WB (B, 4, 4) of base_link for configurations q (B, 11) (planar x, y, theta)."""
    q = np.atleast_2d(q)
    c, s = np.cos(q[:, layout.THETA]), np.sin(q[:, layout.THETA])
    X = np.zeros((q.shape[0], 4, 4))
    X[:, 0, 0], X[:, 0, 1], X[:, 1, 0], X[:, 1, 1] = c, -s, s, c
    X[:, 2, 2] = X[:, 3, 3] = 1.0
    X[:, 0, 3], X[:, 1, 3] = q[:, 0], q[:, 1]
    return X


@numba.njit(cache=True)
def _chain_scratch(n):
    """Scratch buffers for `_chain_one`: R (3,3), p (3,), tmp (3,3), origins and axes (n,3)."""
    return np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.zeros((n, 3)), np.zeros((n, 3))


@numba.njit(cache=True)
def _chain_one(X_PJ, joint_type, axis, column, q, X_out, J_out, with_jacobian, R, p, origins, axes, tmp):
    """FK (and Jacobian) of one configuration; R (3,3), p (3,), origins/axes (n,3), tmp (3,3) are scratch."""
    n = X_PJ.shape[0]
    for r in range(3):
        p[r] = 0.0
        for c in range(3):
            R[r, c] = 1.0 if r == c else 0.0
    for i in range(n):
        # T <- T @ X_PJ[i]
        for r in range(3):
            p[r] += R[r, 0] * X_PJ[i, 0, 3] + R[r, 1] * X_PJ[i, 1, 3] + R[r, 2] * X_PJ[i, 2, 3]
        for r in range(3):
            for c in range(3):
                tmp[r, c] = R[r, 0] * X_PJ[i, 0, c] + R[r, 1] * X_PJ[i, 1, c] + R[r, 2] * X_PJ[i, 2, c]
        for r in range(3):
            for c in range(3):
                R[r, c] = tmp[r, c]
        c_idx = column[i]
        if c_idx < 0:
            continue
        ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
        wx = R[0, 0] * ax + R[0, 1] * ay + R[0, 2] * az
        wy = R[1, 0] * ax + R[1, 1] * ay + R[1, 2] * az
        wz = R[2, 0] * ax + R[2, 1] * ay + R[2, 2] * az
        origins[i, 0], origins[i, 1], origins[i, 2] = p[0], p[1], p[2]
        axes[i, 0], axes[i, 1], axes[i, 2] = wx, wy, wz
        v = q[c_idx]
        if joint_type[i] == JOINT_REVOLUTE:
            # Rotation about the world-frame axis w: R <- Rot(w, v) @ R (same as R @ Rot(a, v)).
            cv = math.cos(v)
            sv = math.sin(v)
            t = 1.0 - cv
            m00 = t * wx * wx + cv
            m01 = t * wx * wy - sv * wz
            m02 = t * wx * wz + sv * wy
            m10 = t * wx * wy + sv * wz
            m11 = t * wy * wy + cv
            m12 = t * wy * wz - sv * wx
            m20 = t * wx * wz - sv * wy
            m21 = t * wy * wz + sv * wx
            m22 = t * wz * wz + cv
            for c in range(3):
                a0, a1, a2 = R[0, c], R[1, c], R[2, c]
                R[0, c] = m00 * a0 + m01 * a1 + m02 * a2
                R[1, c] = m10 * a0 + m11 * a1 + m12 * a2
                R[2, c] = m20 * a0 + m21 * a1 + m22 * a2
        else:
            p[0] += v * wx
            p[1] += v * wy
            p[2] += v * wz
    for r in range(3):
        for c in range(3):
            X_out[r, c] = R[r, c]
        X_out[r, 3] = p[r]
        X_out[3, r] = 0.0
    X_out[3, 3] = 1.0
    if with_jacobian:
        for i in range(n):
            c_idx = column[i]
            if c_idx < 0:
                continue
            zx, zy, zz = axes[i, 0], axes[i, 1], axes[i, 2]
            if joint_type[i] == JOINT_REVOLUTE:
                rx = p[0] - origins[i, 0]
                ry = p[1] - origins[i, 1]
                rz = p[2] - origins[i, 2]
                J_out[0, c_idx] = zy * rz - zz * ry
                J_out[1, c_idx] = zz * rx - zx * rz
                J_out[2, c_idx] = zx * ry - zy * rx
                J_out[3, c_idx] = zx
                J_out[4, c_idx] = zy
                J_out[5, c_idx] = zz
            else:
                J_out[0, c_idx] = zx
                J_out[1, c_idx] = zy
                J_out[2, c_idx] = zz
                J_out[3, c_idx] = 0.0
                J_out[4, c_idx] = 0.0
                J_out[5, c_idx] = 0.0


@numba.njit(cache=True, parallel=True)
def chain_fk_jacobian(X_PJ, joint_type, axis, column, q_chain, X_out, J_out, with_jacobian):
    """Batched chain FK (and Jacobian) into preallocated X_out (B,4,4), J_out (B,6,8)."""
    B = q_chain.shape[0]
    n = X_PJ.shape[0]
    block = 4096
    for k in numba.prange((B + block - 1) // block):
        R, p, tmp, origins, axes = _chain_scratch(n)
        for b in range(k * block, min(B, (k + 1) * block)):
            _chain_one(X_PJ, joint_type, axis, column, q_chain[b], X_out[b], J_out[b], with_jacobian, R, p, origins, axes, tmp)
