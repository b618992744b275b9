"""Foot placement on one retargeted frame, after any retargeter: contacts -> locks -> floor -> leg IK.

The analytic and the learned retargeters both end a frame with the target's global rotations,
local rotations and joints; ``FootPlanter`` then holds feet in contact where the contact began,
lifts them out of the floor and bends the legs to reach (live/retarget/contacts.py has the
contact and lock rules, live/retarget/ik.py the two-bone IK). It keeps the contact state from
frame to frame, so one planter serves one performer-avatar pair.
"""

from __future__ import annotations

import numpy as np

from live.core.skeleton import CHILDREN, PARENTS
from live.retarget.analytic import LIMBS
from live.retarget.contacts import FEET, ContactDetector, ContactThresholds, FootLock, floor_lift
from live.retarget.ik import apply_limb_ik

_LEGS = np.array([limb[:3] for limb in LIMBS[:2]], dtype=np.int64)
_LEG_HINGES = np.array([limb[3] for limb in LIMBS[:2]], dtype=np.float64)
#: The leg IK's default soft reach (docs/retargeting.md: chosen on training clips).
SOFT_IK = 0.05


class FootPlanter:
    """foot_lock: hold feet in contact still; floor: keep ankle and foot joints above y = 0.
    blend_frames, max_slide: the lock's ramp and how far the input may drag it (FootLock);
    soft_ik: the leg IK's soft reach (live/retarget/ik.py ``soft_reach``)."""

    def __init__(self, target_rest: np.ndarray, offsets: np.ndarray, *, foot_lock: bool = True,
                 floor: bool = True, blend_frames: int = 4, thresholds: ContactThresholds = ContactThresholds(),
                 max_slide: float = 0.1, soft_ik: float = SOFT_IK):
        self.offsets = np.asarray(offsets, np.float64)
        self.foot_lock, self.floor = foot_lock, floor
        self.soft_ik = float(soft_ik)
        self.detector = ContactDetector(target_rest, thresholds)
        self.locker = FootLock(target_rest, blend_frames=blend_frames, max_slide=max_slide)
        self.reset()

    @property
    def active(self) -> bool:
        return self.foot_lock or self.floor

    def reset(self) -> None:
        self.detector.reset()
        self.locker.reset()
        self.contact = np.zeros(2, dtype=bool)

    def __call__(self, glob: np.ndarray, loc: np.ndarray, pos: np.ndarray, dt: float) -> None:
        """Place the feet of one frame in place: glob, loc (22, 3, 3), pos (22, 3); dt seconds
        since the frame before."""
        if not self.active:
            return
        ankles = pos[FEET[:, 0]]
        targets = ankles
        if self.foot_lock:
            self.contact = self.detector.update(ankles, dt)
            targets = self.locker.update(ankles, self.contact)
        if self.floor:
            targets = floor_lift(targets, pos[FEET[:, 1]] - ankles)
        if np.max(np.abs(targets - ankles)) > 1e-7:
            apply_limb_ik(glob, loc, pos, self.offsets, _LEGS, _LEG_HINGES, targets, CHILDREN, PARENTS,
                          self.soft_ik)
