"""Latency and throughput accounting for stats.json."""

from __future__ import annotations

import numpy as np

from live.core.report import latency_summary

_MAX_SAMPLES = 200_000


class LatencyRecorder:
    """Collects latencies (ms) with bounded memory: past _MAX_SAMPLES it keeps a uniform
    reservoir sample (seeded, so the figures of a replay do not depend on luck)."""

    def __init__(self) -> None:
        self._values: list[float] = []
        self.count = 0
        self._rng = np.random.default_rng(0)

    def add(self, ms: float) -> None:
        self.count += 1
        if len(self._values) < _MAX_SAMPLES:
            self._values.append(ms)
        else:
            k = int(self._rng.integers(0, self.count))
            if k < _MAX_SAMPLES:
                self._values[k] = ms

    def summary(self) -> dict[str, float | int]:
        """count (all measured), then mean, p50, p95, p99, max (ms) of the kept sample."""
        return latency_summary(self._values, count=self.count)


class StageStats:
    def __init__(self, name: str) -> None:
        self.name = name
        self.frames_in = 0
        self.frames_out = 0
        self.errors = 0
        self.latency = LatencyRecorder()

    def as_dict(self) -> dict:
        return {"frames_in": self.frames_in, "frames_out": self.frames_out, "errors": self.errors,
                "latency_ms": self.latency.summary()}
