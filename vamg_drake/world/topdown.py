"""Top-down plot of an episode: room, furniture, objects, target, robot path."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vamg_drake.world.scenario import AppearAtDistance, AppearAtPhase, MoveAlongPath, Scenario, static_obstacle_shapes  # noqa: E402


def plot_topdown(
    scenario: Scenario,
    base_path: np.ndarray | None = None,
    out: str | Path | None = None,
    title: str = "",
    ax=None,
):
    """Draws the scenario from above; `base_path` is (N, >=2) base positions."""
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7, 7))
    poly = scenario.room.polygon()
    ax.fill(*np.vstack([poly, poly[:1]]).T, color="#f4f1ea", zorder=0)
    layout = scenario.replicacad_layout()
    if layout is not None:  # the walkable floor of a ReplicaCAD scene
        for i in range(len(layout.navmesh.polygons)):
            nav = layout.navmesh.polygon_xy(i)
            ax.fill(*np.vstack([nav, nav[:1]]).T, color="#dcecd5", zorder=0.5)
    for shape in static_obstacle_shapes(scenario):
        fp = shape.footprint()
        is_wall = shape.name.startswith("wall")
        ax.fill(*np.vstack([fp, fp[:1]]).T, color="#555555" if is_wall else "#b08d57", alpha=0.9 if is_wall else 0.6, zorder=1)
    for obj in scenario.objects:
        is_target = obj.name == scenario.target
        ax.plot(obj.xyz[0], obj.xyz[1], "*" if is_target else "o", color="red" if is_target else "#336",
                ms=14 if is_target else 4, zorder=4, label="target" if is_target else None)
    for event in scenario.dynamic_events:
        if isinstance(event, MoveAlongPath):
            w = np.asarray(event.waypoints)
            ax.plot(w[:, 0], w[:, 1], "--", color="purple", zorder=3)
        elif isinstance(event, (AppearAtDistance, AppearAtPhase)):
            ax.plot(event.xyz[0], event.xyz[1], "x", color="purple", ms=10, mew=2, zorder=3)
    s = scenario.robot_start
    ax.plot(s.x, s.y, "o", color="green", ms=10, zorder=5, label="start")
    ax.arrow(s.x, s.y, 0.4 * np.cos(s.yaw), 0.4 * np.sin(s.yaw), width=0.03, color="green", zorder=5)
    if base_path is not None and len(base_path):
        p = np.asarray(base_path)
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:blue", lw=2, zorder=6, label="robot path")
        ax.plot(p[-1, 0], p[-1, 1], "s", color="tab:blue", ms=7, zorder=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or scenario.name)
    ax.legend(loc="upper right", fontsize=8)
    if own:
        fig.tight_layout()
        if out is not None:
            fig.savefig(out, dpi=110)
        plt.close(fig)
    return ax
