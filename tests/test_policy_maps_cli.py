"""The `vamg maps` subcommand (tiny sample counts into a temporary cache)."""

from __future__ import annotations

import argparse
import json

from vamg_drake.policy.maps_cli import add_maps_subparser


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="vamg")
    add_maps_subparser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_maps_build_info_path(tmp_path, capsys) -> None:
    small = ["--reach-samples", "20000", "--torso-samples", "20000", "--cache-dir", str(tmp_path)]
    assert _run(["maps", "info", *small]) == 1
    assert "missing" in capsys.readouterr().err
    assert _run(["maps", "build", "--no-progress", *small]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["size_bytes"] > 0 and summary["reach_voxels"] > 0 and summary["build_s"] >= 0
    assert _run(["maps", "build", "--no-progress", *small]) == 0
    assert "already built" in capsys.readouterr().out
    assert _run(["maps", "info", *small]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["config"]["reach_samples"] == 20000
    assert _run(["maps", "path", *small]) == 0
    assert str(tmp_path) in capsys.readouterr().out
