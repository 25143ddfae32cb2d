"""The learned grasp-quality scorer: physics-labelled trials, training, the
NumPy inference of the exported network, and the grasp-source selection."""

from __future__ import annotations

import dataclasses as dc

import json
from pathlib import Path

import numpy as np
import pytest

from vamg_drake.bench.grasp_trials import (
    GraspDataset,
    GraspTrialConfig,
    TrialResult,
    collect,
    load_dataset,
    run_trial,
)
from vamg_drake.bench.grasp_training import (
    GraspTrainingConfig,
    blend_with_score,
    export,
    fold_score_weight,
    label_consistency,
    out_of_fold_logits,
    repeat_consistency,
    select_score_weight,
    roc_auc,
    same_aimed_grasp,
    top1_precision,
    torch_logits,
    trial_bootstrap_auc,
    train,
    train_model,
)
from vamg_drake.config_validation import InputError
from vamg_drake.diagram import load_diagram_config
from vamg_drake.testing import synthetic_clouds as clouds
from vamg_drake.policy.grasp_candidates import AntipodalGraspConfig, AntipodalGraspSampler
from vamg_drake.policy.learned_grasps import (
    DEFAULT_MODEL_PATH,
    GraspCropConfig,
    GraspModelError,
    GraspQualityModel,
    GraspSourceConfig,
    LearnedGraspScorer,
    candidate_features,
    grasp_frame_crops,
    make_grasp_source,
)

CENTER = np.array([1.0, 0.0, 0.7])

#: A trial whose executed candidates both hold and drop the object (found by
#: running the collector; the labels come from Drake's deterministic physics).
MIXED_TRIAL = dict(index=1, seed=0, object_name="mustard_bottle")


def _scene() -> np.ndarray:
    return np.concatenate([clouds.table_top_cloud(z=CENTER[2], center_xy=CENTER[:2], size=0.6),
                           clouds.can_cloud(center=CENTER, noise=0.001, seed=1)])


def _synthetic_dataset(n: int = 96, seed: int = 0) -> GraspDataset:
    """Crops whose label is whether every point lies between the fingers
    (|y| < 0.35 in crop units) or some lie where a finger closes: a rule the
    network can learn in a few epochs."""
    rng = np.random.default_rng(seed)
    crops = rng.uniform(-1, 1, (n, 32, 3)).astype(np.float32)
    success = rng.uniform(size=n) < 0.5
    crops[success, :, 1] *= 0.35
    X_WG = np.repeat(np.eye(4)[None], n, axis=0)
    return GraspDataset(crops, X_WG, rng.uniform(0.02, 0.08, n), rng.uniform(0, 1, n), success,
                        np.arange(n) // 4, np.arange(n) % 4, np.array(["a"] * n), np.arange(n) % 3 == 0,
                        np.arange(n) % 4 == 3, success.astype(float), "synthetic")


def test_collector_labels_grasps_with_both_outcomes(tmp_path: Path) -> None:
    """A fixed-seed trial: the object dropped on the support, the rendered
    partial cloud, the geometric candidates executed in Drake -- some hold the
    object, some do not -- then near misses the source's first-contact test
    rejects, after them in rank and scored below them; the source's own
    candidates and labels are those of a run without the near misses; the
    trial file round-trips and the collector resumes from it (the trial
    present is not run again)."""
    config = GraspTrialConfig(objects=[MIXED_TRIAL["object_name"]], heldout=[], candidates_per_trial=6, top_k=2,
                              rejected_per_trial=3)
    result = run_trial(MIXED_TRIAL["index"], MIXED_TRIAL["seed"], config)
    assert result.reason == ""
    assert result.object_name == MIXED_TRIAL["object_name"]
    assert len(result.success) == 9
    np.testing.assert_array_equal(result.rejected, np.arange(9) >= 6)
    own = ~result.rejected
    assert result.success[own].any() and not result.success[own].all(), result.success
    assert result.crops.shape == (9, config.crop.num_points, 3)
    assert np.all(result.crop_counts > 0)
    assert np.all(np.abs(result.crops) <= 1.0 + 1e-6)  # G-frame crop within the radius
    assert result.rank[0] == 0  # the geometric source's first choice is always executed
    assert np.all(result.rank[~own] >= result.num_candidates)
    assert result.score[~own].max() < result.score[own].min()
    without = run_trial(MIXED_TRIAL["index"], MIXED_TRIAL["seed"], dc.replace(config, rejected_per_trial=0))
    np.testing.assert_array_equal(without.success, result.success[own])
    np.testing.assert_array_equal(without.rank, result.rank[own])

    result.save(tmp_path / "trial_00000.npz")
    manifest = collect(tmp_path, trials=2, seed=0, config=config, progress=False, time_budget=0.0)
    assert manifest["num_trials"] == 1 and manifest["num_samples"] == 9  # trial 0 kept, trial 1 not started
    data = load_dataset(tmp_path)
    np.testing.assert_array_equal(data.success, result.success)
    np.testing.assert_array_equal(data.rejected, result.rejected)
    assert json.loads((tmp_path / "manifest.json").read_text())["seed"] == 0
    with pytest.raises(ValueError, match="manifest.json"):
        collect(tmp_path, trials=2, seed=1, config=config, progress=False, time_budget=0.0)


def test_repeated_executions_estimate_the_hold_fraction(tmp_path: Path) -> None:
    """Each candidate executed three times: the first execution's outcome is
    the label of a one-execution run (the repeats draw their own noise), the
    hold fraction counts thirds and includes it; a trial file without the
    field (format 3, one execution) loads with the outcome as its fraction."""
    config = GraspTrialConfig(objects=[MIXED_TRIAL["object_name"]], heldout=[], candidates_per_trial=3, top_k=1,
                              rejected_per_trial=0)
    once = run_trial(MIXED_TRIAL["index"], MIXED_TRIAL["seed"], config)
    thrice = run_trial(MIXED_TRIAL["index"], MIXED_TRIAL["seed"], dc.replace(config, executions=3))
    np.testing.assert_array_equal(thrice.success, once.success)
    np.testing.assert_array_equal(once.hold_fraction, once.success.astype(float))
    thirds = 3 * thrice.hold_fraction
    np.testing.assert_allclose(thirds, np.round(thirds))
    assert np.all(thrice.hold_fraction[thrice.success] >= 1 / 3 - 1e-9)
    assert np.all(thrice.hold_fraction[~thrice.success] <= 2 / 3 + 1e-9)

    path = tmp_path / "trial_00000.npz"
    thrice.save(path)
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files if k != "hold_fraction"}
    np.savez_compressed(path, **arrays)
    np.testing.assert_array_equal(TrialResult.load(path).hold_fraction, thrice.success.astype(float))
    with pytest.raises(ValueError, match="executions"):
        dc.replace(config, executions=0).validate()


def test_the_collector_skips_placements_the_oracle_cannot_lift() -> None:
    """Trial 45 of seed 0 drops the power drill in a pose no grasp of the
    oracle check fits: the benchmark leaves such a target out, so the trial
    records the oracle's reason and no samples."""
    result = run_trial(45, 0, GraspTrialConfig())
    assert result.object_name == "power_drill"
    assert result.reason.startswith("oracle grasp check: 'power_drill'"), result.reason
    assert len(result.success) == 0 and result.crops.shape[0] == 0


def test_a_few_training_epochs_reduce_the_loss() -> None:
    data = _synthetic_dataset()
    config = GraspTrainingConfig(point_layers=[16, 32], head_layers=[16], epochs=40, batch_size=16, learning_rate=1e-2)
    _, history = train(data, config)
    assert history[-1] < 0.5 * history[0], history


def test_training_is_seeded_and_the_numpy_model_matches_torch(tmp_path: Path) -> None:
    data = _synthetic_dataset()
    config = GraspTrainingConfig(point_layers=[16, 32], head_layers=[16], epochs=3)
    net_a, hist_a = train(data, config)
    net_b, hist_b = train(data, config)
    assert hist_a == hist_b
    features = candidate_features(data.X_WG, data.width, data.score)
    model = export(net_a, GraspCropConfig(num_points=32), {"note": "test"})
    np.testing.assert_allclose(model.logits(data.crops, features), torch_logits(net_a, data.crops, features),
                               rtol=1e-4, atol=1e-5)
    model.save(tmp_path / "m.npz")
    loaded = GraspQualityModel.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.predict(data.crops, features), model.predict(data.crops, features))
    assert loaded.metadata == {"note": "test"}


def test_train_model_records_its_provenance_and_heldout_metrics() -> None:
    data = _synthetic_dataset()
    model, metrics = train_model(data, GraspTrainingConfig(point_layers=[16], head_layers=[8], epochs=2))
    assert model.metadata["data_digest"] == "synthetic"
    assert model.metadata["heldout_samples"] == int(data.heldout.sum())
    assert set(metrics["heldout"]) >= {"auc", "top1_precision", "geometric_auc", "geometric_top1_precision"}


def test_out_of_fold_logits_hold_out_whole_objects() -> None:
    data = _synthetic_dataset()
    data.objects = np.array([f"object_{i % 8}" for i in range(len(data))])
    config = GraspTrainingConfig(point_layers=[16], head_layers=[8], epochs=15, batch_size=16, learning_rate=1e-2)
    logits = out_of_fold_logits(data, config)
    # The crop rule is learnable from other objects; the geometric score here is noise.
    assert roc_auc(logits, data.success) > 0.8
    weight, table = select_score_weight(data, logits, [0.0, 1.0, 100.0])
    assert weight == 0.0 and table[100.0]["auc"] < table[0.0]["auc"] - 0.2, table
    with pytest.raises(ValueError, match="objects"):
        out_of_fold_logits(data.subset(np.isin(data.objects, ["object_0", "object_1"])), config)


def test_a_folded_score_weight_ranks_as_the_blend() -> None:
    data = _synthetic_dataset()
    config = GraspTrainingConfig(point_layers=[16], head_layers=[8], epochs=3)
    net, _ = train(data, config)
    features = candidate_features(data.X_WG, data.width, data.score)
    logits = torch_logits(net, data.crops, features)
    fold_score_weight(net, 0.7, float(np.std(logits)), float(np.std(data.score)))
    folded = torch_logits(net, data.crops, features)
    blend = blend_with_score(logits, data.score, 0.7)
    np.testing.assert_allclose((folded - folded.mean()) / np.std(logits), blend - blend.mean(), atol=1e-4)


def test_metrics() -> None:
    assert roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == pytest.approx(0.75)
    assert top1_precision(np.array([0.9, 0.1, 0.2, 0.7]), np.array([1, 0, 0, 0]), np.array([0, 0, 1, 1])) == 0.5
    # Against hold fractions: the mean fraction of each group's first-ranked sample.
    assert top1_precision(np.array([0.9, 0.1, 0.2, 0.7]), np.array([0.8, 1.0, 0.0, 0.4]),
                          np.array([0, 0, 1, 1])) == pytest.approx(0.6)


def _pose(rotation_axis: int = 2, angle: float = 0.0, p: tuple = (0.0, 0.0, 0.0)) -> np.ndarray:
    """A pose rotated by ``angle`` about axis ``rotation_axis`` (0: x) at ``p``."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != rotation_axis]
    X = np.eye(4)
    X[[i, i, j, j], [i, j, i, j]] = [c, -s, s, c]
    X[:3, 3] = p
    return X


def test_same_aimed_grasp_allows_the_gripper_symmetry_only() -> None:
    """Within radius and angle, or rolled by half a turn about the approach
    (+x): the same aimed grasp; moved 1 cm, yawed 30 degrees or rolled a
    quarter turn: another."""
    poses = [_pose(), _pose(p=(0.002, 0.0, 0.001)), _pose(p=(0.01, 0.0, 0.0)), _pose(2, np.radians(30.0)),
             _pose(0, np.pi), _pose(0, np.pi / 2)]
    same = same_aimed_grasp(np.stack(poses), 0.005, np.radians(10.0))
    assert same[0].tolist() == [False, True, False, False, True, False]
    assert np.array_equal(same, same.T)


def test_label_consistency_is_the_auc_of_the_neighbours_outcomes() -> None:
    """Pairs aimed at the same grasp: where the pair agrees, its neighbour
    predicts each outcome (AUC 1); where every pair disagrees, it predicts the
    opposite (AUC 0); grasps of different trials are never neighbours."""
    n_pairs = 6
    X = np.repeat(np.eye(4)[None], 2 * n_pairs, axis=0)
    X[:, 0, 3] = np.repeat(np.arange(n_pairs) * 0.1, 2)  # pairs 10 cm apart
    agree = np.repeat(np.arange(n_pairs) % 2 == 0, 2)
    data = _synthetic_dataset(2 * n_pairs)
    data = dc.replace(data, X_WG=X, success=agree, trial=np.zeros(2 * n_pairs, int))
    consistent = label_consistency(data)
    assert consistent["auc"] == 1.0 and consistent["samples"] == 2 * n_pairs and consistent["failures"] == n_pairs
    assert consistent["neighbour_fails_given_fails"] == 1.0
    disagree = dc.replace(data, success=np.arange(2 * n_pairs) % 2 == 0)
    assert label_consistency(disagree)["auc"] == 0.0
    assert label_consistency(disagree)["neighbour_fails_given_fails"] == 0.0
    apart = dc.replace(data, trial=np.arange(2 * n_pairs))
    assert label_consistency(apart)["samples"] == 0


def test_repeat_consistency_predicts_the_first_execution_by_the_others() -> None:
    """Five executions each: where the other four agree with the first, they
    predict it (AUC 1); where they all disagree, the opposite (AUC 0); the
    first execution's own outcome never counts towards its predictor."""
    n = 8
    first = np.arange(n) % 2 == 0
    data = dc.replace(_synthetic_dataset(n), success=first, hold_fraction=first.astype(float))
    agree = repeat_consistency(data, 5)
    assert agree["auc"] == 1.0 and agree["samples"] == n and agree["failures"] == n // 2
    assert agree["others_fail_given_fails"] == 1.0
    # The first held and the other four did not (hold share 1/5), and the reverse (4/5).
    disagree = dc.replace(data, hold_fraction=np.where(first, 0.2, 0.8))
    assert repeat_consistency(disagree, 5)["auc"] == 0.0
    assert repeat_consistency(disagree, 5)["others_fail_given_fails"] == 0.0
    assert np.isnan(repeat_consistency(data, 1)["auc"])


def test_trial_bootstrap_auc_brackets_the_auc_and_resamples_whole_trials() -> None:
    """A perfect score gives [1, 1]; a noisy one an interval around its AUC;
    a single trial gives a zero-width interval (every resample is that trial)."""
    rng = np.random.default_rng(3)
    trial = np.repeat(np.arange(20), 6)
    label = rng.uniform(size=trial.size) < 0.7
    assert trial_bootstrap_auc(label.astype(float), label, trial) == (1.0, 1.0)
    noisy = label + rng.normal(0.0, 0.8, trial.size)
    lo, hi = trial_bootstrap_auc(noisy, label, trial)
    assert lo < roc_auc(noisy, label) < hi and hi - lo > 0.05
    one = np.zeros(trial.size, int)
    lo, hi = trial_bootstrap_auc(noisy, label, one)
    assert lo == hi == pytest.approx(roc_auc(noisy, label))


def test_learned_scorer_reranks_the_geometric_candidates_deterministically() -> None:
    cloud, target = _scene(), CENTER + [0.0, 0.0, 0.06]
    model = GraspQualityModel.load(DEFAULT_MODEL_PATH)
    geometric = AntipodalGraspSampler(AntipodalGraspConfig())
    scorer = LearnedGraspScorer(model, geometric)
    a = scorer.propose(cloud, target, np.random.default_rng(3))
    b = scorer.propose(cloud, target, np.random.default_rng(3))
    base = geometric.propose(cloud, target, np.random.default_rng(3))
    assert len(a) == len(base) > 0
    np.testing.assert_array_equal(a.score, b.score)
    np.testing.assert_array_equal(a.X_WG, b.X_WG)
    assert np.all(np.diff(a.score) <= 0) and np.all((a.score >= 0) & (a.score <= 1))
    # The same set of grasps, reordered.
    key = lambda c: sorted(map(tuple, np.round(c.X_WG[:, :3, 3], 9)))  # noqa: E731
    assert key(a) == key(base)


def test_grasp_frame_crops_are_in_the_grasp_frame() -> None:
    X_WG = np.eye(4)
    X_WG[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    X_WG[:3, 3] = [1.0, 2.0, 3.0]
    p_WS = np.array([[1.0, 2.05, 3.0], [5.0, 5.0, 5.0]])  # +5 cm along G's x; and far away
    crops, counts = grasp_frame_crops(p_WS, X_WG[None], GraspCropConfig(radius=0.1, num_points=4))
    assert counts.tolist() == [1]
    np.testing.assert_allclose(crops[0], np.tile([0.5, 0.0, 0.0], (4, 1)), atol=1e-6)


def test_a_missing_or_corrupt_model_file_is_a_clear_error(tmp_path: Path) -> None:
    missing = tmp_path / "none.npz"
    with pytest.raises(GraspModelError, match=str(missing)):
        GraspQualityModel.load(missing)
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(GraspModelError, match="corrupt.npz: not a readable"):
        GraspQualityModel.load(corrupt)
    with pytest.raises(GraspModelError, match=str(missing)):
        make_grasp_source(GraspSourceConfig(source="learned", model=str(missing)), AntipodalGraspConfig())
    # Only when the configuration asks for it does a missing model fall back.
    source = make_grasp_source(GraspSourceConfig(source="learned", model=str(missing), fallback_to_geometric=True),
                               AntipodalGraspConfig())
    assert isinstance(source, AntipodalGraspSampler)
    assert isinstance(make_grasp_source(GraspSourceConfig(source="learned"), AntipodalGraspConfig()),
                      LearnedGraspScorer)


def test_method_yaml_selects_the_grasp_source(tmp_path: Path) -> None:
    method = tmp_path / "m.yaml"
    method.write_text(f"subgoal: {{grasp_source: {{source: learned, model: {tmp_path / 'gone.npz'}}}}}\n")
    with pytest.raises(InputError, match=r"m\.yaml: .*gone\.npz: grasp-quality model file not found"):
        load_diagram_config(method)
    method.write_text("subgoal: {grasp_source: {source: neural}}\n")
    with pytest.raises(InputError, match=r"subgoal\.grasp_source\.source: unknown grasp source 'neural'"):
        load_diagram_config(method)
    shipped = Path(__file__).parents[1] / "vamg_drake" / "bench" / "methods" / "full_learned_grasps.yaml"
    assert load_diagram_config(shipped).subgoal.grasp_source.source == "learned"
