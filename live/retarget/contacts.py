"""Foot contacts, foot locking and floor clearance, online (frame by frame, state carried).

Contact is decided per foot on the ankle joint, with hysteresis on two quantities measured in
units of the body's leg length L (rest pelvis height), so the same thresholds serve a child and
an adult and are not tuned to one clip:

* height of the ankle above its own rest height: contact starts below 0.05 L, ends above 0.08 L;
* ankle speed: contact starts below 0.4 L/s, ends above 0.8 L/s.

While a foot is in contact its ankle is held at the place where the contact began (the lock);
the lock weight ramps up and down over ``blend_frames`` frames so the leg never pops. A lock
that the input drags further than ``max_slide`` (0.1 L) follows the input at that distance
(a sliding or pivoting source foot). Targets are then lifted so that neither the ankle nor the
foot joint goes below the floor y = 0; the leg reaches them by two-bone IK (live/retarget/ik.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX, NUM_JOINTS, pelvis_height
from live.core.timing import frame_interval_s

#: (ankle, foot) joint indices of the left and right foot.
FEET = np.array(
    [[JOINT_INDEX["left_ankle"], JOINT_INDEX["left_foot"]], [JOINT_INDEX["right_ankle"], JOINT_INDEX["right_foot"]]],
    dtype=np.int64,
)


@dataclass(frozen=True)
class ContactThresholds:
    """Contact thresholds in leg lengths (heights) and leg lengths per second (speeds)."""

    height_on: float = 0.05
    height_off: float = 0.08
    speed_on: float = 0.4
    speed_off: float = 0.8


class ContactDetector:
    """Online foot-contact detector with hysteresis; one ``update`` per frame."""

    def __init__(self, rest_joints: np.ndarray, thresholds: ContactThresholds = ContactThresholds()):
        rest = np.asarray(rest_joints, dtype=np.float64)
        leg = pelvis_height(rest)
        if leg <= 0:
            raise UserInputError("rest skeleton pelvis must be above the floor (y > 0)")
        self.rest_height = rest[FEET[:, 0], 1]
        th = thresholds
        self.h_on, self.h_off = th.height_on * leg, th.height_off * leg
        self.v_on, self.v_off = th.speed_on * leg, th.speed_off * leg
        self.reset()

    def reset(self) -> None:
        self.contact = np.zeros(2, dtype=bool)
        self._last: np.ndarray | None = None

    def update(self, ankles: np.ndarray, dt: float) -> np.ndarray:
        """ankles (2, 3) world positions (left, right); dt seconds since the last frame.

        Returns (2,) bool contacts. The first frame after reset has no speed and counts as still.
        """
        ankles = np.asarray(ankles, dtype=np.float64)
        step = None if self._last is None else ankles - self._last
        speed = np.zeros(2) if step is None else np.sqrt((step * step).sum(-1)) / max(dt, 1e-6)
        self._last = ankles.copy()
        height = ankles[:, 1] - self.rest_height
        start = (height < self.h_on) & (speed < self.v_on)
        keep = self.contact & (height < self.h_off) & (speed < self.v_off)
        self.contact = start | keep
        return self.contact.copy()


def detect_contacts(
    joints: np.ndarray, rest_joints: np.ndarray, fps: float, thresholds: ContactThresholds = ContactThresholds()
) -> np.ndarray:
    """Offline contacts of a whole motion: joints T x 22 x 3 -> T x 2 bool (left, right foot)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (NUM_JOINTS, 3):
        raise UserInputError(f"joints must be (T, 22, 3), got {joints.shape}")
    det = ContactDetector(rest_joints, thresholds)
    return np.stack([det.update(j[FEET[:, 0]], frame_interval_s(fps)) for j in joints]) if len(joints) else np.zeros((0, 2), bool)


class FootLock:
    """Online foot locking: turns contacts and the free ankle positions into ankle targets."""

    def __init__(self, rest_joints: np.ndarray, blend_frames: int = 4, max_slide: float = 0.1):
        self.blend = 1.0 / max(int(blend_frames), 1)
        self.max_slide = max_slide * pelvis_height(rest_joints)
        self.reset()

    def reset(self) -> None:
        self.weight = np.zeros(2)
        self.lock = np.zeros((2, 3))

    def update(self, ankles: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """ankles (2, 3) where the animation puts them; contact (2,) bool -> (2, 3) ankle targets."""
        fresh = contact & (self.weight <= 0.0)
        self.lock[fresh] = ankles[fresh]
        # A lock the source keeps dragging away follows it at max_slide (pivots, slides).
        gap = self.lock - ankles
        dist = np.sqrt((gap * gap).sum(-1))
        far = dist > self.max_slide
        if np.any(far):
            self.lock[far] = ankles[far] + gap[far] * (self.max_slide / dist[far])[:, None]
        self.weight = np.minimum(np.maximum(self.weight + np.where(contact, self.blend, -self.blend), 0.0), 1.0)
        w = self.weight * self.weight * (3.0 - 2.0 * self.weight)  # smoothstep: no velocity jump
        return ankles + w[:, None] * (self.lock - ankles)


def floor_lift(ankle_targets: np.ndarray, foot_offsets: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Raise ankle targets (2, 3) so neither the ankle nor its foot joint (ankle + foot_offsets
    (2, 3), the foot's world offset, kept while the ankle moves) is below y = floor."""
    lowest = np.minimum(ankle_targets[:, 1], ankle_targets[:, 1] + foot_offsets[:, 1])
    out = ankle_targets.copy()
    out[:, 1] += np.maximum(floor - lowest, 0.0)
    return out
