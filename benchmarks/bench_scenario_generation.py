"""Speed of scenario generation: room layout, drop checks, whole scenarios.

Workload (seeded): ``generate_scenario(seed)`` for seeds 0..N-1 with the
default config plus dynamic events and a moving obstacle. Every call to the
drop check is timed (the physics); the rest of the generator is "layout"
(room, furniture, navigability grid, start, events). The drop check is also run
on a fixed set of 10 objects on one table with hydroelastic contact (the
default) and with point contact (the reference: cheaper, but objects rock on
their single contact point, which the final tilt shows).

Usage: python benchmarks/bench_scenario_generation.py [--json] [--seeds N]
"""

import argparse
import json
import statistics
import time

import numpy as np

from vamg_drake.world import rooms
from vamg_drake.world.drop_check import DropCheckConfig, drop_object
from vamg_drake.world.primitives import WorldBox
from vamg_drake.world.scene_geometry import SceneGeometryConfig
from vamg_drake.world.ycb import YCB_OBJECTS, load_ycb_asset

DROP_OBJECTS = ["master_chef_can", "mug", "tennis_ball", "banana", "power_drill", "bowl", "lego_duplo_c", "cups_e", "hammer", "rubiks_cube"]


def bench_generation(seeds: int) -> dict:
    drop_times: list[float] = []
    accepted: list[bool] = []
    original = rooms.drop_object

    def timed_drop(*args, **kwargs):
        t0 = time.perf_counter()
        result = original(*args, **kwargs)
        drop_times.append(time.perf_counter() - t0)
        accepted.append(result.accepted)
        return result

    rooms.drop_object = timed_drop  # instrument, do not replace: the real drop runs
    totals, layouts, n_objects, pedestrians, failures = [], [], [], 0, 0
    config = rooms.RoomGeneratorConfig(dynamic=True, moving_obstacle=True)
    try:
        for seed in range(seeds):
            before = sum(drop_times)
            t0 = time.perf_counter()
            try:
                scenario = rooms.generate_scenario(seed, config)
            except rooms.GenerationError:
                failures += 1
                continue
            total = time.perf_counter() - t0
            totals.append(total)
            layouts.append(total - (sum(drop_times) - before))
            n_objects.append(len(scenario.objects))
            pedestrians += any(e.name == "pedestrian" for e in scenario.dynamic_events)
    finally:
        rooms.drop_object = original
    return {
        "scenarios": len(totals),
        "generation_failures": failures,
        "scenario_s_mean": statistics.mean(totals),
        "scenario_s_max": max(totals),
        "layout_s_mean": statistics.mean(layouts),
        "objects_mean": statistics.mean(n_objects),
        "drop_ms_mean": 1e3 * statistics.mean(drop_times),
        "drop_ms_p90": 1e3 * float(np.percentile(drop_times, 90)),
        "drops_per_object": len(drop_times) / max(1, sum(n_objects)),
        "drop_accept_rate": float(np.mean(accepted)),
        "pedestrian_placed_rate": pedestrians / max(1, len(totals)),
    }


def bench_drop_contact_models() -> dict:
    top = WorldBox("table/top", np.array([0.0, 0.0, 0.7]), np.eye(3), np.array([0.5, 0.4, 0.02]))
    out = {}
    for label, modulus in (("hydroelastic", 1.0e6), ("point_reference", None)):
        geometry = SceneGeometryConfig(hydroelastic_modulus=modulus)
        times, tilts, accepted = [], [], 0
        for name in DROP_OBJECTS:
            t0 = time.perf_counter()
            result = drop_object(name, top, 0.72, np.array([0.1, 0.0]), 0.3, (), DropCheckConfig(), geometry)
            times.append(time.perf_counter() - t0)
            accepted += result.accepted
            tilts.append(float(np.degrees(np.hypot(result.rpy[0], result.rpy[1]))))
        out[f"drop_{label}_ms_mean"] = 1e3 * statistics.mean(times)
        out[f"drop_{label}_accepted"] = accepted
        out[f"drop_{label}_tilt_deg_max"] = max(tilts)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--seeds", type=int, default=6)
    args = parser.parse_args()
    t0 = time.perf_counter()
    for name in YCB_OBJECTS:  # convert once, outside the timings
        load_ycb_asset(name)
    metrics = {"benchmark": "scenario_generation", "ycb_cache_s": time.perf_counter() - t0}
    metrics.update(bench_drop_contact_models())
    metrics.update(bench_generation(args.seeds))
    metrics = {k: round(v, 4) if isinstance(v, float) else v for k, v in metrics.items()}
    if args.json:
        print(json.dumps(metrics))
    else:
        for k, v in metrics.items():
            print(f"{k:32s} {v}")


if __name__ == "__main__":
    main()
