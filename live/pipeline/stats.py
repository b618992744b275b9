"""Latency and throughput accounting for stats.json."""

from __future__ import annotations

import numpy as np

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
        if not self._values:
            return {"count": 0}
        v = np.asarray(self._values, dtype=np.float64)
        p50, p95, p99 = np.percentile(v, [50, 95, 99])
        return {"count": self.count, "mean": round(float(v.mean()), 4), "p50": round(float(p50), 4),
                "p95": round(float(p95), 4), "p99": round(float(p99), 4), "max": round(float(v.max()), 4)}


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
