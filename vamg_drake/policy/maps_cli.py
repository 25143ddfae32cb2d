"""The ``vamg maps`` subcommand: build, inspect and locate the kinematic maps.

The lead wires `add_maps_subparser` into `vamg_drake/cli.py`; it also runs as
``python -m vamg_drake.policy.maps_cli build``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from vamg_drake.policy.kinematic_maps import KinematicMaps, KinematicMapsConfig, default_cache_dir


def add_maps_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds ``maps {build,info,path}`` to a parent parser's subparsers."""
    parser = subparsers.add_parser("maps", help="pre-computed kinematic maps (reachability, capability, torso height)")
    sub = parser.add_subparsers(dest="maps_command", required=True)
    build = sub.add_parser("build", help="build (or rebuild) the maps for the current robot model")
    build.add_argument("--reach-samples", type=int, default=None, help="joint samples for the reachability map")
    build.add_argument("--torso-samples", type=int, default=None, help="joint samples for the torso-height map")
    build.add_argument("--cache-dir", type=Path, default=None, help=f"default: {default_cache_dir()}")
    build.add_argument("--force", action="store_true", help="rebuild even if cached")
    build.add_argument("--no-progress", action="store_true")
    for name in ("info", "path"):
        p = sub.add_parser(name, help="print the cached maps' metadata" if name == "info" else "print the cache folder")
        p.add_argument("--reach-samples", type=int, default=None)
        p.add_argument("--torso-samples", type=int, default=None)
        p.add_argument("--cache-dir", type=Path, default=None)
    parser.set_defaults(func=run_maps_command)
    return parser


def _config(args: argparse.Namespace) -> KinematicMapsConfig:
    config = KinematicMapsConfig()
    if args.reach_samples is not None:
        config.reach_samples = args.reach_samples
    if args.torso_samples is not None:
        config.torso_samples = args.torso_samples
    config.validate()
    return config


def run_maps_command(args: argparse.Namespace) -> int:
    """Runs ``maps build|info|path``; returns the exit code."""
    config = _config(args)
    folder = KinematicMaps.cache_folder(config, args.cache_dir)
    if args.maps_command == "path":
        print(folder)
        return 0
    if args.maps_command == "info":
        try:
            maps = KinematicMaps.load(folder)
        except (FileNotFoundError, ValueError) as e:
            print(f"vamg maps info: {e} (run `vamg maps build`)", file=sys.stderr)
            return 1
        print(json.dumps({**maps.metadata, "folder": str(folder), "size_bytes": maps.size_bytes(folder)}, indent=2))
        return 0
    if folder.exists() and not args.force:
        try:
            maps = KinematicMaps.load(folder)
            print(f"maps already built in {folder} (use --force to rebuild)")
            return 0
        except (FileNotFoundError, ValueError):
            pass
    t0 = time.perf_counter()
    maps = KinematicMaps.build(config, progress=not args.no_progress)
    maps.save(folder)
    summary = {
        "folder": str(folder),
        "build_s": round(time.perf_counter() - t0, 1),
        "size_bytes": maps.size_bytes(folder),
        **{k: maps.metadata[k] for k in ("reach_build_s", "torso_build_s", "reach_voxels", "torso_bins_reached")},
    }
    print(json.dumps(summary))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vamg")
    add_maps_subparser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["maps", *(argv if argv is not None else sys.argv[1:])])
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
