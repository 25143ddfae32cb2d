"""The `vamg` command (also `python -m vamg_drake.cli`).

    vamg run [--scenario FILE | --seed N [--dynamic]] [--config FILE] [--policy full|scripted] [--out DIR] [--time-limit S]
    vamg scenario generate --seed N --out FILE [--replicacad SCENE [--replicacad-dir DIR]]
    vamg scenario import-tasks TASK_FILE --out DIR [--dynamic] [--tasks K]
    vamg maps build            (kinematic maps)
    vamg bench --suite S --methods a,b [--seeds K] --out DIR [--workers N] [--backend local|ray] [--resume [--retry-errors]]
    vamg report DIR [--json [--common-tasks]]
    vamg grasps collect --trials N --out DIR [--workers K] [--seed S]   (physics-labelled grasp trials)
    vamg grasps train --data DIR [--out FILE]                             (the learned grasp-quality model)

Bad input (a file, a field, an argument) ends the command with one line per
problem naming the file and the field, and exit status 1, never a traceback.
`vamg run` also exits with status 1 when the episode ended in ``error`` (its
``episode.json`` holds the traceback).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import tempfile
from pathlib import Path

from tqdm import tqdm

from vamg_drake.bench.grasps_cli import add_grasps_subparser
from vamg_drake.bench.methods import MethodError, load_methods
from vamg_drake.bench.report import common_task_records, load_latest_records, summary_lines, write_report
from vamg_drake.bench.results import ResultsError
from vamg_drake.bench.runner import episode_specs, prepare_episode_caches, run_sweep
from vamg_drake.bench.suites import SuiteError, materialize_suite, suite_config
from vamg_drake.config_validation import InputError
from vamg_drake.diagram import POLICIES, DiagramConfig, load_diagram_config
from vamg_drake.episode import ERROR, run_episode
from vamg_drake.policy.maps_cli import add_maps_subparser
from vamg_drake.provenance import atomic_write_text
from vamg_drake.rendering_check import check_rendering_libraries
from vamg_drake.world.paper_tasks import TaskFileError, import_scene, read_task_file
from vamg_drake.world.replicacad import ReplicaCadError
from vamg_drake.world.replicacad_generator import generate_replicacad_scenario
from vamg_drake.world.rooms import GenerationError, RoomGeneratorConfig, generate_scenario
from vamg_drake.world.scenario import MAX_TIME_LIMIT, Scenario, ScenarioError, load_scenario, save_scenario


def _load_or_generate(args) -> Scenario:
    if args.scenario:
        try:
            return load_scenario(args.scenario)
        except (ScenarioError, FileNotFoundError) as e:
            raise SystemExit(f"vamg: {e}") from None

    _check_seed(args.seed)
    dynamic = bool(getattr(args, "dynamic", False))
    try:
        return generate_scenario(args.seed, RoomGeneratorConfig(dynamic=dynamic))
    except GenerationError as e:
        raise SystemExit(f"vamg: --seed {args.seed}: {e}") from None


def _check_seed(seed: int) -> None:
    if not 0 <= seed < 2**32:
        raise SystemExit(f"vamg: --seed: must be in [0, 2^32), got {seed}")


def _check_out_dir(path: str, option: str = "--out") -> Path:
    """The output directory, created and proven writable (else one line naming it)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise SystemExit(f"vamg: {option} {path}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as e:
        raise SystemExit(f"vamg: {option} {path}: not a writable directory ({e.strerror or e})") from None
    return out


def _check_out_file(path: str, option: str = "--out") -> Path:
    """An output file's path: not a directory, its folder created and writable."""
    out = Path(path)
    if out.is_dir():
        raise SystemExit(f"vamg: {option} {path}: is a directory, not a file")
    _check_out_dir(str(out.parent) if str(out.parent) else ".", option=f"{option} {path}: folder")
    if out.exists() and not os.access(out, os.W_OK):
        raise SystemExit(f"vamg: {option} {path}: not writable")
    return out


def _load_diagram_config(path: str | None) -> DiagramConfig:
    if not path:
        return DiagramConfig()
    try:
        return load_diagram_config(path)
    except InputError as e:
        raise SystemExit(f"vamg: {e}") from None


def _cmd_run(args) -> int:
    if args.policy and args.policy not in POLICIES:
        raise SystemExit(f"vamg run: unknown --policy '{args.policy}' (known: {', '.join(POLICIES)})")

    if args.time_limit is not None and not (math.isfinite(args.time_limit) and 0 < args.time_limit <= MAX_TIME_LIMIT):
        raise SystemExit(f"vamg run: --time-limit: must be a positive number of seconds up to {MAX_TIME_LIMIT:g}, "
                         f"got {args.time_limit}")
    check_rendering_libraries()
    scenario = _load_or_generate(args)
    if args.time_limit is not None:
        scenario.time_limit = args.time_limit
    config = _load_diagram_config(args.config)
    if args.policy:
        config.policy = args.policy
    try:
        config.validate()
    except ValueError as e:
        raise SystemExit(f"vamg run: {e}") from None
    out = _check_out_dir(args.out)
    result = run_episode(scenario, config, out_dir=out, record=not args.no_replay, progress=not args.quiet)
    print(json.dumps({k: v for k, v in result.__dict__.items() if k not in ("timings", "phases", "provenance")}))
    if result.status == ERROR:
        print(f"vamg run: the episode ended in error: {result.detail} (traceback in {out / 'episode.json'})",
              file=sys.stderr)
        return 1
    return 0


def _cmd_scenario_generate(args) -> int:
    _check_seed(args.seed)
    out = _check_out_file(args.out)
    if args.replicacad:
        try:
            scenario = generate_replicacad_scenario(args.replicacad, args.seed, dataset_dir=args.replicacad_dir)
        except ReplicaCadError as e:
            raise SystemExit(f"vamg scenario generate: {e}") from None
    else:
        try:
            scenario = generate_scenario(args.seed)
        except GenerationError as e:
            raise SystemExit(f"vamg scenario generate: --seed {args.seed}: {e}") from None
    save_scenario(scenario, out)
    print(f"wrote {out}: {scenario.name}, {len(scenario.furniture)} furniture, {len(scenario.objects)} objects, target {scenario.target}")
    return 0


def _cmd_scenario_import_tasks(args) -> int:
    if args.tasks is not None and args.tasks < 1:
        raise SystemExit(f"vamg scenario import-tasks: --tasks must be >= 1, got {args.tasks}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise SystemExit(f"vamg scenario import-tasks: --out {out} exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SystemExit(f"vamg scenario import-tasks: --out {out}: {e.strerror}") from None
    try:
        scenes = read_task_file(args.task_file)
        report = []
        count = 0
        for scene in tqdm(scenes, desc="import scenes", disable=not sys.stderr.isatty()):
            wanted = None if args.tasks is None else [t.index for t in scene.tasks[: args.tasks]]
            imported = import_scene(scene, args.dynamic, args.replicacad_dir, tasks=wanted)
            for index, scenario in imported.scenarios:
                save_scenario(scenario, out / f"{scenario.name}.yaml")
                count += 1
            report.append(imported.report())
            print(f"{scene.key}: {imported.apartment} (tasks on its receptacles: {imported.match_scores[imported.apartment]}/"
                  f"{len(scene.tasks)}), {len(imported.scenarios)} scenarios, {len(imported.excluded)} excluded")
    except (TaskFileError, ReplicaCadError) as e:
        raise SystemExit(f"vamg scenario import-tasks: {e}") from None
    atomic_write_text(out / "import.json",
                      json.dumps({"task_file": str(args.task_file), "dynamic": args.dynamic, "scenes": report}, indent=1))
    print(f"wrote {count} scenarios and import.json to {out}")
    return 0


def _cmd_bench(args) -> int:
    try:
        config = suite_config(args.suite, scenes=args.scenes, targets=args.targets)
        if args.task_file:
            config.task_file = args.task_file
        methods = load_methods([m.strip() for m in args.methods.split(",") if m.strip()])
    except (SuiteError, MethodError) as e:
        raise SystemExit(f"vamg bench: {e}") from None
    if args.retry_errors and not args.resume:
        raise SystemExit("vamg bench: --retry-errors: only with --resume (it reruns recorded errors)")
    if args.seeds < 1 or args.workers < 1:
        raise SystemExit(f"vamg bench: --seeds and --workers: must be >= 1, got {args.seeds} and {args.workers}")
    if not (math.isfinite(args.wall_limit) and args.wall_limit > 0):
        raise SystemExit(f"vamg bench: --wall-limit: must be a positive number of seconds, got {args.wall_limit}")
    _check_out_dir(args.out)
    check_rendering_libraries()
    try:
        suite = materialize_suite(config, args.out, progress=not args.quiet)
        specs = episode_specs(suite, methods, args.seeds)
        records = run_sweep(specs, args.out, workers=args.workers, backend=args.backend, resume=args.resume,
                            wall_limit=args.wall_limit, progress=not args.quiet, ray_address=args.ray_address,
                            keep_episodes=not args.no_episode_logs,
                            prepare=lambda: prepare_episode_caches(methods), retry_errors=args.retry_errors)
    except (SuiteError, FileExistsError, ValueError, RuntimeError) as e:
        raise SystemExit(f"vamg bench: {e}") from None
    print(json.dumps({"suite": config.name, "scenarios": len(suite.scenarios), "excluded": len(suite.excluded),
                      "episodes": len(specs), "ran": len(records), "out": str(args.out)}))
    return 0


def _cmd_report(args) -> int:
    try:
        loaded = load_latest_records(args.dir)
        path = write_report(args.dir, loaded)
    except (FileNotFoundError, ResultsError) as e:
        raise SystemExit(f"vamg report: {e}") from None
    if args.json:
        records = common_task_records(loaded[0]) if args.common_tasks else loaded[0]
        for line in summary_lines(records):
            print(json.dumps(line))
    else:
        print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vamg", description="Visibility-aware mobile grasping (Drake).")
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run one episode headless")
    src = run.add_mutually_exclusive_group()
    src.add_argument("--scenario", help="scenario YAML file")
    src.add_argument("--seed", type=int, default=0, help="generate the scenario from this seed (default 0)")
    run.add_argument("--out", default="runs/demo", help="output directory (episode.json, replay.html, topdown.png)")
    run.add_argument("--dynamic", action="store_true", help="with --seed: a dynamic scenario (pedestrian, table-top box)")
    run.add_argument("--config", help="DiagramConfig YAML (partial; defaults fill the rest), e.g. a bench method file")
    run.add_argument("--policy", default=None, help="full (default) or scripted")
    run.add_argument("--time-limit", type=float, default=None, help="override the scenario's time limit [s]")
    run.add_argument("--no-replay", action="store_true", help="skip the Meshcat recording")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_cmd_run)

    scenario = sub.add_parser("scenario", help="scenario tools")
    scenario_sub = scenario.add_subparsers(dest="scenario_command", required=True)
    gen = scenario_sub.add_parser("generate", help="generate a procedural room (or ReplicaCAD) scenario")
    gen.add_argument("--seed", type=int, required=True)
    gen.add_argument("--out", required=True)
    gen.add_argument("--replicacad", metavar="SCENE", help="a ReplicaCAD scene instance (e.g. apt_0) instead of a procedural room")
    gen.add_argument("--replicacad-dir", help="ReplicaCAD dataset (default: $VAMG_REPLICACAD_DIR, $MS_ASSET_DIR, ~/.maniskill/data); stored in the file")
    gen.set_defaults(func=_cmd_scenario_generate)
    imp = scenario_sub.add_parser("import-tasks", help="import the paper authors' ReplicaCAD task file as scenario files")
    imp.add_argument("task_file", help="the authors' grasp_benchmark.json (or a part of it)")
    imp.add_argument("--out", required=True, help="directory for the scenario files and import.json")
    imp.add_argument("--dynamic", action="store_true", help="add the pedestrian box and the manipulation boxes")
    imp.add_argument("--replicacad-dir", help="ReplicaCAD dataset (default: $VAMG_REPLICACAD_DIR, $MS_ASSET_DIR, ~/.maniskill/data)")
    imp.add_argument("--tasks", type=int, default=None, help="import only the first K tasks of each scene")
    imp.set_defaults(func=_cmd_scenario_import_tasks)

    bench = sub.add_parser("bench", help="run a benchmark sweep (isolated, resumable episodes)")
    bench.add_argument("--suite", required=True, help="smoke | static | dynamic | dynamic_moving | trigger_sweep | replicacad | paper_static | paper_dynamic | FILE.yaml")
    bench.add_argument("--methods", required=True, help="comma-separated method names or YAML files (e.g. full,velocity_agnostic)")
    bench.add_argument("--seeds", type=int, default=1, help="repetitions of every scenario (default 1)")
    bench.add_argument("--out", required=True, help="results directory (results.jsonl, suites/)")
    bench.add_argument("--workers", type=int, default=1, help="episodes in flight at once (default 1)")
    bench.add_argument("--backend", choices=("local", "ray"), default="local")
    bench.add_argument("--ray-address", default=None, help="Ray cluster address (default: a local instance)")
    bench.add_argument("--resume", action="store_true",
                       help="skip episodes already in DIR/results.jsonl (run with the method file as it is now)")
    bench.add_argument("--retry-errors", action="store_true",
                       help="with --resume: run again the episodes recorded as error (the report counts the latest)")
    bench.add_argument("--task-file", default=None, help="paper_static/paper_dynamic: the authors' task file (default: $VAMG_PAPER_TASKS)")
    bench.add_argument("--scenes", type=int, default=None, help="override the suite's number of scenes")
    bench.add_argument("--targets", type=int, default=None, help="override the suite's targets per scene")
    bench.add_argument("--wall-limit", type=float, default=900.0, help="per-episode wall-clock limit [s] (default 900)")
    bench.add_argument("--quiet", action="store_true", help="no progress bars")
    bench.add_argument("--no-episode-logs", action="store_true",
                       help="keep no per-episode log, episode.json and top-down plot under DIR/episodes/")
    bench.set_defaults(func=_cmd_bench)

    report = sub.add_parser("report", help="write DIR/report.md and plots from a results directory")
    report.add_argument("dir", help="results directory (holding results.jsonl)")
    report.add_argument("--json", action="store_true",
                        help="print one JSON line per suite and method (episodes, success, Wilson interval, SPL, failures, code)")
    report.add_argument("--common-tasks", action="store_true",
                        help="with --json: count only the tasks every method of the suite ran")
    report.set_defaults(func=_cmd_report)

    add_maps_subparser(sub)
    add_grasps_subparser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
