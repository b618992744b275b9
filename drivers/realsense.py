"""Intel RealSense through open3d: live cameras (open3d.t.io.RealSenseSensor) and .bag
recordings (open3d.t.io.RSBagReader) -> DepthFrame (uint16 millimetres + intrinsics).

open3d aligns depth to the colour camera (``align_depth_to_color``), and its metadata's
intrinsics are the colour camera's, so the two agree. The depth unit comes from the metadata's
``depth_scale`` (raw units per metre: 1000 on the D400 series, 4000 on the L515).

Clocks: a live frame's timestamp (microseconds) is in librealsense's domain (device clock or
its "global time"), not the host monotonic clock. ``DeviceClock`` maps it by keeping the
smallest (host arrival - device time) seen: the sample with the least transport latency.
Bag frames are placed on the host clock from the moment playback starts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from live.core.depth import intrinsics_matrix
from live.core.errors import DeviceError, DeviceNotFoundError, FormatError, UserInputError
from live.core.frames import DepthFrame
from live.core.protocols import StreamInfo

log = logging.getLogger(__name__)


# ---------------------------------------------------------------- conversions
def depth_mm_from_image(depth, depth_scale: float) -> np.ndarray:
    """An open3d (t.geometry.Image or numpy) depth image in raw units -> (H, W) uint16 mm.

    depth_scale: raw units per metre (open3d metadata convention). Values beyond 65.535 m
    saturate; non-finite values become 0 (no data).
    """
    raw = depth.as_tensor().numpy() if hasattr(depth, "as_tensor") else np.asarray(depth)
    if raw.ndim == 3:
        raw = raw[..., 0]
    if depth_scale <= 0:
        raise FormatError(f"RealSense depth scale {depth_scale} is not positive")
    if raw.dtype == np.uint16 and depth_scale == 1000.0:
        return np.array(raw, dtype=np.uint16, copy=True)
    mm = raw.astype(np.float64) * (1000.0 / depth_scale)
    mm = np.where(np.isfinite(mm), mm, 0.0)
    return np.clip(np.rint(mm), 0, 65535).astype(np.uint16)


def intrinsics_from_metadata(metadata) -> np.ndarray:
    """(3, 3) float64 intrinsics of an open3d RGBDVideoMetadata (its PinholeCameraIntrinsic)."""
    k = np.asarray(metadata.intrinsics.intrinsic_matrix, dtype=np.float64).reshape(3, 3)
    if k[0, 0] <= 0 or k[1, 1] <= 0 or (k[0, 0] == 1.0 and k[0, 2] == 0.0):
        raise FormatError("RealSense metadata has no intrinsics")
    return intrinsics_matrix(k[0, 0], k[1, 1], k[0, 2], k[1, 2])


def depth_frame_from_rgbd(rgbd, metadata, t_ns: int, camera_to_world: np.ndarray | None = None,
                          sensor: str = "realsense") -> DepthFrame:
    """An open3d t.geometry.RGBDImage + its RGBDVideoMetadata -> DepthFrame at host time t_ns."""
    depth = depth_mm_from_image(rgbd.depth, float(metadata.depth_scale))
    c2w = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
    return DepthFrame(t_ns=int(t_ns), sensor=sensor, camera_to_world=c2w, depth_mm=depth,
                      intrinsics=intrinsics_from_metadata(metadata))


def stream_info(name: str, metadata, camera_to_world: np.ndarray, **extra: Any) -> StreamInfo:
    meta = {
        "intrinsics": intrinsics_from_metadata(metadata).tolist(),
        "camera_to_world": np.asarray(camera_to_world, dtype=np.float64).tolist(),
        "width": int(metadata.width), "height": int(metadata.height), "fps": float(metadata.fps),
        "device": "realsense", "product": metadata.device_name, "serial": metadata.serial_number,
        "depth_scale": float(metadata.depth_scale), **extra,
    }
    return StreamInfo(name, "depth", meta)


class DeviceClock:
    """Maps a device timestamp (microseconds, any epoch) to host monotonic ns.

    offset = min over frames of (host arrival ns - device ns): the arrival with the least delay
    is the closest to the true offset, and later arrivals are never earlier than capture.
    """

    def __init__(self) -> None:
        self.offset_ns: int | None = None

    def to_host_ns(self, device_us: int, host_arrival_ns: int) -> int:
        device_ns = int(device_us) * 1000
        observed = int(host_arrival_ns) - device_ns
        if self.offset_ns is None or observed < self.offset_ns:
            self.offset_ns = observed
        return device_ns + self.offset_ns


# ---------------------------------------------------------------- discovery
def list_realsense_devices() -> list[dict[str, str]]:
    """[{"name", "serial"}] of the RealSense cameras open3d sees ([] when none)."""
    import open3d as o3d

    try:
        found = o3d.t.io.RealSenseSensor.enumerate_devices()
    except RuntimeError as exc:  # librealsense missing from this open3d build, or a USB error
        log.warning("RealSense discovery failed: %s", exc)
        return []
    return [{"name": str(d.name), "serial": str(d.serial)} for d in found]


def _check_device(serial: str | None) -> str:
    devices = list_realsense_devices()
    if not devices:
        raise DeviceNotFoundError("no RealSense device found (0 devices visible over USB)")
    if serial is None:
        return devices[0]["serial"]
    for d in devices:
        if d["serial"] == serial:
            return serial
    seen = ", ".join(f"{d['serial']} ({d['name']})" for d in devices)
    raise DeviceNotFoundError(f"no RealSense device {serial!r} found (visible: {seen})")


# ---------------------------------------------------------------- sources
class RealSenseSource:
    """A live RealSense camera as a livecap Source (DepthFrames named ``name``).

    width/height/fps pick the depth and colour modes; ``sensor`` injects an already built
    open3d RealSenseSensor-like object and ``host_clock`` the arrival clock (tests). A frame that does not arrive counts in
    counters["empty"]; an exception from the sensor is unrecoverable (DeviceError).
    """

    def __init__(self, serial: str | None = None, *, name: str = "realsense", width: int = 640, height: int = 480,
                 fps: int = 30, camera_to_world: np.ndarray | None = None, sensor: Any = None,
                 host_clock: Callable[[], int] = time.monotonic_ns):
        self.name = name
        self.camera_to_world = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
        self._config = {"depth_resolution": f"{width},{height}", "color_resolution": f"{width},{height}",
                        "depth_format": "RS2_FORMAT_Z16", "color_format": "RS2_FORMAT_RGB8", "fps": str(int(fps))}
        self.serial = serial if sensor is not None else _check_device(serial)
        self._sensor = sensor
        self._injected = sensor is not None
        self._metadata = None
        self._clock = DeviceClock()
        self._host_clock = host_clock
        self._counters = {"frames": 0, "empty": 0}

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def open(self) -> RealSenseSource:
        if self._metadata is not None:
            return self
        if self._sensor is None:
            import open3d as o3d

            self._sensor = o3d.t.io.RealSenseSensor()
            cfg = o3d.t.io.RealSenseSensorConfig({**self._config, "serial": self.serial})
            if not self._sensor.init_sensor(cfg, 0, ""):
                raise DeviceError(f"RealSense {self.serial}: could not configure {self._config}")
        if not self._sensor.start_capture(False):
            raise DeviceError(f"RealSense {self.serial}: could not start capturing")
        self._metadata = self._sensor.get_metadata()
        return self

    def streams(self) -> list[StreamInfo]:
        self.open()
        return [stream_info(self.name, self._metadata, self.camera_to_world)]

    def close(self) -> None:
        if self._metadata is not None and self._sensor is not None:
            self._sensor.stop_capture()
        self._metadata = None
        if not self._injected:
            self._sensor = None

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        self.open()
        try:
            while not stop.is_set():
                try:
                    rgbd = self._sensor.capture_frame(True, True)
                except RuntimeError as exc:
                    raise DeviceError(f"RealSense {self.serial}: {exc}") from None
                arrival = self._host_clock()
                if rgbd.depth.is_empty():
                    self._counters["empty"] += 1
                    continue
                t_ns = self._clock.to_host_ns(self._sensor.get_timestamp(), arrival)
                emit(depth_frame_from_rgbd(rgbd, self._metadata, t_ns, self.camera_to_world, self.name))
                self._counters["frames"] += 1
        finally:
            self.close()


class RealSenseBagSource:
    """A RealSense .bag recording replayed as a Source, at the recorded pace when ``realtime``.

    Frame i is stamped start + (bag time i - bag time 0) on the host monotonic clock, where
    start is when ``run`` began. ``reader`` injects an RSBagReader-like object (tests).
    """

    def __init__(self, path: str | Path, *, name: str = "realsense", realtime: bool = True,
                 camera_to_world: np.ndarray | None = None, reader: Any = None):
        self.path = Path(path)
        self.name = name
        self.realtime = realtime
        self.camera_to_world = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
        if reader is None and not self.path.is_file():
            raise UserInputError(f"RealSense recording {self.path} does not exist")
        self._reader = reader
        self._injected = reader is not None
        self._counters = {"frames": 0, "empty": 0}

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def open(self) -> RealSenseBagSource:
        if self._reader is None:
            import open3d as o3d

            reader = o3d.t.io.RSBagReader()
            if not reader.open(str(self.path)):
                raise FormatError("not a readable RealSense .bag recording", path=str(self.path))
            self._reader = reader
        return self

    def streams(self) -> list[StreamInfo]:
        self.open()
        return [stream_info(self.name, self._reader.metadata, self.camera_to_world, path=str(self.path))]

    def close(self) -> None:
        if self._reader is not None and not self._injected:
            self._reader.close()
            self._reader = None

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        self.open()
        reader, meta = self._reader, self._reader.metadata
        start_ns = time.monotonic_ns()
        first_us: int | None = None
        try:
            while not stop.is_set() and not reader.is_eof():
                rgbd = reader.next_frame()
                if rgbd.depth.is_empty():
                    self._counters["empty"] += 1
                    continue
                ts_us = int(reader.get_timestamp())
                first_us = ts_us if first_us is None else first_us
                t_ns = start_ns + (ts_us - first_us) * 1000
                # Pace with stop.wait so a stop request ends playback at once.
                if self.realtime and stop.wait(max(0.0, (t_ns - time.monotonic_ns()) / 1e9)):
                    return
                emit(depth_frame_from_rgbd(rgbd, meta, t_ns, self.camera_to_world, self.name))
                self._counters["frames"] += 1
        finally:
            self.close()
