"""Write BVH text (tabs, ROOT/JOINT/End Site, degrees, Blender's conventions): any ``BvhClip``,
local rotations encoded into a skeleton's channels, and canonical 22-joint motions."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from live.core.rotations import matrix_to_euler, quat_to_matrix
from live.core.skeleton import JOINT_NAMES, LEAVES, PARENTS, rest_offsets
from live.core.timing import frame_interval_s
from live.io.bvh_clip import BvhClip, BvhSkeleton


def write_bvh(path: str | Path, clip: BvhClip, *, precision: int = 6) -> None:
    """Write a clip as BVH text (tabs, ROOT/JOINT/End Site, degrees, Blender's conventions)."""
    Path(path).write_text(format_bvh(clip, precision=precision), encoding="utf-8")


def format_bvh(clip: BvhClip, *, precision: int = 6) -> str:
    sk = clip.skeleton
    if clip.channels.shape != (clip.num_frames, sk.num_channels):
        raise ValueError(f"channels {clip.channels.shape} do not match the skeleton's "
                         f"{sk.num_channels} channels")
    f = f"{{:.{precision}f}}"
    children: list[list[int]] = [[] for _ in range(sk.num_joints)]
    for j, p in enumerate(sk.parents):
        if p >= 0:
            children[p].append(j)
    ends: dict[int, list[int]] = {}
    for e, p in enumerate(sk.end_parents):
        ends.setdefault(int(p), []).append(e)
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        out.append(f"{ind}{'ROOT' if sk.parents[j] < 0 else 'JOINT'} {sk.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {' '.join(f.format(v) for v in sk.offsets[j])}")
        if sk.channels[j]:
            out.append(f"{ind}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}")
        for c in children[j]:
            emit(c, depth + 1)
        for e in ends.get(j, []):
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            out.append(f"{ind}\t\tOFFSET {' '.join(f.format(v) for v in sk.end_offsets[e])}")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    emit(0, 0)
    # The file lists joints depth-first; MOTION columns must follow that order.
    order: list[int] = []
    todo = [0]
    while todo:
        j = todo.pop()
        order.append(j)
        todo.extend(reversed(children[j]))
    starts = sk.channel_starts()
    cols = np.concatenate([np.arange(starts[j], starts[j] + len(sk.channels[j])) for j in order])
    out += ["MOTION", f"Frames: {clip.num_frames}", f"Frame Time: {clip.frame_time:.8f}"]
    buf = io.StringIO()
    buf.write("\n".join(out) + "\n")
    if clip.num_frames:
        np.savetxt(buf, clip.channels[:, cols], fmt=f"%.{precision}f", delimiter=" ")
    return buf.getvalue()


def clip_from_rotations(skeleton: BvhSkeleton, frame_time: float, rotations: np.ndarray,
                        root: np.ndarray, *, name: str = "") -> BvhClip:
    """Encode local rotations (T, J, 4) and root positions (T, 3) into the skeleton's channels.

    Every joint must have three rotation channels; the root needs its three position channels.
    Non-root position channels get the joint's offset.
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    root = np.asarray(root, dtype=np.float64)
    t = rotations.shape[0]
    mats = quat_to_matrix(rotations)
    cols = np.zeros((t, skeleton.num_channels))
    starts = skeleton.channel_starts()
    for j, ch in enumerate(skeleton.channels):
        rot = [(k, c[0]) for k, c in enumerate(ch) if c.endswith("rotation")]
        if len(rot) != 3:
            raise ValueError(f"joint {skeleton.names[j]} needs 3 rotation channels to encode")
        order = "".join(a for _, a in rot)
        ang = np.rad2deg(matrix_to_euler(mats[:, j], order))
        for i, (k, _) in enumerate(rot):
            cols[:, starts[j] + k] = ang[:, i]
        trans = root if j == 0 else np.broadcast_to(skeleton.offsets[j], (t, 3))
        for k, c in enumerate(ch):
            if c.endswith("position"):
                cols[:, starts[j] + k] = trans[:, "XYZ".index(c[0])]
    return BvhClip(skeleton=skeleton, frame_time=frame_time, channels=cols, name=name)


_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")


def canonical_skeleton(rest_joints: np.ndarray, names: Sequence[str] | None = None) -> BvhSkeleton:
    """The 22-joint canonical skeleton as a BVH hierarchy (offsets from ``rest_joints`` (22, 3)),
    with end sites that continue the leaf bones (head, wrists, feet). names: the joints' names in
    canonical order (an avatar's own bone names), default the canonical ones."""
    rest_joints = np.asarray(rest_joints, dtype=np.float64)
    joint_names = JOINT_NAMES if names is None else _checked_names(names)
    offsets = rest_offsets(rest_joints)
    end_offsets = []
    for j in LEAVES:
        # Extend the leaf's incoming bone by half its length: a visible bone in viewers.
        end_offsets.append(0.5 * offsets[j])
    return BvhSkeleton(
        names=joint_names,
        parents=PARENTS.astype(np.int64),
        offsets=offsets,
        channels=tuple(_ROOT_CHANNELS if p < 0 else _JOINT_CHANNELS for p in PARENTS),
        end_parents=np.array(LEAVES, dtype=np.int64),
        end_offsets=np.array(end_offsets).reshape(-1, 3),
    )


def _checked_names(names: Sequence[str]) -> tuple[str, ...]:
    out = tuple(str(n) for n in names)
    if len(out) != len(JOINT_NAMES):
        raise ValueError(f"{len(out)} joint names for the {len(JOINT_NAMES)} canonical joints")
    if len(set(out)) != len(out) or any(not n or n != "".join(n.split()) for n in out):
        raise ValueError(f"BVH joint names must be unique, non-empty and without whitespace: {out}")
    return out


def write_canonical_bvh(path: str | Path, rotations: np.ndarray, root: np.ndarray,
                        rest_joints: np.ndarray, fps: float, *, precision: int = 6,
                        names: Sequence[str] | None = None) -> None:
    """Write a canonical 22-joint motion (rotations (T, 22, 4) local, root (T, 3) world metres,
    rest_joints (22, 3) T-pose) as a metre-unit BVH whose FK equals
    ``forward_kinematics(rotations, root, rest_joints)``. names: the joints' names in the file
    (canonical order; default the canonical names): only the names change, not the motion."""
    rotations = np.asarray(rotations, dtype=np.float64)
    if rotations.ndim != 3 or rotations.shape[1:] != (len(JOINT_NAMES), 4):
        raise ValueError(f"rotations must be (T, 22, 4), got {rotations.shape}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    clip = clip_from_rotations(canonical_skeleton(rest_joints, names), frame_interval_s(fps), rotations, root)
    write_bvh(path, clip, precision=precision)
