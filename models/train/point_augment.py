"""Training-time augmentation of person-frame samples for depth the renderer did not make.

Our renders fix things real depth varies: the up the finder estimates is a few degrees off on
real frames (no extrinsics, a wall instead of a floor), real sensors add noise our models do not,
and real bodies lose depth in patches (dark hair, dark or shiny clothes, a hand out of range, a
part behind something). Each augmentation is drawn per sample and applied to points and joints
alike where it moves geometry (a tilt), to the points alone where it models the sensor (noise,
holes). Pure numpy on batches: (B, N, 3) points, (B, 22, 3) joints, person frame (origin on the
floor under the person, +y up, camera toward +z).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Augment:
    """What is drawn per sample (zeros: off).

    tilt_deg: sd of the tilt about the person frame's x and z axes through its origin (clipped
    at 2.5 sd); jitter_mm: the per-point noise sd is drawn uniformly up to this; hole_share: the
    share of samples that lose up to ``max_holes`` balls of points, radius drawn in
    ``hole_radius_m``, never more than ``max_lost`` of the sample (the lost points are replaced
    by copies of kept ones, as the finder's sample always holds N points)."""

    tilt_deg: float = 0.0
    jitter_mm: float = 0.0
    hole_share: float = 0.0
    max_holes: int = 2
    hole_radius_m: tuple[float, float] = (0.06, 0.18)
    max_lost: float = 0.35

    @property
    def active(self) -> bool:
        return self.tilt_deg > 0 or self.jitter_mm > 0 or self.hole_share > 0

    def to_card(self) -> dict:
        return asdict(self)


def tilt_matrices(rng: np.random.Generator, n: int, sd_deg: float) -> np.ndarray:
    """(n, 3, 3) rotations about x then z by angles ~ N(0, sd) clipped at 2.5 sd."""
    ax, az = np.radians(np.clip(rng.normal(0.0, sd_deg, (2, n)), -2.5 * sd_deg, 2.5 * sd_deg))
    cx, sx, cz, sz = np.cos(ax), np.sin(ax), np.cos(az), np.sin(az)
    rx = np.zeros((n, 3, 3))
    rx[:, 0, 0] = 1.0
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = cx, -sx, sx, cx
    rz = np.zeros((n, 3, 3))
    rz[:, 2, 2] = 1.0
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = cz, -sz, sz, cz
    return rz @ rx


def punch_holes(points: np.ndarray, rng: np.random.Generator, aug: Augment) -> np.ndarray:
    """points (N, 3) with up to ``aug.max_holes`` balls around random points of the sample
    removed, the sample refilled to N with copies of the kept points."""
    n = len(points)
    keep = np.ones(n, bool)
    for _ in range(int(rng.integers(1, aug.max_holes + 1))):
        centre = points[int(rng.integers(n))]
        radius = rng.uniform(*aug.hole_radius_m)
        cut = keep & (((points - centre) ** 2).sum(1) < radius * radius)
        if (~keep).sum() + cut.sum() > aug.max_lost * n:
            break
        keep &= ~cut
    kept = np.flatnonzero(keep)
    if len(kept) == n:
        return points
    return points[np.concatenate([kept, rng.choice(kept, n - len(kept))])]


def augment_batch(points: np.ndarray, joints: np.ndarray, rng: np.random.Generator, aug: Augment
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(points, joints) of a batch after ``aug``'s draws (float32, new arrays)."""
    pts = np.array(points, np.float64)
    jts = np.array(joints, np.float64)
    b = len(pts)
    if aug.hole_share > 0:
        for i in np.flatnonzero(rng.random(b) < aug.hole_share):
            pts[i] = punch_holes(pts[i], rng, aug)
    if aug.tilt_deg > 0:
        r = tilt_matrices(rng, b, aug.tilt_deg)
        pts = pts @ r.transpose(0, 2, 1)
        jts = jts @ r.transpose(0, 2, 1)
    if aug.jitter_mm > 0:
        sd = rng.uniform(0.0, aug.jitter_mm / 1000.0, (b, 1, 1))
        pts = pts + rng.normal(0.0, 1.0, pts.shape) * sd
    return pts.astype(np.float32), jts.astype(np.float32)


__all__ = ["Augment", "augment_batch", "punch_holes", "tilt_matrices"]
