"""The learned grasp-quality model on held-out objects, beside the geometric ranking, and its speed.

Quality: the model file (default: the committed ``models/grasp_quality.npz``)
scores every executed candidate of the held-out objects' trials in a grasp-
trial directory (`vamg grasps collect`; default ``$VAMG_GRASP_DATA``). The
objects are held out by object: the model never saw them. Reported beside the
geometric source's own ranking of the same candidates:

* ``auc_heldout`` / ``geometric_auc_heldout``: ROC AUC of the model's
  probability / of the geometric score against the physics outcome;
* ``top1_precision_heldout`` / ``geometric_top1_precision_heldout``: the
  success rate of the candidate each ranks first in each scene, among the
  candidates executed there (the geometric source's first choice is always
  executed);
* ``best_top1_precision_heldout``: the ceiling of any ranking of the executed
  candidates (the scenes where at least one of them held);
* ``*_source_heldout``: the same among the candidates the geometric source
  proposes itself (what the policy re-ranks), without the near misses its
  first-contact test rejects that the trials also execute.
* with trials that execute each candidate several times
  (``GraspTrialConfig.executions``, recorded as ``executions``):
  ``top1_hold_fraction_heldout`` / ``geometric_top1_hold_fraction_heldout``,
  the mean share of executions that held of each scene's first-ranked
  candidate (its expected success), and ``auc_held_most_heldout`` /
  ``geometric_auc_held_most_heldout`` against "held in more than half of
  its executions" (with one execution these equal the metrics above), with
  95 % intervals from resampling whole trials (``*_ci95``,
  `trial_bootstrap_auc`);
* ``label_consistency_auc``: over every trial, the AUC of predicting each
  outcome by the outcomes of the other candidates of its trial aimed at the
  same grasp (within 5 mm and 10 degrees; `label_consistency`), with
  ``label_consistency_samples``, ``label_consistency_failures`` and
  ``neighbour_fails_given_fails``. Each candidate is executed once, with
  execution noise, so an outcome is one draw of the aimed grasp's success
  probability: this is what knowing another draw buys, a lower bound on what
  the true probability would score -- how noisy the labels are.
* with several executions per candidate: ``repeat_consistency_auc_heldout``,
  the AUC of the other executions' hold share against the first
  execution's outcome (`repeat_consistency`): what knowing the aimed
  grasp's own chance to hold scores against single outcomes, with
  ``repeat_consistency_failures_heldout`` and
  ``others_fail_given_fails_heldout``.

Speed (seeded, no data needed): ``inference_ms_256`` is `LearnedGraspScorer.score`
for 256 geometric candidates on a can-on-a-table cloud (the grasp-frame crops
and the NumPy forward pass: what re-ranking adds to the geometric source's
``propose``), median of ``--repeats``; the torch forward pass of the same
weights is the reference in the same run (``torch_forward_ms_256``).

BLAS and OpenMP run one thread (``OPENBLAS_NUM_THREADS`` and
``OMP_NUM_THREADS`` default to 1, as an episode beside others gets one core):
on a loaded 2-core machine BLAS's second thread made the 256-candidate
forward pass ~10x slower. The JSON records the settings (``threads``).

Usage: python benchmarks/bench_grasp_model.py [--json] [--data DIR] [--model FILE] [--repeats R]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
for _name in THREAD_VARIABLES:
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from vamg_drake.bench.grasp_trials import load_dataset  # noqa: E402
from vamg_drake.bench.grasp_training import (  # noqa: E402
    GraspQualityNet,
    evaluate,
    label_consistency,
    repeat_consistency,
    torch_logits,
)
from vamg_drake.testing import synthetic_clouds as clouds  # noqa: E402
from vamg_drake.policy.grasp_candidates import AntipodalGraspConfig, AntipodalGraspSampler  # noqa: E402
from vamg_drake.policy.learned_grasps import (  # noqa: E402
    DEFAULT_MODEL_PATH,
    GraspQualityModel,
    LearnedGraspScorer,
    candidate_features,
    grasp_frame_crops,
)


def _torch_net(model: GraspQualityModel) -> GraspQualityNet:
    net = GraspQualityNet([W.shape[0] for W, _ in model.point_layers], [W.shape[0] for W, _ in model.head_layers[:-1]])
    with torch.no_grad():
        for layer, (W, b) in zip([*net.point, *net.head, net.skip], [*model.point_layers, *model.head_layers, model.skip]):
            layer.weight.copy_(torch.from_numpy(W))
            layer.bias.copy_(torch.from_numpy(b))
    return net.eval()


def speed(model: GraspQualityModel, repeats: int) -> dict:
    center = np.array([1.0, 0.0, 0.7])
    cloud = np.concatenate([clouds.table_top_cloud(z=center[2], center_xy=center[:2], size=0.6),
                            clouds.can_cloud(center=center, noise=0.001, seed=1)])
    geometric = AntipodalGraspSampler(AntipodalGraspConfig())
    candidates = geometric.propose(cloud, center + [0.0, 0.0, 0.06], np.random.default_rng(0))
    candidates = candidates.subset(np.arange(256) % len(candidates))
    scorer = LearnedGraspScorer(model, geometric)
    crops, _ = grasp_frame_crops(cloud, candidates.X_WG, model.crop)
    features = candidate_features(candidates.X_WG, candidates.width, candidates.score)
    net = _torch_net(model)
    torch.set_num_threads(1)

    def median_ms(fn) -> float:
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1e3 * float(np.median(times))

    p1, p2 = scorer.score(cloud, candidates), scorer.score(cloud, candidates)
    return {
        "inference_ms_256": round(median_ms(lambda: scorer.score(cloud, candidates)), 3),
        "forward_ms_256": round(median_ms(lambda: model.predict(crops, features)), 3),
        "torch_forward_ms_256": round(median_ms(lambda: torch_logits(net, crops, features)), 3),
        "crop_ms_256": round(median_ms(lambda: grasp_frame_crops(cloud, candidates.X_WG, model.crop)), 3),
        "geometric_propose_ms": round(median_ms(lambda: geometric.propose(cloud, center + [0, 0, 0.06],
                                                                          np.random.default_rng(0))), 3),
        "inference_deterministic": bool(np.array_equal(p1, p2)),
        "numpy_torch_max_abs_logit_diff": float(np.max(np.abs(model.logits(crops, features)
                                                              - torch_logits(net, crops, features)))),
    }


def _executions(data: Path) -> int:
    """Executions per candidate of the trials in ``data`` (its manifest's config; 1 before the field)."""
    manifest = data / "manifest.json"
    config = json.loads(manifest.read_text()).get("config", {}) if manifest.exists() else {}
    return int(config.get("executions", 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--data", default=os.environ.get("VAMG_GRASP_DATA", ""),
                        help="grasp-trial directory (default $VAMG_GRASP_DATA)")
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH))
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    model = GraspQualityModel.load(args.model)
    result: dict = {"model": str(Path(args.model).name), "model_data_digest": model.metadata.get("data_digest")}
    if args.data:
        data = load_dataset(args.data)
        heldout = data.subset(data.heldout)
        metrics = evaluate(model, heldout)
        executions = _executions(Path(args.data))
        result.update({
            "data_digest": data.digest, "same_data_as_model": data.digest == model.metadata.get("data_digest"),
            "trials": int(len(np.unique(data.trial))), "samples": len(data),
            "samples_heldout": metrics["samples"], "scenes_heldout": metrics["scenes"],
            "heldout_objects": sorted(set(heldout.objects.tolist())),
            "success_rate_heldout": round(metrics["success_rate"], 4),
            "auc_heldout": round(metrics["auc"], 4),
            "top1_precision_heldout": round(metrics["top1_precision"], 4),
            "geometric_auc_heldout": round(metrics["geometric_auc"], 4),
            "geometric_top1_precision_heldout": round(metrics["geometric_top1_precision"], 4),
            "best_top1_precision_heldout": round(metrics["best_top1_precision"], 4),
            "samples_source_heldout": metrics["samples_source"],
            "success_rate_source_heldout": round(metrics["success_rate_source"], 4),
            "auc_source_heldout": round(metrics["auc_source"], 4),
            "geometric_auc_source_heldout": round(metrics["geometric_auc_source"], 4),
            "executions": executions,
            "top1_hold_fraction_heldout": round(metrics["top1_hold_fraction"], 4),
            "geometric_top1_hold_fraction_heldout": round(metrics["geometric_top1_hold_fraction"], 4),
            "auc_held_most_heldout": round(metrics["auc_held_most"], 4),
            "geometric_auc_held_most_heldout": round(metrics["geometric_auc_held_most"], 4),
            "auc_held_most_heldout_ci95": [round(v, 4) for v in metrics["auc_held_most_ci95"]],
            "geometric_auc_held_most_heldout_ci95": [round(v, 4) for v in metrics["geometric_auc_held_most_ci95"]],
        })
        consistency = label_consistency(data)
        result.update({
            "label_consistency_auc": round(consistency["auc"], 4),
            "label_consistency_samples": consistency["samples"],
            "label_consistency_failures": consistency["failures"],
            "neighbour_fails_given_fails": round(consistency["neighbour_fails_given_fails"], 4),
        })
        if executions > 1:
            repeats = repeat_consistency(heldout, executions)
            result.update({
                "repeat_consistency_auc_heldout": round(repeats["auc"], 4),
                "repeat_consistency_failures_heldout": repeats["failures"],
                "others_fail_given_fails_heldout": round(repeats["others_fail_given_fails"], 4),
            })
    else:
        result["quality"] = "skipped: no --data (or $VAMG_GRASP_DATA) grasp-trial directory"
    result.update(speed(model, args.repeats))
    result["threads"] = {name: os.environ[name] for name in THREAD_VARIABLES}
    if not args.json:
        for k, v in result.items():
            print(f"{k:36s} {v}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
