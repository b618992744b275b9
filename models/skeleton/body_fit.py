"""How well a skeleton explains a point sample: the person finder's body check.

A performer's sample lies on the skin around the bones of the skeleton regressed from it (a
mean of 7-8 cm from the nearest bone); a still figure, a shelf or a sofa taken for a person does
not: the regressor's skeleton fits it badly (14-30 cm).
"""

from __future__ import annotations

import numpy as np

from live.core.geometry import segment_distances
from live.core.skeleton import BONES

_PARENT = np.array([parent for parent, _ in BONES])
_CHILD = np.array([child for _, child in BONES])


def bone_distances(joints: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) distance (m) of each point (N, 3) to the nearest bone segment of joints (22, 3)."""
    j = np.asarray(joints, np.float64)
    p = np.asarray(points, np.float64)
    return segment_distances(p[:, None], j[_PARENT][None], j[_CHILD][None]).min(axis=1)


def body_fit(joints: np.ndarray, points: np.ndarray, every: int = 4) -> float:
    """Mean distance (m) of the sample to the skeleton's bones, over every ``every``-th point
    (the finder's sample is spread evenly, so a strided subset is too, at a quarter of the
    work): lower fits better."""
    return float(bone_distances(joints, np.asarray(points)[::every]).mean())


__all__ = ["bone_distances", "body_fit"]
