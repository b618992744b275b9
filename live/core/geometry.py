"""Point-to-segment geometry shared by the skeleton stage's body check and the self-contact
correction. Pure numpy, broadcasting."""

from __future__ import annotations

import numpy as np


def segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of points p (..., 3) to segments a-b (..., 3 each), shapes broadcast: paired
    points and segments (K, 3), or every point against every segment (N, 1, 3) and (1, B, 3)."""
    ab = b - a
    ap = p - a
    t = np.clip((ap * ab).sum(axis=-1) / np.maximum((ab * ab).sum(axis=-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(ap - t[..., None] * ab, axis=-1)


__all__ = ["segment_distances"]
