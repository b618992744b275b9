"""The online analytic retargeter: source skeletons or rotations -> avatar poses.

Per frame: rotations from the source joints (live/retarget/analytic.py, limb twists carried from
frame to frame), copied onto the target body with the root scaled by the leg-length ratio, then
optional hand IK, foot locking and floor clearance by two-bone IK. Everything runs on rotation
matrices of one frame; quaternions are made once at the end.
"""

from __future__ import annotations

import numpy as np

from live.core.errors import UserInputError
from live.core.frames import AvatarPose, GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics_matrices, joints_from_global_matrices
from live.core.rotations import matrix_to_quat, quat_to_matrix
from live.core.skeleton import CHILDREN, NUM_JOINTS, PARENTS
from live.core.timing import FrameClock, frame_interval_s
from live.retarget.analytic import LIMBS, RestInfo, leg_ratio, solve_globals
from live.retarget.contacts import ContactThresholds
from live.retarget.feet import SOFT_IK, FootPlanter
from live.retarget.ik import apply_limb_ik
from live.retarget.interface import step_frame

_ARMS = np.array([limb[:3] for limb in LIMBS[2:]], dtype=np.int64)
_ARM_HINGES = np.array([limb[3] for limb in LIMBS[2:]], dtype=np.float64)


class AnalyticRetargeter:
    """Stateful, frame-by-frame retargeter from a source body to a target body (a Retargeter,
    live/retarget/interface.py).

    source_rest, target_rest: (22, 3) T-poses. foot_lock: hold feet in contact still and keep
    feet above y = 0 (floor clearance alone with ``floor=True, foot_lock=False``). hand_ik: wrists
    reach the source's wrist positions relative to the pelvis, scaled by the leg-length ratio.
    fps: frame rate assumed when ``step`` is not given ``dt``. soft_ik: the leg IK's soft reach
    (live/retarget/ik.py ``soft_reach``; 0 = exact): a locked foot then never snaps the knee
    straight and back, for a lag of at most 2 % of the leg's reach when it is fully stretched.
    """

    def __init__(
        self,
        source_rest: np.ndarray,
        target_rest: np.ndarray,
        *,
        foot_lock: bool = True,
        hand_ik: bool = False,
        floor: bool = True,
        fps: float = 30.0,
        blend_frames: int = 4,
        thresholds: ContactThresholds = ContactThresholds(),
        soft_ik: float = SOFT_IK,
    ):
        self.target = RestInfo.of(target_rest)
        self.set_source_rest(source_rest)
        self.hand_ik = hand_ik
        self.dt = frame_interval_s(fps)
        self.clock = FrameClock()
        self.feet = FootPlanter(self.target.rest_joints, self.target.offsets, foot_lock=foot_lock, floor=floor,
                                blend_frames=blend_frames, thresholds=thresholds, soft_ik=soft_ik)
        self.reset()

    @property
    def contact(self) -> np.ndarray:
        """(2,) bool: left, right foot in contact on the last frame."""
        return self.feet.contact

    def set_source_rest(self, rest_joints: np.ndarray) -> None:
        """New performer proportions (rest joints (22, 3)); limb twists and contacts are kept."""
        self.source = RestInfo.of(rest_joints)
        self.ratio = leg_ratio(self.source.rest_joints, self.target.rest_joints)

    def reset(self) -> None:
        """Forget the motion so far (limb twists, contacts, locks, last timestamp)."""
        self.twist = np.zeros(len(LIMBS))
        self.feet.reset()
        self.clock.reset()
        # Global rotations (22, 3, 3) of the last step's target pose (for skinning).
        self.last_globals: np.ndarray | None = None
        self.last_source_globals: np.ndarray | None = None

    def step(
        self, pose: np.ndarray, root: np.ndarray | None = None, dt: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Retarget one frame.

        pose: source joints (22, 3) world metres, or local rotations (22, 4) with ``root`` (3,).
        Returns (root (3,), rotations (22, 4), joints (22, 3)) of the target body.
        """
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape == (NUM_JOINTS, 3):
            src = pose[None]
            glob, loc, self.twist = solve_globals(src, self.source, self.twist)
            src_root = pose[0]
            root_t = src_root * self.ratio
            # Local rotations mean the same on every canonical body, so are the global ones:
            # the target's joints come from the source's globals and the target's bones.
            pos = joints_from_global_matrices(glob, root_t[None], self.target.offsets)
        elif pose.shape == (NUM_JOINTS, 4):
            if root is None:
                raise UserInputError("rotations need a root position")
            src_root = np.asarray(root, dtype=np.float64)
            loc = quat_to_matrix(pose)[None]
            src = None
            root_t = src_root * self.ratio
            pos, glob = forward_kinematics_matrices(loc, root_t[None], self.target.offsets)
        else:
            raise UserInputError(f"a frame is (22, 3) joints or (22, 4) rotations, got {pose.shape}")
        glob, loc, pos = glob[0], loc[0].copy(), pos[0]
        # The performer's own global rotations (the rotation copy's, before any IK): self-contacts
        # are found on the performer's pose (live/retarget/contacts_retargeter.py).
        self.last_source_globals = glob.copy()
        if self.hand_ik:
            if src is None:
                src, _ = forward_kinematics_matrices(quat_to_matrix(pose)[None], src_root[None], self.source.offsets)
            wrists = root_t + (src[0, _ARMS[:, 2]] - src_root) * self.ratio
            apply_limb_ik(glob, loc, pos, self.target.offsets, _ARMS, _ARM_HINGES, wrists, CHILDREN, PARENTS)
        self.feet(glob, loc, pos, self.dt if dt is None else dt)
        self.last_globals = glob
        return root_t, matrix_to_quat(loc), pos

    def process(self, frame: SkeletonFrame | GroundTruth) -> AvatarPose:
        """Retarget a SkeletonFrame (joints) or GroundTruth (rotations + root); dt from t_ns."""
        return step_frame(self.step, frame, self.clock.tick(frame.t_ns))


def retarget_motion(
    source_rest: np.ndarray,
    target_rest: np.ndarray,
    joints: np.ndarray | None = None,
    rotations: np.ndarray | None = None,
    root: np.ndarray | None = None,
    fps: float = 30.0,
    **options,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offline batch: a whole motion through a fresh AnalyticRetargeter (same result as online).

    Give joints T x 22 x 3, or rotations T x 22 x 4 with root T x 3. options: foot_lock, hand_ik,
    floor, blend_frames, thresholds, soft_ik. Returns (root T x 3, rotations T x 22 x 4, joints T x 22 x 3).
    """
    rt = AnalyticRetargeter(source_rest, target_rest, fps=fps, **options)
    if joints is not None:
        frames = [rt.step(j) for j in np.asarray(joints, dtype=np.float64)]
    elif rotations is not None and root is not None:
        frames = [rt.step(q, r) for q, r in zip(np.asarray(rotations), np.asarray(root))]
    else:
        raise UserInputError("retarget_motion needs joints, or rotations and root")
    if not frames:
        return np.zeros((0, 3)), np.zeros((0, NUM_JOINTS, 4)), np.zeros((0, NUM_JOINTS, 3))
    return tuple(np.stack(x) for x in zip(*frames))  # type: ignore[return-value]
