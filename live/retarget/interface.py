"""What every online retargeter offers the pipeline (AnalyticRetargeter, LearnedRetargeter).

The retarget stage holds one retargeter and only talks to it through this protocol: it creates
it with the performer's first rest-pose estimate, tells it the refined estimates while it warms
up (``set_source_rest``), and hands it one frame at a time (``process``). Each retargeter keeps
its own motion state (limb twists, GRU states, foot contacts, the previous frame's timestamp).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from live.core.frames import AvatarPose, GroundTruth, SkeletonFrame


@runtime_checkable
class Retargeter(Protocol):
    """An online, frame-by-frame retargeter from a performer (source body) to an avatar."""

    #: Global rotations (22, 3, 3) of the last frame's avatar pose (skinning reuses them).
    last_globals: np.ndarray | None

    def reset(self) -> None:
        """Forget the motion so far; the bodies stay."""

    def set_source_rest(self, rest_joints: np.ndarray) -> None:
        """New performer proportions ((22, 3) rest joints); the motion state is kept."""

    def process(self, frame: SkeletonFrame | GroundTruth) -> AvatarPose:
        """Retarget one frame: a SkeletonFrame's joints, or a GroundTruth's rotations and root.
        The interval since the previous frame comes from the frames' timestamps."""


def step_frame(step, frame: SkeletonFrame | GroundTruth, dt: float | None) -> AvatarPose:
    """One frame through a retargeter's ``step(pose, root=None, dt=None)``: the joints of a
    SkeletonFrame, or the local rotations and root of a GroundTruth."""
    if isinstance(frame, SkeletonFrame):
        root, rot, joints = step(frame.joints, dt=dt)
    else:
        root, rot, joints = step(frame.rotations, frame.root, dt=dt)
    return AvatarPose(t_ns=frame.t_ns, root=root, rotations=rot, joints=joints)
