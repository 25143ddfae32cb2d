"""Inverse kinematics of the Fetch grasp frame G.

Two solvers with one contract (targets X_WG, a seed configuration, results
``(q (K, 11), ok (K,))`` with continuous joints wrapped into [-pi, pi)):

* `FastIk` -- batched damped-least-squares IK in Numba over the torso + arm
  chain (`arm_chain`), with deterministic random restarts: thousands of
  solves per second, used by the pre-grasp sampler and grasp validation.
* `DrakeIk` -- Drake's `InverseKinematics` (SNOPT) on a plant loaded from
  ``models/fetch/fetch.urdf``: arm-only (base and torso fixed) or whole-body,
  optionally collision-aware (`AddMinimumDistanceLowerBoundConstraint`).

Tolerances are explicit: a solution is accepted when its position error is
below ``position_tolerance`` and its rotation error below ``angle_tolerance``.
"""

import dataclasses as dc
import math

import numba
import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.solvers import Solve
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.policy.arm_chain import CHAIN_LOWER, CHAIN_UPPER, N_CHAIN, ArmChain, base_poses, chain_pose, chain_scratch
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import GRASP_FRAME, fetch_urdf_path


@dc.dataclass
class IkConfig:
    """Tolerances and iteration limits of the IK solvers."""

    position_tolerance: float = 0.002
    angle_tolerance: float = 0.02
    max_iterations: int = 80
    #: Random restarts after the seed fails (FastIk).
    restarts: int = 3
    damping: float = 0.05
    #: Largest joint step per iteration [rad or m].
    max_step: float = 0.4
    seed: int = 0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if self.position_tolerance <= 0 or self.angle_tolerance <= 0:
            raise ValueError("IkConfig: tolerances must be positive")
        if self.max_iterations < 1 or self.restarts < 0:
            raise ValueError("IkConfig: max_iterations >= 1 and restarts >= 0 required")


@numba.njit(cache=True)
def _dls_one(chain, target, q0, active, lower, upper, pos_tol, ang_tol,
             max_iter, damping, max_step, q_out):
    """Damped least squares from q0 towards X_BG = target; `chain` is `ArmChain.arrays`."""
    V, T = chain_scratch(chain[0])
    X = T[chain[5]]  # X_BG (3, 4), updated by `chain_pose`
    J = np.empty((6, N_CHAIN))
    e = np.empty(6)
    Re = np.empty((3, 3))
    q = q0.copy()
    for it in range(max_iter + 1):
        chain_pose(*chain, q, V, T, J, True)
        for r in range(3):
            e[r] = target[r, 3] - X[r, 3]
        # Rotation error: log(R_t R^T) in the base frame.
        for r in range(3):
            for c in range(3):
                Re[r, c] = target[r, 0] * X[c, 0] + target[r, 1] * X[c, 1] + target[r, 2] * X[c, 2]
        vx = 0.5 * (Re[2, 1] - Re[1, 2])
        vy = 0.5 * (Re[0, 2] - Re[2, 0])
        vz = 0.5 * (Re[1, 0] - Re[0, 1])
        cos_a = min(1.0, max(-1.0, 0.5 * (Re[0, 0] + Re[1, 1] + Re[2, 2] - 1.0)))
        angle = math.acos(cos_a)
        s = math.sqrt(vx * vx + vy * vy + vz * vz)
        if s > 1e-9:
            scale = angle / s
        else:
            scale = 1.0
        if angle > 3.0 and s < 1e-3:
            # Near pi: any axis with a large rotation component moves us off the singularity.
            vx, vy, vz, scale = 1.0, 0.0, 0.0, angle
        e[3], e[4], e[5] = vx * scale, vy * scale, vz * scale
        pos_err = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
        if pos_err < pos_tol and angle < ang_tol:
            q_out[:] = q
            return True
        if it == max_iter:
            break
        for c in range(N_CHAIN):
            if not active[c]:
                for r in range(6):
                    J[r, c] = 0.0
        A = J @ J.T
        for r in range(6):
            A[r, r] += damping * damping
        dq = J.T @ np.linalg.solve(A, e)
        biggest = np.max(np.abs(dq))
        if biggest > max_step:
            dq *= max_step / biggest
        for c in range(N_CHAIN):
            v = q[c] + dq[c]
            if v < lower[c]:
                v = lower[c]
            elif v > upper[c]:
                v = upper[c]
            q[c] = v
    q_out[:] = q
    return False


@numba.njit(cache=True, parallel=True)
def _dls_batch(chain, targets, seeds, restarts, active, lower, upper,
               pos_tol, ang_tol, max_iter, damping, max_step, q_out, ok_out):
    for k in numba.prange(targets.shape[0]):
        ok_out[k] = _dls_one(chain, targets[k], seeds[k], active, lower, upper,
                             pos_tol, ang_tol, max_iter, damping, max_step, q_out[k])
        r = 0
        while not ok_out[k] and r < restarts.shape[1]:
            ok_out[k] = _dls_one(chain, targets[k], restarts[k, r], active, lower, upper,
                                 pos_tol, ang_tol, max_iter, damping, max_step, q_out[k])
            r += 1


class FastIk:
    """Batched damped-least-squares IK of the grasp frame (Numba)."""

    def __init__(self, config: IkConfig | None = None, chain: ArmChain | None = None) -> None:
        self.config = config or IkConfig()
        self.chain = chain or ArmChain.load()
        #: The restarts' generator; callers that keep their state in a Context save and restore its state.
        self.rng = np.random.default_rng(self.config.seed)

    def solve_chain(
        self, X_BG: np.ndarray, q_seed_chain: np.ndarray, torso_fixed: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solves base-frame targets X_BG (K, 4, 4) for the 8 chain joints.

        Args:
            X_BG: targets in the base frame.
            q_seed_chain: (8,) or (K, 8) seeds (the torso value is kept when fixed).
            torso_fixed: keep the torso at the seed's value.

        Returns:
            (q_chain (K, 8) with continuous joints wrapped, ok (K,)).
        """
        cfg = self.config
        X_BG = np.ascontiguousarray(np.reshape(X_BG, (-1, 4, 4)), dtype=float)
        K = X_BG.shape[0]
        seeds = np.ascontiguousarray(np.broadcast_to(np.asarray(q_seed_chain, float), (K, N_CHAIN)))
        restarts = self.rng.uniform(layout.SAMPLE_LOWER[layout.TORSO_ARM], layout.SAMPLE_UPPER[layout.TORSO_ARM],
                                     (K, cfg.restarts, N_CHAIN))
        active = np.ones(N_CHAIN, dtype=np.bool_)
        if torso_fixed:
            active[0] = False
            restarts[:, :, 0] = seeds[:, None, 0]
        q = np.empty((K, N_CHAIN))
        ok = np.zeros(K, dtype=np.bool_)
        ch = self.chain
        _dls_batch(ch.arrays, X_BG, seeds, restarts, active,
                   CHAIN_LOWER, CHAIN_UPPER, cfg.position_tolerance, cfg.angle_tolerance,
                   cfg.max_iterations, cfg.damping, cfg.max_step, q, ok)
        q = layout.wrap_configuration(np.concatenate([np.zeros((K, 3)), q], axis=1))[:, layout.TORSO_ARM]
        return q, ok

    def solve(
        self, X_WG: np.ndarray, q_seed: np.ndarray, torso_fixed: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """IK with the base fixed at the seed's (x, y, theta).

        Args:
            X_WG: (K, 4, 4) world-frame grasp targets.
            q_seed: (11,) or (K, 11) seeds; their base (and torso if fixed) are kept.
            torso_fixed: keep the torso too (arm-only IK).

        Returns:
            (q (K, 11), ok (K,)).
        """
        X_WG = np.reshape(X_WG, (-1, 4, 4))
        K = X_WG.shape[0]
        q_seed = np.broadcast_to(np.asarray(q_seed, dtype=float), (K, layout.NQ))
        X_BG = np.linalg.inv(base_poses(q_seed)) @ X_WG
        q_chain, ok = self.solve_chain(X_BG, q_seed[:, layout.TORSO_ARM], torso_fixed)
        q = np.array(q_seed, copy=True)
        q[:, layout.TORSO_ARM] = q_chain
        return layout.wrap_configuration(q), ok

    def solve_arm(self, X_WG: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arm-only IK (base and torso fixed): the `grasp_ranking.ArmIkFn` contract."""
        return self.solve(X_WG, q_seed, torso_fixed=True)


class DrakeIk:
    """Drake `InverseKinematics` on the Fetch plant (one target at a time, ~ms each).

    Args:
        config: tolerances (position box and angle bound of the constraints).
        collision_distance: when set, adds a minimum-distance constraint between
            all collision geometries of the robot model (self-collision).
    """

    def __init__(self, config: IkConfig | None = None, collision_distance: float | None = None) -> None:
        self.config = config or IkConfig()
        self.collision_distance = collision_distance
        builder = DiagramBuilder()
        self.plant, self.scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
        Parser(self.plant).AddModels(str(fetch_urdf_path()))
        world_body = self.plant.GetBodyByName("world") if self.plant.HasBodyNamed("world") else None
        if world_body is not None and world_body.index() != self.plant.world_body().index():
            self.plant.WeldFrames(self.plant.world_frame(), world_body.body_frame())
        self.plant.Finalize()
        self.diagram = builder.Build()
        self._grasp_frame = self.plant.GetFrameByName(GRASP_FRAME)
        names = layout.WHOLE_BODY_JOINTS
        self._q_index = np.array([self.plant.GetJointByName(n).position_start() for n in names])
        self._nq_plant = self.plant.num_positions()

    def _to_plant(self, q: np.ndarray) -> np.ndarray:
        v = np.zeros(self._nq_plant)
        v[self._q_index] = q
        return v

    def solve(
        self, X_WG: np.ndarray, q_seed: np.ndarray, fix_base: bool = True, fix_torso: bool = True
    ) -> tuple[np.ndarray, bool]:
        """One IK solve for the grasp frame at X_WG (4, 4).

        Args:
            X_WG: the target pose.
            q_seed: (11,) initial guess; fixed joints keep its values.
            fix_base / fix_torso: arm-only IK when both are True, whole-body when both are False.

        Returns:
            (q (11,) wrapped, success).
        """
        cfg = self.config
        context = self.diagram.CreateDefaultContext()
        plant_context = self.plant.GetMyMutableContextFromRoot(context)
        ik = InverseKinematics(self.plant, plant_context, with_joint_limits=True)
        qv = ik.q()
        seed = self._to_plant(np.asarray(q_seed, dtype=float))
        X = RigidTransform(np.asarray(X_WG, dtype=float))
        tol = cfg.position_tolerance / math.sqrt(3.0)
        ik.AddPositionConstraint(
            self._grasp_frame, np.zeros(3), self.plant.world_frame(),
            X.translation() - tol, X.translation() + tol,
        )
        ik.AddOrientationConstraint(
            self._grasp_frame, RotationMatrix(), self.plant.world_frame(), X.rotation(), cfg.angle_tolerance
        )
        fixed = list(range(3)) * fix_base + [layout.TORSO] * fix_torso
        prog = ik.get_mutable_prog()
        for i in fixed:
            k = self._q_index[i]
            prog.AddBoundingBoxConstraint(seed[k], seed[k], qv[k])
        others = [k for k in range(self._nq_plant) if k not in self._q_index]
        for k in others:  # head and fingers: stay at the seed (zero)
            prog.AddBoundingBoxConstraint(seed[k], seed[k], qv[k])
        if self.collision_distance is not None:
            ik.AddMinimumDistanceLowerBoundConstraint(self.collision_distance)
        prog.AddQuadraticErrorCost(np.eye(self._nq_plant) * 0.01, seed, qv)
        prog.SetInitialGuess(qv, seed)
        result = Solve(prog)
        q = result.GetSolution(qv)[self._q_index]
        return layout.wrap_configuration(q), bool(result.is_success())
