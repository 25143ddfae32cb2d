"""Grasp candidates for the Fetch parallel-jaw gripper from an observed point cloud.

The paper generates candidates with Contact-GraspNet, whose weights are not
available here. ``AntipodalGraspSampler`` is a geometric replacement: it
estimates surface normals by local PCA (Open3D), pairs surface points whose normals lie
in each other's friction cone along the line joining them (antipodal contacts
no wider than the gripper's 10 cm opening), spins the approach direction around
the closing axis, and keeps only the gripper poses whose fingers and palm --
including their sweep from the pre-grasp pose 5 cm back and the closing sweep
from fully open -- contain no observed point and stay above the surface the
target stands on (which continues under the object and in its occlusion
shadow, where the cloud has no point).

Both contacts must be observed, above the support surface: a flat patch (a
wall, a table top) has no antipodal pair and yields no grasp. Top-down grasps
are also proposed from the target's cluster itself, across slices of it one
pad width thick, where random antipodal pairs rarely meet on a small, lumpy
or single-view object.

Any other generator (a learned network) plugs in through the
``GraspCandidateSource`` protocol.

Frames: ``W`` world, ``G`` the grasp frame of ``FetchKinematics.gripper_pose``:
origin mid finger pads, +x the approach direction, +y the finger-closing axis,
+z = x cross y.
"""

import dataclasses as dc
import math
from typing import Protocol

import numba
import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from vamg_drake.perception.point_clusters import component_nearest, support_height
from vamg_drake.perception.voxels import first_in_voxel
from vamg_drake.robot.layout import GRIPPER_MAX_OPENING


@dc.dataclass(frozen=True)
class GraspCandidates:
    """A set of 6-DoF grasp poses with scores, or none and the reason why.

    Attributes:
        X_WG: (K, 4, 4) grasp-frame poses in the world.
        score: (K,) confidence in [0, 1], higher is better.
        width: (K,) object width between the contacts [m] (0 when unknown).
        failure_reason: empty when K > 0, else a human-readable reason.
    """

    X_WG: np.ndarray
    score: np.ndarray
    width: np.ndarray
    failure_reason: str = ""

    def __len__(self) -> int:
        return int(self.score.shape[0])

    @staticmethod
    def empty(reason: str) -> "GraspCandidates":
        return GraspCandidates(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0), reason)

    def subset(self, index: np.ndarray) -> "GraspCandidates":
        index = np.asarray(index, dtype=int)
        return GraspCandidates(self.X_WG[index], self.score[index], self.width[index], self.failure_reason)


class GraspCandidateSource(Protocol):
    """Anything that proposes grasps from a world-frame cloud around a target.

    A learned network (Contact-GraspNet and the like) implements this too.
    """

    def propose(
        self,
        p_WS: np.ndarray,
        p_WT: np.ndarray,
        rng: np.random.Generator | None = None,
    ) -> GraspCandidates:
        """Returns grasp candidates whose contacts lie near target ``p_WT``.

        Args:
            p_WS: (N, 3) observed points in the world (may include the support
                surface and clutter: they are used as obstacles).
            p_WT: (3,) the target point.
            rng: random generator (a fixed default when None).
        """
        ...


@dc.dataclass
class GripperGeometry:
    """Boxes of the Fetch parallel-jaw gripper in the grasp frame G [m].

    Defaults follow the collision boxes of `models/fetch/fetch.urdf` (G at the
    middle of the finger pads, pads 6 cm long, palm box 12.2 x 12.6 x 8 cm).
    """

    max_opening: float = GRIPPER_MAX_OPENING
    #: x of the fingertips in G.
    fingertip_x: float = 0.031
    #: Length of the finger pads along x (from the fingertip back to the palm).
    finger_length: float = 0.06
    #: Finger thickness along the closing axis y.
    finger_thickness: float = 0.014
    #: Finger extent along z.
    finger_width: float = 0.026
    #: Palm depth along x behind the fingers.
    palm_depth: float = 0.122
    #: Palm extent along z.
    palm_height: float = 0.08


@dc.dataclass
class AntipodalGraspConfig:
    """Parameters of the geometric antipodal grasp sampler."""

    gripper: GripperGeometry = dc.field(default_factory=GripperGeometry)
    #: Candidates' contact midpoints lie within this distance of the target (paper: 10 cm).
    grasp_radius: float = 0.10
    #: Points within this distance of the target are used as obstacles.
    crop_radius: float = 0.30
    #: Voxel size of the downsampled cloud [m].
    voxel_size: float = 0.004
    #: Neighbours used to estimate each normal.
    normal_neighbours: int = 16
    #: Coulomb friction coefficient; the cone half-angle is atan(mu).
    friction_coefficient: float = 0.4
    #: Perpendicular tolerance of the search for the opposite contact [m].
    line_tolerance: float = 0.004
    #: Thinnest graspable object [m]: a single surface has no thickness.
    min_width: float = 0.004
    #: Clearance between an open finger or the palm and any point other than
    #: the object [m] (the palm's faces too: a palm built flush with a table
    #: top touches it).
    margin: float = 0.004
    #: How far the gripper travels along the approach before the grasp (pre-grasp offset).
    approach_distance: float = 0.05
    #: Contact midpoint positions along x of G tried in turn (0: the middle of
    #: the pads; > 0: the gripper held back so the contacts sit nearer the
    #: fingertips). A candidate whose mid-pad grasp collides is retried at the
    #: next offset: a ball under ~6 cm on a table has no mid-pad grasp (the
    #: fingertips or the 8 cm palm reach below its centre into the table top)
    #: but has top-down grasps 1-2 cm further out (test with a 4.7 cm ball) [m].
    contact_offsets: list[float] = dc.field(default_factory=lambda: [0.0, 0.01, 0.02])
    #: Number of seed contact points.
    num_seeds: int = 250
    #: Approach directions tried around each closing axis.
    num_approaches: int = 12
    #: Fewest points within ``grasp_radius`` of the target to attempt sampling.
    min_points: int = 20
    #: Fewest object points between the fingers.
    min_support: int = 4
    #: Where the closing pads first touch the object: its points within this
    #: distance of its extremes along the closing axis, on each side [m]. Most of
    #: them must have normals in the friction cone of the closing axis, lie
    #: ``min_tip_distance`` inside the fingertips (a third of the object's depth
    #: in the pads if that is less), and reach ``min_pad_span`` of
    #: the pad's half width on both sides of the pads' middle. The contact pair
    #: sampled is not where flat pads touch first: a cube closed diagonally is
    #: touched at its edges near the fingertips and spun out, a cup closed in
    #: front of its widest section is pushed out, and the fingers close on
    #: air after first touching the object at the tips.
    contact_band: float = 0.003
    min_tip_distance: float = 0.01
    #: Friction coefficient of the first-contact test (the simulated fingers'
    #: is 0.8; the pair sampling above uses the stricter ``friction_coefficient``).
    contact_friction_coefficient: float = 0.6
    min_pad_span: float = 0.5
    #: First-contact points whose normals lie within acos(``facing_approach_cos``)
    #: of the approach axis belong to a face seen head-on from the approach
    #: side (a top face, for a top-down grasp); the face the pad touches under
    #: that face's edge was not seen. With a value <= 1 they neither pass nor
    #: fail the first-contact test, and a side with no other first-contact
    #: point is not tested: a single view of a brick shows its top and one
    #: side, so the far side's first contact is never observed. Off (above 1:
    #: every point is tested) for the policy: in closed loop it admitted
    #: grasps whose pads overlap a flat clamp's top centimetre over an unseen
    #: side, which closed on nothing. The grasp trials use 0.866 (30 deg), so
    #: the learned scorer sees such candidates fail.
    facing_approach_cos: float = 2.0
    #: Where no candidate passes the first-contact test, keep those that pass
    #: it without its friction-cone part (the pads' first contacts still lie
    #: inside the fingertips and across the pads' middle, but the observed
    #: normals there are not checked), their scores scaled by
    #: ``unchecked_normals_score_scale``. The PCA normals of the few points at
    #: a small, lumpy or curved object's extremes are the least reliable part
    #: of the test (a banana's flank, a clamp's rim); a grasp tried can fail
    #: and be retried, no grasp ends the step.
    unchecked_normals_fallback: bool = True
    unchecked_normals_score_scale: float = 0.5
    #: Where no candidate passes even without the friction cone, keep those
    #: that pass it with the first contacts taken within ``rough_contact_band``
    #: of the extremes (normals unchecked), their scores scaled by
    #: ``rough_surface_score_scale``. On a lumpy surface, a bag of marbles,
    #: the extreme along the closing axis is the top of one bump: the points
    #: within ``contact_band`` of it are one small curved patch, never across
    #: the pads' middle, although flat pads closing on it rest on several
    #: bumps at once. 0 (the default, as the grasp trials use it): off; 0.01
    #: gives the marbles candidates in most single views, and the policy uses
    #: it (`SubgoalPipelineConfig.grasps`).
    rough_contact_band: float = 0.0
    rough_surface_score_scale: float = 0.25
    #: Most candidates returned (highest scores first).
    max_candidates: int = 400
    #: Top-down grasps proposed from the target's cluster itself, at this many
    #: closing-axis yaws from its major axis (0: none): the straight-down approach, the closing
    #: axis level and through the middle of the cluster's extent along it, the
    #: pads' middle 3 cm under its top or, for a low object, as low as the
    #: fingertips clear the support surface by ``top_down_floor_clearance``
    #: (beyond the 5 mm for sensor noise of `support_height`).
    #: They pass the same clearance and first-contact tests as the antipodal
    #: pairs, whose random seeds and PCA normals rarely pair up on a small or
    #: lumpy object (a Lego brick may get a single pair; marbles, a
    #: racquetball or a plum none, or none reachable).
    top_down_yaws: int = 16
    top_down_floor_clearance: float = 0.0
    #: A cluster longer than the pads are wide (a banana, a screwdriver, a
    #: clamp) is also grasped top-down across slices of it, one pad width
    #: thick, every ``top_down_slice_step`` along it, each slice's own width
    #: and height setting the grasp's (up to ``top_down_max_slices`` per yaw,
    #: middle first) [m].
    top_down_slice_step: float = 0.02
    top_down_max_slices: int = 7
    #: Grasp quality (in [0, 1], as the antipodal alignment) given to top-down grasps.
    top_down_quality: float = 0.8
    #: Each top-down grasp is also proposed tilted about its closing axis by
    #: these angles [deg] (towards the side its closing axis' yaw faces; with
    #: an even ``top_down_yaws`` the opposite yaw tilts the other way), at
    #: quality ``top_down_tilted_quality``. Under a TV screen or a shelf a straight-down
    #: approach puts the wrist and forearm into the overhang, and beside a taller
    #: object the upright wrist meets it; a tilted approach reaches in lower
    #: and from the side (on a stacking cup beside a taller object, under a
    #: table's edge). A long object lying flat gets none that pass: leaning
    #: along it, the palm meets its far end. Empty: straight down only.
    top_down_tilts_deg: list[float] = dc.field(default_factory=lambda: [45.0, 60.0])
    top_down_tilted_quality: float = 0.6
    #: Cluster points: linked to the target's nearest point by steps of at
    #: most this many point spacings, within ``grasp_radius``.
    cluster_link: float = 2.0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if not 0.0 < self.friction_coefficient:
            raise ValueError(f"AntipodalGraspConfig.friction_coefficient must be > 0, got {self.friction_coefficient}")
        if not 0.0 < self.grasp_radius <= self.crop_radius:
            raise ValueError(
                f"AntipodalGraspConfig: need 0 < grasp_radius <= crop_radius, got {self.grasp_radius}, {self.crop_radius}"
            )
        if self.num_seeds < 1 or self.num_approaches < 1:
            raise ValueError("AntipodalGraspConfig.num_seeds and num_approaches must be >= 1")
        if not self.top_down_slice_step > 0.0 or self.top_down_max_slices < 1:
            raise ValueError(f"AntipodalGraspConfig: need top_down_slice_step > 0 and top_down_max_slices >= 1, "
                             f"got {self.top_down_slice_step}, {self.top_down_max_slices}")
        if any(not 0.0 < t < 90.0 for t in self.top_down_tilts_deg):
            raise ValueError(f"AntipodalGraspConfig.top_down_tilts_deg must lie in (0, 90), got {self.top_down_tilts_deg}")
        if not 0.0 <= self.top_down_tilted_quality <= 1.0:
            raise ValueError(f"AntipodalGraspConfig.top_down_tilted_quality must be in [0, 1], "
                             f"got {self.top_down_tilted_quality}")
        if not self.facing_approach_cos > 0.0:
            raise ValueError(f"AntipodalGraspConfig.facing_approach_cos must be > 0 (above 1: no point is left "
                             f"out), got {self.facing_approach_cos}")
        if not 0.0 < self.unchecked_normals_score_scale <= 1.0:
            raise ValueError(f"AntipodalGraspConfig.unchecked_normals_score_scale must be in (0, 1], "
                             f"got {self.unchecked_normals_score_scale}")
        if not 0.0 < self.rough_surface_score_scale <= 1.0 or self.rough_contact_band < 0.0:
            raise ValueError(f"AntipodalGraspConfig: need rough_contact_band >= 0 and rough_surface_score_scale in "
                             f"(0, 1], got {self.rough_contact_band}, {self.rough_surface_score_scale}")
        if not 0.0 <= self.min_pad_span <= 1.0:
            raise ValueError(f"AntipodalGraspConfig.min_pad_span must be in [0, 1], got {self.min_pad_span}")
        if not self.contact_offsets or any(not 0.0 <= o < self.gripper.finger_length / 2 for o in self.contact_offsets):
            raise ValueError(f"AntipodalGraspConfig.contact_offsets must be a non-empty list in "
                             f"[0, {self.gripper.finger_length / 2}), got {self.contact_offsets}")


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Keeps one point per ``voxel``-sized cell (the first in input order)."""
    if points.shape[0] == 0 or voxel <= 0:
        return points
    return points[first_in_voxel(points, voxel)]


def estimate_normals(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Unoriented unit normals and surface variation by PCA of the k nearest neighbours.

    Returns:
        normals (N, 3) and curvature (N,) = smallest eigenvalue / trace.
    """
    k = int(min(k, points.shape[0]))
    _, nbr = cKDTree(points).query(points, k=k)
    local = points[nbr] - points[nbr].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", local, local) / k
    eigval, eigvec = np.linalg.eigh(cov)
    normals = eigvec[:, :, 0]
    curvature = eigval[:, 0] / np.maximum(eigval.sum(axis=1), 1e-12)
    return normals, curvature


def estimate_normals_open3d(points: np.ndarray, k: int) -> np.ndarray:
    """The unoriented unit normals of `estimate_normals` (PCA of the k nearest
    neighbours) computed by Open3D: 3.6x faster on the grasp source's clouds
    with the same normals (median |cos| 1.0; `benchmarks/bench_pointcloud_open3d.py`)."""
    k = int(min(k, points.shape[0]))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=float)))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k))
    return np.asarray(cloud.normals)


def gripper_lowest_z(X_WG: np.ndarray, gripper: GripperGeometry, approach_distance: float) -> np.ndarray:
    """The lowest world height (K,) of the open fingers and the palm at grasps
    X_WG (K, 4, 4), each swept back ``approach_distance`` along its approach
    (the boxes of `_clearance_kernel`, from their corners)."""
    g = gripper
    x_pads = g.fingertip_x - g.finger_length
    hy = 0.5 * g.max_opening + g.finger_thickness
    boxes = ((x_pads - approach_distance, g.fingertip_x, 0.5 * g.finger_width),  # fingers: x_lo, x_hi, z half
             (x_pads - g.palm_depth - approach_distance, x_pads, 0.5 * g.palm_height))  # palm
    r = np.asarray(X_WG, dtype=float).reshape(-1, 4, 4)[:, 2, :]  # world z of G's axes and origin
    lowest = np.full(r.shape[0], np.inf)
    for x_lo, x_hi, hz in boxes:
        xm, hx = 0.5 * (x_lo + x_hi), 0.5 * (x_hi - x_lo)
        z = r[:, 3] + r[:, 0] * xm - np.abs(r[:, 0]) * hx - np.abs(r[:, 1]) * hy - np.abs(r[:, 2]) * hz
        lowest = np.minimum(lowest, z)
    return lowest


def _frames_from_axes(x_axis: np.ndarray, y_axis: np.ndarray, origin: np.ndarray) -> np.ndarray:
    X = np.zeros((x_axis.shape[0], 4, 4))
    X[:, :3, 0] = x_axis
    X[:, :3, 1] = y_axis
    X[:, :3, 2] = np.cross(x_axis, y_axis)
    X[:, :3, 3] = origin
    X[:, 3, 3] = 1.0
    return X


class AntipodalGraspSampler:
    """Geometric antipodal grasp sampler (a ``GraspCandidateSource``)."""

    def __init__(self, config: AntipodalGraspConfig | None = None) -> None:
        self.config = config or AntipodalGraspConfig()
        self._line_tolerance = self.config.line_tolerance
        self._margin = self.config.margin
        self._spacing = 0.0

    def propose(
        self,
        p_WS: np.ndarray,
        p_WT: np.ndarray,
        rng: np.random.Generator | None = None,
    ) -> GraspCandidates:
        cfg = self.config
        rng = rng if rng is not None else np.random.default_rng(0)
        p_WS = np.asarray(p_WS, dtype=float).reshape(-1, 3)
        p_WT = np.asarray(p_WT, dtype=float).reshape(3)
        if not np.all(np.isfinite(p_WT)):
            return GraspCandidates.empty(f"target point is not finite: {p_WT}")
        crop, near = self._crop(p_WS, p_WT)
        if np.count_nonzero(near) < cfg.min_points:
            return GraspCandidates.empty(
                f"too few observed points near the target: {np.count_nonzero(near)} within "
                f"{cfg.grasp_radius} m (need {cfg.min_points})"
            )
        normals = self._prepare(crop)
        # The support: the plane under the target (a table top), as the collision model sees it.
        z_support = support_height(crop, p_WT, cfg.grasp_radius)
        on_object = crop[:, 2] > z_support + max(self._spacing, cfg.voxel_size)
        families = [self._antipodal_family(crop, normals, near, on_object, rng),
                    self._top_down_family(crop, near & on_object, p_WT, z_support)]
        families = [f for f in families if f is not None]
        if not families:
            return GraspCandidates.empty("no antipodal contact pair within the gripper opening near the target")
        x_axis, y_axis, center, width, quality = (np.concatenate(a) for a in zip(*families))
        # The first-contact test's levels, strictest first: (normals, contact band, score scale).
        levels = [(normals, None, 1.0)]
        if cfg.unchecked_normals_fallback:
            levels.append((None, None, cfg.unchecked_normals_score_scale))
        if cfg.rough_contact_band > cfg.contact_band:
            levels.append((None, cfg.rough_contact_band, cfg.rough_surface_score_scale))
        for level_normals, band, scale in levels:
            X_WG, ok, offset = self._clear_frames(crop, level_normals, x_axis, y_axis, center, width, z_support, band)
            if np.any(ok):
                break
        if not np.any(ok):
            return GraspCandidates.empty("every antipodal grasp collides with the observed cloud (no finger clearance)")
        X_WG, width, quality, center, offset = X_WG[ok], width[ok], quality[ok], center[ok], offset[ok]
        proximity = 1.0 - np.clip(np.linalg.norm(center - p_WT, axis=1) / cfg.grasp_radius, 0.0, 1.0)
        # Contacts nearer the fingertips hold less: 1 cm of offset costs 0.01.
        score = scale * (0.7 * quality + 0.3 * proximity - offset)
        order = np.argsort(-score, kind="stable")[: cfg.max_candidates]
        return GraspCandidates(X_WG[order], score[order], width[order])

    def _antipodal_family(self, crop: np.ndarray, normals: np.ndarray, near: np.ndarray, on_object: np.ndarray,
                          rng: np.random.Generator) -> tuple | None:
        """(approach x, closing y, contact centre, width, quality) per grasp, each
        antipodal pair spun through ``num_approaches``; None without a pair.

        Both contacts lie above the support surface (`on_object`): a point of
        the table top is not a contact on the object, and a low object's top
        face paired with the table beside it looks perfectly antipodal (both
        normals vertical) while its lower finger would have to pass through
        the table."""
        cfg = self.config
        objects = np.flatnonzero(on_object)
        pairs = self._antipodal_pairs(crop[objects], normals[objects], np.flatnonzero(near[objects]), rng)
        if pairs.shape[0] == 0:
            return None
        pairs = objects[pairs]
        i, j = pairs[:, 0], pairs[:, 1]
        p1, p2 = crop[i], crop[j]
        width = np.linalg.norm(p2 - p1, axis=1)
        y_axis = (p2 - p1) / width[:, None]
        cos_cone = np.cos(np.arctan(cfg.friction_coefficient))
        alignment = 0.5 * (np.abs(np.sum(normals[i] * y_axis, 1)) + np.abs(np.sum(normals[j] * y_axis, 1)))
        quality = np.clip((alignment - cos_cone) / (1.0 - cos_cone), 0.0, 1.0)
        center = 0.5 * (p1 + p2)

        # Approach directions: spin a unit vector perpendicular to y around y.
        helper = np.where(np.abs(y_axis[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
        u = np.cross(y_axis, helper)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        v = np.cross(y_axis, u)
        # Angle 0 is u = y x z: horizontal whenever the closing axis is not
        # vertical, so the set always holds the level side approaches (and,
        # with num_approaches divisible by 4, the straight top-down one) that
        # objects standing on tables need; a random offset tilted every side
        # approach by up to 15 deg and drove the palm into the table.
        angles = np.arange(cfg.num_approaches) * (2 * np.pi / cfg.num_approaches)
        ca, sa = np.cos(angles), np.sin(angles)
        x_axis = (ca[None, :, None] * u[:, None, :] + sa[None, :, None] * v[:, None, :]).reshape(-1, 3)
        rep = lambda a: np.repeat(a, cfg.num_approaches, axis=0)  # noqa: E731
        return x_axis, rep(y_axis), rep(center), rep(width), rep(quality)

    def _top_down_family(self, crop: np.ndarray, above: np.ndarray, p_WT: np.ndarray,
                         z_support: float) -> tuple | None:
        """Top-down grasps of the target's cluster (``top_down_yaws``) among
        the points `above` (within ``grasp_radius``, above the support at
        `z_support`), in the form of `_antipodal_family`; None when there are none.

        Per yaw, the pads close across slices of the cluster one pad width
        thick (`_top_down_slices`): the whole cluster when no slice fits
        beside the middle one, else slices along it; each also tilted by
        ``top_down_tilts_deg``."""
        cfg = self.config
        if cfg.top_down_yaws < 1:
            return None
        points = self._target_cluster(crop[above], p_WT)
        if points is None:
            return None
        # Yaws from the cluster's major horizontal axis: with top_down_yaws
        # divisible by 4 the set closes along both principal axes, where a
        # box's faces (not its corners) meet the pads first.
        xy = points[:, :2] - points[:, :2].mean(axis=0)
        _, eigvec = np.linalg.eigh(xy.T @ xy)
        yaw0 = float(np.arctan2(eigvec[1, 1], eigvec[0, 1]))
        yaw = yaw0 + np.arange(cfg.top_down_yaws) * (2 * np.pi / cfg.top_down_yaws)
        y_axis = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=1)
        z_axis = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros_like(yaw)], axis=1)  # x cross y, x = -z_W
        g = cfg.gripper
        out_y, out_center, out_width, out_top = [], [], [], []
        for k in range(cfg.top_down_yaws):
            for center, width, top in self._top_down_slices(points, y_axis[k], z_axis[k], z_support):
                out_y.append(y_axis[k])
                out_center.append(center)
                out_width.append(width)
                out_top.append(top)
        if not out_y:
            return None
        width = np.array(out_width)
        keep = (width >= cfg.min_width) & (width <= g.max_opening - 2.0 * self._margin)
        if not np.any(keep):
            return None
        y_axis, center, width, top = np.array(out_y)[keep], np.array(out_center)[keep], width[keep], np.array(out_top)[keep]
        n = y_axis.shape[0]
        x_axis = np.tile([0.0, 0.0, -1.0], (n, 1))
        families = [(x_axis, y_axis, center, width, np.full(n, cfg.top_down_quality))]
        side = np.cross(x_axis, y_axis)  # z of the straight-down G: level, across the closing axis
        for tilt in np.radians(cfg.top_down_tilts_deg):
            # The tilted pads reach less deep: their middle cos(tilt) x 3 cm
            # under the slice's top, but not below its middle height (their
            # first contacts span the pads' middle along z of G, which now
            # leans). Fingertips reaching into the support fail its test.
            tilted = center.copy()
            tilted[:, 2] = np.maximum(top - 0.5 * g.finger_length * np.cos(tilt), 0.5 * (top + z_support))
            families.append((np.cos(tilt) * x_axis + np.sin(tilt) * side, y_axis, tilted, width,
                             np.full(n, cfg.top_down_tilted_quality)))
        return tuple(np.concatenate(a) for a in zip(*families))

    def _top_down_slices(self, points: np.ndarray, y_axis: np.ndarray, z_axis: np.ndarray,
                         z_support: float) -> list[tuple[np.ndarray, float, float]]:
        """(contact centre, width, slice top height) of top-down grasps closing along `y_axis`
        (horizontal) across slices of `points` one pad width thick along
        `z_axis`: the pads' middle 3 cm under the slice's top or, for a low
        object, as low as the fingertips clear the support; middle slice first."""
        cfg = self.config
        g = cfg.gripper
        along_y, along_z = points[:, :2] @ y_axis[:2], points[:, :2] @ z_axis[:2]
        lo, hi = along_z.min(), along_z.max()
        half = 0.5 * g.finger_width
        mid = 0.5 * (lo + hi)
        reach = max(0.5 * (hi - lo) - half, 0.0)  # farthest slice centre from the middle
        steps = np.arange(0.0, reach + 1e-9, cfg.top_down_slice_step)
        offsets = [mid + sgn * d for d in steps for sgn in ((1,) if d == 0 else (-1, 1))]
        offsets = offsets[: cfg.top_down_max_slices]
        out = []
        for c in offsets:
            band = np.abs(along_z - c) <= half if len(offsets) > 1 else np.ones(along_z.shape, bool)
            if np.count_nonzero(band) < cfg.min_support:
                continue
            y_lo, y_hi = along_y[band].min(), along_y[band].max()
            top = points[band, 2].max()
            height = max(top - 0.5 * g.finger_length, z_support + g.fingertip_x + cfg.top_down_floor_clearance)
            center = 0.5 * (y_lo + y_hi) * y_axis + c * z_axis
            center[2] = height
            out.append((center, float(y_hi - y_lo), float(top)))
        return out

    def _target_cluster(self, above: np.ndarray, p_WT: np.ndarray) -> np.ndarray | None:
        """The target's points: those of `above` (the points within
        ``grasp_radius`` above the support) linked to its nearest point; None
        when too few."""
        cfg = self.config
        if above.shape[0] < cfg.min_support:
            return None
        points = above[component_nearest(above, p_WT, cfg.cluster_link * max(self._spacing, cfg.voxel_size))]
        return points if points.shape[0] >= cfg.min_support else None

    def verify(self, p_WS: np.ndarray, p_WT: np.ndarray, X_WG: np.ndarray, width: np.ndarray) -> np.ndarray:
        """Whether grasps X_WG (K, 4, 4) of object widths `width` (K,), proposed
        from an earlier cloud, still pass the clearance and first-contact tests
        (`_clearance_kernel`) on the cloud p_WS around p_WT: a grasp chosen
        from a far view is re-checked on the view from close by, even where
        the new proposals (random antipodal pairs) do not happen to repeat it."""
        X_WG = np.asarray(X_WG, dtype=float).reshape(-1, 4, 4)
        crop, near = self._crop(p_WS, p_WT)
        if np.count_nonzero(near) < self.config.min_points:
            return np.zeros(X_WG.shape[0], dtype=bool)
        normals = self._prepare(crop)
        return self._clearance_ok(crop, X_WG, np.asarray(width, dtype=float).reshape(-1), normals,
                                  support_height(crop, p_WT, self.config.grasp_radius))

    def _crop(self, p_WS: np.ndarray, p_WT: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The finite points within `crop_radius` of the target, voxel-downsampled,
        and which lie within `grasp_radius` of it."""
        cfg = self.config
        p_WS = np.asarray(p_WS, dtype=float).reshape(-1, 3)
        p_WT = np.asarray(p_WT, dtype=float).reshape(3)
        p_WS = p_WS[np.all(np.isfinite(p_WS), axis=1)]
        crop = p_WS[np.linalg.norm(p_WS - p_WT, axis=1) <= cfg.crop_radius]
        crop = voxel_downsample(crop, cfg.voxel_size)
        return crop, np.linalg.norm(crop - p_WT, axis=1) <= cfg.grasp_radius

    def _prepare(self, crop: np.ndarray) -> np.ndarray:
        """Sets the tolerances from the cloud's point spacing and returns its normals."""
        cfg = self.config
        # Tolerances grow with the cloud's point spacing (a map voxelized at
        # 1-2 cm instead of a raw depth cloud); ``voxel_size`` sets the floor.
        spacing = float(np.median(cKDTree(crop).query(crop, k=2)[0][:, 1]))
        self._line_tolerance = max(cfg.line_tolerance, 0.75 * spacing)
        self._margin = max(cfg.margin, 0.5 * spacing)
        self._spacing = spacing
        return estimate_normals_open3d(crop, cfg.normal_neighbours)

    def _clear_frames(self, points: np.ndarray, normals: np.ndarray | None, x_axis: np.ndarray, y_axis: np.ndarray,
                      center: np.ndarray, width: np.ndarray, z_support: float = -np.inf,
                      contact_band: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grasp frames X_WG (K, 4, 4) with the contacts at the first of
        ``contact_offsets`` where the gripper clears the cloud and the support
        surface at `z_support` (`_clearance_ok`; without `normals`, the first
        contacts' friction cone is not checked; `contact_band` overrides the
        config's), whether one does (K,), and that offset (K,)."""
        X_WG = np.empty((x_axis.shape[0], 4, 4))
        ok = np.zeros(x_axis.shape[0], dtype=bool)
        offset = np.zeros(x_axis.shape[0])
        todo = np.arange(x_axis.shape[0])
        for contact_x in self.config.contact_offsets:
            X = _frames_from_axes(x_axis[todo], y_axis[todo], center[todo] - contact_x * x_axis[todo])
            clear = self._clearance_ok(points, X, width[todo], normals, z_support, contact_band)
            X_WG[todo] = X
            ok[todo[clear]] = True
            offset[todo] = contact_x
            todo = todo[~clear]
            if todo.size == 0:
                break
        return X_WG, ok, offset

    def _antipodal_pairs(
        self, points: np.ndarray, normals: np.ndarray, seeds_pool: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Index pairs (i, j) of antipodal contacts, i among the seeds."""
        cfg = self.config
        cos_cone = float(np.cos(np.arctan(cfg.friction_coefficient)))
        max_width = cfg.gripper.max_opening - 2.0 * self._margin
        seeds = rng.choice(seeds_pool, size=min(cfg.num_seeds, seeds_pool.size), replace=False)
        return _antipodal_pair_kernel(np.ascontiguousarray(points, dtype=float),
                                      np.ascontiguousarray(normals, dtype=float), np.asarray(seeds, np.int64),
                                      float(self._line_tolerance), float(cfg.min_width), float(max_width), cos_cone)

    def _clearance_ok(self, points: np.ndarray, X_WG: np.ndarray, width: np.ndarray,
                      normals: np.ndarray | None = None, z_support: float = -np.inf,
                      contact_band: float | None = None) -> np.ndarray:
        """True where the fingers' closing sweep and the palm's approach sweep are
        point-free and the pads' first contacts hold (`_clearance_kernel`), and
        the open fingers and the palm stay above the support surface at
        `z_support` (the table top continues under the object and in its
        occlusion shadow, where the cloud has no point to collide with); without
        `normals` the first contacts' friction-cone test is skipped;
        `contact_band` overrides the config's."""
        cfg = self.config
        g = cfg.gripper
        if normals is None:
            normals = np.zeros_like(points)
            cos_cone = -1.0  # every point's normal qualifies
            facing_cos = 2.0  # and none faces the approach
        else:
            cos_cone = float(np.cos(np.arctan(cfg.contact_friction_coefficient)))
            facing_cos = cfg.facing_approach_cos
        # 1 um of slack: a top-down grasp built with its fingertips exactly on
        # the support rounds to either side of it.
        above = gripper_lowest_z(X_WG, g, cfg.approach_distance) >= z_support - 1e-6
        return above & _clearance_kernel(
            np.ascontiguousarray(points),
            np.ascontiguousarray(normals, dtype=float),
            cos_cone,
            np.ascontiguousarray(X_WG),
            np.ascontiguousarray(width),
            self._margin,
            0.5 * g.max_opening,
            g.fingertip_x,
            g.finger_length,
            g.finger_thickness,
            g.finger_width,
            g.palm_depth + cfg.approach_distance,
            g.palm_height,
            cfg.min_support,
            max(cfg.min_pad_span * 0.5 * g.finger_width - 0.5 * self._spacing, 0.0),
            max(cfg.contact_band if contact_band is None else contact_band, self._spacing),
            cfg.min_tip_distance,
            facing_cos,
        )


#: Width bins [m] of the antipodal pair search: one pair per seed and bin.
PAIR_WIDTH_BIN = 0.01


@numba.njit(cache=True)
def _antipodal_pair_kernel(points, normals, seeds, line_tolerance, min_width, max_width, cos_cone):
    """Index pairs (i, j) (P, 2) of antipodal contacts, i among ``seeds`` (in
    their order): j lies within ``line_tolerance`` of the line through i along
    its normal, ``min_width``..``max_width`` away, and both normals lie within
    the friction cone (``cos_cone``) of the line i-j. One pair per seed and
    ``PAIR_WIDTH_BIN`` of width, the lowest j (the other contacts on the same
    line are the same surface sampled twice); per seed, widths ascending."""
    n_bins = int(math.floor(max_width / PAIR_WIDTH_BIN)) + 1
    out = np.empty((seeds.shape[0] * n_bins, 2), np.int64)
    first = np.empty(n_bins, np.int64)
    m = 0
    for a in range(seeds.shape[0]):
        i = seeds[a]
        first[:] = -1
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        for j in range(points.shape[0]):
            dx = points[j, 0] - px
            dy = points[j, 1] - py
            dz = points[j, 2] - pz
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            # Each test as "not (passes)", so that a NaN normal fails it.
            if not (min_width <= dist <= max_width):
                continue
            along = dx * nx + dy * ny + dz * nz
            if not (abs(along) >= cos_cone * dist):
                continue
            perp2 = dist * dist - along * along
            if perp2 < 0.0:
                perp2 = 0.0
            if not (math.sqrt(perp2) <= line_tolerance):
                continue
            if not (abs((dx / dist) * normals[j, 0] + (dy / dist) * normals[j, 1] + (dz / dist) * normals[j, 2])
                    >= cos_cone):
                continue
            b = int(math.floor(dist / PAIR_WIDTH_BIN))
            if first[b] < 0:
                first[b] = j
        for b in range(n_bins):
            if first[b] >= 0:
                out[m, 0] = i
                out[m, 1] = first[b]
                m += 1
    return out[:m].copy()


@numba.njit(cache=True, inline="always")
def _tip_coordinates(points: np.ndarray, n: int, X_WG: np.ndarray, k: int, fingertip_x: float):
    """Point n in grasp frame k: (squared distance to its origin, x relative to
    the fingertips, y, z)."""
    dx = points[n, 0] - X_WG[k, 0, 3]
    dy = points[n, 1] - X_WG[k, 1, 3]
    dz = points[n, 2] - X_WG[k, 2, 3]
    x = X_WG[k, 0, 0] * dx + X_WG[k, 1, 0] * dy + X_WG[k, 2, 0] * dz - fingertip_x
    y = X_WG[k, 0, 1] * dx + X_WG[k, 1, 1] * dy + X_WG[k, 2, 1] * dz
    z = X_WG[k, 0, 2] * dx + X_WG[k, 1, 2] * dy + X_WG[k, 2, 2] * dz
    return dx * dx + dy * dy + dz * dz, x, y, z


@numba.njit(cache=True, parallel=True)
def _clearance_kernel(
    points: np.ndarray,
    normals: np.ndarray,
    cos_cone: float,
    X_WG: np.ndarray,
    width: np.ndarray,
    margin: float,
    half_open: float,
    fingertip_x: float,
    finger_length: float,
    finger_thickness: float,
    finger_width: float,
    palm_sweep: float,
    palm_height: float,
    min_support: int,
    min_span_z: float,
    contact_band: float,
    min_tip_distance: float,
    facing_cos: float,
) -> np.ndarray:
    """Per candidate: no point in the closing sweep of the pads or the approach
    sweep of the palm and open fingers (both grown by ``margin``; on the pads'
    inner side the margin is in ``width``), at least ``min_support`` points between
    the pads, and where the closing pads first touch the object (the points
    within ``contact_band`` of its extremes along +-y of G, on each side):
    normals in the friction cone of the closing axis (`cos_cone`), at least
    ``min_tip_distance`` inside the fingertips, and reaching ``min_span_z`` on
    both sides of the pads' middle along z (not over the object's edge).
    First-contact points whose normals face the approach (|n . x| >=
    ``facing_cos``) are left out of that test, and a side left with none is
    not tested (its face was not seen)."""
    k_count = X_WG.shape[0]
    ok = np.zeros(k_count, dtype=np.bool_)
    reach2 = (abs(fingertip_x) + finger_length + palm_sweep) ** 2 + (half_open + finger_thickness) ** 2 + palm_height**2
    for k in numba.prange(k_count):
        inner = 0.5 * width[k] + margin
        support = 0
        y_pos = 0.0
        y_neg = 0.0
        x_min = 0.0
        free = True
        for n in range(points.shape[0]):
            r2, x, y_signed, z_signed = _tip_coordinates(points, n, X_WG, k, fingertip_x)
            if r2 > reach2 or x > 0.0 or x < -finger_length - palm_sweep:
                continue
            y = abs(y_signed)
            z = abs(z_signed)
            if x >= -finger_length:
                if z <= 0.5 * finger_width:
                    if y < inner:
                        support += 1
                        x_min = min(x_min, x)
                        y_pos = max(y_pos, y_signed)
                        y_neg = min(y_neg, y_signed)
                    elif y <= half_open + finger_thickness + margin:
                        free = False
                        break
            elif y <= half_open + finger_thickness + margin and z <= 0.5 * palm_height + margin:
                free = False
                break
        if not free or support < min_support or y_pos <= 0.0 or y_neg >= 0.0:
            continue
        # The first contacts of the closing pads, one side at a time. An object
        # reaching less than 3 min_tip_distance into the pads (a 2 cm brick
        # grasped from above, its support just under the fingertips) is held
        # at the tips: a third of its depth is "deep" enough.
        tip_depth = min(min_tip_distance, -x_min / 3.0)
        good = True
        for side in range(2):
            extreme = y_pos if side == 0 else -y_neg
            count = 0
            in_cone = 0
            deep = 0
            z_low = 0.0
            z_high = 0.0
            for n in range(points.shape[0]):
                r2, x, y_signed, z_signed = _tip_coordinates(points, n, X_WG, k, fingertip_x)
                y_side = y_signed if side == 0 else -y_signed
                if r2 > reach2 or y_side < extreme - contact_band or y_side > extreme:
                    continue
                if x > 0.0 or x < -finger_length or abs(z_signed) > 0.5 * finger_width:
                    continue
                n_x = abs(X_WG[k, 0, 0] * normals[n, 0] + X_WG[k, 1, 0] * normals[n, 1]
                          + X_WG[k, 2, 0] * normals[n, 2])
                if n_x >= facing_cos:
                    continue
                count += 1
                n_y = abs(X_WG[k, 0, 1] * normals[n, 0] + X_WG[k, 1, 1] * normals[n, 1]
                          + X_WG[k, 2, 1] * normals[n, 2])
                if n_y >= cos_cone:
                    in_cone += 1
                if x <= -tip_depth:
                    deep += 1
                z_low = min(z_low, z_signed)
                z_high = max(z_high, z_signed)
            # Most first-contact points face the pad, lie inside the fingertips,
            # and the contact reaches across the pads' middle.
            if count == 0:
                continue
            if (2 * in_cone < count or 2 * deep < count or z_low > -min_span_z or z_high < min_span_z):
                good = False
                break
        ok[k] = good
    return ok
