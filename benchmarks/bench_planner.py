"""Benchmark of the whole-body planner on seeded problems in furnished rooms.

Workload: `--problems` (default 50) problems `vamg_drake.testing.planning_problems.room_problem(seed)`,
seeds 0..N-1: the walls and furniture of the procedural room
`vamg_drake.world.rooms.generate_scenario(seed)` (15-50 m^2, rectangular or
L-shaped, 3-12 pieces of furniture), start at the scenario's robot pose, goal
within 0.8 m of the target object (>= 2.5 m from the start, base line of
sight blocked by furniture where such a goal exists: `blocked_fraction`),
random collision-free torso/arm configurations at both ends.

Measured per problem:
  * ours: `WholeBodyPlanner.plan` wall time (and its process CPU time,
    `cpu_*`: less disturbed on a shared machine; `load_average` says how
    shared it was) on a planner just given the room
    (so it includes the per-map 2D base costmap; planning + refinement + time
    parametrization), success, and every successful trajectory re-checked in
    Drake's exact geometry at 1 cm sphere-displacement resolution
    (ground_truth_collisions counts plans with any colliding state).
    `plan_only_median_ms`: a second `plan` of the same problem on the warm
    costmap.
  * reference: OMPL RRTConnect over the same 11-D space (base x, y, theta as
    free coordinates: holonomic, so an easier problem than ours) with a Drake
    SceneGraph validity check (`DrakeCollisionWorld`), a wall-clock budget of
    `--reference-budget` (0.6 s: 3 attempts x 0.2 s, the time budget our
    planner had before its budget became RRT-Connect iterations), no
    simplification.

Our planner's budget is deterministic (`PlannerConfig.attempt_budget_iterations`):
`rrt_iterations_max` is the most any problem used over its attempts, and
`wall_limit_hits` counts attempts stopped by the wall-clock safety net
(nonzero: those plans depend on the machine).

Untimed warm-up: `--warm-up` problems (seeds 10000...) planned after
`WholeBodyPlanner.warm_up()` (numba compiles its kernels, or loads them from
its cache, on first use), and one reference run.

With --json the last line is one JSON object of the metrics.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker, densify
from vamg_drake.testing.drake_reference import DrakeCollisionWorld
from vamg_drake.testing.planning_problems import room_problem
from vamg_drake.planning.whole_body_planner import PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout


def ompl_reference(problem, drake: DrakeCollisionWorld, budget_s: float, resolution: float) -> tuple[bool, float]:
    """(solved, ms) for OMPL RRTConnect with Drake validity checking."""
    from ompl import base as ob
    from ompl import geometric as og

    try:
        from ompl import util as ou

        ou.setLogLevel(ou.LOG_ERROR)
    except (ImportError, AttributeError):
        pass
    n = layout.NQ
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    lo = layout.SAMPLE_LOWER.copy()
    hi = layout.SAMPLE_UPPER.copy()
    corners = np.concatenate([prim.footprint() for prim in problem.obstacles])
    lo[:2], hi[:2] = corners.min(axis=0), corners.max(axis=0)
    for i in range(n):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    space.setLongestValidSegmentFraction(resolution / space.getMaximumExtent())
    ss = og.SimpleSetup(space)
    q = np.empty(n)

    def valid(state) -> bool:
        for i in range(n):
            q[i] = state[i]
        return drake.is_valid(q)

    ss.setStateValidityChecker(valid)
    start, goal = space.allocState(), space.allocState()
    qs = layout.wrap_configuration(problem.q_start)
    qg = layout.wrap_configuration(problem.q_goal)
    for i in range(n):
        start[i] = float(qs[i])
        goal[i] = float(qg[i])
    ss.setStartAndGoalStates(start, goal)
    ss.setPlanner(og.RRTConnect(ss.getSpaceInformation()))
    t0 = time.perf_counter()
    status = ss.solve(budget_s)
    ms = 1e3 * (time.perf_counter() - t0)
    solved = bool(status) and bool(ss.haveExactSolutionPath())
    return solved, ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--problems", type=int, default=50)
    parser.add_argument("--map", action="store_true",
                        help="plan on a 0.03 m voxel map of the room instead of its exact primitives")
    parser.add_argument("--no-reference", action="store_true")
    parser.add_argument("--reference-resolution", type=float, default=0.05,
                        help="OMPL motion-check step in configuration space (joint units)")
    parser.add_argument("--reference-budget", type=float, default=0.6, help="OMPL reference's time budget [s]")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--warm-up", type=int, default=4, help="untimed warm-up problems (seeds 10000...)")
    args = parser.parse_args()

    config = PlannerConfig()
    budget_s = args.reference_budget
    base_checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    rows = []
    # Warm up the JIT (compiles or loads the cache) outside the timings: a
    # few problems, so that the later stages' kernels (along-path and
    # fixed-base searches, exact base-pose zones) are loaded too, and the
    # reference once.
    for k in range(args.warm_up):
        warm = room_problem(10_000 + k, base_checker)
        warm_planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(warm.obstacles), config)
        warm_planner.warm_up()
        warm_planner.plan(warm.q_start, warm.q_goal)
        if k == 0 and not args.no_reference:
            ompl_reference(warm, DrakeCollisionWorld(warm.obstacles), 0.05, args.reference_resolution)
    for seed in range(args.problems):
        problem = room_problem(seed, base_checker)
        env = CollisionEnvironment.from_primitives(problem.obstacles)
        if args.map:
            env = env.voxelized(0.03)
        planner = WholeBodyPlanner.for_fetch(env, PlannerConfig(seed=seed))
        t0, c0 = time.perf_counter(), time.process_time()
        result = planner.plan(problem.q_start, problem.q_goal)
        ms = 1e3 * (time.perf_counter() - t0)
        cpu_ms = 1e3 * (time.process_time() - c0)
        t0 = time.perf_counter()
        planner.plan(problem.q_start, problem.q_goal)  # again, on the warm costmap
        plan_only_ms = 1e3 * (time.perf_counter() - t0)
        drake = DrakeCollisionWorld(problem.obstacles)
        gt_bad = False
        if result.success:
            dense = densify(result.trajectory.q, planner.checker, resolution=0.01)
            gt_bad = any(drake.in_collision(q) for q in dense) or not np.all(layout.within_limits(dense))
        row = dict(seed=seed, success=result.success, reason=result.reason, ms=ms, cpu_ms=cpu_ms,
                   plan_only_ms=plan_only_ms,
                   costmap_ms=result.timings.get("costmap", 0.0), blocked=problem.blocked,
                   attempts=result.attempts, gt_collision=gt_bad, rrt_iterations=result.rrt_iterations,
                   wall_limit_hits=result.wall_limit_hits,
                   duration_s=result.trajectory.duration if result.success else None)
        if not args.no_reference:
            row["ref_success"], row["ref_ms"] = ompl_reference(problem, drake, budget_s, args.reference_resolution)
        rows.append(row)
        if not args.json:
            print(row, flush=True)

    ms = np.array([r["ms"] for r in rows])
    ok = np.array([r["success"] for r in rows])
    metrics = dict(
        problems=len(rows),
        workload="room_problem: generate_scenario(seed) walls+furniture, seeds 0..N-1",
        environment="voxel_map_0.03" if args.map else "exact_primitives",
        success_rate=float(ok.mean()),
        median_ms=float(np.median(ms)),
        p95_ms=float(np.percentile(ms, 95)),
        median_ms_successful=float(np.median(ms[ok])) if ok.any() else None,
        cpu_median_ms=float(np.median([r["cpu_ms"] for r in rows])),
        cpu_p95_ms=float(np.percentile([r["cpu_ms"] for r in rows], 95)),
        load_average=os.getloadavg()[0],
        plan_only_median_ms=float(np.median([r["plan_only_ms"] for r in rows])),
        costmap_median_ms=float(np.median([r["costmap_ms"] for r in rows])),
        blocked_fraction=float(np.mean([r["blocked"] for r in rows])),
        ground_truth_collisions=int(sum(r["gt_collision"] for r in rows)),
        failure_reasons={k: int(sum(r["reason"] == k for r in rows)) for k in sorted({r["reason"] for r in rows if r["reason"]})},
        budget_iterations=config.attempt_budget_iterations,
        max_attempts=config.max_attempts,
        rrt_iterations_max=int(max(r["rrt_iterations"] for r in rows)),
        wall_limit_hits=int(sum(r["wall_limit_hits"] for r in rows)),
    )
    if not args.no_reference:
        ref_ms = np.array([r["ref_ms"] for r in rows])
        ref_ok = np.array([r["ref_success"] for r in rows])
        both = ok & ref_ok
        metrics.update(
            reference="OMPL RRTConnect + Drake SceneGraph point-pair check (holonomic base, no simplification)",
            reference_success_rate=float(ref_ok.mean()),
            reference_median_ms=float(np.median(ref_ms)),
            reference_budget_ms=1e3 * budget_s,
            speedup_vs_reference=float(np.median(ref_ms) / np.median(ms)),
            speedup_on_both_solved=float(np.median(ref_ms[both]) / np.median(ms[both])) if both.any() else None,
        )
    print(json.dumps(metrics))


if __name__ == "__main__":
    main()
