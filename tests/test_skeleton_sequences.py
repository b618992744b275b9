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


def test_anny_sequences_cache_apart_and_never_reach_validation(tmp_path, monkeypatch, shared_bvh):
    import sim.skeleton_sequences as seq

    monkeypatch.setattr(seq, "CACHE_DIR", tmp_path)
    assert seq._cache_path("train", 10, 2, anny=64, anny_share=0.7) != seq._cache_path("train", 10, 2)
    assert seq._cache_path("train", 10, 2, anny=64, anny_share=0.0) == seq._cache_path("train", 10, 2)
    # The validation split ignores Anny bodies: its data (and cache) are those without them.
    built = []
    monkeypatch.setattr(seq, "build_bodies", lambda specs, progress: built.append(specs))
    val = seq.generate_sequences("val", 1, seed=5, anny=64, anny_share=1.0)
    assert built == [] and not any(str(b).startswith("anny:") for b in val["body"])
    assert [p.name for p in tmp_path.glob("seq_val_1_5_*.npz")] == [seq._cache_path("val", 1, 5).name]


def test_in_place_sequences_keep_the_performer_on_the_spot_and_the_others_as_they_were(tmp_path, monkeypatch,
                                                                                        shared_bvh):
    import sim.skeleton_sequences as seq

    monkeypatch.setattr(seq, "CACHE_DIR", tmp_path)
    assert seq._cache_path("train", 10, 2, in_place_share=0.3) != seq._cache_path("train", 10, 2)
    assert seq._cache_path("train", 10, 2, in_place_share=0.0) == seq._cache_path("train", 10, 2)
    clips = seq.generate_sequences("val", 3, seed=5, cache=False)
    still = seq.generate_sequences("val", 3, seed=5, cache=False, in_place_share=1.0)
    assert not clips["in_place"].any() and still["in_place"].all()
    np.testing.assert_array_equal(still["clip"], clips["clip"])
    np.testing.assert_array_equal(still["body"], clips["body"])

    def travel(d):  # horizontal pelvis path length per sequence (m)
        return np.linalg.norm(np.diff(d["joints"][:, :, 0, [0, 2]], axis=1), axis=-1).sum(axis=1)

    assert travel(still).max() < 0.5 * travel(clips).max()
