"""Fault injection for the runner's isolation tests: episodes that crash, hang or raise.

Module-level so that spawned worker processes can import them (they inherit sys.path).
"""

import os
import time


def crashing_episode(spec):
    os._exit(7)  # the process dies without a word, as a segfault in a solver would


def hanging_episode(spec):
    time.sleep(3600)


def raising_episode(spec):
    raise RuntimeError(f"boom in {spec.key}")


def quick_episode(spec):
    """An episode that ends at once with a paper category (no simulation)."""
    return {"scenario": spec.scenario_id, "status": "collision", "detail": "quick", "sim_time": 1.0}
