"""Whole-body planner: plans are valid in Drake's exact geometry, failures say why."""

import numpy as np
import pytest

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.testing.planning_problems import make_problem
from vamg_drake.planning.whole_body_planner import FailureReason, PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout

# Generous budgets: tests check correctness, benchmarks/bench_planner.py speed.
CONFIG = PlannerConfig(attempt_wall_limit_s=5.0)


@pytest.fixture(scope="module")
def base_checker():
    return SphereCollisionChecker.for_fetch(CollisionEnvironment())


def _dense_1cm(q: np.ndarray, checker: SphereCollisionChecker) -> np.ndarray:
    from vamg_drake.planning.sphere_collision import densify

    return densify(q, checker, resolution=0.01)


@pytest.mark.parametrize("seed", [4, 7])
def test_plan_in_generated_room_is_free_in_drake_exact_geometry(seed, base_checker):
    from vamg_drake.testing.drake_reference import DrakeCollisionWorld

    problem = make_problem(seed, base_checker)
    env = CollisionEnvironment.from_primitives(problem.obstacles).voxelized(0.03)  # the map's view
    planner = WholeBodyPlanner.for_fetch(env, CONFIG)
    result = planner.plan(problem.q_start, problem.q_goal)
    assert result.success, result.message
    traj = result.trajectory
    np.testing.assert_allclose(traj.q[0], problem.q_start)
    np.testing.assert_allclose(layout.wrap_configuration(traj.q[-1]), layout.wrap_configuration(problem.q_goal),
                               atol=1e-9)
    assert traj.max_rate_ratio() <= 1.0 + 1e-9
    drake = DrakeCollisionWorld(problem.obstacles)
    dense = _dense_1cm(traj.q, planner.checker)
    assert np.all(layout.within_limits(dense))
    colliding = [i for i, q in enumerate(dense) if drake.in_collision(q)]
    assert colliding == []


@pytest.mark.parametrize("seed", [3])
def test_plan_in_procedural_room_is_free_in_drake_exact_geometry(seed, base_checker):
    """The benchmark's workload: a `generate_scenario` room, goal at the target."""
    from vamg_drake.testing.drake_reference import DrakeCollisionWorld
    from vamg_drake.testing.planning_problems import room_problem

    problem = room_problem(seed, base_checker)
    assert problem.blocked  # furniture between start and goal
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(problem.obstacles), CONFIG)
    result = planner.plan(problem.q_start, problem.q_goal)
    assert result.success, result.message
    dense = _dense_1cm(result.trajectory.q, planner.checker)
    assert np.all(layout.within_limits(dense))
    drake = DrakeCollisionWorld(problem.obstacles)
    assert [i for i, q in enumerate(dense) if drake.in_collision(q)] == []


def test_same_seed_gives_the_same_plan(base_checker):
    problem = make_problem(8, base_checker)
    env = CollisionEnvironment.from_primitives(problem.obstacles)
    a = WholeBodyPlanner.for_fetch(env, CONFIG).plan(problem.q_start, problem.q_goal)
    b = WholeBodyPlanner.for_fetch(env, CONFIG).plan(problem.q_start, problem.q_goal)
    assert a.success and b.success
    np.testing.assert_array_equal(a.trajectory.q, b.trajectory.q)
    np.testing.assert_array_equal(a.trajectory.times, b.trajectory.times)


def test_infeasible_and_bad_input_fail_fast_with_reason(base_checker):
    problem = make_problem(4, base_checker)
    env = CollisionEnvironment.from_primitives(problem.obstacles)
    planner = WholeBodyPlanner.for_fetch(env, CONFIG)
    qs, qg = problem.q_start, problem.q_goal
    inside_table = qg.copy()
    table = next(b for b in problem.obstacles if b.name == "table/base")
    inside_table[:2] = table.p_WB[:2]
    cases = {
        FailureReason.GOAL_IN_COLLISION: (qs, inside_table),
        FailureReason.START_IN_COLLISION: (inside_table, qg),
    }
    nan_goal = qg.copy()
    nan_goal[5] = np.nan
    out_of_limits = qg.copy()
    out_of_limits[layout.TORSO] = 0.9
    for reason, (a, b) in cases.items():
        r = planner.plan(a, b)
        assert not r.success and r.reason == reason and r.trajectory is None
        assert r.timings["total"] < 100.0
    for bad, field in [(nan_goal, "shoulder_lift_joint"), (out_of_limits, "torso_lift_joint")]:
        r = planner.plan(qs, bad)
        assert r.reason == FailureReason.INVALID_INPUT and field in r.message
    r = planner.plan(qs, np.zeros(7))
    assert r.reason == FailureReason.INVALID_INPUT and "11" in r.message


def test_walled_in_goal_reports_no_base_path(base_checker):
    from vamg_drake.world.primitives import WorldBox

    walls = [WorldBox(f"pen/{k}", np.array(c, float), np.eye(3), np.array(h, float)) for k, (c, h) in enumerate([
        ([3.0, 1.0, 0.5], [1.0, 0.05, 0.5]), ([3.0, 3.0, 0.5], [1.0, 0.05, 0.5]),
        ([2.0, 2.0, 0.5], [0.05, 1.0, 0.5]), ([4.0, 2.0, 0.5], [0.05, 1.0, 0.5])])]
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(walls), CONFIG)
    r = planner.plan(layout.stow_configuration(0.0, 0.0, 0.0), layout.stow_configuration(3.0, 2.0, 0.0))
    assert not r.success and r.reason == FailureReason.NO_BASE_PATH


def test_empty_map_plans_and_replan_check_sees_new_obstacles():
    from vamg_drake.world.primitives import WorldBox

    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_points(np.zeros((0, 3))), CONFIG)
    qs = layout.stow_configuration(0.0, 0.0, 0.0)
    qg = layout.stow_configuration(2.0, 0.0, 0.0)
    r = planner.plan(qs, qg)
    assert r.success
    assert planner.trajectory_is_valid(r.trajectory)
    blocker = WorldBox("new", np.array([1.0, 0.0, 0.5]), np.eye(3), np.array([0.1, 0.1, 0.5]))
    planner.set_environment(CollisionEnvironment.from_primitives([blocker]))
    assert not planner.trajectory_is_valid(r.trajectory)


def test_door_too_narrow_for_the_base_ends_at_the_search_limit(base_checker):
    """The 2D relaxation lets the search through a 0.62 m door that the base's
    footprint cannot pass: the expansion-capped search gives up (no hang).
    (A 0.68 m door is passable: the base's spheres are 0.31 m in radius.)"""
    from vamg_drake.world.primitives import WorldBox

    door, g = 0.62, np.array([3.0, 2.0])
    side = (0.75 - door / 2) / 2
    walls = [WorldBox(f"pen/{k}", np.array([*c, 0.5], float), np.eye(3), np.array([*h, 0.5], float))
             for k, (c, h) in enumerate([
                 (g + [0.0, -0.7], [0.75, 0.05]), (g + [0.0, 0.7], [0.75, 0.05]), (g + [0.7, 0.0], [0.05, 0.75]),
                 (g + [-0.7, -(door / 2 + side)], [0.05, side]), (g + [-0.7, door / 2 + side], [0.05, side])])]
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(walls), CONFIG)
    r = planner.plan(layout.stow_configuration(0.0, 2.0, 0.0), layout.stow_configuration(*g, 0.0))
    assert not r.success and r.reason == FailureReason.NO_BASE_PATH, r.message
    assert "search" in r.message  # the search ran (the 2D relaxation did not rule it out)


def test_warm_up_does_not_change_the_plan(base_checker):
    """`warm_up` only loads the compiled kernels: the same plan after it."""
    from vamg_drake.testing.planning_problems import room_problem

    problem = room_problem(3, base_checker)
    env = CollisionEnvironment.from_primitives(problem.obstacles)
    cold = WholeBodyPlanner.for_fetch(env, CONFIG).plan(problem.q_start, problem.q_goal)
    planner = WholeBodyPlanner.for_fetch(env, CONFIG)
    planner.warm_up()
    warm = planner.plan(problem.q_start, problem.q_goal)
    assert cold.success and warm.success
    np.testing.assert_array_equal(cold.trajectory.q, warm.trajectory.q)


_COMPILES_AFTER_WARM_UP = """
import sys
import numpy as np
from numba.core.registry import CPUDispatcher
from vamg_drake.planning import (collision_environment, distance_field, hybrid_astar, reeds_shepp, sphere_checks,
                                 sphere_collision, whole_body_planner, whole_body_rrt)
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.whole_body_planner import WholeBodyPlanner
from vamg_drake.robot import kinematics, layout, spheres

def signatures():
    return {(m.__name__, k): len(v.signatures) for m in (collision_environment, distance_field, hybrid_astar,
            reeds_shepp, sphere_checks, sphere_collision, whole_body_planner, whole_body_rrt, kinematics, spheres)
            for k, v in vars(m).items() if isinstance(v, CPUDispatcher)}

planner = WholeBodyPlanner.for_fetch(CollisionEnvironment())
planner.warm_up()
before = signatures()
rng = np.random.default_rng(3)
# A map of points unlike the warm-up's: a cabinet beside the path, a shelf at the goal.
cabinet = np.column_stack([rng.uniform(0.8, 1.4, 3000), rng.uniform(0.5, 1.0, 3000), rng.uniform(0.0, 0.9, 3000)])
shelf = np.column_stack([rng.uniform(2.0, 2.5, 3000), rng.uniform(-1.8, -1.2, 3000), np.full(3000, 0.9)])
planner.set_environment(CollisionEnvironment.from_points(np.concatenate([cabinet, shelf]), resolution=0.05))
q_goal = layout.stow_configuration(2.2, -0.6, -1.2)
q_goal[3:] = [0.2, 0.6, -0.4, 0.3, 1.1, 0.2, 0.9, 0.1]
result = planner.plan(layout.stow_configuration(0.0, 0.0, 0.3), q_goal)
new = sorted(f"{m}.{k}" for (m, k), n in signatures().items() if n > before.get((m, k), 0))
print("success", result.success, result.message)
print("new", new)
sys.exit(1 if new or not result.success else 0)
"""


def test_warm_up_compiles_every_kernel_a_plan_in_a_point_map_needs():
    """After `warm_up`, a plan in a map of points compiles nothing: an
    episode's first plan must not spend its wall-clock safety net compiling
    (run in a fresh process, so earlier tests' compilations do not count)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _COMPILES_AFTER_WARM_UP], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]


def test_fixed_base_searches_between_the_along_path_search_rounds(base_checker):
    """Bench room 26: the along-path search (c) does not connect in its first
    round, the fixed-base searches (d) do; the plan is free in Drake's exact
    geometry at 1 cm."""
    from vamg_drake.testing.drake_reference import DrakeCollisionWorld
    from vamg_drake.testing.planning_problems import room_problem

    problem = room_problem(26, base_checker)
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(problem.obstacles),
                                         PlannerConfig(seed=26, attempt_wall_limit_s=5.0))
    calls = []
    along, carry = planner._along_base_path, planner._via_carry

    def along_spy(*a, **k):
        out = along(*a, **k)
        calls.append(("c", out is not None))
        return out

    def carry_spy(*a, **k):
        out = carry(*a, **k)
        calls.append(("d" if k.get("search", True) else "b", out is not None))
        return out

    planner._along_base_path, planner._via_carry = along_spy, carry_spy
    result = planner.plan(problem.q_start, problem.q_goal)
    assert result.success, result.message
    assert calls[-2:] == [("c", False), ("d", True)], calls
    drake = DrakeCollisionWorld(problem.obstacles)
    assert not any(drake.in_collision(q) for q in _dense_1cm(result.trajectory.q, planner.checker))


def test_refine_joins_pieces_around_a_one_waypoint_piece():
    """A base piece of zero length (one waypoint) between two arm pieces joined
    nothing, and the next piece's join test indexed the empty remainder (static
    s0021 and s0036, nav_and_manip: IndexError in the planner)."""
    from collections import defaultdict

    from vamg_drake.planning.whole_body_planner import _AttemptBudget

    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment(), CONFIG)
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    q1 = q0.copy()
    q1[layout.TORSO] += 0.1
    arm = np.linspace(q0, q1, 4)
    still = q1[None].copy()
    q2 = q1.copy()
    q2[layout.BASE_XY] += 0.2
    drive = np.linspace(q1, q2, 5)
    budget = _AttemptBudget(CONFIG.attempt_budget_iterations, CONFIG.attempt_wall_limit_s)
    path = planner._refine([arm, still, drive], defaultdict(float), np.random.default_rng(0), budget)
    np.testing.assert_allclose(path[0], q0)
    np.testing.assert_allclose(path[-1], q2)
    assert np.all(np.max(np.abs(np.diff(path, axis=0)), axis=1) > 0)  # no repeated waypoint
    with pytest.raises(RuntimeError, match="do not join"):
        planner._refine([arm, drive[1:]], defaultdict(float), np.random.default_rng(0), budget)


def test_the_budget_is_iterations_not_wall_time(base_checker):
    """The same problem gives the same plan on any machine at any load (issue
    19): an attempt's budget counts RRT-Connect iterations; the wall-clock
    limit is a safety net, counted when it fires. Room problem 25: the first
    attempt's searches all fail (1200 iterations), the second connects."""
    from vamg_drake.testing.planning_problems import room_problem

    problem = room_problem(25, base_checker)
    env = CollisionEnvironment.from_primitives(problem.obstacles)
    a, b = (WholeBodyPlanner.for_fetch(env, PlannerConfig(seed=25)).plan(problem.q_start, problem.q_goal)
            for _ in range(2))
    assert a.success and a.attempts == 2 and a.wall_limit_hits == 0
    assert a.rrt_iterations == b.rrt_iterations > 0
    np.testing.assert_array_equal(a.trajectory.q, b.trajectory.q)
    small = WholeBodyPlanner.for_fetch(env, PlannerConfig(seed=25, attempt_budget_iterations=50))
    result = small.plan(problem.q_start, problem.q_goal)
    assert not result.success and result.reason == FailureReason.TIMEOUT, result.message
    assert "RRT-Connect iterations" in result.message and result.rrt_iterations == 150
    stopped = WholeBodyPlanner.for_fetch(env, PlannerConfig(seed=25, attempt_wall_limit_s=0.0))
    result = stopped.plan(problem.q_start, problem.q_goal)
    assert not result.success and result.reason == FailureReason.TIMEOUT
    assert result.wall_limit_hits == stopped.wall_limit_hits == 3
