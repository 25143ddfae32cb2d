"""The benchmark: scenario suites, methods, an isolated resumable runner, metrics and report.

* ``suites``: smoke / static / dynamic / dynamic_moving / trigger_sweep, validated
  (drop check in the generator, ``validate_scenario``, ``oracle_grasp``).
* ``methods``: the full system and the paper's baselines as ``DiagramConfig`` YAML files.
* ``runner``: ``vamg bench`` (process per episode, wall-clock limit, ``--resume``, Ray).
* ``results``: ``results.jsonl`` (fsynced lines, truncated-tail repair, the category list).
* ``metrics``: Wilson intervals, SPL and its grid shortest path.
* ``report``: ``vamg report`` (report.md + PNG plots).
"""
