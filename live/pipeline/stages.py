"""The cloud stage and the retarget stage.

The cloud stage turns each depth frame into a world-frame point cloud; the skeleton stage lives
in models.skeleton.runtime; the retarget stage drives any retargeter of live.retarget through its
interface. live.app.assemble puts the stages together.
"""

from __future__ import annotations

import numpy as np

from live.core.depth import points_to_world
from live.core.frames import AvatarPose, FrameResult, SkeletonFrame
from live.retarget.interface import Retargeter


class CloudStage:
    """Depth image or camera-frame cloud -> world-frame cloud (float32), kept on the result."""

    name = "cloud"

    def __init__(self) -> None:
        self.world_points: np.ndarray | None = None

    def process(self, result: FrameResult) -> bool:
        if result.depth is None:
            return False
        pts = result.depth.cloud()
        self.world_points = points_to_world(pts, result.depth.camera_to_world)
        result.points = len(pts)
        return len(pts) > 0


class RetargetStage:
    """Performer skeletons -> avatar poses on another body (analytic or learned retargeter).

    The performer's rest skeleton is unknown live: it is estimated from the skeletons seen
    (median bone lengths), refined over the first ``warmup`` frames, then frozen so that the
    avatar's proportions stay steady. ``skin=True`` also poses the avatar mesh (LBS).
    """

    name = "retarget"

    def __init__(self, avatar, *, kind: str = "analytic", foot_lock: bool = True, hand_ik: bool = False,
                 skin: bool = False, warmup: int = 30, use_truth: bool = False, model_path=None):
        if kind not in ("analytic", "learned"):
            from live.core.errors import UserInputError

            raise UserInputError(f"--retarget must be analytic or learned, not {kind!r}")
        self.avatar = avatar
        self.kind = kind
        self.foot_lock = foot_lock
        self.hand_ik = hand_ik
        self.skin = skin and len(getattr(avatar, "faces", ())) > 0
        self.warmup = warmup
        self.use_truth = use_truth
        self.model_path = model_path
        # Load now what the performer's first frame would otherwise wait for (~130 ms: the body
        # library's mean T-pose that estimate_rest_joints takes its bone directions from).
        from live.body.library import mean_rest_template
        from live.retarget.analytic import estimate_rest_joints  # noqa: F401 - imported once, here

        mean_rest_template()
        self._seen: list[np.ndarray] = []
        self._retargeter: Retargeter | None = None

    def _make(self, rest: np.ndarray) -> Retargeter:
        if self.kind == "learned":
            from live.retarget.learned import LearnedRetargeter

            return LearnedRetargeter(self.model_path, rest, self.avatar.rest_joints, foot_lock=self.foot_lock, floor=True)
        from live.retarget.retargeter import AnalyticRetargeter

        return AnalyticRetargeter(rest, self.avatar.rest_joints, foot_lock=self.foot_lock, hand_ik=self.hand_ik)

    def _source_frame(self, result: FrameResult) -> SkeletonFrame | None:
        """The performer's skeleton to retarget: the frame's (with ``use_truth`` its ground-truth
        joints). Behind a lagging skeleton model it is of an earlier instant than the result's
        (and, for the skeletons it gives at the end, of the frame's)."""
        if not self.use_truth:
            return result.skeleton
        if result.truth is None:
            return None
        truth = result.truth
        return SkeletonFrame(t_ns=truth.t_ns, joints=truth.joints, confidence=np.ones(len(truth.joints), np.float32))

    def process(self, result: FrameResult) -> bool:
        from live.retarget.analytic import estimate_rest_joints

        frame = self._source_frame(result)
        if frame is None:
            return False
        if len(self._seen) < self.warmup:
            self._seen.append(np.asarray(frame.joints, np.float64))
            rest = estimate_rest_joints(np.stack(self._seen))
            if self._retargeter is None:
                self._retargeter = self._make(rest)
            else:
                self._retargeter.set_source_rest(rest)
        pose = self._retargeter.process(frame)
        glob = self._retargeter.last_globals
        rig = getattr(self.avatar, "rig", None)
        if rig is not None:
            # A VRM / glTF avatar: joints its file has no bone for turn with their parent, so that
            # its own bones (VMC, avatar.bvh) can take the pose (live/body/gltf_rig.py).
            glob, rotations, joints = rig.fit_pose(glob, pose.joints, self.avatar.rest_joints)
            pose = AvatarPose(t_ns=pose.t_ns, root=pose.root, rotations=rotations, joints=joints)
        vertices = None
        if self.skin:
            from live.body.skinning import pose_transforms, skin

            # The retargeter's own global rotations and joints: no second FK from quaternions.
            g = pose_transforms(glob, pose.joints, self.avatar.rest_joints)
            vertices = skin(self.avatar.vertices, self.avatar.weights, g[None])[0]
        result.avatar = AvatarPose(t_ns=pose.t_ns, root=np.asarray(pose.root, np.float32),
                                   rotations=np.asarray(pose.rotations, np.float32),
                                   joints=np.asarray(pose.joints, np.float32), vertices=vertices)
        return True
