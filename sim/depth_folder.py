"""Depth recorded by other tools: a folder of 16-bit PNG depth images (millimetres, 0 = no
data) plus ``intrinsics.json``, replayed in file-name order like a session.

intrinsics.json: {"fx", "fy", "cx", "cy", "width", "height"} and optionally "fps" (default 30),
"camera_to_world" (4x4 list) and "timestamps_ns" (one per image). See ../shared/CONVENTIONS.md.
Every field is checked when the folder is opened (a FormatError names the first one that is
wrong), and so is every image's PNG header (16-bit grayscale of width x height): no image is
decoded before its declared size is known to fit. Images that fail are skipped and counted
(``bad_images``); a folder where every image fails is an error.
"""

from __future__ import annotations

import math
import struct
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from live.core.depth import intrinsics_matrix
from live.core.errors import FormatError, UserInputError
from live.core.frames import DepthFrame
from live.core.jsonfile import read_json
from live.core.protocols import StreamInfo
from live.core.timing import frame_interval_ns, seconds_between

#: Ceilings of what intrinsics.json may declare (docs/reliability.md): a side of 8192 pixels
#: and 2^25 pixels (64 MiB of 16-bit depth) per image, 0.01-1000 fps, timestamps spanning 11.6 days.
MAX_IMAGE_SIDE = 8192
MAX_IMAGE_PIXELS = 1 << 25
MIN_FPS, MAX_FPS = 0.01, 1000.0
MAX_SPAN_NS = 1_000_000 * 1_000_000_000
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class FolderMeta:
    """What intrinsics.json says, checked: intrinsics (3, 3), image size, fps, camera_to_world
    (4, 4) rigid, timestamps_ns (one per image, strictly increasing) or None."""

    intrinsics: np.ndarray
    width: int
    height: int
    fps: float
    camera_to_world: np.ndarray
    timestamps_ns: list[int] | None = field(default=None)


def _number(meta: dict, key: str, where: str, *, positive: bool = False, default: float | None = None) -> float:
    value = meta.get(key, default)
    if value is None:
        raise FormatError(f"intrinsics.json has no {key!r}", path=where)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FormatError(f"{key} must be a finite number, not {value!r}", path=where)
    if positive and not value > 0:
        raise FormatError(f"{key} must be > 0, not {value!r}", path=where)
    return float(value)


def _side(meta: dict, key: str, where: str) -> int:
    value = _number(meta, key, where, positive=True)
    if value != int(value) or value > MAX_IMAGE_SIDE:
        raise FormatError(f"{key} must be a whole number of pixels in 1..{MAX_IMAGE_SIDE}, not {meta[key]!r}",
                          path=where)
    return int(value)


def _camera_to_world(value, where: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=np.float64)
    except (ValueError, TypeError):
        m = np.zeros(0)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise FormatError("camera_to_world must be a 4x4 list of finite numbers", path=where)
    rot = m[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # 1e308 entries: not rigid, no warning
        rigid = np.allclose(rot.T @ rot, np.eye(3), atol=1e-3) and np.linalg.det(rot) > 0
    if not np.allclose(m[3], [0, 0, 0, 1]) or not rigid:
        raise FormatError("camera_to_world must be a rigid transform (a rotation and a translation)", path=where)
    return m


def _timestamps(value, count: int, where: str) -> list[int]:
    if not isinstance(value, list):
        raise FormatError(f"timestamps_ns must be a list of integers, not {type(value).__name__}", path=where)
    if len(value) != count:
        raise FormatError(f"timestamps_ns has {len(value)} entries for {count} images", path=where)
    out = []
    for i, t in enumerate(value):
        ok = isinstance(t, int) and not isinstance(t, bool) or isinstance(t, float) and t.is_integer()
        if not ok or not 0 <= t < 2**63:
            raise FormatError(f"timestamps_ns[{i}] must be an integer in 0..2^63-1, not {t!r}", path=where)
        out.append(int(t))
    if any(b <= a for a, b in zip(out, out[1:])):
        raise FormatError("timestamps_ns must increase from image to image", path=where)
    if out and out[-1] - out[0] > MAX_SPAN_NS:
        raise FormatError(f"timestamps_ns span {(out[-1] - out[0]) / 1e9:.3g} s, more than "
                          f"{MAX_SPAN_NS / 1e9:.0f} s", path=where)
    return out


def read_folder_meta(path: Path, image_count: int) -> FolderMeta:
    """Read and check a depth folder's intrinsics.json (FormatError naming what is wrong)."""
    where = str(path)
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise FormatError("intrinsics.json must be a JSON object", path=where)
    fx, fy = _number(meta, "fx", where, positive=True), _number(meta, "fy", where, positive=True)
    cx, cy = _number(meta, "cx", where), _number(meta, "cy", where)
    width, height = _side(meta, "width", where), _side(meta, "height", where)
    if width * height > MAX_IMAGE_PIXELS:
        raise FormatError(f"{width}x{height} images are larger than {MAX_IMAGE_PIXELS} pixels", path=where)
    fps = _number(meta, "fps", where, positive=True, default=30.0)
    if not MIN_FPS <= fps <= MAX_FPS:
        raise FormatError(f"fps must be in {MIN_FPS:g}..{MAX_FPS:g}, not {fps:g}", path=where)
    c2w = _camera_to_world(meta["camera_to_world"], where) if "camera_to_world" in meta else np.eye(4)
    stamps = meta.get("timestamps_ns")
    return FolderMeta(intrinsics_matrix(fx, fy, cx, cy), width, height, fps, c2w,
                      None if stamps is None else _timestamps(stamps, image_count, where))


def png_problem(path: Path, width: int, height: int) -> str | None:
    """Why ``path`` is not a 16-bit grayscale PNG of width x height (from its header alone), or None."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return png_problem_of_bytes(head, width, height)


def png_problem_of_bytes(head: bytes, width: int, height: int) -> str | None:
    """``png_problem`` of a PNG's first bytes (at least 26)."""
    if len(head) < 26 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return "not a PNG file"
    w, h, bits, colour = struct.unpack(">IIBB", head[16:26])
    if bits != 16 or colour != 0:
        return f"{bits}-bit {'grayscale' if colour == 0 else 'colour'} (depth images are 16-bit grayscale)"
    if (w, h) != (width, height):
        return f"{w}x{h}, not the {width}x{height} of intrinsics.json"
    return None


#: Deflate's largest compression ratio: image data this many times smaller than the raw pixels
#: cannot hold them.
_DEFLATE_MAX_RATIO = 1032


def png_chunks_problem(data: bytes, width: int, height: int) -> str | None:
    """Why a 16-bit grayscale PNG's bytes are damaged (a chunk running past the end, a chunk CRC
    that does not match, no IEND, too little image data for width x height), or None. Checked
    before decoding: libpng would print its own complaint about a damaged stream to stderr,
    where only livecap's one line belongs."""
    i = len(_PNG_SIGNATURE)
    image_bytes = 0
    while i + 12 <= len(data):
        (length,) = struct.unpack_from(">I", data, i)
        end = i + 12 + length
        if end > len(data):
            return f"a PNG chunk at byte {i} runs past the end of the file"
        if zlib.crc32(data[i + 4:end - 4]) != struct.unpack_from(">I", data, end - 4)[0]:
            return f"the PNG chunk at byte {i} fails its CRC"
        kind = data[i + 4:i + 8]
        if kind == b"IDAT":
            image_bytes += length
        if kind == b"IEND":
            if image_bytes * _DEFLATE_MAX_RATIO < height * (1 + 2 * width):
                return f"{image_bytes} bytes of image data cannot hold {width}x{height} pixels"
            return None
        i = end
    return "the PNG ends before its IEND chunk"


class DepthFolderSource:
    def __init__(self, folder: str | Path, *, speed: float | None = None, name: str | None = None):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise UserInputError(f"no such depth folder: {self.folder}")
        meta_path = self.folder / "intrinsics.json"
        if not meta_path.is_file():
            raise FormatError("a depth folder needs intrinsics.json (fx, fy, cx, cy, width, height)",
                              path=str(self.folder))
        self.images = sorted(self.folder.glob("*.png"))
        if not self.images:
            raise FormatError("no *.png depth images", path=str(self.folder))
        meta = read_folder_meta(meta_path, len(self.images))
        self.intrinsics, self.width, self.height, self.fps = meta.intrinsics, meta.width, meta.height, meta.fps
        self.camera_to_world = meta.camera_to_world
        # Header problems per image, known before anything is decoded.
        self.problems = {i: p for i, img in enumerate(self.images)
                         if (p := png_problem(img, self.width, self.height)) is not None}
        if len(self.problems) == len(self.images):
            first = self.problems[0]
            raise FormatError(f"none of the {len(self.images)} images is usable: {self.images[0].name} is {first}",
                              path=str(self.folder))
        period = frame_interval_ns(self.fps)
        self.timestamps = meta.timestamps_ns or [i * period for i in range(len(self.images))]
        self.name = name or self.folder.name or "folder"
        self.speed = speed
        self.error: str | None = None
        self._counters = {"frames": 0, "bad_images": 0}

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def streams(self) -> list[StreamInfo]:
        return [StreamInfo(self.name, "depth", {
            "intrinsics": self.intrinsics.tolist(), "camera_to_world": self.camera_to_world.tolist(),
            "width": self.width, "height": self.height, "fps": self.fps, "folder": str(self.folder)})]

    def read(self, i: int) -> np.ndarray | None:
        """Image i as (height, width) uint16, or None when it is not one (counted by ``run``)."""
        if i in self.problems:
            return None
        try:
            data = self.images[i].read_bytes()
        except OSError as exc:
            self.problems[i] = f"unreadable ({exc.strerror or exc})"
            return None
        problem = png_problem_of_bytes(data, self.width, self.height) or png_chunks_problem(data, self.width, self.height)
        if problem is not None:
            self.problems[i] = problem
            return None
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            return None
        if img is None or img.dtype != np.uint16 or img.shape != (self.height, self.width):
            return None
        return img

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        start = time.monotonic()
        t0 = self.timestamps[0]
        try:
            for i, t_ns in enumerate(self.timestamps):
                if stop.is_set():
                    return
                if self.speed:
                    delay = start + seconds_between(t0, t_ns) / self.speed - time.monotonic()
                    if delay > 0 and stop.wait(delay):
                        return
                img = self.read(i)
                if img is None:
                    # An unreadable or non-16-bit image is a counted event, not the end of the replay.
                    self._counters["bad_images"] += 1
                    continue
                self._counters["frames"] += 1
                emit(DepthFrame(t_ns=t_ns, sensor=self.name, camera_to_world=self.camera_to_world,
                                depth_mm=img, intrinsics=self.intrinsics))
        finally:
            bad = self._counters["bad_images"]
            if bad:
                first = min(self.problems.items(), default=None)
                self.error = (f"{self.folder}: skipped {bad} of {len(self.images)} images"
                              + (f" (first: {self.images[first[0]].name}: {first[1]})" if first else " (not decodable)"))


__all__ = ["DepthFolderSource", "FolderMeta", "png_chunks_problem", "png_problem", "read_folder_meta"]
