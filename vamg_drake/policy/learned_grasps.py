"""A learned grasp-quality scorer behind the ``GraspCandidateSource`` seam.

The network (trained with torch in `vamg_drake.bench.grasp_training` on our
own physics trials, `vamg_drake.bench.grasp_trials`) is PointNet-style: a
shared per-point MLP over the candidate's cloud crop in its grasp frame G,
max-pooled, concatenated with the candidate's features (width, geometric
score, gravity in G), and an MLP head plus a linear path from the features
giving the logit of "the object rises and stays in the gripper".

Inference runs here in NumPy from the exported weights (`GraspQualityModel`):
the forward pass of a network this small is a few matrix products, it is
deterministic (no thread-dependent reductions beyond BLAS's), and the policy
does not pay torch's multi-second import in every episode process. The
training module checks that both forward passes agree.

``LearnedGraspScorer`` re-ranks the geometric source's candidates by
predicted success (optionally dropping those below a probability); which
source the policy uses is `GraspSourceConfig` (``subgoal.grasp_source`` of a
method YAML).

Frames: ``W`` world, ``G`` grasp frame (origin mid finger pads, +x approach,
+y closing; `vamg_drake.policy.grasp_candidates`).
"""

import dataclasses as dc
import json
from pathlib import Path

import numba
import numpy as np
from scipy.spatial import cKDTree

from vamg_drake.policy.grasp_candidates import (
    AntipodalGraspConfig,
    AntipodalGraspSampler,
    GraspCandidates,
    GraspCandidateSource,
)
from vamg_drake.robot.layout import GRIPPER_MAX_OPENING

#: Committed model file (see README, "Learned grasp quality").
DEFAULT_MODEL_PATH = Path(__file__).resolve().parents[2] / "models" / "grasp_quality.npz"
#: The model file's format tag and version (bumped when the architecture or
#: the crop changes; an older file is refused, never misread).
MODEL_FORMAT = "vamg-grasp-quality"
MODEL_VERSION = 1
GRASP_SOURCES = ("geometric", "learned")


@dc.dataclass
class GraspCropConfig:
    """The cloud crop around a grasp that the network sees.

    Attributes:
        radius: points within this distance of G's origin [m] (covers the
            fingers, 6 cm pads, and the palm front).
        num_points: points per crop (see `grasp_frame_crops`).
    """

    radius: float = 0.10
    num_points: int = 128


@numba.njit(cache=True)
def _crops_in_order(points, order, X_WG, radius, crops, have):
    """crops[k, :have[k]]: the first points of ``order`` within ``radius`` of
    X_WG[k]'s origin (at most crops.shape[1]), in G, divided by ``radius``."""
    n = crops.shape[1]
    r2 = radius * radius
    for k in range(X_WG.shape[0]):
        c0, c1, c2 = X_WG[k, 0, 3], X_WG[k, 1, 3], X_WG[k, 2, 3]
        h = 0
        for i in order:
            d0, d1, d2 = points[i, 0] - c0, points[i, 1] - c1, points[i, 2] - c2
            if d0 * d0 + d1 * d1 + d2 * d2 <= r2:
                for a in range(3):  # p_GP = R_WG^T p_WP
                    crops[k, h, a] = (X_WG[k, 0, a] * d0 + X_WG[k, 1, a] * d1 + X_WG[k, 2, a] * d2) / radius
                h += 1
                if h == n:
                    break
        have[k] = h


def grasp_frame_crops(p_WS: np.ndarray, X_WG: np.ndarray, config: GraspCropConfig,
                      rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each grasp's crop of cloud p_WS, in G and divided by ``radius``.

    A crop is ``num_points`` of the points within ``radius`` of G's origin,
    drawn without replacement (all of them, some repeated, when there are
    fewer): the first ``num_points`` inside the ball in one random
    permutation of the cloud (Numba: one pass per crop that stops when it is
    full, where 256 neighbour lists of a k-d tree took hundreds of ms).

    Args:
        p_WS: (M, 3) cloud.
        X_WG: (K, 4, 4) grasp poses.
        rng: draws the subsample (a fixed default: deterministic).

    Returns:
        crops (K, num_points, 3) float32 and the distinct points in each
        (K,; at most ``num_points``); an empty crop is all zeros.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    p_WS = np.ascontiguousarray(p_WS, dtype=float).reshape(-1, 3)
    X_WG = np.ascontiguousarray(X_WG, dtype=float)
    K, n = X_WG.shape[0], config.num_points
    crops = np.zeros((K, n, 3), np.float32)
    have = np.zeros(K, np.int64)
    if K == 0 or p_WS.shape[0] == 0:
        return crops, have
    _crops_in_order(p_WS, rng.permutation(p_WS.shape[0]), X_WG, float(config.radius), crops, have)
    for k in np.flatnonzero((have > 0) & (have < n)):  # fewer points than slots: repeat random ones
        crops[k, have[k]:] = crops[k, rng.integers(0, have[k], n - have[k])]
    return crops, have


#: Inputs beside the crop, per candidate (`candidate_features`).
NUM_FEATURES = 5
#: The column of `candidate_features` that holds the geometric score.
SCORE_FEATURE = 1


def candidate_features(X_WG: np.ndarray, width: np.ndarray, score: np.ndarray) -> np.ndarray:
    """The per-candidate inputs beside the crop, (K, 5): width / max opening,
    geometric score, and gravity's direction in G (the crop alone does not
    say which way is down: a top-down and a side grasp of a can look alike)."""
    g_G = np.einsum("kji,j->ki", np.asarray(X_WG, float)[:, :3, :3], np.array([0.0, 0.0, -1.0]))
    return np.concatenate([np.asarray(width, float)[:, None] / GRIPPER_MAX_OPENING,
                           np.asarray(score, float)[:, None], g_G], axis=1).astype(np.float32)


class GraspModelError(ValueError):
    """A model file that is missing, unreadable or of another format (the message names it)."""


class GraspQualityModel:
    """The exported network: NumPy forward pass over (crops, features).

    Layers (weights W (out, in), biases b) are stored as ``point.<i>.W/b`` for
    the shared per-point MLP, ``head.<i>.W/b`` for the head (ReLU after
    every layer but the head's last) and ``skip.0.W/b`` for the linear path
    from the features to the logit.
    """

    def __init__(self, point_layers: list[tuple[np.ndarray, np.ndarray]],
                 head_layers: list[tuple[np.ndarray, np.ndarray]], crop: GraspCropConfig, metadata: dict,
                 skip: tuple[np.ndarray, np.ndarray]) -> None:
        self.point_layers = [(W.astype(np.float32), b.astype(np.float32)) for W, b in point_layers]
        self.head_layers = [(W.astype(np.float32), b.astype(np.float32)) for W, b in head_layers]
        self.skip = (skip[0].astype(np.float32), skip[1].astype(np.float32))
        self.crop = crop
        self.metadata = metadata

    def logits(self, crops: np.ndarray, features: np.ndarray) -> np.ndarray:
        """(K,) logits of crops (K, N, 3) and features (K, F)."""
        crops = np.asarray(crops, np.float32)
        K, N = crops.shape[:2]
        h = crops.reshape(K * N, 3)  # one 2-D product per layer (BLAS), not K small ones
        for W, b in self.point_layers:
            h = h @ W.T
            h += b
            np.maximum(h, 0.0, out=h)  # every point layer is followed by ReLU
        features = np.asarray(features, np.float32)
        h = np.concatenate([h.reshape(K, N, -1).max(axis=1), features], axis=1)
        for i, (W, b) in enumerate(self.head_layers):
            h = h @ W.T + b
            if i < len(self.head_layers) - 1:
                np.maximum(h, 0.0, out=h)
        return h[:, 0] + (features @ self.skip[0].T + self.skip[1])[:, 0]

    def predict(self, crops: np.ndarray, features: np.ndarray) -> np.ndarray:
        """(K,) success probabilities."""
        return 1.0 / (1.0 + np.exp(-self.logits(crops, features).astype(float)))

    def save(self, path: str | Path) -> None:
        arrays = {}
        for prefix, layers in (("point", self.point_layers), ("head", self.head_layers), ("skip", [self.skip])):
            for i, (W, b) in enumerate(layers):
                arrays[f"{prefix}.{i}.W"], arrays[f"{prefix}.{i}.b"] = W, b
        header = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "crop": dc.asdict(self.crop),
                  "metadata": self.metadata}
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, header=np.array(json.dumps(header)), **arrays)
        tmp.replace(path)

    @staticmethod
    def load(path: str | Path) -> "GraspQualityModel":
        """Reads a model file.

        Raises:
            GraspModelError: the file is missing, not a model file, or of another version.
        """
        path = Path(path)
        if not path.is_file():
            raise GraspModelError(f"{path}: grasp-quality model file not found (train one with "
                                  f"`vamg grasps train --data DIR --out {path}`)")
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                arrays = {k: data[k] for k in data.files if k != "header"}
        except Exception as e:  # a truncated, corrupt or foreign file
            raise GraspModelError(f"{path}: not a readable grasp-quality model file ({type(e).__name__}: {e})") from None
        if header.get("format") != MODEL_FORMAT or header.get("version") != MODEL_VERSION:
            raise GraspModelError(f"{path}: format {header.get('format')!r} version {header.get('version')!r}, "
                                  f"expected {MODEL_FORMAT!r} version {MODEL_VERSION}")

        def layers(prefix: str) -> list[tuple[np.ndarray, np.ndarray]]:
            out = []
            while f"{prefix}.{len(out)}.W" in arrays:
                out.append((arrays[f"{prefix}.{len(out)}.W"], arrays[f"{prefix}.{len(out)}.b"]))
            return out

        point, head, skip = layers("point"), layers("head"), layers("skip")
        if (not point or not head or len(skip) != 1 or point[0][0].shape[1] != 3 or head[-1][0].shape[0] != 1
                or skip[0][0].shape != (1, NUM_FEATURES)):
            raise GraspModelError(f"{path}: layer shapes are not those of a grasp-quality network")
        try:
            crop = GraspCropConfig(**header["crop"])
        except TypeError as e:
            raise GraspModelError(f"{path}: header field 'crop': {e}") from None
        return GraspQualityModel(point, head, crop, header.get("metadata", {}), skip[0])


@dc.dataclass
class GraspSourceConfig:
    """Which grasp candidate source the policy uses.

    Attributes:
        source: "geometric" (the antipodal sampler's ranking) or "learned"
            (its candidates re-ranked by the grasp-quality model).
        model: the model file (empty: the committed ``models/grasp_quality.npz``).
        fallback_to_geometric: when the model file is missing or unreadable,
            use the geometric source (with a warning) instead of failing.
        min_probability: the learned source drops candidates predicted below
            this (all of them kept when none reaches it).
    """

    source: str = "geometric"
    model: str = ""
    fallback_to_geometric: bool = False
    min_probability: float = 0.0

    def validate(self, where: str = "grasp_source") -> None:
        if self.source not in GRASP_SOURCES:
            raise ValueError(f"{where}.source: unknown grasp source '{self.source}' (known: {', '.join(GRASP_SOURCES)})")
        if not 0.0 <= self.min_probability < 1.0:
            raise ValueError(f"{where}.min_probability: must be in [0, 1), got {self.min_probability}")

    def model_path(self) -> Path:
        return Path(self.model) if self.model else DEFAULT_MODEL_PATH


class LearnedGraspScorer:
    """Geometric candidates re-ranked by the learned success probability (a
    ``GraspCandidateSource``); the returned score is that probability."""

    def __init__(self, model: GraspQualityModel, base: AntipodalGraspSampler,
                 min_probability: float = 0.0) -> None:
        self.model = model
        self.base = base
        self.min_probability = min_probability

    def score(self, p_WS: np.ndarray, candidates: GraspCandidates) -> np.ndarray:
        """(K,) predicted success of each candidate on cloud p_WS."""
        if len(candidates) == 0:
            return np.zeros(0)
        crops, _ = grasp_frame_crops(p_WS, candidates.X_WG, self.model.crop)
        return self.model.predict(crops, candidate_features(candidates.X_WG, candidates.width, candidates.score))

    def propose(self, p_WS: np.ndarray, p_WT: np.ndarray, rng: np.random.Generator | None = None) -> GraspCandidates:
        candidates = self.base.propose(p_WS, p_WT, rng)
        if len(candidates) == 0:
            return candidates
        probability = self.score(np.asarray(p_WS, dtype=float).reshape(-1, 3), candidates)
        keep = probability >= self.min_probability
        if not np.any(keep):
            keep[:] = True
        order = np.flatnonzero(keep)[np.argsort(-probability[keep], kind="stable")]
        ranked = candidates.subset(order)
        return GraspCandidates(ranked.X_WG, probability[order], ranked.width)

    def verify(self, p_WS: np.ndarray, p_WT: np.ndarray, X_WG: np.ndarray, width: np.ndarray) -> np.ndarray:
        """The geometric source's re-check of grasps on a new cloud."""
        return self.base.verify(p_WS, p_WT, X_WG, width)


def make_grasp_source(config: GraspSourceConfig, grasps: AntipodalGraspConfig) -> GraspCandidateSource:
    """The grasp candidate source ``config`` selects.

    Raises:
        GraspModelError: the learned source's model file is missing or
            unreadable and ``fallback_to_geometric`` is off.
    """
    config.validate()
    geometric = AntipodalGraspSampler(grasps)
    if config.source == "geometric":
        return geometric
    try:
        model = GraspQualityModel.load(config.model_path())
    except GraspModelError as e:
        if not config.fallback_to_geometric:
            raise
        print(f"warning: {e}; grasp_source.fallback_to_geometric is set: using the geometric source")
        return geometric
    return LearnedGraspScorer(model, geometric, config.min_probability)
