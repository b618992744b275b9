"""Retargeting: motion from a performer's skeleton onto an avatar body (issue 5).

The analytic retargeter recovers local rotations from joint positions, copies them onto the
target body (same meaning on every canonical T-pose body), scales root motion by the leg-length
ratio, then fixes contacts with two-bone IK. See docs/retargeting.md.
"""

from live.retarget.analytic import (
    estimate_rest_joints,
    fk_matrices,
    leg_ratio,
    local_rotations_from_joints,
    retarget,
)
from live.retarget.contacts import ContactDetector, ContactThresholds, FootLock, detect_contacts, floor_lift
from live.retarget.ik import two_bone_ik
from live.retarget.stage import AnalyticRetargeter, retarget_motion

__all__ = [
    "AnalyticRetargeter",
    "ContactDetector",
    "ContactThresholds",
    "FootLock",
    "detect_contacts",
    "estimate_rest_joints",
    "fk_matrices",
    "floor_lift",
    "leg_ratio",
    "local_rotations_from_joints",
    "retarget",
    "retarget_motion",
    "two_bone_ik",
]
