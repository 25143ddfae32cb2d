"""Benchmark: real-time factor of a 30 s scripted episode with depth at 10 Hz.

Workload: the procedural room of seed 0 (or --scenario FILE); the scripted
driver drives towards the target and sweeps the head; the head camera renders
320x240 depth at 10 Hz. Reported: real_time_factor (sim s / wall s, higher is
better; target >= 1.0 on one core), the median depth render time, and the
same episode without the camera (the physics-only reference).

    python benchmarks/bench_world.py [--json] [--sim-time 30] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from pydrake.systems.analysis import Simulator  # noqa: E402

from vamg_drake.diagram import DiagramConfig, build_diagram  # noqa: E402
from vamg_drake.world.world_builder import WorldConfig  # noqa: E402


def _scenario(args):
    if args.scenario:
        from vamg_drake.world.scenario import load_scenario

        return load_scenario(args.scenario)
    from vamg_drake.world.rooms import generate_scenario

    return generate_scenario(args.seed)


def run(scenario, sim_time: float, camera: bool) -> dict:
    scenario.time_limit = sim_time + 1.0
    ed = build_diagram(scenario, DiagramConfig(policy="scripted", world=WorldConfig(enable_camera=camera)))
    simulator = Simulator(ed.diagram)
    simulator.Initialize()
    t0 = time.perf_counter()
    simulator.AdvanceTo(sim_time)
    wall = time.perf_counter() - t0
    reached = simulator.get_context().get_time()
    renders = ed.timings.samples.get("depth_render", [])
    return dict(
        sim_time=reached,
        wall_time=wall,
        real_time_factor=reached / wall,
        depth_frames=len(renders),
        depth_render_ms_median=float(np.median(renders)) if renders else None,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--sim-time", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenario", default=None)
    args = parser.parse_args()
    with_camera = run(_scenario(args), args.sim_time, camera=True)
    physics_only = run(_scenario(args), args.sim_time, camera=False)
    result = dict(
        benchmark="world",
        workload=f"scripted episode, {args.sim_time:.0f} s, seed {args.seed}, depth 320x240 @ 10 Hz",
        real_time_factor=round(with_camera["real_time_factor"], 3),
        depth_render_ms_median=round(with_camera["depth_render_ms_median"] or float("nan"), 2),
        depth_frames=with_camera["depth_frames"],
        sim_time=round(with_camera["sim_time"], 2),
        wall_time=round(with_camera["wall_time"], 2),
        reference_physics_only_real_time_factor=round(physics_only["real_time_factor"], 3),
        target_real_time_factor=1.0,
    )
    if not args.json:
        for k, v in result.items():
            print(f"{k:>40}: {v}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
