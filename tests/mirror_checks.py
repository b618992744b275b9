"""The avatar keeps the performer's left and right: one check shared by the avatar tests."""

from __future__ import annotations

import numpy as np

from live.core.skeleton import JOINT_INDEX

# (left joint, right joint, least cosine in any frame): a mirror gives a negative cosine.
# Another body's proportions turn the line between hands 20-25 cm apart by up to ~30 degrees
# (cosine 0.88 in one frame of the demo, 0.95 and more elsewhere); hips stay parallel.
PAIRS = (("left_hip", "right_hip", 0.99), ("left_wrist", "right_wrist", 0.8))


def assert_left_right_kept(avatar: np.ndarray, performer: np.ndarray) -> None:
    """avatar, performer (T, 22, 3): the line from each right joint to its left one points the
    same way on both, judged where the performer's pair is at least 60 % of its usual distance
    apart (hands close together leave their direction to a few mm of noise)."""
    for a, b, least in PAIRS:
        da = avatar[:, JOINT_INDEX[a]] - avatar[:, JOINT_INDEX[b]]
        dp = performer[:, JOINT_INDEX[a]] - performer[:, JOINT_INDEX[b]]
        cos = np.sum(da * dp, axis=1) / np.linalg.norm(da, axis=1) / np.linalg.norm(dp, axis=1)
        gap = np.linalg.norm(dp, axis=1)
        apart = gap > 0.6 * np.median(gap)
        assert apart.sum() > 20 and cos[apart].min() > least, (a, cos[apart].min())
        assert np.median(cos[apart]) > 0.98, (a, np.median(cos[apart]))
