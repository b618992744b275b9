"""OAK-D depth camera driver (depthai 3.x): device stereo depth -> DepthFrame, device IMU -> MocapPacket.

The IMU streams as ``<name>_imu``: the accelerometer and gyro in the depth camera's axes (the
reports depthai aligns on the device, ``imu_reports``, with the calibration's fine correction,
``aligned_imu_correction``), the BNO08x's fused orientation as the chip's own. The skeleton stage
takes world up from its still periods (live.core.gravity).

Clocks: depthai stamps every message twice. ``getTimestampDevice()`` is the camera's own clock;
``getTimestamp()`` is that instant already converted by depthai's time sync to the host's
steady clock (``dai.Clock.now()``). On Linux that clock is CLOCK_MONOTONIC, the same one as
time.monotonic_ns(), but nothing promises it elsewhere, so the driver measures the offset
between the two host clocks once per connection (``measure_clock_offset``) and adds it.

Only the functions at the top touch depthai message objects, and all of them work on objects
built on the host, so they are tested without a camera. ``OakSource`` takes an ``opener`` (a
factory of sessions) so its gap / reconnect / shutdown logic is tested with a fake session too.
"""

from __future__ import annotations

import datetime
import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from drivers.oak_settings import OakSettings, apply_stereo_config, oak_settings, stereo_config
from live.core.errors import DeviceError, DeviceNotFoundError
from live.core.frames import DepthFrame, MocapPacket
from live.core.gravity import CAMERA_IMU_SUFFIX
from live.core.protocols import StreamInfo
from live.core.rotations import matrix_to_quat, quat_multiply

log = logging.getLogger(__name__)


# ---------------------------------------------------------------- clocks
def timedelta_to_ns(td: datetime.timedelta) -> int:
    """Exact int nanoseconds of a timedelta (depthai's timestamp type; microsecond resolution)."""
    return (td.days * 86_400 + td.seconds) * 1_000_000_000 + td.microseconds * 1_000


def estimate_clock_offset(samples: np.ndarray) -> int:
    """Offset (ns) to add to a reference-clock reading to get host monotonic time.

    samples: K x 3 int64 rows (host_before, reference, host_after): the reference clock read
    between two host reads. The tightest bracket bounds the read latency best, so it wins and
    the reference instant is taken at its middle.
    """
    s = np.asarray(samples, dtype=np.int64).reshape(-1, 3)
    if len(s) == 0:
        raise ValueError("need at least one clock sample")
    i = int(np.argmin(s[:, 2] - s[:, 0]))
    before, ref, after = (int(v) for v in s[i])
    return before + (after - before) // 2 - ref


def measure_clock_offset(reference_now: Callable[[], datetime.timedelta] | None = None, n: int = 16) -> int:
    """Offset (ns) from depthai's host clock (dai.Clock.now) to time.monotonic_ns()."""
    if reference_now is None:
        import depthai as dai

        reference_now = dai.Clock.now
    rows = []
    for _ in range(n):
        before = time.monotonic_ns()
        ref = timedelta_to_ns(reference_now())
        rows.append((before, ref, time.monotonic_ns()))
    return estimate_clock_offset(np.array(rows, dtype=np.int64))


def device_to_host_ns(timestamp: datetime.timedelta, clock_offset_ns: int) -> int:
    """A depthai getTimestamp() value -> int64 ns of the host monotonic clock."""
    return timedelta_to_ns(timestamp) + int(clock_offset_ns)


# ---------------------------------------------------------------- calibration
def socket_from_name(name: str):
    """"CAM_C" / "right" / "rgb" ... -> dai.CameraBoardSocket."""
    import depthai as dai

    aliases = {"LEFT": "CAM_B", "RIGHT": "CAM_C", "RGB": "CAM_A", "COLOR": "CAM_A"}
    key = aliases.get(name.upper(), name.upper())
    if not hasattr(dai.CameraBoardSocket, key):
        raise ValueError(f"unknown OAK camera socket {name!r}")
    return getattr(dai.CameraBoardSocket, key)


def intrinsics_from_calibration(calib, socket, width: int, height: int) -> np.ndarray:
    """(3, 3) float64 pinhole intrinsics of one camera scaled to width x height pixels.

    calib: dai.CalibrationHandler (device.readCalibration() or CalibrationHandler.fromJson);
    socket: dai.CameraBoardSocket or its name. depthai scales and, for a different aspect
    ratio, crops the calibrated image the way the ISP does.
    """
    if isinstance(socket, str):
        socket = socket_from_name(socket)
    try:
        k = calib.getCameraIntrinsics(socket, int(width), int(height))
    except RuntimeError as exc:
        raise DeviceError(f"the OAK calibration has no intrinsics for {socket.name}: {exc}") from None
    return np.asarray(k, dtype=np.float64).reshape(3, 3)


def extrinsics_from_calibration(calib, src, dst) -> np.ndarray:
    """(4, 4) float64 rigid transform taking points in camera ``src``'s frame to ``dst``'s,
    translation in metres (depthai stores centimetres)."""
    import depthai as dai

    src = socket_from_name(src) if isinstance(src, str) else src
    dst = socket_from_name(dst) if isinstance(dst, str) else dst
    try:
        m = calib.getCameraExtrinsics(src, dst, False, dai.LengthUnit.METER)
    except RuntimeError as exc:
        raise DeviceError(f"the OAK calibration has no extrinsics {src.name} -> {dst.name}: {exc}") from None
    return np.asarray(m, dtype=np.float64).reshape(4, 4)


#: A calibrated IMU -> camera rotation smaller than this is a fine correction (mounting tolerance);
#: a larger one is the sensor's own mounting on the board, which the device-aligned reports undo.
MAX_IMU_CORRECTION_DEG = 20.0


def imu_reports(dai) -> tuple[Any, Any, str]:
    """(accelerometer report, gyroscope report, their name) to enable on the IMU node.

    Both come aligned on the device to the camera axes convention (+x right, +y down, +z
    forward): depthai >= 3.6 has ACCELEROMETER_CALIBRATED / GYROSCOPE_CALIBRATED (also
    bias-corrected with the factory calibration; its RAW reports are in the chip's own axes);
    older 3.x firmware delivered the RAW reports aligned the same way.
    """
    sensors = dai.IMUSensor
    if hasattr(sensors, "ACCELEROMETER_CALIBRATED") and hasattr(sensors, "GYROSCOPE_CALIBRATED"):
        return sensors.ACCELEROMETER_CALIBRATED, sensors.GYROSCOPE_CALIBRATED, "calibrated"
    return sensors.ACCELEROMETER_RAW, sensors.GYROSCOPE_RAW, "raw"


def rotation_angle_deg(r: np.ndarray) -> float:
    """The angle (degrees) of a 3x3 rotation matrix."""
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def aligned_imu_correction(imu_to_camera: np.ndarray | None) -> np.ndarray | None:
    """What turns the device-aligned IMU vectors (``imu_reports``) into the depth camera's axes:
    the calibration's IMU -> camera rotation when it is a small correction, else None (a large one
    is the chip's mounting, already undone on the device; applying it again would turn gravity by
    a right angle or more)."""
    if imu_to_camera is None or rotation_angle_deg(imu_to_camera) > MAX_IMU_CORRECTION_DEG:
        return None
    return imu_to_camera


def imu_to_camera_rotation(calib, socket) -> np.ndarray | None:
    """(3, 3) rotation taking IMU-frame vectors to the camera frame, or None when the
    calibration does not link the IMU to that camera."""
    socket = socket_from_name(socket) if isinstance(socket, str) else socket
    try:
        m = np.asarray(calib.getImuToCameraExtrinsics(socket, False), dtype=np.float64).reshape(4, 4)
    except RuntimeError:
        return None
    r = m[:3, :3]
    # An unset link reads back as zeros; a real one is a rotation.
    return r if abs(np.linalg.det(r) - 1.0) < 1e-3 else None


# ---------------------------------------------------------------- messages -> records
def depth_frame_from_imgframe(img, intrinsics: np.ndarray, camera_to_world: np.ndarray | None = None,
                              clock_offset_ns: int = 0, sensor: str = "oak") -> DepthFrame:
    """A depthai RAW16 depth ImgFrame (millimetres) -> DepthFrame with the image and intrinsics.

    intrinsics: (3, 3) of the depth image; camera_to_world: (4, 4) (identity if None). The image
    is copied: the message's buffer is recycled by depthai once the message is dropped.
    """
    import depthai as dai

    if img.getType() != dai.ImgFrame.Type.RAW16:
        raise DeviceError(f"OAK depth frame has type {img.getType().name}, expected RAW16 millimetres")
    depth = np.array(img.getFrame(), dtype=np.uint16, copy=True).reshape(img.getHeight(), img.getWidth())
    c2w = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
    return DepthFrame(
        t_ns=device_to_host_ns(img.getTimestamp(), clock_offset_ns),
        sensor=sensor,
        camera_to_world=c2w,
        depth_mm=depth,
        intrinsics=np.asarray(intrinsics, dtype=np.float64),
    )


def depth_frame_from_pointcloud(pcd, intrinsics: np.ndarray | None = None, camera_to_world: np.ndarray | None = None,
                                clock_offset_ns: int = 0, sensor: str = "oak", metres_per_unit: float = 0.001) -> DepthFrame:
    """A depthai PointCloudData (on-device unprojection) -> DepthFrame with camera-frame points.

    metres_per_unit: the PointCloud node's length unit (depthai's default is millimetres).
    Points at the origin (pixels without depth) are dropped.
    """
    pts = np.asarray(pcd.getPoints(), dtype=np.float32).reshape(-1, 3) * np.float32(metres_per_unit)
    pts = pts[np.any(pts != 0.0, axis=1)]
    c2w = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
    k = None if intrinsics is None else np.asarray(intrinsics, dtype=np.float64)
    return DepthFrame(t_ns=device_to_host_ns(pcd.getTimestamp(), clock_offset_ns), sensor=sensor,
                      camera_to_world=c2w, points=np.ascontiguousarray(pts), intrinsics=k)


def mocap_packets_from_imu(imu_data, clock_offset_ns: int = 0, device: str = "oak_imu",
                           imu_to_camera: np.ndarray | None = None, with_rotation: bool = True,
                           rotate_orientation: bool = True) -> list[MocapPacket]:
    """A depthai IMUData -> one MocapPacket per IMU packet (sensor id 0).

    acc (1, 3) m/s^2 and gyro (1, 3) rad/s; quats (1, 4) (w, x, y, z) from the rotation vector
    when ``with_rotation`` (the BNO085 has one, the BMI270 does not: quats stay None). With
    ``imu_to_camera`` (3, 3) the vectors are expressed in that camera's axes and, with
    ``rotate_orientation``, the orientation becomes the camera's (else it stays the chip's own).
    t_ns is the accelerometer's timestamp, counter its sequence number.
    """
    r = None if imu_to_camera is None else np.asarray(imu_to_camera, dtype=np.float64)
    q_cam_in_imu = None if r is None or not rotate_orientation else matrix_to_quat(r.T)
    out = []
    for p in imu_data.packets:
        a, g = p.acceleroMeter, p.gyroscope
        acc = np.array([[a.x, a.y, a.z]], dtype=np.float64)
        gyro = np.array([[g.x, g.y, g.z]], dtype=np.float64)
        quats = None
        if with_rotation:
            rv = p.rotationVector
            q = np.array([rv.real, rv.i, rv.j, rv.k], dtype=np.float64)
            quats = q[None] if np.any(q != 0.0) else None
        if r is not None:
            acc, gyro = acc @ r.T, gyro @ r.T
            if quats is not None and q_cam_in_imu is not None:
                quats = quat_multiply(quats, q_cam_in_imu[None])
        out.append(MocapPacket(
            t_ns=device_to_host_ns(a.getTimestamp(), clock_offset_ns), device=device,
            sensors=np.zeros(1, dtype=np.int32),
            quats=None if quats is None else quats.astype(np.float32),
            counter=np.array([a.getSequenceNum()], dtype=np.int64),
            acc=acc.astype(np.float32), gyro=gyro.astype(np.float32),
        ))
    return out


# ---------------------------------------------------------------- discovery
def list_oak_devices(timeout_s: float = 3.0, connected: bool = False) -> list:
    """dai.DeviceInfo of the OAK devices visible now ([] if the search outlasts timeout_s).

    connected=True also lists devices another process is using (state BOOTED). The search
    runs in a daemon thread because XLink discovery can block for seconds on a sick bus.
    """
    result: list = []
    error: list[BaseException] = []

    def search() -> None:
        try:
            import depthai as dai

            found = dai.Device.getAllConnectedDevices() if connected else dai.Device.getAllAvailableDevices()
            result.extend(found)
        except Exception as exc:  # reported below; discovery must never crash the caller
            error.append(exc)

    t = threading.Thread(target=search, name="oak-discovery", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        log.warning("OAK discovery did not finish within %.1f s", timeout_s)
        return []
    if error:
        log.warning("OAK discovery failed: %s", error[0])
    return list(result)


def find_oak_device(device_id: str | None = None, timeout_s: float = 3.0):
    """The dai.DeviceInfo for ``device_id`` (MXID or name such as a USB path or IP; None =
    the first one). Raises DeviceNotFoundError naming what is visible."""
    devices = list_oak_devices(timeout_s)
    if device_id is None:
        if not devices:
            raise DeviceNotFoundError("no OAK device found (0 devices visible over USB)")
        return devices[0]
    want = device_id.strip().lower()
    for info in devices:
        if want in (info.getDeviceId().lower(), info.name.lower()):
            return info
    seen = ", ".join(f"{d.getDeviceId()} ({d.name})" for d in devices) or "none"
    raise DeviceNotFoundError(f"no OAK device {device_id!r} found (visible: {seen})")


# ---------------------------------------------------------------- source
class OakSession(Protocol):
    """One open connection: what it streams, and reads that raise DeviceError when it is gone."""

    def streams(self) -> list[StreamInfo]: ...

    def read(self, timeout_s: float) -> list[object]: ...

    def close(self) -> None: ...


def backoff_delay(attempt: int, initial_s: float, maximum_s: float) -> float:
    """Seconds to wait before reconnect attempt ``attempt`` (0-based): doubling, capped."""
    return float(min(maximum_s, initial_s * (2.0 ** min(attempt, 30))))


class OakSource:
    """An OAK-D as a livecap Source: DepthFrames named ``name`` and, with an IMU, MocapPackets
    from ``<name>_imu``.

    A disconnect mid-stream counts one gap (counters["gaps"]), then the device is reopened with
    exponential backoff (``backoff_s`` = (first, max) seconds) until it is back or
    ``reconnect_timeout_s`` passes (then DeviceError). No frame for ``stall_timeout_s`` counts as
    a disconnect too. ``run`` returns within about read_timeout_s of ``stop`` being set.
    The constructor fails fast with DeviceNotFoundError when no matching device is visible.
    """

    def __init__(self, settings: OakSettings | str | None = None, device_id: str | None = None, *,
                 name: str = "oak", camera_to_world: np.ndarray | None = None,
                 opener: Callable[[], OakSession] | None = None, backoff_s: tuple[float, float] = (0.25, 4.0),
                 reconnect_timeout_s: float = 60.0, stall_timeout_s: float = 3.0, read_timeout_s: float = 0.1,
                 discovery_timeout_s: float = 3.0):
        if settings is None or isinstance(settings, str):
            settings = oak_settings(settings or "default")
        self.settings = settings
        self.name = name
        self.camera_to_world = np.eye(4) if camera_to_world is None else np.asarray(camera_to_world, dtype=np.float64)
        self._backoff_s = backoff_s
        self._reconnect_timeout_s = reconnect_timeout_s
        self._stall_timeout_s = stall_timeout_s
        self._read_timeout_s = read_timeout_s
        self._counters = {"frames": 0, "imu_packets": 0, "gaps": 0, "reconnects": 0}
        self._session: OakSession | None = None
        self._streams: list[StreamInfo] | None = None
        if opener is None:
            info = find_oak_device(device_id, discovery_timeout_s)
            self.device_id = info.getDeviceId()
            # Reconnects look the device up again by MXID: its USB path may change on replug.
            def opener() -> _DepthaiSession:
                return _DepthaiSession(self.settings, find_oak_device(self.device_id, discovery_timeout_s),
                                       self.camera_to_world, self.name)
        else:
            self.device_id = device_id or "fake"
        self._opener = opener

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def open(self) -> OakSource:
        if self._session is None:
            self._session = self._opener()
            self._streams = self._session.streams()
        return self

    def streams(self) -> list[StreamInfo]:
        self.open()
        return list(self._streams or [])

    def close(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            session.close()

    def __enter__(self) -> OakSource:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        try:
            self.open()  # a failure here is not a gap: the device never streamed
            last_frame = time.monotonic()
            while not stop.is_set():
                if self._session is None:
                    if not self._reconnect(stop):
                        return
                    last_frame = time.monotonic()
                    continue
                try:
                    items = self._session.read(self._read_timeout_s)
                    stalled = time.monotonic() - last_frame > self._stall_timeout_s
                    if stalled and not any(isinstance(i, DepthFrame) for i in items):
                        raise DeviceError(f"OAK {self.device_id}: no frame for {self._stall_timeout_s:g} s")
                except DeviceError as exc:
                    self._start_gap(exc)
                    continue
                for item in items:
                    if isinstance(item, DepthFrame):
                        self._counters["frames"] += 1
                        last_frame = time.monotonic()
                    else:
                        self._counters["imu_packets"] += 1
                    emit(item)
        finally:
            self.close()

    def _start_gap(self, exc: BaseException) -> None:
        self._counters["gaps"] += 1
        log.warning("OAK %s lost (%s); reconnecting", self.device_id, exc)
        self._gap_start = time.monotonic()
        self._attempt = 0
        try:
            self.close()
        except Exception as close_exc:  # a dead device may fail to close; it is gone either way
            log.debug("closing the lost OAK failed: %s", close_exc)

    def _reconnect(self, stop: threading.Event) -> bool:
        """One backoff wait and reopen attempt; False when stop was set meanwhile."""
        if stop.wait(backoff_delay(self._attempt, *self._backoff_s)):
            return False
        try:
            self.open()
        except DeviceError as exc:
            self._attempt += 1
            if time.monotonic() - self._gap_start > self._reconnect_timeout_s:
                raise DeviceError(f"OAK {self.device_id} did not come back within "
                                  f"{self._reconnect_timeout_s:g} s: {exc}") from None
            return True
        self._counters["reconnects"] += 1
        log.info("OAK %s back after %.2f s", self.device_id, time.monotonic() - self._gap_start)
        return True


class _DepthaiSession:
    """A started depthai pipeline on one device: stereo depth (+ IMU) queues."""

    def __init__(self, settings: OakSettings, info, camera_to_world: np.ndarray, name: str):
        import depthai as dai

        self._dai = dai
        self._name = name
        self._c2w = camera_to_world
        self._device = None
        self._pipeline = None
        conf = stereo_config(settings)
        try:
            self._device = dai.Device(info)
            self._start(dai, settings, conf)
        except RuntimeError as exc:
            self.close()
            raise DeviceError(f"OAK {info.getDeviceId()}: could not start: {exc}") from None

    def _start(self, dai, settings: OakSettings, conf: dict[str, Any]) -> None:
        dev = self._device
        width, height = conf["size"]
        calib = dev.readCalibration()
        self._intrinsics = intrinsics_from_calibration(calib, conf["depth_socket"], width, height)
        self._offset = measure_clock_offset(dai.Clock.now)
        pipeline = dai.Pipeline(dev)
        preset = getattr(dai.node.StereoDepth.PresetMode, conf["preset_mode"])
        stereo = pipeline.create(dai.node.StereoDepth).build(True, preset, (width, height), conf["fps"])
        stereo.setLeftRightCheck(conf["left_right_check"])
        stereo.setSubpixel(conf["subpixel"])
        stereo.setExtendedDisparity(conf["extended_disparity"])
        stereo.setDepthAlign(getattr(dai.StereoDepthConfig.AlgorithmControl.DepthAlign, conf["depth_align"]))
        apply_stereo_config(stereo.initialConfig, settings)
        self._pointcloud = conf["on_device_pointcloud"]
        if self._pointcloud:
            pc = pipeline.create(dai.node.PointCloud)
            pc.initialConfig.setLengthUnit(dai.LengthUnit.METER)
            stereo.depth.link(pc.inputDepth)
            self._depth_q = pc.outputPointCloud.createOutputQueue(maxSize=4, blocking=False)
        else:
            self._depth_q = stereo.depth.createOutputQueue(maxSize=4, blocking=False)
        imu_name = dev.getConnectedIMU()
        self._imu_q = None
        self._imu_rotation = not imu_name.upper().startswith("BMI")
        # The reports come aligned to the camera axes; the calibration adds at most a fine correction.
        calibrated_r = imu_to_camera_rotation(calib, conf["depth_socket"])
        self._imu_r = aligned_imu_correction(calibrated_r)
        acc_report, gyro_report, self._imu_reports = imu_reports(dai)
        if conf["imu_rate_hz"] and imu_name and imu_name.upper() != "NONE":
            imu = pipeline.create(dai.node.IMU)
            rate = int(conf["imu_rate_hz"])
            sensors = [acc_report]
            if self._imu_rotation:
                sensors.append(dai.IMUSensor.ROTATION_VECTOR)
            imu.enableIMUSensor(sensors, rate)
            # The BNO08x gives calibrated rotation rates up to 100 Hz; telling still from moving needs no more.
            imu.enableIMUSensor(gyro_report, min(rate, 100))
            imu.setBatchReportThreshold(1)
            imu.setMaxBatchReports(10)
            self._imu_q = imu.out.createOutputQueue(maxSize=50, blocking=False)
        if conf["ir_dot_intensity"] > 0 and dev.getIrDrivers():
            dev.setIrLaserDotProjectorIntensity(conf["ir_dot_intensity"])
        pipeline.start()
        self._pipeline = pipeline
        meta = {
            "intrinsics": self._intrinsics.tolist(), "camera_to_world": np.asarray(self._c2w).tolist(),
            "width": width, "height": height, "fps": conf["fps"], "device": "oak",
            "mxid": dev.getDeviceId(), "product": dev.getProductName(), "usb_speed": dev.getUsbSpeed().name,
            "settings": settings.name, "clock_offset_ns": self._offset,
        }
        self._streams = [StreamInfo(self._name, "depth", meta)]
        if self._imu_q is not None:
            # What a replay needs to judge (or redo) the axes: the reports, the correction applied
            # and the calibration's own IMU -> camera rotation.
            self._streams.append(StreamInfo(f"{self._name}{CAMERA_IMU_SUFFIX}", "imu", {
                "imu": imu_name, "rate_hz": conf["imu_rate_hz"], "orientation": self._imu_rotation,
                "orientation_frame": "imu", "frame": "camera", "reports": self._imu_reports,
                "imu_to_camera_applied": None if self._imu_r is None else self._imu_r.tolist(),
                "calibration_imu_to_camera": None if calibrated_r is None else calibrated_r.tolist(),
                "depthai": getattr(dai, "__version__", "")}))

    def streams(self) -> list[StreamInfo]:
        return list(self._streams)

    def read(self, timeout_s: float) -> list[object]:
        out: list[object] = []
        try:
            if self._pipeline is None or not self._pipeline.isRunning():
                raise DeviceError(f"OAK {self._name}: pipeline stopped")
            if self._imu_q is not None:
                for msg in self._imu_q.tryGetAll():
                    out.extend(mocap_packets_from_imu(msg, self._offset, f"{self._name}{CAMERA_IMU_SUFFIX}",
                                                      self._imu_r, self._imu_rotation, rotate_orientation=False))
            msg = self._depth_q.get(datetime.timedelta(seconds=timeout_s))
        except DeviceError:
            raise
        except Exception as exc:  # XLink / queue errors all mean the link is gone
            raise DeviceError(f"OAK {self._name}: {exc}") from None
        if msg is not None:
            if self._pointcloud:
                out.append(depth_frame_from_pointcloud(msg, self._intrinsics, self._c2w, self._offset,
                                                       self._name, metres_per_unit=1.0))
            else:
                out.append(depth_frame_from_imgframe(msg, self._intrinsics, self._c2w, self._offset, self._name))
        return out

    def close(self) -> None:
        pipeline, device, self._pipeline, self._device = self._pipeline, self._device, None, None
        for what, obj in (("stop", pipeline), ("close", device)):
            if obj is None:
                continue
            try:
                obj.stop() if what == "stop" else obj.close()
            except Exception as exc:  # a vanished device cannot be stopped; nothing left to free
                log.debug("OAK %s failed: %s", what, exc)
