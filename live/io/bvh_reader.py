"""Read BVH text into a ``BvhClip`` (any channel layout; lengths scaled to metres on request,
the unit guessed from the body size when asked). Malformed files raise FormatError with the line.
Conventions: live/io/bvh_clip.py.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.io.bvh_clip import BvhClip, BvhSkeleton
from live.io.bvh_kinematics import skeleton_span

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
#: Ceilings of a BVH file (docs/reliability.md), checked before the motion rows are parsed: the
#: file size, joints, declared frames and values (frames x channels: a 96-channel rig's 62 500
#: frames, 8.7 min at 120 fps, take about 1 GB once mapped to the canonical skeleton), the frame
#: time (10 kHz to 0.1 Hz) and the clip's length (a day).
MAX_BVH_BYTES = 512 * 1024 * 1024
MAX_BVH_JOINTS = 1000
MAX_BVH_FRAMES = 500_000
MAX_BVH_VALUES = 6_000_000
MIN_FRAME_TIME_S, MAX_FRAME_TIME_S = 1e-4, 10.0
MAX_CLIP_SECONDS = 24 * 3600.0
#: Largest magnitude of an OFFSET or a motion value (file units or degrees): no length or angle
#: is larger, and 1e308 would overflow to inf in the first product.
MAX_BVH_MAGNITUDE = 1e9


def read_bvh(path: str | Path, *, scale: float | str = 1.0) -> BvhClip:
    """Read a BVH file. ``scale`` multiplies lengths (offsets and position channels): a number
    (metres per file unit), a key of UNIT_SCALES, or "auto" for ``guess_scale``."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_BVH_BYTES:
            raise FormatError(f"larger than the {MAX_BVH_BYTES >> 20} MiB a BVH file may be", path=str(path))
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
    if len(skeleton.names) > MAX_BVH_JOINTS:
        raise FormatError(f"{len(skeleton.names)} joints, more than the {MAX_BVH_JOINTS} a BVH rig may have",
                          path=where, line=motion_line + 1)
    frames, frame_time, data_line = _parse_motion_header(lines, motion_line, where)
    _check_motion_size(frames, frame_time, skeleton.num_channels, where, motion_line + 2)
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
            x, y, z = _floats(tok[1:], 3, "OFFSET", where, lineno)
            vals = (x, y, z)
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
    if max(abs(v) for v in vals) > MAX_BVH_MAGNITUDE:
        raise FormatError(f"{what} has a value beyond ±{MAX_BVH_MAGNITUDE:g}: {' '.join(tok)!r}", path=where,
                          line=lineno)
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


def _check_motion_size(frames: int, frame_time: float, ncols: int, where: str, line: int) -> None:
    """The declared motion against the ceilings above, before any row is parsed."""
    if frames > MAX_BVH_FRAMES:
        raise FormatError(f"declares {frames} frames, more than the {MAX_BVH_FRAMES} a BVH clip may have",
                          path=where, line=line)
    if frames * ncols > MAX_BVH_VALUES:
        raise FormatError(f"declares {frames} frames of {ncols} channels, more than the {MAX_BVH_VALUES} values "
                          "a BVH clip may hold", path=where, line=line)
    if not MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S:
        raise FormatError(f"frame time {frame_time:g} s is outside {MIN_FRAME_TIME_S:g}..{MAX_FRAME_TIME_S:g} s",
                          path=where, line=line + 1)
    if frames * frame_time > MAX_CLIP_SECONDS:
        raise FormatError(f"{frames} frames of {frame_time:g} s last {frames * frame_time:.0f} s, more than the "
                          f"{MAX_CLIP_SECONDS:.0f} s a BVH clip may last", path=where, line=line + 1)


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
    if values.size == frames * ncols and np.isfinite(values).all() and \
            (values.size == 0 or np.abs(values).max() <= MAX_BVH_MAGNITUDE):
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
        if np.abs(vals).max() > MAX_BVH_MAGNITUDE:
            raise FormatError(f"frame {row} has a value beyond ±{MAX_BVH_MAGNITUDE:g}", path=where, line=lineno)
        row += 1
    raise FormatError(f"truncated MOTION: {row} of {frames} frames", path=where,
                      line=start + len(lines))


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _position_columns(skeleton: BvhSkeleton) -> np.ndarray:
    starts = skeleton.channel_starts()
    cols = [starts[j] + k for j, ch in enumerate(skeleton.channels)
            for k, c in enumerate(ch) if c.endswith("position")]
    return np.array(cols, dtype=np.int64)


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
