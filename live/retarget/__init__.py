"""Retargeting: motion from a performer's skeleton onto an avatar body.

The analytic retargeter recovers local rotations from joint positions, copies them onto the
target body (same meaning on every canonical T-pose body), scales root motion by the leg-length
ratio, then fixes contacts with two-bone IK (docs/retargeting.md); the learned retargeter is a
recurrent network with forward kinematics (docs/learned_retargeting.md).
"""
