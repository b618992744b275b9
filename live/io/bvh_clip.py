"""BVH (Biovision Hierarchy) data for any rig: the hierarchy (``BvhSkeleton``), a clip's MOTION
channels (``BvhClip``) and their decoding into local rotations and translations.

Conventions (the ones Blender's importer and the CMU conversions follow):
- OFFSET is a joint's rest translation in its parent's frame. A joint with position channels
  uses the channel values as its local translation instead of the offset (for the root they are
  its world position).
- Rotation channels are degrees; their order in CHANNELS is the Euler order, applied as
  R = R_first @ R_second @ R_third (intrinsic), e.g. "Zrotation Xrotation Yrotation" -> "ZXY".
  Joints may have any subset and order of the six channels.
- World: whatever the file uses; BVH files are y-up by convention and the BVH modules
  (bvh_reader, bvh_kinematics, bvh_writer) keep their axes.

Shapes: T frames, J joints, E end sites, C channels. Joint positions (T, J, 3), global rotation
matrices (T, J, 3, 3), local quaternions (T, J, 4) as (w, x, y, z).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from live.core.rotations import euler_to_matrix, matrix_to_quat


@dataclass(frozen=True)
class BvhSkeleton:
    """The HIERARCHY block: joints in file order (parents before children).

    names (J,), parents (J,) int (-1 for the root), offsets (J, 3) in file units (times the scale
    given to the reader), channels: per joint the channel names in file order.
    end_parents (E,) int and end_offsets (E, 3): the "End Site" blocks.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    end_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def channel_starts(self) -> np.ndarray:
        """(J,) column of each joint's first channel in the MOTION rows."""
        counts = np.array([len(c) for c in self.channels], dtype=np.int64)
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    def end_names(self) -> tuple[str, ...]:
        """Names given to end sites: '<parent>/end' (BVH end sites have no name of their own)."""
        return tuple(f"{self.names[p]}/end" for p in self.end_parents)

    def scaled(self, scale: float) -> BvhSkeleton:
        return BvhSkeleton(self.names, self.parents, self.offsets * scale, self.channels,
                           self.end_parents, self.end_offsets * scale)


@dataclass(frozen=True)
class BvhClip:
    """A skeleton plus its MOTION block: channels (T, C) float64 exactly as in the file
    (degrees; positions times the reader's scale)."""

    skeleton: BvhSkeleton
    frame_time: float
    channels: np.ndarray
    name: str = ""

    @property
    def num_frames(self) -> int:
        return int(self.channels.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def local_rotations(self) -> np.ndarray:
        """(T, J, 3, 3) local rotation matrices decoded from the rotation channels."""
        return _local_matrices(self.skeleton, self.channels)

    def local_quaternions(self) -> np.ndarray:
        """(T, J, 4) local rotations as (w, x, y, z) quaternions."""
        return matrix_to_quat(self.local_rotations())

    def local_translations(self) -> np.ndarray:
        """(T, J, 3) local translations: offsets, or position channels where a joint has them."""
        return _local_translations(self.skeleton, self.channels)

    def root_positions(self) -> np.ndarray:
        """(T, 3) world position of the root joint."""
        return self.local_translations()[:, 0]


def _local_matrices(skeleton: BvhSkeleton, channels: np.ndarray) -> np.ndarray:
    t = channels.shape[0]
    out = np.broadcast_to(np.eye(3), (t, skeleton.num_joints, 3, 3)).copy()
    starts = skeleton.channel_starts()
    # Joints sharing a rotation order are decoded in one batched call.
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    for j, ch in enumerate(skeleton.channels):
        rot = [(k, c[0]) for k, c in enumerate(ch) if c.endswith("rotation")]
        if not rot:
            continue
        order = "".join(a for _, a in rot)
        joints, cols = groups.setdefault(order, ([], []))
        joints.append(j)
        cols.append([starts[j] + k for k, _ in rot])
    for order, (joints, cols) in groups.items():
        angles = np.deg2rad(channels[:, np.array(cols)])  # (T, n, len(order))
        if len(order) < 3:  # fewer than three rotation channels: the missing axes are zero
            missing = "".join(a for a in "XYZ" if a not in order)
            angles = np.concatenate([angles, np.zeros(angles.shape[:-1] + (len(missing),))], -1)
            order += missing
        out[:, joints] = euler_to_matrix(angles, order)
    return out


def _local_translations(skeleton: BvhSkeleton, channels: np.ndarray) -> np.ndarray:
    t = channels.shape[0]
    out = np.broadcast_to(skeleton.offsets, (t, skeleton.num_joints, 3)).copy()
    starts = skeleton.channel_starts()
    for j, ch in enumerate(skeleton.channels):
        for k, c in enumerate(ch):
            if c.endswith("position"):
                out[:, j, "XYZ".index(c[0])] = channels[:, starts[j] + k]
    return out
