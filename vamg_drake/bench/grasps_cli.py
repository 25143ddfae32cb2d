"""``vamg grasps collect`` and ``vamg grasps train``: physics-labelled grasp
trials and the grasp-quality model trained on them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vamg_drake.bench.grasp_trials import GraspTrialConfig, collect, load_dataset
from vamg_drake.config_validation import InputError, load_typed_file
from vamg_drake.policy.learned_grasps import DEFAULT_MODEL_PATH


def _cmd_collect(args) -> int:
    config = GraspTrialConfig()
    if args.config:
        try:
            config = load_typed_file(args.config, GraspTrialConfig, GraspTrialConfig())
        except InputError as e:
            raise SystemExit(f"vamg grasps collect: {e}") from None
    try:
        manifest = collect(args.out, args.trials, seed=args.seed, workers=args.workers, config=config,
                           progress=not args.quiet, time_budget=args.time_budget)
    except ValueError as e:
        raise SystemExit(f"vamg grasps collect: {e}") from None
    print(json.dumps({k: manifest[k] for k in ("num_trials", "num_samples", "num_successes", "seed")}
                     | {"out": str(args.out)}))
    return 0


def _cmd_train(args) -> int:
    # torch takes ~1.5 s to import; only training needs it, not every `vamg` command.
    from vamg_drake.bench.grasp_training import GraspTrainingConfig, train_model

    try:
        data = load_dataset(args.data)
    except ValueError as e:
        raise SystemExit(f"vamg grasps train: {e}") from None
    config = GraspTrainingConfig(seed=args.seed)
    if args.epochs is not None:
        config = GraspTrainingConfig(epochs=args.epochs, seed=args.seed)

    def progress(epoch: int, loss: float) -> None:
        if not args.quiet and (epoch % 10 == 0 or epoch == config.epochs - 1):
            print(f"epoch {epoch + 1}/{config.epochs}: loss {loss:.4f}")

    model, metrics = train_model(data, config, progress=progress)
    model.metadata["data"] = str(args.data)
    model.save(args.out)
    print(json.dumps({"out": str(args.out), "samples": len(data), "digest": data.digest, **{
        f"{split}_{k}": v for split, m in metrics.items() for k, v in m.items()}}))
    return 0


def add_grasps_subparser(sub: argparse._SubParsersAction) -> None:
    grasps = sub.add_parser("grasps", help="physics-labelled grasp trials and the learned grasp-quality model")
    grasps_sub = grasps.add_subparsers(dest="grasps_command", required=True)
    col = grasps_sub.add_parser("collect", help="run grasp trials (resumable: trials already in OUT are kept)")
    col.add_argument("--trials", type=int, required=True, help="trials (scenes) 0..N-1 of this seed")
    col.add_argument("--out", required=True, help="directory for trial_*.npz and manifest.json")
    col.add_argument("--workers", type=int, default=1, help="trials in flight at once (default 1)")
    col.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    col.add_argument("--config", help="GraspTrialConfig YAML (partial; defaults fill the rest)")
    col.add_argument("--time-budget", type=float, default=None, help="start no trial after this many seconds")
    col.add_argument("--quiet", action="store_true", help="no progress bar")
    col.set_defaults(func=_cmd_collect)
    tr = grasps_sub.add_parser("train", help="train the grasp-quality model on collected trials")
    tr.add_argument("--data", required=True, help="a directory written by `vamg grasps collect`")
    tr.add_argument("--out", default=str(DEFAULT_MODEL_PATH), help=f"model file (default {DEFAULT_MODEL_PATH})")
    tr.add_argument("--epochs", type=int, default=None, help="training epochs (default: GraspTrainingConfig's)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--quiet", action="store_true")
    tr.set_defaults(func=_cmd_train)
