"""A loaded machine on demand: processes that spin NumPy beside a measurement.

Used to check that an episode does not depend on the machine's load
(`benchmarks/bench_episode.py`, tests/test_determinism.py): the same scenario,
config and code must give the same episode with or without them.
"""

import contextlib
import multiprocessing as mp

import numpy as np


def _spin(stop) -> None:
    """Elementwise NumPy work (no BLAS threads) until `stop` is set."""
    a = np.linspace(0.0, 1.0, 1 << 16)
    while not stop.is_set():
        for _ in range(50):
            np.sin(a, out=a)
            np.add(a, 1.0, out=a)


@contextlib.contextmanager
def busy_cpu(processes: int = 1):
    """Keeps `processes` CPU-bound processes running during the with-block.

    They are spawned (not forked), so they share nothing with the caller's
    simulation state or threads."""
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    procs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(processes)]
    for p in procs:
        p.start()
    try:
        yield
    finally:
        stop.set()
        for p in procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join()
