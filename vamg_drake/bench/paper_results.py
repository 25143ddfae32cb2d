"""The paper's simulation results (appendix Table "Simulation evaluation results").

Success and failure categories in % of 400 episodes per method and suite
("Unknown Environment" is our ``static`` suite, "Dynamic Environment" our
``dynamic`` suite), keyed like `vamg_drake.bench.results.CATEGORIES`, so
that ``vamg report`` can set each measured row beside the paper's.
"""

#: Episodes per method and suite in the paper.
PAPER_EPISODES = 400

_COLUMNS = ("success", "collision", "grasp", "ik", "reachability", "perception", "planning")
_ROWS = {
    "static": {
        "nav_and_manip": (46.00, 17.50, 15.75, 0.00, 0.00, 0.25, 20.50),
        "capmap_placement": (44.25, 23.25, 14.50, 0.00, 0.25, 0.50, 17.25),
        "direct_grasping": (28.25, 3.25, 4.00, 8.75, 1.75, 0.75, 53.25),
        "closed_loop_replanning": (61.25, 6.75, 15.25, 0.75, 0.50, 0.25, 15.25),
        "velocity_agnostic": (63.75, 8.00, 15.50, 0.25, 2.50, 0.25, 9.75),
        "full": (68.75, 6.25, 13.25, 0.50, 2.25, 0.25, 8.75),
    },
    "dynamic": {
        "nav_and_manip": (40.00, 24.75, 14.25, 0.00, 0.00, 1.50, 19.50),
        "capmap_placement": (40.00, 23.50, 13.00, 0.00, 0.00, 1.25, 22.25),
        "direct_grasping": (25.75, 1.50, 2.00, 5.75, 1.00, 0.75, 63.25),
        "closed_loop_replanning": (56.75, 8.50, 14.75, 0.50, 0.75, 0.25, 18.50),
        "velocity_agnostic": (54.00, 13.75, 15.50, 0.75, 3.25, 0.00, 12.75),
        "full": (58.00, 9.75, 16.00, 0.00, 2.25, 0.00, 14.00),
    },
}
#: (suite, method) -> {category: % of the paper's episodes}.
PAPER_RESULTS: dict[tuple[str, str], dict[str, float]] = {
    (suite, method): dict(zip(_COLUMNS, values)) for suite, rows in _ROWS.items() for method, values in rows.items()
}

#: Our suites that run the paper's own suites: its authors' task file
#: (``paper_static``, ``paper_dynamic``) and our procedural rooms.
SUITE_OF_PAPER = {"static": "static", "dynamic": "dynamic", "paper_static": "static", "paper_dynamic": "dynamic"}
#: Our variants of a paper method that its row compares with (the map seeded
#: with the static apartment, as the authors' released runner does).
METHOD_OF_PAPER = {"full_prior_map": "full"}


def paper_row(suite: str, method: str) -> dict[str, float] | None:
    """The paper's percentages for our (suite, method), or None where it reports none."""
    paper_suite = SUITE_OF_PAPER.get(suite)
    if paper_suite is None:
        return None
    return PAPER_RESULTS.get((paper_suite, METHOD_OF_PAPER.get(method, method)))

