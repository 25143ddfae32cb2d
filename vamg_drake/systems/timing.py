"""ModuleTimings: wall-clock timings of the diagram's modules, for episode.json."""

from __future__ import annotations

import numpy as np


class ModuleTimings:
    """Collects per-module call durations [ms]."""

    def __init__(self) -> None:
        self.samples: dict[str, list[float]] = {}

    def add(self, module: str, ms: float) -> None:
        self.samples.setdefault(module, []).append(float(ms))

    def clear(self) -> None:
        """Forgets every sample (a new episode on the same diagram)."""
        self.samples.clear()

    def summary(self) -> dict[str, dict[str, float]]:
        """{module: {count, median_ms, p95_ms, total_ms}}."""
        out = {}
        for name, values in sorted(self.samples.items()):
            a = np.asarray(values)
            out[name] = dict(
                count=int(a.size),
                median_ms=float(np.median(a)),
                p95_ms=float(np.percentile(a, 95)),
                total_ms=float(a.sum()),
            )
        return out
