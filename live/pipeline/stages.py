"""Pipeline stages and how the CLI assembles them.

The cloud stage turns each depth frame into a world-frame point cloud; the skeleton stage
(models.skeleton) and the retarget stage (live.retarget) join when their models are present.
"""

from __future__ import annotations

import numpy as np

from live.core.depth import points_to_world
from live.core.frames import FrameResult


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
        result.latency_ms.setdefault("points", float(len(pts)))
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
        self._retargeter = None
        self._last_t_ns: int | None = None

    def _make(self, rest: np.ndarray):
        if self.kind == "learned":
            from live.retarget.learned import LearnedRetargeter

            return LearnedRetargeter(self.model_path, rest, self.avatar.rest_joints, foot_lock=self.foot_lock, floor=True)
        from live.retarget.retargeter import AnalyticRetargeter

        return AnalyticRetargeter(rest, self.avatar.rest_joints, foot_lock=self.foot_lock, hand_ik=self.hand_ik)

    def _update_source(self, rest: np.ndarray) -> None:
        """New performer proportions; motion state (contacts, twists, GRU state) is kept."""
        from live.retarget.analytic import leg_ratio
        from live.core.skeleton import pelvis_height

        r = self._retargeter
        if self.kind == "learned":
            from live.retarget.learned import rest_features

            r.source_rest = np.asarray(rest, np.float64)
            r.src_leg = max(pelvis_height(r.source_rest), 1e-3)
            r.ratio = r.tgt_leg / r.src_leg
            r._src_feat = rest_features(r.source_rest)
        else:
            r.source = type(r.source).of(rest)
            r.ratio = leg_ratio(r.source.rest_joints, r.target.rest_joints)

    def process(self, result: FrameResult) -> bool:
        from live.core.frames import AvatarPose
        from live.retarget.analytic import estimate_rest_joints

        # The pose is of the skeleton's own instant: behind a lagging skeleton model that is an
        # earlier frame than the result's (and, for the skeletons it gives at the end, the frame's).
        if self.use_truth:
            if result.truth is None:
                return False
            joints, t_ns = result.truth.joints, result.truth.t_ns
        elif result.skeleton is not None:
            joints, t_ns = result.skeleton.joints, result.skeleton.t_ns
        else:
            return False
        if len(self._seen) < self.warmup:
            self._seen.append(np.asarray(joints, np.float64))
            rest = estimate_rest_joints(np.stack(self._seen))
            if self._retargeter is None:
                self._retargeter = self._make(rest)
            else:
                self._update_source(rest)
        dt = None
        if self._last_t_ns is not None and t_ns > self._last_t_ns:
            dt = (t_ns - self._last_t_ns) / 1e9
        self._last_t_ns = t_ns
        root, rotations, avatar_joints = self._retargeter.step(joints, dt=dt)
        vertices = None
        if self.skin:
            from live.body.skinning import pose_transforms, skin

            # The retargeter's own global rotations and joints: no second FK from quaternions.
            g = pose_transforms(self._retargeter.last_globals, avatar_joints, self.avatar.rest_joints)
            vertices = skin(self.avatar.vertices, self.avatar.weights, g[None])[0]
        result.avatar = AvatarPose(t_ns=t_ns, root=np.asarray(root, np.float32),
                                   rotations=np.asarray(rotations, np.float32),
                                   joints=np.asarray(avatar_joints, np.float32), vertices=vertices)
        return True
