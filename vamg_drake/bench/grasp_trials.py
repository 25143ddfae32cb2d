"""Grasp trials: labelled grasp candidates from our own physics, for the learned scorer.

One *trial* is one scene: a YCB object dropped in a random pose onto a box
support (the drop check), seen by the head camera from one or more plausible
base poses (a rendered depth image per view, back-projected as the robot's
perception does), optionally completed by the mirror as the subgoal pipeline
does, given to the geometric grasp source, and a subset of its candidates
(with a few near misses its first-contact test rejects) executed with the
oracle's free gripper in Drake (approach, close, lift, hold:
`vamg_drake.bench.oracle_grasp.simulate_grasp`). Each executed
candidate is recorded with its cloud crop in the grasp frame, pose, width,
geometric score and outcome.

Objects are split into training and held-out sets by object (never by
trial), so the held-out metrics measure generalisation to unseen shapes.

Data layout under the output directory: ``trial_<index>.npz`` per trial
(written atomically, so an interrupted run resumes by skipping the files
present) and ``manifest.json`` (configuration, seed, object split, the
trials present and their sample counts), rewritten at the end of a run.
"""

import dataclasses as dc
import hashlib
import json
import math
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from pydrake.geometry import Box, Mesh
from pydrake.math import RigidTransform, RollPitchYaw
from tqdm import tqdm

from vamg_drake.bench.oracle_grasp import GraspCandidate, OracleGraspConfig, check_graspable_at, simulate_grasp
from vamg_drake.perception.depth_points import DepthBackProjector, DepthToPointsConfig
from vamg_drake.perception.point_clusters import MirrorCompletionConfig, mirrored_object_points
from vamg_drake.perception.shape_depth_render import ShapeDepthRenderer, look_at
from vamg_drake.policy.grasp_candidates import AntipodalGraspConfig, AntipodalGraspSampler, GripperGeometry
from vamg_drake.policy.grasp_ranking import near_any_grasp
from vamg_drake.policy.learned_grasps import GraspCropConfig, grasp_frame_crops
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.world.drop_check import DropCheckConfig, drop_object
from vamg_drake.world.primitives import WorldBox
from vamg_drake.world.ycb import YCB_OBJECTS, load_ycb_asset

#: Objects kept out of training (every fifth of the paper's list, so each
#: family -- cans, fruit, balls, cups, Lego, tools -- is represented on both sides).
DEFAULT_HELDOUT: tuple[str, ...] = tuple(list(YCB_OBJECTS)[2::5])

#: A first-contact-rejected candidate within this distance [m] and approach
#: angle [rad] of one of the source's is the same grasp, not a near miss.
REJECTED_RADIUS = 0.01
REJECTED_ANGLE = math.radians(15.0)

#: Bump when the trial format or the labelling changes.
TRIAL_FORMAT_VERSION = 4


def fetch_oracle_config() -> OracleGraspConfig:
    """The oracle gripper sized as the Fetch gripper the policy plans for
    (`GripperGeometry`: 6 cm pads, 1.4 cm thick, 2.6 cm wide, 10 cm opening)."""
    g = GripperGeometry()
    return OracleGraspConfig(finger_length=g.finger_length, finger_thickness=g.finger_thickness,
                             finger_width=g.finger_width, max_opening=g.max_opening, hold_time=0.5)


@dc.dataclass
class GraspTrialConfig:
    """Parameters of the grasp-trial collector.

    Attributes:
        objects: YCB objects drawn from (empty: all 50 of the paper's list).
        heldout: objects of the held-out split (the rest are training objects).
        support_height_range: height of the support's top [m].
        support_size: (x, y, z) of the box support [m].
        placement_radius: the object is dropped within this distance of the support's centre [m].
        camera_distance_range: horizontal camera-to-object distance [m] (a base 0.6-1.3 m away).
        camera_height_range: camera height [m] (Fetch head, torso down to up).
        multi_view_probability: chance of a second view from another base pose.
        mirror_probability: chance the cloud is completed by the mirror.
        camera: head camera resolution.
        candidates_per_trial: candidates executed per trial: the top ``top_k``
            by geometric score, the rest drawn uniformly from the others.
        top_k: see ``candidates_per_trial``.
        rejected_per_trial: further candidates executed per trial, drawn
            uniformly from those of the source with its first-contact test
            off (`without_first_contact_test`: collision-free, pads anywhere
            on the object) that are not near one of its own, so mostly those
            the test rejects: the near misses a ranking
            has to tell from good grasps (fingers on a rim, contacts at the
            fingertips, across an edge). With only the source's candidates
            nearly every grasp holds in the free-gripper physics and the
            labels hold too few failures to learn from.
        rejected_score_scale: their recorded geometric score is the relaxed
            source's times this, below every level the policy's source
            proposes (it never proposes them); their rank follows the source's.
        drop_attempts: placements tried before a trial gives up.
        oracle_check: skip a placement that the benchmark's oracle grasp
            check (`OracleGraspConfig`, as `paper_static` and the procedural
            suites use it) cannot lift: the benchmark leaves such targets
            out, and no ranking can pick a grasp that holds them (the
            assembled toy airplane, whose convex hull the fingers cannot
            close on, or a power drill in most poses).
        depth_noise: std of the Gaussian noise added to each depth pixel [m].
        execution_position_noise: std of the executed grasp's offset from the
            candidate, per axis [m]: the arm does not reach a grasp exactly
            (IK, tracking and base errors), so the label is whether the grasp
            holds near where it was aimed -- without it nearly every
            candidate on an object lifts it in the ideal free-gripper physics
            and the labels say which object, not which grasp.
        execution_rotation_noise: std of the executed grasp's rotation about a random axis [rad].
        executions: times each candidate is executed, each with its own
            execution noise. ``success`` is the first execution's outcome
            (the same as with one execution: the others draw their noise from
            their own stream) and ``hold_fraction`` the share of executions
            that held: one execution is one draw of the aimed grasp's chance
            to hold, and several estimate it (`label_consistency` measures
            how noisy single draws are).
        crop: the grasp-frame crop recorded per candidate.
        grasps: the geometric grasp source, with the first-contact test
            leaving out points that face the approach (more candidates on
            single views, whose failures the learned scorer learns from).
        mirror: the mirror completion.
    """

    objects: list[str] = dc.field(default_factory=list)
    heldout: list[str] = dc.field(default_factory=lambda: list(DEFAULT_HELDOUT))
    support_height_range: list[float] = dc.field(default_factory=lambda: [0.4, 0.9])
    support_size: list[float] = dc.field(default_factory=lambda: [0.6, 0.5, 0.05])
    placement_radius: float = 0.08
    camera_distance_range: list[float] = dc.field(default_factory=lambda: [0.6, 1.3])
    camera_height_range: list[float] = dc.field(default_factory=lambda: [1.05, 1.45])
    multi_view_probability: float = 0.5
    mirror_probability: float = 0.5
    camera: HeadCameraConfig = dc.field(default_factory=HeadCameraConfig)
    candidates_per_trial: int = 8
    top_k: int = 3
    rejected_per_trial: int = 4
    rejected_score_scale: float = 0.1
    drop_attempts: int = 4
    oracle_check: bool = True
    depth_noise: float = 0.001
    execution_position_noise: float = 0.01
    execution_rotation_noise: float = 0.06
    executions: int = 1
    crop: GraspCropConfig = dc.field(default_factory=GraspCropConfig)
    grasps: AntipodalGraspConfig = dc.field(default_factory=lambda: AntipodalGraspConfig(facing_approach_cos=0.866))
    mirror: MirrorCompletionConfig = dc.field(default_factory=MirrorCompletionConfig)

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if self.candidates_per_trial < 1 or not 0 <= self.top_k <= self.candidates_per_trial:
            raise ValueError(f"GraspTrialConfig: need candidates_per_trial >= 1 and 0 <= top_k <= it, "
                             f"got {self.candidates_per_trial}, {self.top_k}")
        if self.executions < 1:
            raise ValueError(f"GraspTrialConfig: need executions >= 1, got {self.executions}")
        if self.rejected_per_trial < 0 or not 0.0 < self.rejected_score_scale <= 1.0:
            raise ValueError(f"GraspTrialConfig: need rejected_per_trial >= 0 and rejected_score_scale in (0, 1], "
                             f"got {self.rejected_per_trial}, {self.rejected_score_scale}")

    def object_names(self) -> list[str]:
        names = list(self.objects) or list(YCB_OBJECTS)
        unknown = [n for n in [*names, *self.heldout] if n not in YCB_OBJECTS]
        if unknown:
            raise ValueError(f"GraspTrialConfig: unknown YCB objects {unknown}")
        return names


@dc.dataclass
class TrialResult:
    """One trial's samples (K executed candidates) and what the scene was."""

    index: int
    object_name: str
    heldout: bool
    views: int
    mirrored: bool
    num_candidates: int
    reason: str
    crops: np.ndarray  # (K, N, 3) float32 grasp-frame points
    crop_counts: np.ndarray  # (K,) points in the crop before resampling
    X_WG: np.ndarray  # (K, 4, 4)
    width: np.ndarray  # (K,)
    score: np.ndarray  # (K,) geometric score
    rank: np.ndarray  # (K,) rank among the geometric candidates (0: best)
    success: np.ndarray  # (K,) bool
    lift: np.ndarray  # (K,)
    rejected: np.ndarray  # (K,) bool: rejected by the source's first-contact test
    hold_fraction: np.ndarray  # (K,) share of the candidate's executions that held

    def save(self, path: Path) -> None:
        arrays = {k: v for k, v in dc.asdict(self).items() if isinstance(v, np.ndarray)}
        meta = {k: v for k, v in dc.asdict(self).items() if not isinstance(v, np.ndarray)}
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, path)

    @staticmethod
    def load(path: Path) -> "TrialResult":
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {k: data[k] for k in data.files if k != "meta"}
        if "hold_fraction" not in arrays and "success" in arrays:  # format 3: one execution per candidate
            arrays["hold_fraction"] = arrays["success"].astype(float)
        missing = sorted({f.name for f in dc.fields(TrialResult)} - set(meta) - set(arrays))
        if missing:
            raise ValueError(f"{path}: no {', '.join(missing)} (a trial file of an older format than "
                             f"{TRIAL_FORMAT_VERSION}; collect the trials again)")
        return TrialResult(**meta, **arrays)


def without_first_contact_test(config: AntipodalGraspConfig) -> AntipodalGraspConfig:
    """`config` with the pads' first-contact test made vacuous (every normal
    in the friction cone, contacts anywhere along the pads and across them):
    its candidates need only clear the cloud and the support."""
    return dc.replace(config, contact_friction_coefficient=1e6, min_tip_distance=0.0, min_pad_span=0.0)


def _support_box(height: float, size: list[float]) -> WorldBox:
    half = 0.5 * np.asarray(size, dtype=float)
    return WorldBox("support/top", np.array([0.0, 0.0, height - half[2]]), np.eye(3), half)


def observe(renderer: ShapeDepthRenderer, projector: DepthBackProjector, X_WCs: list[np.ndarray],
            noise: float, rng: np.random.Generator) -> np.ndarray:
    """World points of the depth images seen from camera poses X_WCs (noisy depth)."""
    clouds = []
    for X_WC in X_WCs:
        depth = renderer.render(X_WC)
        if noise > 0:
            finite = np.isfinite(depth) & (depth > 0)
            depth = depth.copy()
            depth[finite] += rng.normal(0.0, noise, np.count_nonzero(finite)).astype(depth.dtype)
        clouds.append(projector.points_W(depth, X_WC))
    return np.concatenate(clouds) if clouds else np.zeros((0, 3))


def perturbed(X_WG: np.ndarray, position_std: float, rotation_std: float, rng: np.random.Generator) -> np.ndarray:
    """X_WG moved by Gaussian noise: an offset (per axis) and a rotation about a random axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.normal(0.0, rotation_std)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    X = X_WG.copy()
    X[:3, :3] = R @ X_WG[:3, :3]
    X[:3, 3] = X_WG[:3, 3] + rng.normal(0.0, position_std, 3)
    return X


def oracle_candidate(X_WG: np.ndarray, width: float, gripper: GripperGeometry) -> GraspCandidate:
    """The oracle's candidate (origin at the fingertips) of grasp X_WG (origin mid-pads)."""
    p = X_WG[:3, 3] + gripper.fingertip_x * X_WG[:3, 0]
    return GraspCandidate("policy", p, X_WG[:3, :3].copy(), float(width))


def run_trial(index: int, seed: int, config: GraspTrialConfig, oracle: OracleGraspConfig | None = None) -> TrialResult:
    """Trial ``index`` of run ``seed`` (depends only on the arguments)."""
    oracle = oracle or fetch_oracle_config()
    rng = np.random.default_rng([seed, index])
    names = config.object_names()
    name = names[int(rng.integers(len(names)))]
    heldout = name in config.heldout
    height = float(rng.uniform(*config.support_height_range))
    support = _support_box(height, config.support_size)

    def empty(reason: str, views: int = 0, mirrored: bool = False, num: int = 0) -> TrialResult:
        n = config.crop.num_points
        return TrialResult(index, name, heldout, views, mirrored, num, reason, np.zeros((0, n, 3), np.float32),
                           np.zeros(0, int), np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0), np.zeros(0, int),
                           np.zeros(0, bool), np.zeros(0), np.zeros(0, bool), np.zeros(0))

    drop = None
    for _ in range(config.drop_attempts):
        r = config.placement_radius * math.sqrt(rng.uniform())
        phi = rng.uniform(0, 2 * math.pi)
        drop = drop_object(name, support, height, np.array([r * math.cos(phi), r * math.sin(phi)]),
                           float(rng.uniform(-math.pi, math.pi)), config=DropCheckConfig())
        if drop.accepted:
            break
    if drop is None or not drop.accepted:
        return empty(f"no stable placement: {drop.reason if drop else ''}")
    X_WO = RigidTransform(RollPitchYaw(drop.rpy), drop.xyz)
    if config.oracle_check:
        verdict = check_graspable_at(name, X_WO, support, height, OracleGraspConfig())
        if not verdict.graspable:
            return empty(f"oracle grasp check: {verdict.reason}")
    asset = load_ycb_asset(name)

    intrinsics = CameraIntrinsics.from_config(config.camera)
    renderer = ShapeDepthRenderer(intrinsics, [
        (Mesh(str(asset.visual_path)), X_WO),
        (Box(*(2 * support.half_extents)), RigidTransform(support.p_WB)),
    ])
    projector = DepthBackProjector(intrinsics, DepthToPointsConfig())
    p_WT = np.asarray(drop.xyz, dtype=float)
    views = 2 if rng.uniform() < config.multi_view_probability else 1
    azimuth = rng.uniform(-math.pi, math.pi)
    X_WCs = []
    for v in range(views):
        a = azimuth + (0.0 if v == 0 else rng.choice([-1, 1]) * rng.uniform(math.radians(30), math.radians(90)))
        d = rng.uniform(*config.camera_distance_range)
        p_WC = p_WT + np.array([d * math.cos(a), d * math.sin(a), 0.0])
        p_WC[2] = rng.uniform(*config.camera_height_range)
        X_WCs.append(look_at(p_WC, p_WT + rng.normal(0.0, 0.03, 3)))
    cloud = observe(renderer, projector, X_WCs, config.depth_noise, rng)
    cloud = cloud[np.linalg.norm(cloud - p_WT, axis=1) <= 0.30]
    mirrored = bool(rng.uniform() < config.mirror_probability)
    if mirrored and len(cloud):
        cloud = np.concatenate([cloud, mirrored_object_points(cloud, p_WT, config.mirror)])

    sampler = AntipodalGraspSampler(config.grasps)
    candidates = sampler.propose(cloud, p_WT, rng)
    if len(candidates) == 0:
        return empty(f"no geometric candidate: {candidates.failure_reason}", views, mirrored)
    k = min(config.candidates_per_trial, len(candidates))
    top = np.arange(min(config.top_k, k))
    rest = rng.choice(np.arange(len(top), len(candidates)), size=k - len(top), replace=False)
    chosen = np.concatenate([top, np.sort(rest)]).astype(int)
    X_WG, width = candidates.X_WG[chosen], candidates.width[chosen]
    score, rank = candidates.score[chosen], chosen
    if config.rejected_per_trial > 0:
        # Their own stream: the source's candidates and labels stay those of a run without them.
        relaxed_rng = np.random.default_rng([seed, index, 2])
        relaxed = AntipodalGraspSampler(without_first_contact_test(config.grasps)).propose(cloud, p_WT, relaxed_rng)
        fresh = np.flatnonzero(~near_any_grasp(relaxed.X_WG, candidates.X_WG, REJECTED_RADIUS, REJECTED_ANGLE))
        if fresh.size:
            extra = np.sort(relaxed_rng.choice(fresh, size=min(config.rejected_per_trial, fresh.size), replace=False))
            X_WG = np.concatenate([X_WG, relaxed.X_WG[extra]])
            width = np.concatenate([width, relaxed.width[extra]])
            score = np.concatenate([score, config.rejected_score_scale * relaxed.score[extra]])
            rank = np.concatenate([rank, len(candidates) + extra])
    rejected = np.arange(len(rank)) >= k
    # Its own stream: the labels do not depend on how crops are drawn.
    crops, counts = grasp_frame_crops(cloud, X_WG, config.crop, np.random.default_rng([seed, index, 1]))
    success, lift, holds = np.zeros(len(rank), bool), np.zeros(len(rank)), np.zeros(len(rank))
    # Its own stream: the first executions' noise and labels are those of a run with one execution.
    repeat_rng = np.random.default_rng([seed, index, 3])
    for j in range(len(rank)):
        for e in range(config.executions):
            X_exec = perturbed(X_WG[j], config.execution_position_noise, config.execution_rotation_noise,
                               rng if e == 0 else repeat_rng)
            ok, rise, _ = simulate_grasp(name, X_WO, support,
                                         oracle_candidate(X_exec, width[j], config.grasps.gripper), oracle)
            holds[j] += ok
            if e == 0:
                success[j], lift[j] = ok, rise
    return TrialResult(index, name, heldout, views, mirrored, len(candidates), "", crops.astype(np.float32), counts,
                       X_WG, width, score, rank.astype(int), success, lift, rejected, holds / config.executions)


def _trial_path(out: Path, index: int) -> Path:
    return out / f"trial_{index:05d}.npz"


def _worker(args: tuple) -> tuple[int, int, float]:
    index, seed, config, out = args
    t0 = time.perf_counter()
    result = run_trial(index, seed, config)
    result.save(_trial_path(out, index))
    return index, len(result.success), time.perf_counter() - t0


def collect(out: str | Path, trials: int, seed: int = 0, workers: int = 1, config: GraspTrialConfig | None = None,
            progress: bool = True, time_budget: float | None = None) -> dict:
    """Runs trials 0..trials-1 of run ``seed`` into ``out`` (those already there are
    skipped) and writes the manifest; stops starting new trials after
    ``time_budget`` seconds. Returns the manifest."""
    config = config or GraspTrialConfig()
    config.validate()
    config.object_names()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    manifest_path = out / "manifest.json"
    if manifest_path.exists():
        previous = json.loads(manifest_path.read_text())
        if previous.get("seed") != seed or previous.get("format") != TRIAL_FORMAT_VERSION:
            raise ValueError(f"{manifest_path}: holds run seed={previous.get('seed')} format={previous.get('format')}; "
                             f"cannot resume it with seed={seed} format={TRIAL_FORMAT_VERSION} (use another --out)")
    _write_manifest(out, seed, config, complete=False)
    todo = [i for i in range(trials) if not _trial_path(out, i).exists()]
    t0 = time.perf_counter()
    bar = tqdm(total=len(todo), desc="grasp trials", unit="trial", disable=not progress)
    jobs = [(i, seed, config, out) for i in todo]
    try:
        if workers <= 1:
            for job in jobs:
                if time_budget is not None and time.perf_counter() - t0 >= time_budget:
                    break
                _worker(job)
                bar.update()
        else:
            with multiprocessing.get_context("spawn").Pool(workers) as pool:
                for _ in pool.imap_unordered(_worker, jobs):
                    bar.update()
                    if time_budget is not None and time.perf_counter() - t0 >= time_budget:
                        pool.terminate()
                        break
    finally:
        bar.close()
    return _write_manifest(out, seed, config, complete=True)


def _write_manifest(out: Path, seed: int, config: GraspTrialConfig, complete: bool) -> dict:
    files = sorted(out.glob("trial_*.npz"))
    trials, samples, successes = [], 0, 0
    for f in files:
        r = TrialResult.load(f)
        trials.append({"index": r.index, "object": r.object_name, "heldout": r.heldout, "samples": len(r.success),
                       "successes": int(r.success.sum()), "reason": r.reason})
        samples += len(r.success)
        successes += int(r.success.sum())
    manifest = {
        "format": TRIAL_FORMAT_VERSION, "seed": seed, "complete": complete,
        "objects": config.object_names(), "heldout": list(config.heldout),
        "config": dc.asdict(config), "trials": trials, "num_trials": len(trials),
        "num_samples": samples, "num_successes": successes,
    }
    path = out / "manifest.json"
    fd, tmp = tempfile.mkstemp(dir=out, suffix=".json.tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(manifest, f, indent=1)
    os.replace(tmp, path)
    return manifest


@dc.dataclass
class GraspDataset:
    """Samples of a trial directory, flattened: crops (M, N, 3), grasp poses
    (M, 4, 4), width, score, success (the first execution held), and per
    sample the trial index, the geometric rank, object, split, whether the
    source's first-contact test rejected it and the share of its executions
    that held."""

    crops: np.ndarray
    X_WG: np.ndarray
    width: np.ndarray
    score: np.ndarray
    success: np.ndarray
    trial: np.ndarray
    rank: np.ndarray
    objects: np.ndarray
    heldout: np.ndarray
    rejected: np.ndarray
    hold_fraction: np.ndarray
    digest: str

    def subset(self, mask: np.ndarray) -> "GraspDataset":
        return GraspDataset(self.crops[mask], self.X_WG[mask], self.width[mask], self.score[mask], self.success[mask],
                            self.trial[mask], self.rank[mask], self.objects[mask], self.heldout[mask],
                            self.rejected[mask], self.hold_fraction[mask], self.digest)

    def __len__(self) -> int:
        return int(self.success.shape[0])


def load_dataset(data: str | Path) -> GraspDataset:
    """All samples of the trials under ``data`` (a directory written by `collect`).

    Raises:
        ValueError: no trial files there, or a file that does not load (named).
    """
    data = Path(data)
    files = sorted(data.glob("trial_*.npz"))
    if not files:
        raise ValueError(f"{data}: no trial_*.npz files (run `vamg grasps collect --out {data}` first)")
    parts, digest = [], hashlib.sha256()
    for f in files:
        try:
            r = TrialResult.load(f)
        except Exception as e:  # a truncated or foreign file
            raise ValueError(f"{f}: not a grasp-trial file ({type(e).__name__}: {e})") from None
        digest.update(f.name.encode())
        digest.update(r.crops.tobytes())
        digest.update(r.success.tobytes())
        if np.any(r.hold_fraction != r.success):  # trials of one execution keep their digest
            digest.update(r.hold_fraction.tobytes())
        parts.append(r)
    cat = lambda key: np.concatenate([getattr(r, key) for r in parts])  # noqa: E731
    k = [len(r.success) for r in parts]
    return GraspDataset(
        crops=cat("crops").astype(np.float32), X_WG=cat("X_WG"), width=cat("width"), score=cat("score"), success=cat("success"),
        trial=np.repeat([r.index for r in parts], k), rank=cat("rank"),
        objects=np.repeat([r.object_name for r in parts], k), heldout=np.repeat([r.heldout for r in parts], k),
        rejected=cat("rejected"), hold_fraction=cat("hold_fraction"), digest=digest.hexdigest()[:16],
    )
