"""BVH (Biovision Hierarchy) reading, writing and forward kinematics for any rig.

Conventions (the ones Blender's importer and the CMU conversions follow):
- OFFSET is a joint's rest translation in its parent's frame. A joint with position channels
  uses the channel values as its local translation instead of the offset (for the root they are
  its world position).
- Rotation channels are degrees; their order in CHANNELS is the Euler order, applied as
  R = R_first @ R_second @ R_third (intrinsic), e.g. "Zrotation Xrotation Yrotation" -> "ZXY".
  Joints may have any subset and order of the six channels.
- World: whatever the file uses; BVH files are y-up by convention and this module keeps their axes.

Shapes: T frames, J joints, E end sites, C channels. Joint positions (T, J, 3), global rotation
matrices (T, J, 3, 3), local quaternions (T, J, 4) as (w, x, y, z).
"""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.rotations import euler_to_matrix, matrix_to_euler, matrix_to_quat, quat_to_matrix
from live.core.skeleton import JOINT_NAMES, PARENTS, rest_offsets

_CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CHANNEL_LOOKUP = {c.lower(): c for c in _CHANNEL_NAMES}

#: Candidate length units of BVH files, in metres per file unit (see guess_scale).
UNIT_SCALES: dict[str, float] = {
    "m": 1.0,
    "dm": 0.1,
    "inch": 0.0254,
    "cmu": 0.0254 / 0.45,  # CMU ASF/cgspeed "mb" unit: 1/0.45 inch
    "cm": 0.01,
    "mm": 0.001,
}
#: Typical toe-to-fingertip path length of an adult, metres (see guess_scale).
SPAN_M = 2.3


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


# ----------------------------------------------------------------------------- parsing


def read_bvh(path: str | Path, *, scale: float | str = 1.0) -> BvhClip:
    """Read a BVH file. ``scale`` multiplies lengths (offsets and position channels): a number
    (metres per file unit), a key of UNIT_SCALES, or "auto" for ``guess_scale``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise FormatError(f"cannot read BVH file: {exc.strerror or exc}", path=str(path)) from exc
    return parse_bvh(text, name=path.stem, path=str(path), scale=scale)


def parse_bvh(text: str, *, name: str = "", path: str | None = None,
              scale: float | str = 1.0) -> BvhClip:
    """Parse BVH text (see ``read_bvh``)."""
    where = path or "<bvh>"
    # Only the text before the motion rows is split into lines; the rows go to numpy whole.
    m = re.search(r"^[ \t]*Frame[ \t]+Time[^\n]*\n?", text, re.MULTILINE | re.IGNORECASE)
    head_end = m.end() if m else len(text)
    lines = text[:head_end].splitlines()
    skeleton, motion_line = _parse_hierarchy(lines, where)
    frames, frame_time, data_line = _parse_motion_header(lines, motion_line, where)
    channels = _parse_motion_rows(text[head_end:], data_line, frames, skeleton.num_channels,
                                  where)
    if isinstance(scale, str):
        if scale == "auto":
            scale = guess_scale(skeleton)
        elif scale in UNIT_SCALES:
            scale = UNIT_SCALES[scale]
        else:
            raise FormatError(f"unknown BVH unit {scale!r} (use a number, 'auto' or one of "
                              f"{', '.join(UNIT_SCALES)})", path=where)
    scale = float(scale)
    if scale != 1.0:
        skeleton = skeleton.scaled(scale)
        channels = channels.copy()
        channels[:, _position_columns(skeleton)] *= scale
    return BvhClip(skeleton=skeleton, frame_time=frame_time, channels=channels, name=name)


def _parse_hierarchy(lines: list[str], where: str) -> tuple[BvhSkeleton, int]:
    """Parse up to the MOTION keyword; returns the skeleton and the index of the MOTION line."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[tuple[float, float, float]] = []
    stack: list[int] = []  # joint index per open brace; -2 marks an End Site block
    pending: int | None = None  # a joint/end site declared, its "{" not yet seen
    current: int | None = None  # the block whose OFFSET/CHANNELS we expect
    seen_hierarchy = False
    for i, raw in enumerate(lines):
        tok = raw.split()
        if not tok:
            continue
        key = tok[0].upper()
        lineno = i + 1
        if key == "HIERARCHY":
            seen_hierarchy = True
        elif key in ("ROOT", "JOINT"):
            if key == "ROOT" and (stack or names):
                raise FormatError("only one ROOT is supported", path=where, line=lineno)
            if key == "JOINT" and not stack:
                raise FormatError("JOINT outside a ROOT block", path=where, line=lineno)
            if stack and stack[-1] == -2:
                raise FormatError("JOINT inside an End Site", path=where, line=lineno)
            names.append(" ".join(tok[1:]) or f"joint{len(names)}")
            parents.append(stack[-1] if stack else -1)
            offsets.append((0.0, 0.0, 0.0))
            channels.append(())
            pending = current = len(names) - 1
        elif key == "END":
            if not stack or stack[-1] < 0:
                raise FormatError("End Site outside a joint", path=where, line=lineno)
            end_parents.append(stack[-1])
            end_offsets.append((0.0, 0.0, 0.0))
            pending = -2
            current = -2
        elif key == "{":
            if pending is None:
                raise FormatError("unexpected '{'", path=where, line=lineno)
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                raise FormatError("unbalanced '}'", path=where, line=lineno)
            stack.pop()
            current = stack[-1] if stack else None
        elif key == "OFFSET":
            vals = _floats(tok[1:], 3, "OFFSET", where, lineno)
            if current == -2:
                end_offsets[-1] = vals
            elif current is not None:
                offsets[current] = vals
            else:
                raise FormatError("OFFSET outside a joint", path=where, line=lineno)
        elif key == "CHANNELS":
            if current is None or current < 0:
                raise FormatError("CHANNELS outside a joint", path=where, line=lineno)
            channels[current] = _channels(tok[1:], where, lineno)
        elif key == "MOTION":
            if stack or pending is not None:
                raise FormatError("truncated HIERARCHY: MOTION before all joint blocks are "
                                  "closed", path=where, line=lineno)
            if not names:
                raise FormatError("no ROOT joint before MOTION", path=where, line=lineno)
            skeleton = BvhSkeleton(
                names=tuple(names),
                parents=np.array(parents, dtype=np.int64),
                offsets=np.array(offsets, dtype=np.float64).reshape(-1, 3),
                channels=tuple(channels),
                end_parents=np.array(end_parents, dtype=np.int64),
                end_offsets=np.array(end_offsets, dtype=np.float64).reshape(-1, 3),
            )
            return skeleton, i
        else:
            raise FormatError(f"unexpected {tok[0]!r} in HIERARCHY", path=where, line=lineno)
    if not seen_hierarchy:
        raise FormatError("not a BVH file (no HIERARCHY)", path=where, line=1)
    if stack or pending is not None:
        raise FormatError("truncated HIERARCHY: file ends inside a joint block", path=where,
                          line=len(lines))
    raise FormatError("missing MOTION block", path=where, line=len(lines))


def _floats(tok: list[str], n: int, what: str, where: str, lineno: int) -> tuple[float, ...]:
    if len(tok) != n:
        raise FormatError(f"{what} needs {n} numbers, got {len(tok)}", path=where, line=lineno)
    try:
        vals = tuple(float(t) for t in tok)
    except ValueError:
        raise FormatError(f"{what} has a non-number: {' '.join(tok)!r}", path=where,
                          line=lineno) from None
    if not all(np.isfinite(vals)):
        raise FormatError(f"{what} is not finite: {' '.join(tok)!r}", path=where, line=lineno)
    return vals


def _channels(tok: list[str], where: str, lineno: int) -> tuple[str, ...]:
    try:
        n = int(tok[0])
    except (IndexError, ValueError):
        raise FormatError("CHANNELS needs a count", path=where, line=lineno) from None
    if n != len(tok) - 1:
        raise FormatError(f"CHANNELS says {n} but lists {len(tok) - 1}", path=where, line=lineno)
    out = []
    for t in tok[1:]:
        c = _CHANNEL_LOOKUP.get(t.lower())
        if c is None:
            raise FormatError(f"unknown channel {t!r}", path=where, line=lineno)
        if c in out:
            raise FormatError(f"channel {c} listed twice", path=where, line=lineno)
        out.append(c)
    return tuple(out)


def _parse_motion_header(lines: list[str], motion_line: int, where: str) -> tuple[int, float, int]:
    """'Frames: N' and 'Frame Time: dt' after MOTION; returns (N, dt, first data line index)."""
    found: dict[str, str] = {}
    i = motion_line + 1
    while i < len(lines) and len(found) < 2:
        s = lines[i].strip()
        i += 1
        if not s:
            continue
        key, _, value = s.partition(":")
        key = " ".join(key.lower().split())
        if key not in ("frames", "frame time") or not value.strip():
            raise FormatError(f"expected 'Frames:' and 'Frame Time:', got {s[:40]!r}", path=where,
                              line=i)
        found[key] = value.strip()
        try:
            if key == "frames":
                frames = int(value)
                if frames < 0:
                    raise ValueError
            else:
                frame_time = float(value)
                if not (np.isfinite(frame_time) and frame_time > 0):
                    raise ValueError
        except ValueError:
            raise FormatError(f"bad {key} value {value.strip()!r}", path=where, line=i) from None
    if len(found) < 2:
        raise FormatError("truncated MOTION header", path=where, line=len(lines))
    return frames, frame_time, i


def _parse_motion_rows(body: str, start: int, frames: int, ncols: int,
                       where: str) -> np.ndarray:
    """The MOTION rows (``body``, starting at 0-based line ``start``) as a (T, C) float64 array;
    fast path in C, slow path only to explain an error (which line, what is wrong)."""
    try:
        with warnings.catch_warnings():
            # Older numpy warns (newer raises) when it stops early on a bad token.
            warnings.simplefilter("ignore", DeprecationWarning)
            values = np.fromstring(body, dtype=np.float64, sep=" ")
    except ValueError:
        values = np.zeros(0)
    if values.size == frames * ncols and np.isfinite(values).all():
        return values.reshape(frames, ncols)
    # Slow path: find the first offending line.
    row = 0
    lines = body.splitlines()
    for i, line in enumerate(lines):
        tok = line.split()
        if not tok:
            continue
        lineno = start + i + 1
        if row >= frames:
            raise FormatError(f"more motion rows than the {frames} frames declared", path=where,
                              line=lineno)
        if len(tok) != ncols:
            raise FormatError(f"frame {row} has {len(tok)} values, the hierarchy needs {ncols}",
                              path=where, line=lineno)
        try:
            vals = np.array([float(t) for t in tok])
        except ValueError:
            bad = next(t for t in tok if not _is_float(t))
            raise FormatError(f"frame {row} has a non-number {bad!r}", path=where,
                              line=lineno) from None
        if not np.isfinite(vals).all():
            raise FormatError(f"frame {row} has a NaN or infinite value", path=where, line=lineno)
        row += 1
    raise FormatError(f"truncated MOTION: {row} of {frames} frames", path=where,
                      line=start + len(lines))


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


# ----------------------------------------------------------------------------- channels


def _position_columns(skeleton: BvhSkeleton) -> np.ndarray:
    starts = skeleton.channel_starts()
    cols = [starts[j] + k for j, ch in enumerate(skeleton.channels)
            for k, c in enumerate(ch) if c.endswith("position")]
    return np.array(cols, dtype=np.int64)


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


# ----------------------------------------------------------------------------- kinematics


def bvh_forward_kinematics(clip: BvhClip, *, end_sites: bool = False
                           ) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions (T, J, 3) and global rotations (T, J, 3, 3) of every frame.

    With ``end_sites`` the positions are (T, J + E, 3) and rotations (T, J + E, 3, 3): end sites
    follow the joints, in ``skeleton.end_names()`` order, with their parent's rotation.
    """
    return skeleton_forward_kinematics(clip.skeleton, clip.local_rotations(),
                                       clip.local_translations(), end_sites=end_sites)


def skeleton_forward_kinematics(skeleton: BvhSkeleton, local_rot: np.ndarray,
                                local_trans: np.ndarray, *, end_sites: bool = False
                                ) -> tuple[np.ndarray, np.ndarray]:
    """FK from local rotations (T, J, 3, 3) and local translations (T, J, 3)."""
    ne = len(skeleton.end_parents) if end_sites else 0
    # Per-joint contiguous (T, 3, 3) blocks: strided views of a (T, J, 3, 3) array make
    # numpy's small-matrix products several times slower.
    rot = np.ascontiguousarray(np.moveaxis(local_rot, 1, 0))
    trans = np.ascontiguousarray(np.moveaxis(local_trans, 1, 0))
    glob: list[np.ndarray] = []
    pos: list[np.ndarray] = []
    for j, p in enumerate(skeleton.parents):
        if p < 0:
            glob.append(rot[j])
            pos.append(trans[j])
        else:
            glob.append(glob[p] @ rot[j])
            pos.append(pos[p] + np.einsum("tij,tj->ti", glob[p], trans[j]))
    for e in range(ne):
        p = skeleton.end_parents[e]
        glob.append(glob[p])
        pos.append(pos[p] + glob[p] @ skeleton.end_offsets[e])
    return np.stack(pos, axis=1), np.stack(glob, axis=1)


def rest_positions(skeleton: BvhSkeleton, *, end_sites: bool = False) -> np.ndarray:
    """(J, 3) (or (J + E, 3)) world positions of the zero-rotation pose, root at its offset."""
    n = skeleton.num_joints
    pos, _ = skeleton_forward_kinematics(
        skeleton, np.broadcast_to(np.eye(3), (1, n, 3, 3)), skeleton.offsets[None],
        end_sites=end_sites)
    return pos[0]


def guess_scale(skeleton: BvhSkeleton) -> float:
    """Metres per file unit, guessed from the body size in the file's units.

    The size is the longest path between two leaves along the bones (toe to fingertip through
    the spine: 2.2-2.6 m for an adult, whatever the rest pose; 2.2 m on the CMU rigs). The unit
    of UNIT_SCALES that brings it closest to SPAN_M (in log scale) wins: neighbouring units
    differ by >2x, so children and tall adults still get the right unit.
    """
    size = skeleton_span(skeleton)
    if size <= 0:
        return 1.0
    best = min(UNIT_SCALES.values(), key=lambda s: abs(np.log(size * s / SPAN_M)))
    return float(best)


def skeleton_span(skeleton: BvhSkeleton) -> float:
    """Longest leaf-to-leaf path length through the hierarchy (tree diameter), file units."""
    n = skeleton.num_joints
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    down = np.zeros(n)  # longest path from each joint down to a leaf of its subtree
    for e, p in enumerate(skeleton.end_parents):
        down[p] = max(down[p], float(np.linalg.norm(skeleton.end_offsets[e])))
    best = 0.0
    for j in range(n - 1, 0, -1):  # children come after parents in file order
        p = skeleton.parents[j]
        cand = down[j] + lengths[j]
        best = max(best, down[p] + cand)  # joins the best branch seen so far at p
        down[p] = max(down[p], cand)
    return float(max(best, down[0]))


# ----------------------------------------------------------------------------- writing


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


def canonical_skeleton(rest_joints: np.ndarray) -> BvhSkeleton:
    """The 22-joint canonical skeleton as a BVH hierarchy (offsets from ``rest_joints`` (22, 3)),
    with end sites that continue the leaf bones (head, wrists, feet)."""
    rest_joints = np.asarray(rest_joints, dtype=np.float64)
    offsets = rest_offsets(rest_joints)
    leaves = [j for j in range(len(JOINT_NAMES)) if j not in set(PARENTS.tolist())]
    end_offsets = []
    for j in leaves:
        # Extend the leaf's incoming bone by half its length: a visible bone in viewers.
        end_offsets.append(0.5 * offsets[j])
    return BvhSkeleton(
        names=JOINT_NAMES,
        parents=PARENTS.astype(np.int64),
        offsets=offsets,
        channels=tuple(_ROOT_CHANNELS if p < 0 else _JOINT_CHANNELS for p in PARENTS),
        end_parents=np.array(leaves, dtype=np.int64),
        end_offsets=np.array(end_offsets).reshape(-1, 3),
    )


def write_canonical_bvh(path: str | Path, rotations: np.ndarray, root: np.ndarray,
                        rest_joints: np.ndarray, fps: float, *, precision: int = 6) -> None:
    """Write a canonical 22-joint motion (rotations (T, 22, 4) local, root (T, 3) world metres,
    rest_joints (22, 3) T-pose) as a metre-unit BVH whose FK equals
    ``forward_kinematics(rotations, root, rest_joints)``."""
    rotations = np.asarray(rotations, dtype=np.float64)
    if rotations.ndim != 3 or rotations.shape[1:] != (len(JOINT_NAMES), 4):
        raise ValueError(f"rotations must be (T, 22, 4), got {rotations.shape}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    clip = clip_from_rotations(canonical_skeleton(rest_joints), 1.0 / fps, rotations, root)
    write_bvh(path, clip, precision=precision)
