"""A clip on the canonical 22-joint skeleton (``Motion``, what
``live.motion.rig_mapping.load_motion`` returns) and its resampling to another frame rate."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_slerp


@dataclass(frozen=True)
class Motion:
    """A clip on the canonical skeleton. joints (T, 22, 3) float32 world metres (y up);
    rotations (T, 22, 4) local (w, x, y, z) relative to the canonical T-pose; root (T, 3) pelvis
    world position; rest_joints (22, 3) the performer's T-pose, feet on y = 0."""

    name: str
    fps: float
    joints: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    rest_joints: np.ndarray
    source_rig: str

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[0])


def resample(motion: Motion, fps: float) -> Motion:
    """The motion at another frame rate: rotations slerped, root linear, joints by FK."""
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    n = motion.num_frames
    count = int(np.floor((n - 1) * fps / motion.fps + 1e-9)) + 1
    pos = np.arange(count) * (motion.fps / fps)  # in source frames
    i0 = np.minimum(np.floor(pos).astype(np.int64), n - 1)
    i1 = np.minimum(i0 + 1, n - 1)
    w = (pos - i0)[:, None]
    rot = quat_slerp(motion.rotations[i0].astype(np.float64), motion.rotations[i1].astype(np.float64),
                     w[:, :, None]).astype(np.float32)
    root = ((1 - w) * motion.root[i0] + w * motion.root[i1]).astype(np.float32)
    joints, _ = forward_kinematics(rot, root, motion.rest_joints)
    return replace(motion, fps=float(fps), joints=joints.astype(np.float32), rotations=rot,
                   root=root)
