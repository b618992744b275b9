"""The PA-Acc budget: scaled skeleton error, offline smoothing, the held-out runs behind them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("live.body.library")

from live.evaluation.retarget import held_out_runs  # noqa: E402
from research.acc_budget import budget, format_budget, scaled_error, smoothed  # noqa: E402

BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bvh"
CLIP = "mb_12_01.bvh"  # held-out subject 12


def test_scaled_error_keeps_the_error_and_scales_it():
    rng = np.random.default_rng(0)
    truth, estimate = rng.normal(size=(2, 5, 22, 3))
    np.testing.assert_allclose(scaled_error(estimate, truth, 1.0), estimate)
    np.testing.assert_allclose(scaled_error(estimate, truth, 0.0), truth)
    half = scaled_error(estimate, truth, 0.5)
    np.testing.assert_allclose(half - truth, 0.5 * (estimate - truth))


def test_smoothing_keeps_steady_motion_and_damps_jitter():
    t = np.arange(40, dtype=np.float64)
    steady = np.stack([t, 2 * t, -t], axis=-1)[:, None, :] * 0.01  # (T, 1, 3), constant velocity
    np.testing.assert_allclose(smoothed(steady, 1.5)[8:-8], steady[8:-8], atol=1e-12)
    jitter = steady + 0.01 * (-1.0) ** t[:, None, None]
    acc = lambda x: np.abs(x[2:] - 2 * x[1:-1] + x[:-2]).max()  # noqa: E731
    assert acc(smoothed(jitter, 1.0)[8:-8]) < 0.1 * acc(jitter[8:-8])


def test_held_out_runs_pair_each_body_with_the_next():
    if not (BVH / CLIP).is_file():
        pytest.skip("no CMU clips in ../shared")
    runs = list(held_out_runs((CLIP,), max_frames=5, seed=3))
    assert len(runs) == 4 and [r.seed for r in runs] == [3, 4, 5, 6]
    names = [r.source.name for r in runs]
    assert [r.target.name for r in runs] == names[1:] + names[:1]
    assert all(r.motion.num_frames == 5 for r in runs)


def test_budget_on_a_short_clip():
    """Exact joints (error x 0) score 0 at the skeleton; the shipped stage does not; both
    retargeters run behind every variant."""
    if not (BVH / CLIP).is_file():
        pytest.skip("no CMU clips in ../shared")
    result = budget((CLIP,), max_frames=8, alphas=(1.0, 0.0), sigmas=(1.0,))
    assert result["runs"] == 4
    v = result["variants"]
    assert set(v) == {"as shipped", "error x 0", "offline Gaussian, sigma 1 frames"}
    assert v["error x 0"]["skeleton"] == {"mpjpe": 0.0, "pa_acc_mm_per_frame2": pytest.approx(0.0, abs=1e-12)}
    assert 0.005 < v["as shipped"]["skeleton"]["mpjpe"] < 0.2
    for row in v.values():
        for kind in ("analytic", "learned"):
            assert np.isfinite(row[kind]["mpjpe"]) and row[kind]["pa_acc_mm_per_frame2"] >= 0
    assert result["truth"]["acc_mm_per_frame2"] > 0
    table = format_budget(result)
    assert "| as shipped |" in table and "4 runs" in table
