"""Mixed pixels at depth edges: the returns a real sensor gives where a pixel sees both the
person and what lies behind them (stereo matching across the silhouette, a time-of-flight
pixel summing two ranges). Their depth lies between the two surfaces, so their points float
in the air around the body: behind the arms, beside the legs."""

from __future__ import annotations

import numpy as np


def edge_pixels_at(z: np.ndarray, valid: np.ndarray, flat: np.ndarray, share: float) -> np.ndarray:
    """(K,) bool: which of the pixels ``flat`` (K,) (flat indices) of the depth image ``z`` (H, W)
    metres, where ``valid`` (H, W), have a valid 4-neighbour more than ``share`` of their own
    range nearer or farther. Both sides of a depth edge are marked, the person's silhouette
    against a wall behind them included: what lies there is the least reliable depth in a real
    frame, and the regressor learns the same trimmed silhouette from training data drawn through
    this test. Only the given pixels are tested: the fine sample visits a few thousand of a box's."""
    h, w = z.shape
    padded = np.zeros((h + 2, w + 2), z.dtype)  # 0 = no depth, around the image too: no edge there
    np.copyto(padded[1:-1, 1:-1], z, where=valid)
    padded = padded.reshape(-1)
    at = (flat // w + 1) * (w + 2) + flat % w + 1
    here = padded[at]
    limit = here * np.float32(share)
    edge = np.zeros(len(flat), bool)
    for step in (1, -1, w + 2, -(w + 2)):
        there = padded[at + step]
        edge |= (there > 0) & (np.abs(there - here) > limit)
    return edge & (here > 0)


def edge_pixels(z: np.ndarray, share: float) -> np.ndarray:
    """(H, W) bool: ``edge_pixels_at`` over the whole image, its pixels with depth (z > 0) valid."""
    return edge_pixels_at(z, z > 0, np.arange(z.size), share).reshape(z.shape)
