"""Depth recorded by other tools: a folder of 16-bit PNG depth images (millimetres, 0 = no
data) plus ``intrinsics.json``, replayed in file-name order like a session.

intrinsics.json: {"fx", "fy", "cx", "cy", "width", "height"} and optionally "fps" (default 30),
"camera_to_world" (4x4 list) and "timestamps_ns" (one per image). See ../shared/CONVENTIONS.md.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from live.core.depth import intrinsics_matrix
from live.core.errors import FormatError, UserInputError
from live.core.frames import DepthFrame
from live.core.protocols import StreamInfo
from live.core.timing import frame_interval_ns, seconds_between


class DepthFolderSource:
    def __init__(self, folder: str | Path, *, speed: float | None = None, name: str | None = None):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise UserInputError(f"no such depth folder: {self.folder}")
        meta_path = self.folder / "intrinsics.json"
        if not meta_path.is_file():
            raise FormatError("a depth folder needs intrinsics.json (fx, fy, cx, cy, width, height)",
                              path=str(self.folder))
        try:
            meta = json.loads(meta_path.read_text())
            self.intrinsics = intrinsics_matrix(float(meta["fx"]), float(meta["fy"]),
                                                float(meta["cx"]), float(meta["cy"]))
            self.width, self.height = int(meta["width"]), int(meta["height"])
        except (ValueError, KeyError, TypeError) as exc:
            raise FormatError(f"bad intrinsics.json ({exc})", path=str(meta_path)) from None
        self.fps = float(meta.get("fps", 30.0))
        self.camera_to_world = np.asarray(meta.get("camera_to_world", np.eye(4)), dtype=np.float64)
        if self.camera_to_world.shape != (4, 4):
            raise FormatError("camera_to_world must be a 4x4 list", path=str(meta_path))
        self.images = sorted(self.folder.glob("*.png"))
        if not self.images:
            raise FormatError("no *.png depth images", path=str(self.folder))
        stamps = meta.get("timestamps_ns")
        if stamps is not None and len(stamps) != len(self.images):
            raise FormatError(f"timestamps_ns has {len(stamps)} entries for {len(self.images)} images",
                              path=str(meta_path))
        period = frame_interval_ns(self.fps)
        self.timestamps = [int(t) for t in stamps] if stamps is not None else [i * period for i in range(len(self.images))]
        self.name = name or self.folder.name or "folder"
        self.speed = speed
        self._counters = {"frames": 0, "bad_images": 0}

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def streams(self) -> list[StreamInfo]:
        return [StreamInfo(self.name, "depth", {
            "intrinsics": self.intrinsics.tolist(), "camera_to_world": self.camera_to_world.tolist(),
            "width": self.width, "height": self.height, "fps": self.fps, "folder": str(self.folder)})]

    def read(self, i: int) -> np.ndarray | None:
        img = cv2.imread(str(self.images[i]), cv2.IMREAD_UNCHANGED)
        if img is None or img.dtype != np.uint16 or img.ndim != 2:
            return None
        return img

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        start = time.monotonic()
        t0 = self.timestamps[0]
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
