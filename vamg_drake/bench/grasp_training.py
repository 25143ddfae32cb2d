"""Training the grasp-quality network (torch, CPU) on grasp trials, and its metrics.

The network is the PointNet-style one of `vamg_drake.policy.learned_grasps`:
training happens here in torch; `export` copies the weights into the NumPy
`GraspQualityModel` the policy runs (and `torch_logits` / the tests check
that both give the same outputs).

Training is seeded and single-threaded by default (`torch.manual_seed`,
`torch.use_deterministic_algorithms`), so the same data and configuration
give the same model file. Augmentation: the Fetch gripper and the physics
are mirror-symmetric about G's x-z plane, so a crop reflected across y
(with gravity's y component) keeps its label.

Model selection holds out objects, never single trials: `train_model`
scores every training sample with a network trained without its object
(`out_of_fold_logits`), picks the weight of the geometric score blended into
the network's logit on those scores (`select_score_weight`), and folds it
into the final network's linear path (`fold_score_weight`). The held-out
objects are only evaluated.
"""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
import torch
from scipy.stats import rankdata

from vamg_drake.bench.grasp_trials import GraspDataset
from vamg_drake.policy.grasp_ranking import same_grasp_pairs
from vamg_drake.policy.learned_grasps import (
    MODEL_VERSION,
    NUM_FEATURES,
    SCORE_FEATURE,
    GraspCropConfig,
    GraspQualityModel,
    candidate_features,
)


@dc.dataclass
class GraspTrainingConfig:
    """Network size and optimiser settings."""

    #: Points of each crop the network sees (the first ones of the stored
    #: crops, which are in random order); 64 points and a 32-64 point MLP keep
    #: 256 candidates' inference within 30 ms on one loaded core.
    num_points: int = 64
    point_layers: list[int] = dc.field(default_factory=lambda: [32, 64])
    head_layers: list[int] = dc.field(default_factory=lambda: [64, 32])
    epochs: int = 60
    batch_size: int = 64
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0
    threads: int = 1
    augment_mirror: bool = True
    #: Weights of the geometric score added to the network's logit, both
    #: standardised (``alpha`` in ``z(logit) + alpha z(score)``); `train_model`
    #: picks one by `out_of_fold_logits` over the training objects and folds
    #: it into the linear path (empty: the network alone). A network trained on
    #: a few dozen objects ranks the objects it has not seen no better than
    #: the geometric score; the blend is chosen on objects held out of
    #: training, as the final evaluation holds out its own.
    score_weights: list[float] = dc.field(default_factory=lambda: [0.0, 0.5, 1.0, 2.0])
    #: Object folds of that cross-validation.
    folds: int = 4


class GraspQualityNet(torch.nn.Module):
    """Shared per-point MLP, max-pool, then an MLP head over [pooled, features],
    plus a linear skip from the features to the logit (the geometric score
    and width alone are a strong ranking; the crop's part learns corrections)."""

    def __init__(self, point_layers: list[int], head_layers: list[int]) -> None:
        super().__init__()
        sizes = [3, *point_layers]
        self.point = torch.nn.ModuleList(torch.nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        sizes = [point_layers[-1] + NUM_FEATURES, *head_layers, 1]
        self.head = torch.nn.ModuleList(torch.nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.skip = torch.nn.Linear(NUM_FEATURES, 1)

    def forward(self, crops: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        h = crops
        for layer in self.point:
            h = torch.relu(layer(h))
        h = torch.cat([h.max(dim=1).values, features], dim=1)
        for i, layer in enumerate(self.head):
            h = layer(h)
            if i < len(self.head) - 1:
                h = torch.relu(h)
        return h[:, 0] + self.skip(features)[:, 0]


def dataset_features(data: GraspDataset) -> np.ndarray:
    """The candidate features (`candidate_features`) of every sample."""
    return candidate_features(data.X_WG, data.width, data.score)


def export(net: GraspQualityNet, crop: GraspCropConfig, metadata: dict) -> GraspQualityModel:
    """The NumPy model of ``net``'s current weights."""
    as_np = lambda layers: [(l.weight.detach().numpy().copy(), l.bias.detach().numpy().copy()) for l in layers]  # noqa: E731
    return GraspQualityModel(as_np(net.point), as_np(net.head), crop, metadata, as_np([net.skip])[0])


def torch_logits(net: GraspQualityNet, crops: np.ndarray, features: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.from_numpy(np.asarray(crops, np.float32)), torch.from_numpy(np.asarray(features, np.float32))).numpy()


def _seed(config: GraspTrainingConfig) -> None:
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    torch.use_deterministic_algorithms(True)


def train(data: GraspDataset, config: GraspTrainingConfig | None = None,
          progress=None) -> tuple[GraspQualityNet, list[float]]:
    """Trains a network on all of ``data`` (the caller picks the split).

    Returns:
        the network and the mean training loss of each epoch.
    """
    config = config or GraspTrainingConfig()
    if len(data) == 0:
        raise ValueError("train: no samples")
    _seed(config)
    net = GraspQualityNet(config.point_layers, config.head_layers)
    crops = torch.from_numpy(np.ascontiguousarray(data.crops[:, :config.num_points], dtype=np.float32))
    features = torch.from_numpy(dataset_features(data))
    # The share of executions that held: a soft label where a candidate ran several times.
    labels = torch.from_numpy(data.hold_fraction.astype(np.float32))
    positives = float(labels.sum())
    pos_weight = torch.tensor((len(labels) - positives) / max(positives, 1.0))
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=pos_weight)
    optimiser = torch.optim.AdamW(net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, max(config.epochs, 1))
    generator = torch.Generator().manual_seed(config.seed)
    mirror = torch.tensor([1.0, -1.0, 1.0])
    mirror_features = torch.tensor([1.0, 1.0, 1.0, -1.0, 1.0])
    history = []
    for epoch in range(config.epochs):
        net.train()
        order = torch.randperm(len(labels), generator=generator)
        total = 0.0
        for start in range(0, len(order), config.batch_size):
            idx = order[start:start + config.batch_size]
            c, f, y = crops[idx], features[idx], labels[idx]
            if config.augment_mirror:
                flip = torch.rand(len(idx), generator=generator) < 0.5
                c = torch.where(flip[:, None, None], c * mirror, c)
                f = torch.where(flip[:, None], f * mirror_features, f)
            loss = loss_fn(net(c, f), y)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total += loss.item() * len(idx)
        schedule.step()
        history.append(total / len(labels))
        if progress is not None:
            progress(epoch, history[-1])
    net.eval()
    return net, history


def roc_auc(score: np.ndarray, label: np.ndarray) -> float:
    """Area under the ROC curve (ties count half); NaN without both classes."""
    label = np.asarray(label, bool)
    n_pos, n_neg = int(label.sum()), int((~label).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[label].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def trial_bootstrap_auc(score: np.ndarray, label: np.ndarray, trial: np.ndarray, draws: int = 1000,
                        seed: int = 0) -> tuple[float, float]:
    """95 % interval of `roc_auc` over ``draws`` resamples of whole trials
    (scenes) with replacement: the candidates of one trial share an object,
    a pose and a cloud, so they are not independent samples. Resamples
    without both labels are skipped; NaNs if none has them."""
    members = [np.flatnonzero(trial == t) for t in np.unique(trial)]
    if not members:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    aucs = []
    for _ in range(draws):
        idx = np.concatenate([members[i] for i in rng.integers(len(members), size=len(members))])
        aucs.append(roc_auc(score[idx], label[idx]))
    aucs = np.array(aucs)
    aucs = aucs[np.isfinite(aucs)]
    if not len(aucs):
        return float("nan"), float("nan")
    lo, hi = np.percentile(aucs, [2.5, 97.5])
    return float(lo), float(hi)


def top1_precision(score: np.ndarray, label: np.ndarray, group: np.ndarray) -> float:
    """Mean label (success, or a hold fraction) of the highest-scored sample of each group (scene)."""
    hits = []
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        hits.append(float(label[members[np.argmax(score[members])]]))
    return float(np.mean(hits)) if hits else float("nan")


def same_aimed_grasp(X: np.ndarray, radius: float, angle: float) -> np.ndarray:
    """(K, K) True where grasps X[i] and X[j] (K, 4, 4) are the same aimed
    grasp up to ``radius`` [m] and ``angle`` [rad]: centres within the radius,
    approach axes (+x of G) and closing axes (+y, up to sign: the gripper is
    symmetric) within the angle. The diagonal is False."""
    same = same_grasp_pairs(X, X, radius, angle, match_roll=True)
    np.fill_diagonal(same, False)
    return same


def label_consistency(data: GraspDataset, radius: float = 0.005, angle: float = np.radians(10.0)) -> dict:
    """How far one executed outcome predicts another's at the same aimed grasp.

    Within each trial (one object, one pose, one cloud), a sample's outcome is
    predicted by the mean outcome of the other samples aimed at the same grasp
    (`same_aimed_grasp`). The trials execute each candidate once, with
    position and rotation noise, so each outcome is one draw of the aimed
    grasp's success probability and neighbours are further draws: a low AUC
    means noisy labels. It is a lower bound on what the true probability
    would score (a few draws estimate it), not a ceiling.

    Returns:
        ``auc`` over the samples with such neighbours (NaN without both
        outcomes), ``samples`` and ``failures`` among them, and
        ``neighbour_fails_given_fails``: the mean failure rate of a failed
        sample's neighbours.
    """
    predicted, label = [], []
    for t in np.unique(data.trial):
        members = np.flatnonzero(data.trial == t)
        same = same_aimed_grasp(data.X_WG[members], radius, angle)
        outcome = data.success[members].astype(float)
        for i in np.flatnonzero(same.any(axis=1)):
            predicted.append(outcome[same[i]].mean())
            label.append(bool(data.success[members[i]]))
    predicted, label = np.array(predicted, float), np.array(label, bool)
    return {
        "auc": roc_auc(predicted, label), "samples": int(label.size), "failures": int((~label).sum()),
        "neighbour_fails_given_fails": float(np.mean(1.0 - predicted[~label])) if (~label).any() else float("nan"),
    }


def repeat_consistency(data: GraspDataset, executions: int) -> dict:
    """How far a grasp's other executions predict its first one.

    With trials that execute each candidate ``executions`` times
    (`GraspTrialConfig.executions`), ``success`` is the first execution's
    outcome and ``hold_fraction`` the share of all executions that held, so
    the share among the other ``executions - 1`` is
    ``(executions * hold_fraction - success) / (executions - 1)``. Its AUC
    against ``success`` is what a scorer that knew the aimed grasp's chance
    to hold (estimated from the other draws of the very same grasp, the same
    cloud and pose, fresh execution noise) scores against single outcomes:
    the noise level of the labels that `label_consistency` estimates from
    neighbouring grasps.

    Returns:
        ``auc`` (NaN with one execution or without both outcomes), ``samples``
        and ``failures`` (first executions that failed), and
        ``others_fail_given_fails``: the other executions' mean failure rate
        where the first failed.
    """
    if executions < 2:
        return {"auc": float("nan"), "samples": 0, "failures": 0, "others_fail_given_fails": float("nan")}
    first = data.success.astype(bool)
    others = (executions * data.hold_fraction - first) / (executions - 1)
    return {
        "auc": roc_auc(others, first), "samples": int(first.size), "failures": int((~first).sum()),
        "others_fail_given_fails": float(np.mean(1.0 - others[~first])) if (~first).any() else float("nan"),
    }


def _fold_count(config: GraspTrainingConfig) -> int:
    """The object folds of `out_of_fold_logits` (at least 2)."""
    return max(config.folds, 2)


def out_of_fold_logits(data: GraspDataset, config: GraspTrainingConfig) -> np.ndarray:
    """Each sample's logit from a network trained without its object: the
    objects are dealt into ``config.folds`` folds (a seeded shuffle) and each
    fold is scored by a network trained on the others.

    Raises:
        ValueError: fewer objects than folds.
    """
    objects = np.unique(data.objects)
    folds = _fold_count(config)
    if len(objects) < folds:
        raise ValueError(f"out_of_fold_logits: {len(objects)} objects, need at least {folds} (one per fold)")
    shuffled = np.random.default_rng(config.seed).permutation(objects)
    fold_of = {o: i % folds for i, o in enumerate(shuffled)}
    fold = np.array([fold_of[o] for o in data.objects])
    features = dataset_features(data)
    crops = data.crops[:, :config.num_points]
    logits = np.empty(len(data))
    for k in range(folds):
        net, _ = train(data.subset(fold != k), config)
        logits[fold == k] = torch_logits(net, crops[fold == k], features[fold == k])
    return logits


def blend_with_score(logits: np.ndarray, score: np.ndarray, weight: float) -> np.ndarray:
    """``z(logits) + weight z(score)`` (z: standardised over these samples)."""
    z = lambda x: (x - x.mean()) / max(float(x.std()), 1e-9)  # noqa: E731
    return z(np.asarray(logits, float)) + weight * z(np.asarray(score, float))


def select_score_weight(data: GraspDataset, logits: np.ndarray, weights: list[float]) -> tuple[float, dict]:
    """The weight whose blend (`blend_with_score`) of out-of-fold ``logits``
    ranks ``data`` best (AUC + top-1 precision; the first of equals), and
    each weight's metrics."""
    table = {}
    for w in weights:
        blended = blend_with_score(logits, data.score, w)
        table[float(w)] = {"auc": roc_auc(blended, data.success),
                           "top1_precision": top1_precision(blended, data.success, data.trial)}
    best = max(table, key=lambda w: table[w]["auc"] + table[w]["top1_precision"])
    return best, table


def fold_score_weight(net: GraspQualityNet, weight: float, logit_std: float, score_std: float) -> None:
    """Adds ``weight`` standardised geometric scores to ``net``'s logit, in
    its linear path: the ranking of `blend_with_score` (a logit scaled by
    ``logit_std`` is one standard deviation per unit)."""
    with torch.no_grad():
        net.skip.weight[0, SCORE_FEATURE] += float(weight * logit_std / max(score_std, 1e-9))


def evaluate(model: GraspQualityModel, data: GraspDataset) -> dict:
    """AUC and top-1 precision of the model and of the geometric ranking on ``data``."""
    p = model.predict(data.crops[:, :model.crop.num_points], dataset_features(data))
    geometric = -data.rank.astype(float)  # rank 0 is the geometric source's first choice
    metrics = {
        "samples": len(data), "scenes": int(len(np.unique(data.trial))),
        "success_rate": float(np.mean(data.success)) if len(data) else float("nan"),
        "auc": roc_auc(p, data.success), "top1_precision": top1_precision(p, data.success, data.trial),
        "geometric_auc": roc_auc(data.score, data.success),
        "geometric_top1_precision": top1_precision(geometric, data.success, data.trial),
        # The best any ranking of the executed candidates can do: scenes with one that held.
        "best_top1_precision": top1_precision(data.success.astype(float), data.success, data.trial),
        # Against the share of executions that held (one execution: the same as above).
        "top1_hold_fraction": top1_precision(p, data.hold_fraction, data.trial),
        "geometric_top1_hold_fraction": top1_precision(geometric, data.hold_fraction, data.trial),
        "auc_held_most": roc_auc(p, data.hold_fraction > 0.5),
        "geometric_auc_held_most": roc_auc(data.score, data.hold_fraction > 0.5),
        "auc_held_most_ci95": trial_bootstrap_auc(p, data.hold_fraction > 0.5, data.trial),
        "geometric_auc_held_most_ci95": trial_bootstrap_auc(data.score, data.hold_fraction > 0.5, data.trial),
    }
    # The same among the candidates the source itself proposes (what the
    # policy re-ranks), without the first-contact-rejected near misses.
    own = ~data.rejected
    metrics.update({
        "samples_source": int(own.sum()),
        "success_rate_source": float(np.mean(data.success[own])) if own.any() else float("nan"),
        "auc_source": roc_auc(p[own], data.success[own]),
        "geometric_auc_source": roc_auc(data.score[own], data.success[own]),
    })
    return metrics


def train_model(data: GraspDataset, config: GraspTrainingConfig | None = None, crop: GraspCropConfig | None = None,
                progress=None) -> tuple[GraspQualityModel, dict]:
    """Trains on the training objects of ``data`` and evaluates on its held-out
    objects; returns the exported model (its metadata says how it was made) and
    the metrics."""
    config = config or GraspTrainingConfig()
    crop = crop or GraspCropConfig(num_points=min(config.num_points, int(data.crops.shape[1])))
    train_set, heldout = data.subset(~data.heldout), data.subset(data.heldout)
    t0 = time.perf_counter()
    weight, blend_table = 0.0, {}
    if config.score_weights and len(np.unique(train_set.objects)) >= _fold_count(config):
        weight, blend_table = select_score_weight(train_set, out_of_fold_logits(train_set, config), config.score_weights)
    net, history = train(train_set, config, progress)
    if weight:
        logits = torch_logits(net, train_set.crops[:, :config.num_points], dataset_features(train_set))
        fold_score_weight(net, weight, float(np.std(logits)), float(np.std(train_set.score)))
    metadata = {
        "model_version": MODEL_VERSION, "data_digest": data.digest, "torch": torch.__version__,
        "training_objects": sorted(set(train_set.objects.tolist())),
        "heldout_objects": sorted(set(heldout.objects.tolist())),
        "training_samples": len(train_set), "heldout_samples": len(heldout),
        "training": dc.asdict(config), "epochs": config.epochs, "final_loss": history[-1] if history else None,
        "score_weight": weight, "score_weight_cross_validation": {str(w): m for w, m in blend_table.items()},
        "training_seconds": round(time.perf_counter() - t0, 1),
    }
    model = export(net, crop, metadata)
    metrics = {"train": evaluate(model, train_set), "heldout": evaluate(model, heldout) if len(heldout) else {}}
    model.metadata["metrics"] = metrics
    return model, metrics
