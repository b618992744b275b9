"""Consecutive-frame data for the temporal skeleton model: seeded, cached, extendable."""

from __future__ import annotations

import numpy as np


def test_more_sequences_extend_the_cached_ones(tmp_path, monkeypatch, shared_bvh):
    import sim.skeleton_sequences as seq

    monkeypatch.setattr(seq, "CACHE_DIR", tmp_path)
    small = seq.generate_sequences("val", 1, seed=5)
    assert len(list(tmp_path.glob("seq_val_1_5_*.npz"))) == 1
    calls = []
    real = seq.run_jobs
    monkeypatch.setattr(seq, "run_jobs", lambda fn, jobs, *a, **k: calls.append(len(jobs)) or real(fn, jobs, *a, **k))
    more = seq.generate_sequences("val", 2, seed=5)
    assert calls == [1]  # only the new sequence was rendered
    fresh = seq.generate_sequences("val", 2, seed=5, cache=False)
    for key in fresh:
        np.testing.assert_array_equal(more[key], fresh[key], err_msg=key)
        np.testing.assert_array_equal(more[key][:1], small[key], err_msg=key)
    assert more["found"].shape == (2, seq.SEQUENCE_FRAMES)
