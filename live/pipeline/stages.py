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

    contacts: "auto" (the default: on when the avatar has a mesh), "on" or "off": keep the
    performer's self-contacts on the avatar and its hands and forearms out of its body
    (live/retarget/contacts_retargeter.py). The performer's body surface is the one given by
    ``set_performer_body`` (a synthetic session's true body) or a template fitted to the
    estimated skeleton. estimated: the skeletons are the depth stage's (centimetres off): the
    performer's contacts are read with live.retarget.contacts_self.ESTIMATED (wider gaps, kept
    touching); False for a fused or suit skeleton (``replay --only imu|fused``) and with
    ``use_truth``.
    """

    name = "retarget"

    def __init__(self, avatar, *, kind: str = "analytic", foot_lock: bool = True, hand_ik: bool = False,
                 skin: bool = False, warmup: int = 30, use_truth: bool = False, model_path=None,
                 contacts: str = "auto", estimated: bool = True):
        from live.core.errors import UserInputError

        if kind not in ("analytic", "learned"):
            raise UserInputError(f"--retarget must be analytic or learned, not {kind!r}")
        if contacts not in ("auto", "on", "off"):
            raise UserInputError(f"--contacts must be on or off, not {contacts!r}")
        self.avatar = avatar
        self.kind = kind
        self.foot_lock = foot_lock
        self.hand_ik = hand_ik
        self.skin = skin and len(getattr(avatar, "faces", ())) > 0
        self.warmup = warmup
        self.use_truth = use_truth
        self.estimated = estimated
        self.model_path = model_path
        # Load now what the performer's first frame would otherwise wait for (~130 ms: the body
        # library's mean T-pose that estimate_rest_joints takes its bone directions from).
        from live.body.library import mean_rest_template
        from live.retarget.analytic import estimate_rest_joints  # noqa: F401 - imported once, here

        mean_rest_template()
        self._seen: list[np.ndarray] = []
        self._retargeter: Retargeter | None = None
        # The avatar's and the performer's surfaces for self-contacts, built (or read from the
        # cache) now rather than on the first frame.
        self._contacts = self._contact_surfaces(contacts)

    def _contact_surfaces(self, mode: str):
        if mode == "off":
            return None
        if len(getattr(self.avatar, "faces", ())) == 0:
            if mode == "on":
                from live.core.errors import UserInputError

                raise UserInputError("--contacts on needs an avatar with a mesh (this one is a point cloud)")
            return None
        from live.core.errors import UserInputError
        from live.retarget.contacts_retargeter import PerformerSurfaces
        from live.retarget.contacts_surface import body_surface, warm_up

        try:
            surfaces = [body_surface(self.avatar), PerformerSurfaces()]
        except UserInputError as exc:
            if mode == "on":
                raise
            import logging

            logging.getLogger(__name__).warning("self-contacts off: %s", exc)
            return None
        warm_up(surfaces[0])
        return surfaces

    @property
    def contacts(self) -> bool:
        """True when the stage keeps self-contacts."""
        return self._contacts is not None

    def set_performer_body(self, body) -> None:
        """The performer's true body (a synthetic session's), for its self-contacts; before the
        first frame."""
        if self._contacts is not None and len(getattr(body, "faces", ())):
            from live.retarget.contacts_surface import body_surface

            self._contacts[1] = body_surface(body)

    @property
    def counters(self) -> dict[str, int]:
        """Self-contact counts (stats.json): frames with a hand contact, frames corrected."""
        return dict(getattr(self._retargeter, "counters", {})) if self._contacts is not None else {}

    def _make(self, rest: np.ndarray) -> Retargeter:
        inner: Retargeter
        if self.kind == "learned":
            from live.retarget.learned import LearnedRetargeter

            inner = LearnedRetargeter(self.model_path, rest, self.avatar.rest_joints, foot_lock=self.foot_lock,
                                      floor=True)
        else:
            from live.retarget.retargeter import AnalyticRetargeter

            inner = AnalyticRetargeter(rest, self.avatar.rest_joints, foot_lock=self.foot_lock, hand_ik=self.hand_ik)
        if self._contacts is None:
            return inner
        from live.retarget.contacts_retargeter import ContactRetargeter
        from live.retarget.contacts_self import settings_for

        target, performer = self._contacts
        return ContactRetargeter(inner, target, self.avatar.rest_joints, rest, performer,
                                 settings=settings_for(self.estimated and not self.use_truth))

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
