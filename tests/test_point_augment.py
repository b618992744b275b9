"""Training-time augmentation of person-frame samples (models/train/point_augment.py): pure numpy."""

from __future__ import annotations

import numpy as np

from models.train.point_augment import Augment, augment_batch, punch_holes, tilt_matrices


def _batch(rng, b=16, n=512):
    pts = rng.normal(0.0, 0.3, (b, n, 3)).astype(np.float32) + np.array([0, 1.0, 0], np.float32)
    jts = rng.normal(0.0, 0.3, (b, 22, 3)).astype(np.float32) + np.array([0, 1.0, 0], np.float32)
    return pts, jts


def test_off_by_default_and_seeded():
    rng = np.random.default_rng(0)
    pts, jts = _batch(rng)
    assert not Augment().active
    aug = Augment(tilt_deg=3, jitter_mm=6, hole_share=0.5)
    a = augment_batch(pts, jts, np.random.default_rng(1), aug)
    b = augment_batch(pts, jts, np.random.default_rng(1), aug)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert a[0].shape == pts.shape and a[1].shape == jts.shape and a[0].dtype == np.float32


def test_tilt_turns_points_and_joints_alike_within_its_clip():
    rng = np.random.default_rng(2)
    r = tilt_matrices(rng, 500, 4.0)
    assert np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    up = np.degrees(np.arccos(np.clip(r[:, 1, 1], -1, 1)))
    assert up.max() <= np.hypot(10.0, 10.0) + 1e-6 and np.median(up) > 1.0
    pts, jts = _batch(rng, b=4)
    p2, j2 = augment_batch(pts, jts, np.random.default_rng(3), Augment(tilt_deg=4))
    # a rigid turn about the origin: each point keeps its distance to each joint
    d0 = np.linalg.norm(pts[:, :5, None] - jts[:, None], axis=-1)
    d1 = np.linalg.norm(p2[:, :5, None] - j2[:, None], axis=-1)
    assert np.allclose(d0, d1, atol=1e-5) and not np.allclose(p2, pts)


def test_jitter_moves_points_not_joints():
    rng = np.random.default_rng(4)
    pts, jts = _batch(rng)
    p2, j2 = augment_batch(pts, jts, rng, Augment(jitter_mm=8))
    assert np.array_equal(j2, jts)
    moved = np.linalg.norm(p2 - pts, axis=-1)
    assert 0 < moved.mean() < 0.02


def test_holes_take_out_a_ball_and_refill_from_what_is_kept():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.5, 0.5, (512, 3))
    aug = Augment(hole_share=1.0, max_holes=1, hole_radius_m=(0.2, 0.2))
    out = punch_holes(pts, np.random.default_rng(6), aug)
    assert out.shape == pts.shape
    kept = {tuple(p) for p in out}
    assert kept <= {tuple(p) for p in pts}  # only copies of kept points
    lost = len({tuple(p) for p in pts} - kept)
    assert 0 < lost <= aug.max_lost * len(pts)
    # the lost points lie in one ball of the radius
    gone = np.array([p for p in pts if tuple(p) not in kept])
    assert np.linalg.norm(gone - gone.mean(0), axis=1).max() < 0.4
