"""The torso + arm serial chain of the Fetch in its base frame: batched FK and Jacobian.

The chain runs from ``base_link`` (frame B) to the grasp frame G
(``gripper_link``) through the 8 joints ``q[TORSO_ARM]`` (torso lift and the 7
arm joints). It is the robot's kinematic tree
(`vamg_drake.robot.kinematics.parse_kinematic_tree`) masked to the path to G
and evaluated by the robot's one kinematics kernel
(`vamg_drake.robot.kinematics.link_transforms`, `tip_jacobian`) with the base
at the origin, where B is the world frame. Kinematic maps and the fast IK need
the pose *and* the geometric Jacobian for millions of configurations.
"""

from __future__ import annotations

import dataclasses as dc
import functools

import numba
import numpy as np

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import (
    GRASP_FRAME,
    JOINT_FIXED,
    NX,
    KinematicTree,
    link_transforms,
    parse_kinematic_tree,
    tip_jacobian,
)

#: Number of chain joints (torso + 7 arm).
N_CHAIN = 8
CHAIN_LOWER = layout.Q_LOWER[layout.TORSO_ARM]
CHAIN_UPPER = layout.Q_UPPER[layout.TORSO_ARM]
CHAIN_CONTINUOUS = layout.IS_CONTINUOUS[layout.TORSO_ARM]


@dc.dataclass(frozen=True)
class ArmChain:
    """The kinematic tree masked to the chain from base_link to the grasp frame.

    Attributes:
        parent, X_PJ, axis, var_index: the tree's arrays (`KinematicTree`).
        joint_type: the tree's joint types, JOINT_SKIPPED off the path to the tip.
        tip: index of the grasp frame's link.
        column: (NX,) chain column (0..7) of each extended-configuration
            variable, -1 for the variables that are not torso/arm joints.
    """

    parent: np.ndarray
    X_PJ: np.ndarray
    joint_type: np.ndarray
    axis: np.ndarray
    var_index: np.ndarray
    tip: int
    column: np.ndarray

    @staticmethod
    @functools.cache
    def load() -> "ArmChain":
        """The chain of the authored Fetch model."""
        return ArmChain.from_tree(parse_kinematic_tree())

    @staticmethod
    def from_tree(tree: KinematicTree, tip: str = GRASP_FRAME, root: str = "base_link") -> "ArmChain":
        tip_index = tree.index(tip)
        root_index = tree.index(root)
        path = []
        i = tip_index
        while i != root_index:
            if i < 0:
                raise ValueError(f"'{tip}' is not below '{root}' in the kinematic tree")
            path.append(i)
            i = int(tree.parent[i])
        moving = sorted(int(tree.var_index[i]) for i in path if tree.joint_type[i] != JOINT_FIXED)
        if moving != list(range(layout.TORSO, layout.NQ)):
            raise ValueError("the chain base_link -> gripper must contain exactly the torso and 7 arm joints")
        joint_type = tree.subtree_joint_types([tip_index])
        # The chain is expressed in B by evaluating the tree with the base at
        # the origin: that needs X_W(root) = identity there.
        T = np.empty((tree.parent.shape[0], 3, 4))
        link_transforms(tree.parent, tree.X_PJ, joint_type, tree.axis, tree.var_index, np.zeros(NX), T)
        if not np.array_equal(T[root_index], np.eye(4)[:3]):
            raise ValueError(f"'{root}' is not at the world origin when the base coordinates are zero")
        column = np.full(NX, -1, dtype=np.int64)
        column[layout.TORSO:layout.NQ] = np.arange(N_CHAIN)
        return ArmChain(tree.parent, tree.X_PJ, joint_type, tree.axis, tree.var_index, tip_index, column)

    @property
    def arrays(self) -> tuple:
        """The chain's arrays as the compiled functions take them."""
        return (self.parent, self.X_PJ, self.joint_type, self.axis, self.var_index, self.tip, self.column)

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
        chain_fk_jacobian(*self.arrays, q_chain, X, J, with_jacobian)
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
def chain_scratch(parent):
    """Scratch for `chain_pose`: the extended configuration v (NX,) (zero
    base, head and fingers) and the link poses T (L, 3, 4)."""
    return np.zeros(NX), np.empty((parent.shape[0], 3, 4))


@numba.njit(cache=True)
def chain_pose(parent, X_PJ, joint_type, axis, var_index, tip, column, q, v, T, J, with_jacobian):
    """FK of the chain at q (8,): X_BG is T[tip] afterwards (3, 4); J (6, 8)
    the Jacobian when `with_jacobian`. v, T come from `chain_scratch`."""
    for k in range(column.shape[0]):
        if column[k] >= 0:
            v[k] = q[column[k]]
    link_transforms(parent, X_PJ, joint_type, axis, var_index, v, T)
    if with_jacobian:
        tip_jacobian(parent, joint_type, axis, var_index, T, tip, column, J)


@numba.njit(cache=True, parallel=True)
def chain_fk_jacobian(parent, X_PJ, joint_type, axis, var_index, tip, column, q_chain, X_out, J_out, with_jacobian):
    """Batched chain FK (and Jacobian) into preallocated X_out (B,4,4), J_out (B,6,8)."""
    B = q_chain.shape[0]
    block = 4096
    for k in numba.prange((B + block - 1) // block):
        v, T = chain_scratch(parent)
        for b in range(k * block, min(B, (k + 1) * block)):
            chain_pose(parent, X_PJ, joint_type, axis, var_index, tip, column, q_chain[b], v, T, J_out[b],
                       with_jacobian)
            for r in range(3):
                for c in range(4):
                    X_out[b, r, c] = T[tip, r, c]
            X_out[b, 3, 0] = 0.0
            X_out[b, 3, 1] = 0.0
            X_out[b, 3, 2] = 0.0
            X_out[b, 3, 3] = 1.0
