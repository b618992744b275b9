"""Summary figures of a set of measurements (latencies in ms, mostly): percentiles, mean, max.

The one place they are computed, so that stats.json, ``livecap eval`` and the benchmarks report
the same statistic under the same name (linear-interpolation percentiles, numpy's default).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

#: The percentiles every latency report gives.
PERCENTILES = (50, 95, 99)


def _rounded(x: float, digits: int | None) -> float:
    return float(x) if digits is None else round(float(x), digits)


def percentiles(values: Iterable[float], qs: Sequence[float] = PERCENTILES, digits: int | None = None) -> dict[str, float]:
    """{"p50": ..., "p95": ..., "p99": ...} (one key per q) of ``values``; {} when there are none.
    ``digits``: rounded to that many decimals (None: as computed)."""
    a = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=np.float64)
    if not a.size:
        return {}
    return {f"p{q:g}": _rounded(p, digits) for q, p in zip(qs, np.percentile(a, list(qs)))}


def latency_summary(values: Iterable[float], count: int | None = None, digits: int | None = 4) -> dict[str, float | int]:
    """{"count", "mean", "p50", "p95", "p99", "max"} of ``values`` ({"count": 0} when empty).
    ``count``: how many were measured when ``values`` is a sample of them (default len(values))."""
    a = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=np.float64)
    if not a.size:
        return {"count": 0}
    out: dict[str, float | int] = {"count": int(len(a) if count is None else count), "mean": _rounded(a.mean(), digits)}
    out.update(percentiles(a, PERCENTILES, digits))
    out["max"] = _rounded(a.max(), digits)
    return out


def p50_p95(summary: dict) -> str:
    """A summary's median and 95th percentile as the CLI prints them: "1.23 / 4.56"."""
    return f"{summary['p50']:.2f} / {summary['p95']:.2f}"
