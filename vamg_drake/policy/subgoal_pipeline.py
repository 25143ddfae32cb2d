"""The real subgoal samplers: grasp, pre-grasp and observe, wired to maps, IK and collision.

`SubgoalPipeline` owns the kinematic maps, the IK, a `GraspCandidateSource`
(``config.grasp_source``: the geometric `AntipodalGraspSampler`, or its
candidates re-ranked by the learned `LearnedGraspScorer`), the pre-grasp and observe samplers, and builds the collision check from
the map points at each call. `SubgoalPipeline.samplers()` returns the
`SubgoalSamplers` the behaviour tree calls.

Collision checks use the planner's `SphereCollisionChecker` on the map points near
the target and the robot, minus a small ball around the target, which only
the robot body (every sphere but the gripper's) must keep clear of: the
fingers are meant to reach the object, and the grasp sampler has already
checked the fingers and palm against the cloud itself at finer resolution.
The gripper keeps clear of the target's support surface in that ball too
(`CollisionEnvironment.grasp_target_floor`), except at the grasp and on the
approach to it (`collision_fn(..., grasp=True)`): there the grasp source's
own finer check of the gripper decides, since the collision model's finger
spheres reach 1 cm past the fingertips and would leave no grasp of a small
object, such as a 2 cm Lego brick, on a counter.

Target checks (bad input): a non-finite target, or one enclosed by map points
on (nearly) all sides -- inside furniture -- fails every stage at once with a
clear reason; a target outside the room fails because no navigable base cell
lies within the arm's reach of it.
"""

import dataclasses as dc
import time

import numpy as np
from scipy.spatial import cKDTree

from vamg_drake.perception.point_clusters import MirrorCompletionConfig, mirrored_object_points
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import CollisionCheckerConfig, SphereCollisionChecker
from vamg_drake.planning.whole_body_planner import PlannerConfig
from vamg_drake.policy.arm_chain import base_poses
from vamg_drake.policy.behaviour_tree import FailureCategory, PolicyInputs, SubgoalProposal, SubgoalSamplers
from vamg_drake.policy.grasp_candidates import AntipodalGraspConfig, GraspCandidates, GraspCandidateSource
from vamg_drake.policy.grasp_ranking import (
    GraspRankingConfig,
    near_any_grasp,
    pose_distance,
    pregrasp_poses,
    select_grasp_goal,
)
from vamg_drake.policy.ik import FastIk
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.learned_grasps import GraspSourceConfig, make_grasp_source
from vamg_drake.policy.observe_sampler import ObserveConfig, ObserveSampler
from vamg_drake.policy.pregrasp_sampler import BaseCostmap, PregraspConfig, PregraspSampler
from vamg_drake.policy.visibility import TargetVisibility
from vamg_drake.robot.head_camera import HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.robot.spheres import SphereModel


@dc.dataclass
class SubgoalPipelineConfig:
    """Parameters of the real samplers."""

    #: The grasp configuration is collision-checked too: ``collision_fn`` lets the
    #: gripper reach into the target's ball.
    ranking: GraspRankingConfig = dc.field(default_factory=lambda: GraspRankingConfig(check_grasp_collision=True))
    pregrasp: PregraspConfig = dc.field(default_factory=PregraspConfig)
    observe: ObserveConfig = dc.field(default_factory=ObserveConfig)
    #: The geometric grasp candidate source (used unless another source is
    #: given), with its rough-surface first-contact level on: where a view
    #: leaves no candidate at the stricter levels (a bag of marbles, whose
    #: extremes are single bumps), first contacts within 1 cm of the extremes,
    #: at a quarter score (`AntipodalGraspConfig.rough_contact_band`).
    grasps: AntipodalGraspConfig = dc.field(default_factory=lambda: AntipodalGraspConfig(rough_contact_band=0.01))
    #: Which source ranks the grasps: the geometric one, or its candidates
    #: re-ranked by the learned grasp-quality model (`vamg_drake.policy.learned_grasps`).
    grasp_source: GraspSourceConfig = dc.field(default_factory=GraspSourceConfig)
    #: Distance field resolution of the collision environment [m].
    collision_resolution: float = 0.03
    #: Map points within this horizontal distance of the target (or the robot) are obstacles [m].
    collision_crop: float = 2.2
    #: Map points above this height cannot touch the robot [m].
    collision_max_height: float = 2.0
    #: The gripper ignores map points this close to the target [m].
    target_clearance: float = 0.10
    #: Map points around the target given to the grasp candidate source [m].
    grasp_cloud_radius: float = 0.30
    #: A map point with a dense-cloud point this close is left out of the grasp cloud [m].
    dense_cover_radius: float = 0.04
    #: Shape completion of the dense cloud: a head camera sees one side of the
    #: object, and an antipodal grasp needs both. The target's own points are
    #: mirrored about the vertical axis through the target point (exact for the
    #: round and box-like objects when that point is the object's centre; the
    #: role a learned grasp network's shape prior plays in the paper). Grasps
    #: are proposed on the completed cloud first and, when it yields none (an
    #: object seen from above, or one that is not symmetric, such as a curved
    #: banana), on the observed cloud alone.
    mirror: MirrorCompletionConfig = dc.field(default_factory=MirrorCompletionConfig)
    #: With a dense target cloud, the pre-grasp sampler's end-effector poses are
    #: the grasp candidates' pre-grasp poses (else the sphere around the target).
    pregrasp_from_grasps: bool = True
    #: The grasp stage tries the grasp its last pre-grasp was accepted for first
    #: when the base is within this distance of that pre-grasp's [m].
    aimed_grasp_tolerance: float = 0.15
    #: ... and when the current candidates (from the denser cloud seen on
    #: arrival) still hold one within this SE(3) distance of it (`pose_distance`,
    #: metres + 0.1 per radian); that candidate is tried (a grasp chosen from
    #: the far, sparse view can close the fingertips on a cube's top edge).
    #: Otherwise the aimed grasp itself is tried if the grasp source re-checks it
    #: on the close view and it still passes (`AntipodalGraspSampler.verify`).
    aimed_grasp_match: float = 0.03
    #: With the candidates' pre-grasp poses as end-effector poses (a dense
    #: target cloud), a pre-grasp sample accepts first the grasp whose
    #: pre-grasp pose its arm was drawn at; when another grasp is accepted, the
    #: proposal puts the arm at that grasp's pre-grasp pose instead (same base
    #: and torso; if the target stays visible from there). Either way the
    #: grasp-move starts where it ends. Otherwise the arm reconfigured next to
    #: the target and, starting with the gripper around it, could sweep the
    #: object over (a metre or more of gripper travel to a goal a few cm away).
    pregrasp_at_aimed_grasp: bool = True
    #: A grasp that closed on nothing (`PolicyInputs.failed_grasps`) rules out
    #: the candidates within this distance of it [m] whose approach axes lie
    #: within ``failed_grasp_angle`` [deg] of its (any roll: a ball squeezed
    #: out of the fingertips is squeezed out at every roll).
    failed_grasp_radius: float = 0.02
    failed_grasp_angle: float = 30.0
    #: Enclosure test: rays from the target, blocked by a point within
    #: ``enclosure_ray_radius`` of the ray between ``enclosure_min_distance``
    #: (beyond the target object's own surface) and ``enclosure_range``.
    enclosure_min_distance: float = 0.08
    enclosure_range: float = 0.8
    enclosure_ray_radius: float = 0.03
    #: The target is "inside furniture" when at least this fraction of the 26 rays is blocked.
    enclosure_fraction: float = 0.95

    def validate(self) -> None:
        """Raises ValueError naming the bad field of a nested sampler config
        (``grasp_source`` is checked by `GraspSourceConfig.validate`, which names its own path)."""
        self.ranking.validate()
        self.pregrasp.validate()
        self.observe.validate()
        self.grasps.validate()


@dc.dataclass(frozen=True)
class PipelineMemory:
    """The `SubgoalPipeline`'s memory between samples (`SamplerMemory`): its
    and its IK's random generator states, the grasp its last pre-grasp was
    aimed at, its collision check of the last map (reused while the map
    and the base stay the same), the base (x, y) of its last pre-grasp goal
    and the pre-grasp bases reached without a grasp."""

    rng: dict
    ik_rng: dict
    aimed_grasp: tuple | None
    collision_key: tuple | None
    collision_fns: tuple | None
    last_pregrasp_base: tuple | None = None
    tried_bases: tuple = ()


class SubgoalPipeline:
    """Grasp / pre-grasp / observe samplers over the real components.

    Args:
        maps: the kinematic maps.
        camera: the head camera (``WorldConfig.camera``) whose view the
            visibility checks model.
        max_depth: the depth range of the visibility checks [m]: the range
            within which the map integrates the camera's points (the map's
            `DepthToPointsConfig.depth_max`, see `TargetVisibility`).
        grasp_source: the grasp candidates (default: ``config.grasp_source``).
        config: the samplers' parameters.
        seed: seed of the samplers' random generator.
        timings: optional `vamg_drake.systems.timing.ModuleTimings`.
        collision: the goals' collision check parameters (the sphere padding):
            the planner's (`PlannerConfig.checker_config`), so that a goal the
            samplers call free is free for the planner too; default: those of
            the default `PlannerConfig`.
    """

    def __init__(
        self,
        maps: KinematicMaps,
        camera: HeadCameraConfig,
        max_depth: float,
        grasp_source: GraspCandidateSource | None = None,
        config: SubgoalPipelineConfig | None = None,
        seed: int = 0,
        timings=None,
        collision: CollisionCheckerConfig | None = None,
        lift_height: float = 0.0,
    ) -> None:
        self.config = config or SubgoalPipelineConfig()
        #: How far the behaviour lifts a closed grasp [m] (`BehaviourConfig.lift_height`): grasps whose lift hits the map are not chosen.
        self.lift_height = float(lift_height)
        self.collision = collision or PlannerConfig().checker_config()
        #: Optional `vamg_drake.systems.timing.ModuleTimings` (grasp candidates, samplers).
        self.timings = timings
        self.maps = maps
        self.grasp_source = grasp_source or make_grasp_source(self.config.grasp_source, self.config.grasps)
        self.ik = FastIk()
        self.visibility = TargetVisibility(camera, max_depth)
        self.pregrasp = PregraspSampler(maps, self.ik, self.visibility, self.config.pregrasp)
        self.observe = ObserveSampler(self.visibility, self.config.observe)
        self.spheres = SphereModel.load()
        self.rng = np.random.default_rng(seed)
        self._candidates: tuple | None = None  # (inputs, GraspCandidates) of the last proposal
        self._aimed_grasp: tuple | None = None  # (q_pregrasp, X_WG) the last pre-grasp was accepted for
        self._cache_key: tuple | None = None
        self._cache: tuple | None = None
        self._last_pregrasp_base: tuple | None = None  # (x, y) of the last pre-grasp goal
        self._tried_bases: tuple = ()  # (x, y) of pre-grasp goals reached without a grasp

    def samplers(self) -> SubgoalSamplers:
        return SubgoalSamplers(self._timed("subgoal_grasp", self.sample_grasp),
                               self._timed("subgoal_pregrasp", self.sample_pregrasp),
                               self._timed("subgoal_observe", self.sample_observe), memory=(self,))

    def save_state(self) -> "PipelineMemory":
        """`SamplerMemory`: what the samplers' next answers depend on besides their inputs."""
        return PipelineMemory(self.rng.bit_generator.state, self.ik.rng.bit_generator.state, self._aimed_grasp,
                              self._cache_key, self._cache, self._last_pregrasp_base, self._tried_bases)

    def load_state(self, state: "PipelineMemory") -> None:
        """`SamplerMemory`: restores a `save_state`."""
        self.rng.bit_generator.state = state.rng
        self.ik.rng.bit_generator.state = state.ik_rng
        self._aimed_grasp, self._cache_key, self._cache = state.aimed_grasp, state.collision_key, state.collision_fns
        self._last_pregrasp_base, self._tried_bases = state.last_pregrasp_base, state.tried_bases
        self._candidates = None

    def _timed(self, name: str, sampler):
        def timed(inputs: PolicyInputs) -> SubgoalProposal:
            t0 = time.perf_counter()
            try:
                return sampler(inputs)
            finally:
                if self.timings is not None:
                    self.timings.add(name, 1e3 * (time.perf_counter() - t0))
        return timed

    # -- shared pieces ------------------------------------------------------

    def target_problem(self, p_WM: np.ndarray, p_WT: np.ndarray) -> str:
        """A reason when the target is unusable (non-finite, enclosed by the map), else ''."""
        p_WT = np.asarray(p_WT, dtype=float).reshape(-1)
        if p_WT.shape != (3,) or not np.all(np.isfinite(p_WT)):
            return f"target must be a finite 3-vector, got {p_WT}"
        cfg = self.config
        dist = np.linalg.norm(p_WM - p_WT, axis=1)
        near = p_WM[(dist <= cfg.enclosure_range) & (dist >= cfg.enclosure_min_distance)]
        if near.shape[0] < 26:
            return ""
        d = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(-1, 3)
        d = d[np.any(d != 0, axis=1)].astype(float)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        rel = near - p_WT
        t = rel @ d.T  # (N, 26)
        perp = np.linalg.norm(rel[:, None, :] - t[..., None] * d[None], axis=2)
        blocked = np.any((t > 0.0) & (perp <= cfg.enclosure_ray_radius), axis=0)
        if blocked.mean() >= cfg.enclosure_fraction:
            return (f"target {np.round(p_WT, 3).tolist()} is enclosed by map points on {int(blocked.sum())}/26 "
                    f"sides within {cfg.enclosure_range} m (inside furniture?)")
        return ""

    def collision_fn(self, p_WM: np.ndarray, p_WT: np.ndarray, q: np.ndarray, grasp: bool = False):
        """Batched ``is_free`` for configurations near the target under map points p_WM.

        One distance field holds the map points near the target and the robot;
        those within ``target_clearance`` of the target may touch the gripper's
        spheres only (`CollisionEnvironment.grasp_target`), and with `grasp`
        those of its support surface too.
        """
        cfg = self.config
        key = (p_WM.shape[0], float(p_WM.sum()) if p_WM.size else 0.0, tuple(np.round(p_WT, 4)),
               tuple(np.round(np.asarray(q)[:2], 1)))
        if self._cache_key == key:
            return self._cache[int(grasp)]
        centers = np.stack([p_WT[:2], np.asarray(q, float)[:2]])
        dxy = np.min(np.linalg.norm(p_WM[:, None, :2] - centers[None], axis=2), axis=1) if p_WM.size else np.zeros(0)
        local = p_WM[(dxy <= cfg.collision_crop) & (p_WM[:, 2] <= cfg.collision_max_height)] if p_WM.size else p_WM
        if local.shape[0] == 0:
            local = np.array([[1e3, 1e3, 1e3]])  # nothing observed: one far point
        env = CollisionEnvironment.from_points(local, cfg.collision_resolution, grasp_target=p_WT,
                                               grasp_target_radius=cfg.target_clearance)
        checker = SphereCollisionChecker.for_fetch(env, self.collision)
        grasp_free = checker.with_environment(dc.replace(env, grasp_target_floor=-np.inf)).is_free
        self._cache_key, self._cache = key, (checker.is_free, grasp_free)
        return self._cache[int(grasp)]

    @staticmethod
    def _points(inputs: PolicyInputs) -> np.ndarray:
        p = np.asarray(inputs.p_WM, dtype=float).reshape(-1, 3)
        return p[np.all(np.isfinite(p), axis=1)]

    # -- the samplers ----------------------------------------------------------

    def sample_grasp(self, inputs: PolicyInputs) -> SubgoalProposal:
        """Grasp goal with the base and torso fixed (paper Algorithm 1)."""
        p_WM, q = self._points(inputs), np.asarray(inputs.q, float)
        p_WT = np.asarray(inputs.p_WT, float)
        problem = self.target_problem(p_WM, p_WT)
        if problem:
            return SubgoalProposal.failure(problem, FailureCategory.PERCEPTION)
        candidates = self._grasp_candidates(inputs, p_WM, p_WT)
        failed = inputs.failed_grasps
        if failed is not None and len(candidates):
            untried = ~self._near_failed(candidates.X_WG, failed)
            if not np.any(untried):
                return SubgoalProposal.failure(
                    f"every grasp candidate is one that closed on nothing ({len(failed)} tried)",
                    FailureCategory.SUBGOAL)
            candidates = candidates.subset(np.flatnonzero(untried))
        if len(candidates) == 0:
            return SubgoalProposal.failure(f"no grasp candidates: {candidates.failure_reason}", FailureCategory.PERCEPTION)
        # The grasp the last pre-grasp was accepted for comes first (IK and
        # collision re-checked; the capability map already had its say).
        goal, aimed = None, self._aimed_grasp
        if aimed is not None and failed is not None and self._near_failed(aimed[1][None], failed)[0]:
            aimed = None
        if aimed is not None and np.linalg.norm(aimed[0][:2] - q[:2]) <= self.config.aimed_grasp_tolerance:
            q_aimed, X_aimed, width_aimed = aimed
            match = self._matching_pose(candidates.X_WG, X_aimed)
            if match is not None:
                goal = self._grasp_goal(candidates.subset([match]), q, p_WM, p_WT, capability=False)
            elif self._still_valid(inputs, p_WM, p_WT, X_aimed, width_aimed):
                kept = GraspCandidates(X_aimed[None], np.ones(1), np.array([width_aimed]))
                goal = self._grasp_goal(kept, q, p_WM, p_WT, capability=False)
        if goal is None or not goal.success:
            goal = self._grasp_goal(candidates, q, p_WM, p_WT)
        if not goal.success:
            category = FailureCategory.SUBGOAL if "collision" in goal.failure_reason else FailureCategory.REACHABILITY
            return SubgoalProposal.failure(goal.failure_reason, category)
        _, head = self.visibility.check(goal.q_pregrasp[None], p_WT)
        return SubgoalProposal(True, goal.q_pregrasp, goal.q_grasp, head[0], lift_height=goal.lift_height,
                               q_pull=goal.q_pull)

    def _near_failed(self, X_WG: np.ndarray, failed: np.ndarray) -> np.ndarray:
        """(K,) True for the grasps X_WG (K, 4, 4) that repeat a failed one (`failed_grasp_radius`)."""
        return near_any_grasp(X_WG, failed, self.config.failed_grasp_radius, np.radians(self.config.failed_grasp_angle))

    def _matching_pose(self, X_WP: np.ndarray, X_WQ: np.ndarray) -> int | None:
        """The index of the pose in X_WP (K, 4, 4) nearest to X_WQ (`pose_distance`),
        if it lies within `aimed_grasp_match`; else None."""
        d = pose_distance(X_WP, X_WQ[None], self.config.ranking.rotation_weight)
        nearest = int(np.argmin(d))
        return nearest if d[nearest] <= self.config.aimed_grasp_match else None

    def _still_valid(self, inputs: PolicyInputs, p_WM: np.ndarray, p_WT: np.ndarray, X_WG: np.ndarray,
                     width: float) -> bool:
        """Whether the grasp source, where it can re-check a grasp (`verify`),
        finds grasp X_WG still clear with valid first contacts on this tick's cloud."""
        verify = getattr(self.grasp_source, "verify", None)
        if verify is None:
            return False
        return bool(verify(self._grasp_cloud(inputs, p_WM, p_WT), p_WT, X_WG[None], np.array([width]))[0])

    def _grasp_goal(self, candidates: GraspCandidates, q: np.ndarray, p_WM: np.ndarray, p_WT: np.ndarray,
                    capability: bool = True, is_free=None, grasp_is_free=None):
        """The paper's grasp goal sampling from configuration q (base and torso
        fixed); `is_free` and `grasp_is_free` default to `collision_fn` around q."""
        X_WB = base_poses(q)[0]
        p_WE = FetchKinematics.instance().gripper_pose(q)[:3, 3]
        return select_grasp_goal(
            candidates, q, X_WB, p_WE, self.ik.solve_arm, is_free or self.collision_fn(p_WM, p_WT, q),
            self.maps.capability.is_reachable if capability else None, self.config.ranking,
            grasp_is_free or self.collision_fn(p_WM, p_WT, q, grasp=True), self.lift_height, rng=self.ik.rng,
        )

    def _grasp_candidates(self, inputs: PolicyInputs, p_WM: np.ndarray, p_WT: np.ndarray):
        """The grasp candidates for these inputs, proposed once per tick: the
        grasp and pre-grasp stages of one tree tick share the same inputs."""
        if self._candidates is not None and self._candidates[0] is inputs:
            return self._candidates[1]
        t0 = time.perf_counter()
        candidates = self.grasp_source.propose(self._grasp_cloud(inputs, p_WM, p_WT, completed=True), p_WT, self.rng)
        if len(candidates) == 0 and self.config.mirror.enabled:
            observed = self.grasp_source.propose(self._grasp_cloud(inputs, p_WM, p_WT), p_WT, self.rng)
            if len(observed):
                candidates = observed
        if self.timings is not None:
            self.timings.add("grasp_candidates", 1e3 * (time.perf_counter() - t0))
        self._candidates = (inputs, candidates)
        return candidates

    def _grasp_cloud(self, inputs: PolicyInputs, p_WM: np.ndarray, p_WT: np.ndarray,
                     completed: bool = False) -> np.ndarray:
        """The cloud around the target for grasp candidates: the dense cloud where
        it has points (with the mirrored completion when `completed` and
        ``mirror.enabled``), the map's points elsewhere."""
        cloud = p_WM[np.linalg.norm(p_WM - p_WT, axis=1) <= self.config.grasp_cloud_radius]
        if inputs.p_WS is not None and len(inputs.p_WS):
            # The dense cloud replaces the coarse map voxels where it has points:
            # voxel centres lie up to half a voxel off the surface and would
            # block every finger placement on small objects.
            dense = np.asarray(inputs.p_WS, dtype=float).reshape(-1, 3)
            dense = dense[np.linalg.norm(dense - p_WT, axis=1) <= self.config.grasp_cloud_radius]
            if len(dense) and completed and self.config.mirror.enabled:
                dense = np.concatenate([dense, mirrored_object_points(dense, p_WT, self.config.mirror)])
            if len(dense):
                d, _ = cKDTree(dense).query(cloud, distance_upper_bound=self.config.dense_cover_radius)
                cloud = np.concatenate([dense, cloud[~np.isfinite(d)]])
        return cloud

    def sample_pregrasp(self, inputs: PolicyInputs) -> SubgoalProposal:
        """Whole-body pre-grasp configuration (paper Algorithm 3)."""
        p_WM, q = self._points(inputs), np.asarray(inputs.q, float)
        p_WT = np.asarray(inputs.p_WT, float)
        problem = self.target_problem(p_WM, p_WT)
        if problem:
            return SubgoalProposal.failure(problem, FailureCategory.PERCEPTION)
        costmap = BaseCostmap.from_points(p_WM, self.config.pregrasp.costmap,
                                          include_xy=np.stack([p_WT[:2], q[:2]]), robot_xy=q[:2])
        last = self._last_pregrasp_base
        if last is not None and np.linalg.norm(q[:2] - last) <= self.config.pregrasp.reached_tolerance:
            # Asked again from the last pre-grasp goal: the grasp stage found
            # no grasp there, so bases near it (the same views) come last.
            self._tried_bases = self._tried_bases + (last,)
            self._last_pregrasp_base = None  # recorded once
        ee_poses, accept = None, None
        aimed_pregrasp = None  # (accepted sample, its grasp's pre-grasp configuration, its head pan/tilt)
        is_free = self.collision_fn(p_WM, p_WT, q)  # its crop covers the target's surroundings
        grasp_is_free = self.collision_fn(p_WM, p_WT, q, grasp=True)
        if self.config.pregrasp_from_grasps:
            # With grasp candidates, aim p_ee at their pre-grasp poses (once the
            # target is seen densely) and accept a pre-grasp only if the grasp
            # stage finds a grasp from it; that grasp is tried first there.
            candidates = self._grasp_candidates(inputs, p_WM, p_WT)
            if len(candidates):
                if inputs.p_WS is not None and len(inputs.p_WS):
                    ee_poses = pregrasp_poses(candidates.X_WG, self.config.ranking.pregrasp_offset)

                def accept(q_pre: np.ndarray) -> bool:
                    nonlocal aimed_pregrasp
                    at_own_grasp = ee_poses is not None and self.config.pregrasp_at_aimed_grasp
                    # The grasp whose pre-grasp pose the arm was sampled at comes first.
                    own = self._matching_pose(ee_poses, FetchKinematics.instance().gripper_pose(q_pre)) \
                        if at_own_grasp else None
                    goal = None
                    if own is not None:
                        goal = self._grasp_goal(candidates.subset([own]), q_pre, p_WM, p_WT, capability=False,
                                                is_free=is_free, grasp_is_free=grasp_is_free)
                    if goal is None or not goal.success:
                        goal = self._grasp_goal(candidates, q_pre, p_WM, p_WT, is_free=is_free,
                                                grasp_is_free=grasp_is_free)
                    if not goal.success:
                        return False
                    if at_own_grasp:
                        # The arm goes to the grasp's own pre-grasp, which must see the target too.
                        visible, head = self.visibility.check(goal.q_pregrasp[None], p_WT)
                        if not visible[0]:
                            return False
                        aimed_pregrasp = (q_pre, goal.q_pregrasp, head[0])
                    self._aimed_grasp = (q_pre, goal.X_WG, float(candidates.width[goal.candidate_index]))
                    return True

        result = self.pregrasp.sample(p_WM, p_WT, q, is_free, self.rng, costmap=costmap,
                                      ee_poses=ee_poses, accept=accept,
                                      tried_xy=self._tried_xy(inputs))
        if not result.success:
            category = FailureCategory.REACHABILITY if result.funnel["ik"] == 0 else FailureCategory.SUBGOAL
            return SubgoalProposal.failure(result.failure_reason, category)
        self._last_pregrasp_base = (float(result.q[0]), float(result.q[1]))
        if aimed_pregrasp is not None:
            sample, q_aimed, head = aimed_pregrasp
            if np.allclose(sample, result.q):
                return SubgoalProposal(True, q_aimed, head=head)
        return SubgoalProposal(True, result.q, head=result.head)

    def _tried_xy(self, inputs: PolicyInputs) -> np.ndarray:
        """(K, 2) the bases the pre-grasp sampler tries last: those of pre-grasp
        goals reached without a grasp, and those whose motion failed
        (`PolicyInputs.failed_bases`: a base in a pocket the base planner
        cannot enter, or behind furniture, would be drawn again nearest
        first)."""
        tried = np.array(self._tried_bases, dtype=float).reshape(-1, 2)
        if inputs.failed_bases is not None and len(inputs.failed_bases):
            tried = np.concatenate([tried, np.asarray(inputs.failed_bases, dtype=float).reshape(-1, 2)])
        return tried

    def sample_observe(self, inputs: PolicyInputs) -> SubgoalProposal:
        """A base pose at a standoff that sees the target, arm stowed."""
        p_WM, q = self._points(inputs), np.asarray(inputs.q, float)
        p_WT = np.asarray(inputs.p_WT, float)
        problem = self.target_problem(p_WM, p_WT)
        if problem:
            return SubgoalProposal.failure(problem, FailureCategory.PERCEPTION)
        result = self.observe.sample(p_WM, p_WT, q, self.collision_fn(p_WM, p_WT, q), self.rng)
        if not result.success:
            return SubgoalProposal.failure(result.failure_reason, FailureCategory.SUBGOAL)
        return SubgoalProposal(True, result.q, head=result.head)
