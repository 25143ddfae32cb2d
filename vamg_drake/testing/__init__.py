"""Seeded workloads and references for the tests and benchmarks.

Synthetic point clouds, whole-body planning problems in procedural rooms, a
Drake SceneGraph collision reference and closed-loop tracking rollouts. The
product never imports this package (the top layer of
`tests/test_import_structure.py`).
"""
