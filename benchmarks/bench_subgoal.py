"""Speed and completeness of the subgoal samplers.

Workload (seeded): ``--problems`` table-top scenes (a walled 6 m room, a table
of random size, height and position, a can at a random spot on it, up to three
clutter boxes on the table near the can and up to three pieces of furniture,
the robot stowed at a random free start >= 1.5 m away). Per problem:

* pregrasp: `PregraspSampler.sample` with the paper's budget (20 bases x 128),
  first valid sample returned (the collision environment is built beforehand
  and timed separately as collision_env_ms);
* grasp_candidates: `AntipodalGraspSampler.propose` on the map points within
  0.3 m of the target (the paper's Contact-GraspNet takes 1.2 s on a GPU);
* completeness: a problem is *solvable* when any of ``--reference-seeds`` runs
  with 8,192 samples solves it; for each budget N the fraction of the solvable
  problems solved with N samples (``--seeds`` seeds each) is reported
  (paper: ~95% near 2,000 samples).

References in the same run: Drake `InverseKinematics` (SNOPT) against the
batched Numba `FastIk` on the same arm-only targets; and a map-free pre-grasp
sampler (no capability filter, uniform torso height, uniform base cells) on
the same solvable problems and budget (``ablation_*``).

Usage: python benchmarks/bench_subgoal.py [--json] [--problems N] [--seeds S]
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import json
import time

import numpy as np

from vamg_drake.testing import synthetic_clouds
from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.policy.grasp_candidates import AntipodalGraspSampler
from vamg_drake.policy.ik import DrakeIk, FastIk
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.pregrasp_sampler import BaseCostmap, PregraspSampler
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics

BUDGETS = (32, 64, 128, 256, 512, 1024, 2048, 2560, 4096)
REFERENCE_BUDGET = 8192


def make_problem(rng: np.random.Generator):
    """A random cluttered table-top scene: (points, target, q_start)."""
    half = 3.0
    size = (rng.uniform(0.5, 0.9), rng.uniform(0.6, 1.4))
    center = rng.uniform(-half + 1.0, half - 1.0, 2)
    height = rng.uniform(0.45, 0.9)
    offset = (rng.uniform(-0.5, 0.5) * (size[0] - 0.1), rng.uniform(-0.5, 0.5) * (size[1] - 0.1))
    points, target = synthetic_clouds.tabletop_scene(tuple(center), size, height, offset, room_half_size=half)
    parts = [points]
    # Clutter on the table near the target (not on it).
    for _ in range(rng.integers(0, 4)):
        while True:
            xy = target[:2] + rng.uniform(-0.3, 0.3, 2)
            if np.linalg.norm(xy - target[:2]) > 0.12 and np.all(np.abs(xy - center) < np.array(size) / 2 - 0.04):
                break
        h = rng.uniform(0.05, 0.3)
        parts.append(synthetic_clouds.box_surface_cloud([*(xy - 0.04), height], [*(xy + 0.04), height + h], 0.02))
    # Furniture around the table.
    for _ in range(rng.integers(0, 4)):
        lo = rng.uniform(-half, half - 0.6, 2)
        hi = lo + rng.uniform(0.3, 0.8, 2)
        if np.all(hi > center - np.array(size) / 2 - 0.3) and np.all(lo < center + np.array(size) / 2 + 0.3):
            continue
        parts.append(synthetic_clouds.box_surface_cloud([*lo, 0.0], [*hi, rng.uniform(0.4, 1.2)]))
    points = np.concatenate(parts)
    while True:
        start = rng.uniform(-half + 0.5, half - 0.5, 2)
        clear = np.min(np.linalg.norm(points[:, :2] - start, axis=1)) > 0.45
        if clear and np.linalg.norm(start - target[:2]) >= 1.5:
            break
    return points, target, layout.stow_configuration(start[0], start[1], rng.uniform(-np.pi, np.pi))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--problems", type=int, default=20)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--reference-seeds", type=int, default=2)
    parser.add_argument("--ik-reference", type=int, default=40, help="targets solved by both IK solvers")
    args = parser.parse_args()

    t0 = time.perf_counter()
    maps = KinematicMaps.load_or_build()
    maps_load_s = time.perf_counter() - t0
    pipeline = SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max)
    sampler: PregraspSampler = pipeline.pregrasp
    grasp_source = AntipodalGraspSampler()
    rng = np.random.default_rng(2024)
    problems = [make_problem(rng) for _ in range(args.problems)]

    # Warm-up (JIT compilation) outside the timings.
    pts, target, q0 = problems[0]
    sampler.sample(pts, target, q0, pipeline.collision_fn(pts, target, q0), np.random.default_rng(0), max_samples=128)
    grasp_source.propose(pts[np.linalg.norm(pts - target, axis=1) < 0.3], target)

    pregrasp_ms, pregrasp_ok, env_ms, grasp_ms, n_grasps = [], [], [], [], []
    solved_at = {n: [] for n in BUDGETS}
    solvable = []
    for i, (pts, target, q0) in enumerate(problems):
        t = time.perf_counter()
        is_free = pipeline.collision_fn(pts, target, q0)
        costmap = BaseCostmap.from_points(pts, sampler.config.costmap, include_xy=np.stack([target[:2], q0[:2]]), robot_xy=q0[:2])
        env_ms.append(1e3 * (time.perf_counter() - t))
        t = time.perf_counter()
        r = sampler.sample(pts, target, q0, is_free, np.random.default_rng(100 + i), costmap=costmap)
        pregrasp_ms.append(1e3 * (time.perf_counter() - t))
        pregrasp_ok.append(r.success)
        cloud = pts[np.linalg.norm(pts - target, axis=1) < 0.3]
        t = time.perf_counter()
        g = grasp_source.propose(cloud, target, np.random.default_rng(i))
        grasp_ms.append(1e3 * (time.perf_counter() - t))
        n_grasps.append(len(g))
        ok_ref = r.success or any(
            sampler.sample(pts, target, q0, is_free, np.random.default_rng(1000 + 17 * i + s), REFERENCE_BUDGET, costmap).success
            for s in range(args.reference_seeds)
        )
        solvable.append(ok_ref)
        if not ok_ref:
            continue
        for n in BUDGETS:
            for s in range(args.seeds):
                res = sampler.sample(pts, target, q0, is_free, np.random.default_rng(5000 + 31 * i + s), n, costmap)
                solved_at[n].append(res.success)

    curve = {str(n): round(float(np.mean(v)), 3) if v else None for n, v in solved_at.items()}

    # Ablation: the same sampler without the kinematic maps and the cost weighting.
    plain = PregraspSampler(maps, pipeline.ik, pipeline.visibility,
                            dc.replace(sampler.config, use_capability=False, use_torso_map=False, weight_bases=False))
    ablation_ok, ablation_ms = [], []
    for i, (pts, target, q0) in enumerate(problems):
        if not solvable[i]:
            continue
        is_free = pipeline.collision_fn(pts, target, q0)
        for s in range(args.seeds):
            t = time.perf_counter()
            res = plain.sample(pts, target, q0, is_free, np.random.default_rng(5000 + 31 * i + s), 2560)
            ablation_ms.append(1e3 * (time.perf_counter() - t))
            ablation_ok.append(res.success)

    # IK reference: Drake InverseKinematics vs FastIk on the same arm-only targets.
    krng = np.random.default_rng(7)
    q = krng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (args.ik_reference, layout.NQ))
    X = FetchKinematics.instance().gripper_pose(q)
    seeds = np.tile(layout.stow_configuration(0, 0, 0), (args.ik_reference, 1))
    seeds[:, :4] = q[:, :4]
    fast = FastIk()
    fast.solve_arm(X[:2], seeds[:2])
    t = time.perf_counter()
    _, ok_fast = fast.solve_arm(X, seeds)
    fast_us = 1e6 * (time.perf_counter() - t) / args.ik_reference
    drake = DrakeIk()
    t = time.perf_counter()
    ok_drake = [drake.solve(X[k], seeds[k])[1] for k in range(args.ik_reference)]
    drake_ms = 1e3 * (time.perf_counter() - t) / args.ik_reference

    result = {
        "problems": args.problems,
        "pregrasp_ms_median": round(float(np.median(pregrasp_ms)), 1),
        "pregrasp_ms_p90": round(float(np.percentile(pregrasp_ms, 90)), 1),
        "pregrasp_success_rate": round(float(np.mean(pregrasp_ok)), 3),
        "collision_env_ms_median": round(float(np.median(env_ms)), 1),
        "grasp_candidates_ms_median": round(float(np.median(grasp_ms)), 1),
        "grasp_candidates_found_rate": round(float(np.mean(np.array(n_grasps) > 0)), 3),
        "solvable_problems": int(np.sum(solvable)),
        "completeness_curve": curve,
        "completeness_at_2560": curve["2560"],
        "ablation_no_maps_completeness_at_2560": round(float(np.mean(ablation_ok)), 3) if ablation_ok else None,
        "ablation_no_maps_ms_median": round(float(np.median(ablation_ms)), 1) if ablation_ms else None,
        "ik_fast_us_per_solve": round(fast_us, 1),
        "ik_fast_success": round(float(np.mean(ok_fast)), 3),
        "ik_drake_ms_per_solve": round(drake_ms, 2),
        "ik_drake_success": round(float(np.mean(ok_drake)), 3),
        "maps_load_s": round(maps_load_s, 2),
        "maps_reach_build_s": maps.metadata.get("reach_build_s"),
        "maps_torso_build_s": maps.metadata.get("torso_build_s"),
        "maps_reach_voxels": maps.metadata.get("reach_voxels"),
        "paper": {"pregrasp_ms": 369, "grasp_candidates_ms": 1200, "completeness_near_2000": 0.95},
    }
    if not args.json:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
