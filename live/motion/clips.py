"""A clip on the canonical 22-joint skeleton (``Motion``, what
``live.motion.rig_mapping.load_motion`` returns) and its resampling to another frame rate."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from live.core.errors import UserInputError
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_slerp

#: Most frames ``resample`` makes (docs/reliability.md): 2 hours at 30 fps, 0.87 GB at the peak
#: while resampling. A clip's length times the new rate is checked before anything is allocated.
MAX_RESAMPLED_FRAMES = 216_000


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
    """The motion at another frame rate: rotations slerped, root linear, joints by FK.
    UserInputError (a ValueError) for a rate that is not a positive number or a result longer
    than MAX_RESAMPLED_FRAMES."""
    if not (np.isfinite(fps) and fps > 0):
        raise UserInputError(f"fps must be positive, got {fps}")
    n = motion.num_frames
    frames = np.floor((n - 1) * fps / motion.fps + 1e-9) + 1
    if not frames <= MAX_RESAMPLED_FRAMES:
        raise UserInputError(f"{motion.name or 'the motion'} lasts {(n - 1) / motion.fps:.0f} s: at {fps:g} fps that "
                             f"is {frames:.0f} frames, more than the {MAX_RESAMPLED_FRAMES} a clip may be resampled to")
    count = int(frames)
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
