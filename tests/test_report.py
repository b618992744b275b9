"""Latency summaries: one computation for stats.json, livecap eval and the benchmarks."""

from __future__ import annotations

import numpy as np

from live.core.report import PERCENTILES, latency_summary, p50_p95, percentiles
from live.pipeline.stats import LatencyRecorder


def test_latency_summary_is_numpys_percentiles():
    v = np.random.default_rng(0).gamma(2.0, 3.0, size=997)
    s = latency_summary(v)
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    assert list(s) == ["count", "mean", "p50", "p95", "p99", "max"]
    assert s == {"count": 997, "mean": round(float(v.mean()), 4), "p50": round(float(p50), 4),
                 "p95": round(float(p95), 4), "p99": round(float(p99), 4), "max": round(float(v.max()), 4)}
    assert latency_summary([]) == {"count": 0}
    assert latency_summary(v[:10], count=50)["count"] == 50
    assert latency_summary([1.0, 2.0], digits=None)["mean"] == 1.5


def test_percentiles_one_by_one_or_together_agree():
    v = list(np.random.default_rng(1).normal(5, 2, size=301))
    assert percentiles(v, digits=3) == {f"p{q}": round(float(np.percentile(v, q)), 3) for q in PERCENTILES}
    assert list(percentiles(v, (50, 95))) == ["p50", "p95"]
    assert percentiles(v, (99.9,)).keys() == {"p99.9"}
    assert percentiles([]) == {}


def test_the_pipeline_recorder_reports_through_it():
    rec = LatencyRecorder()
    for ms in (3.0, 1.0, 2.0, 10.0):
        rec.add(ms)
    assert rec.summary() == latency_summary([3.0, 1.0, 2.0, 10.0])
    assert p50_p95(rec.summary()) == "2.50 / 8.95"
