"""Keeping a suit's sensors on one heading without a camera: what joints allow, against magnetism.

Each sensor's orientation filter takes its heading from its magnetometer; near steel, a floor
with rebar or a laptop, one sensor's field bends and its heading walks away from the others'.
A body limits how far a segment's heading may differ from its parent's for long: a knee or an
elbow is a hinge (the shank points where the thigh points, however bent), a foot toes out a
little, a hip or a shoulder turns inward or outward and comes back. So the heading a segment
keeps against its parent, averaged over seconds, beyond what it had in the calibration pose, is
its sensor's heading error.

``HeadingGuard.update(glob, dt)`` takes the measured segments' rotations (S, 4) and returns each
sensor's heading correction (S,) radians (a yaw about world up applied on the left, SuitSolver's
``yaw_correction``): a low-pass filter (``tau_s`` for hinges, ``tau_ball_s`` for other joints) of
the difference between its heading and its parent's (each the yaw of the segment's forward axis,
weighted by how horizontal that axis is): in the calibration pose (T or N) every segment faces
forward, so that difference is zero at rest. It works down the tree
from the pelvis, so a parent is corrected before its child is measured against it. Sensors
without a measured parent (the pelvis) keep their heading.
"""

from __future__ import annotations

import numpy as np

from live.core.heading import direction_yaw, wrap_angle, yaw_quat
from live.core.rotations import quat_multiply, quat_rotate
from live.core.skeleton import DEPTHS, JOINT_INDEX, PARENTS

HINGES = frozenset(JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("knee", "elbow"))
FORWARD = np.array([0.0, 0.0, 1.0])


class HeadingGuard:
    """Heading corrections of S sensors on segments ``joints`` (S,) (see the module doc)."""

    def __init__(self, joints: np.ndarray, *, tau_s: float = 2.0, tau_ball_s: float = 8.0):
        self.joints = np.asarray(joints, np.int64)
        row = {int(j): i for i, j in enumerate(self.joints)}
        self.parent_row = np.full(len(self.joints), -1)
        for i, j in enumerate(self.joints):
            p = int(PARENTS[int(j)])
            while p >= 0 and p not in row:
                p = int(PARENTS[p])
            self.parent_row[i] = row.get(p, -1)
        self.order = [int(i) for i in np.argsort([DEPTHS[int(j)] for j in self.joints], kind="stable")]
        self.tau = np.array([tau_s if int(j) in HINGES else tau_ball_s for j in self.joints])
        self.correction = np.zeros(len(self.joints))

    def update(self, glob: np.ndarray, dt: float) -> np.ndarray:
        """This frame's segment rotations (S, 4), before any correction -> corrections (S,)."""
        fwd = quat_rotate(np.asarray(glob, np.float64), FORWARD)
        heading = direction_yaw(fwd)
        weight = np.clip(np.hypot(fwd[:, 0], fwd[:, 2]), 0.0, 1.0) ** 2  # a vertical axis has no heading
        for i in self.order:
            p = self.parent_row[i]
            if p < 0:
                continue
            err = float(wrap_angle((heading[i] + self.correction[i]) - (heading[p] + self.correction[p])))
            gain = (1.0 - np.exp(-dt / self.tau[i])) * weight[i] * weight[p]
            self.correction[i] = float(wrap_angle(self.correction[i] - gain * err))
        return self.correction.copy()

    def apply(self, glob: np.ndarray) -> np.ndarray:
        """Segment rotations (S, 4) with the current corrections."""
        return quat_multiply(yaw_quat(self.correction), np.asarray(glob, np.float64))


__all__ = ["HeadingGuard", "HINGES"]
