"""OAK-D driver without hardware: settings -> depthai config, calibration, message conversion,
clock conversion, discovery failure, and the source's gap / reconnect / shutdown logic."""

import datetime
import json
import sys
import threading
import time

import numpy as np
import pytest

dai = pytest.importorskip("depthai")

from drivers.oak import (  # noqa: E402
    OakSource,
    backoff_delay,
    depth_frame_from_imgframe,
    depth_frame_from_pointcloud,
    device_to_host_ns,
    estimate_clock_offset,
    extrinsics_from_calibration,
    find_oak_device,
    imu_to_camera_rotation,
    intrinsics_from_calibration,
    list_oak_devices,
    measure_clock_offset,
    mocap_packets_from_imu,
    timedelta_to_ns,
)
from drivers.oak_settings import PRESETS, OakSettings, apply_stereo_config, oak_settings, stereo_config  # noqa: E402
from live.core.depth import depth_to_points  # noqa: E402
from live.core.errors import DeviceError, DeviceNotFoundError, UserInputError  # noqa: E402
from live.core.frames import DepthFrame, MocapPacket  # noqa: E402
from live.core.protocols import Source, StreamInfo  # noqa: E402
from live.core.rotations import quat_to_matrix  # noqa: E402


# ---------------------------------------------------------------- settings
def test_presets():
    fast, default, accurate = PRESETS["fast"], PRESETS["default"], PRESETS["accurate"]
    assert (fast.width, fast.height, fast.fps, fast.subpixel) == (640, 400, 120.0, False)
    assert (default.width, default.height, default.fps) == (640, 400, 30.0)
    assert (accurate.width, accurate.height, accurate.fps) == (1280, 800, 15.0)
    assert accurate.subpixel and accurate.spatial_filter and accurate.temporal_filter


def test_overrides_and_validation():
    s = oak_settings("fast", fps=60.0, confidence_threshold=200)
    assert s.fps == 60.0 and s.confidence_threshold == 200 and s.name == "fast"
    for bad in ({"width": 320}, {"fps": 240.0}, {"median": "9x9"}, {"confidence_threshold": 300},
                {"min_depth_m": 5.0, "max_depth_m": 1.0}, {"preset_mode": "MAGIC"}):
        with pytest.raises(UserInputError):
            oak_settings("default", **bad)
    with pytest.raises(UserInputError, match="unknown OAK preset"):
        oak_settings("turbo")
    with pytest.raises(UserInputError, match="unknown OAK setting"):
        oak_settings("default", exposure=3)


def test_stereo_config_is_plain_data():
    conf = stereo_config(PRESETS["accurate"])
    assert json.loads(json.dumps(conf)) == conf
    assert conf["size"] == [1280, 800] and conf["median"] == "KERNEL_7x7"
    assert conf["threshold_mm"] == [200, 8000]
    assert conf["depth_socket"] == "CAM_C" and conf["depth_align"] == "RECTIFIED_RIGHT"
    assert stereo_config(oak_settings(median="off"))["median"] == "MEDIAN_OFF"
    assert stereo_config(oak_settings(imu=False))["imu_rate_hz"] == 0


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_apply_stereo_config_on_depthai_message(name):
    s = PRESETS[name]
    cfg = apply_stereo_config(dai.StereoDepthConfig(), oak_settings(name, confidence_threshold=180))
    assert cfg.getSubpixel() == s.subpixel
    assert cfg.getLeftRightCheck() == s.left_right_check
    assert cfg.getConfidenceThreshold() == 180
    assert cfg.getMedianFilter().name == stereo_config(s)["median"]
    post = cfg.postProcessing
    assert post.spatialFilter.enable == s.spatial_filter
    assert post.temporalFilter.enable == s.temporal_filter
    assert (post.thresholdFilter.minRange, post.thresholdFilter.maxRange) == (200, 8000)
    assert cfg.getDepthUnit() == dai.StereoDepthConfig.AlgorithmControl.DepthUnit.MILLIMETER


def test_unset_confidence_keeps_depthai_default():
    default = dai.StereoDepthConfig().getConfidenceThreshold()
    assert apply_stereo_config(dai.StereoDepthConfig(), OakSettings()).getConfidenceThreshold() == default


# ---------------------------------------------------------------- calibration
def _camera_entry(k, width, height, to_socket=-1, rotation=(), translation_cm=(0.0, 0.0, 0.0)):
    t = dict(zip("xyz", translation_cm))
    return {
        "cameraType": 0, "distortionCoeff": [0.0] * 14, "height": height, "width": width,
        "intrinsicMatrix": k, "lensPosition": 0, "specHfovDeg": 72.0,
        "extrinsics": {"lengthUnit": 1, "rotationMatrix": [list(r) for r in rotation], "toCameraSocket": to_socket,
                       "toDeviceId": "", "translation": t, "specTranslation": t},
    }


@pytest.fixture(scope="module")
def calibration():
    """An OAK-D-like calibration: CAM_B (left) -> CAM_C (right) 7.5 cm baseline, IMU -> CAM_C."""
    data = dai.CalibrationHandler().eepromToJson()  # depthai's own schema, every field defaulted
    k_left = [[802.0, 0.0, 642.0], [0.0, 801.0, 398.0], [0.0, 0.0, 1.0]]
    k_right = [[800.0, 0.0, 640.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]]
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    data["cameraData"] = [
        [1, _camera_entry(k_left, 1280, 800, to_socket=2, rotation=eye, translation_cm=(-7.5, 0.0, 0.0))],
        [2, _camera_entry(k_right, 1280, 800)],
    ]
    # IMU axes: x_cam = -y_imu, y_cam = x_imu, z_cam = z_imu (a 90 degree turn about z).
    data["imuExtrinsics"] = {"lengthUnit": 1, "rotationMatrix": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                             "toCameraSocket": 2, "toDeviceId": "", "translation": {"x": 1.0, "y": 2.0, "z": 0.0},
                             "specTranslation": {"x": 1.0, "y": 2.0, "z": 0.0}}
    return dai.CalibrationHandler.fromJson(json.loads(json.dumps(data)))


def test_intrinsics_scale_with_resolution(calibration):
    k400 = intrinsics_from_calibration(calibration, dai.CameraBoardSocket.CAM_C, 640, 400)
    np.testing.assert_allclose(k400, [[400.0, 0.0, 320.0], [0.0, 400.0, 200.0], [0.0, 0.0, 1.0]])
    k800 = intrinsics_from_calibration(calibration, "right", 1280, 800)
    np.testing.assert_allclose(k800, [[800.0, 0.0, 640.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]])
    assert k400.dtype == np.float64 and k400.shape == (3, 3)


def test_missing_camera_is_a_device_error(calibration):
    with pytest.raises(DeviceError, match="no intrinsics for CAM_A"):
        intrinsics_from_calibration(calibration, "CAM_A", 640, 400)


def test_extrinsics_in_metres(calibration):
    m = extrinsics_from_calibration(calibration, "CAM_B", "CAM_C")
    np.testing.assert_allclose(m[:3, :3], np.eye(3))
    np.testing.assert_allclose(m[:3, 3], [-0.075, 0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(m[3], [0, 0, 0, 1])


def test_imu_to_camera_rotation(calibration):
    r = imu_to_camera_rotation(calibration, "CAM_C")
    np.testing.assert_allclose(r, [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert imu_to_camera_rotation(dai.CalibrationHandler(), "CAM_C") is None


# ---------------------------------------------------------------- clocks
def test_timedelta_to_ns_is_exact():
    td = datetime.timedelta(days=2, seconds=7, microseconds=123456)
    assert timedelta_to_ns(td) == (2 * 86400 + 7) * 10**9 + 123456 * 1000
    assert device_to_host_ns(td, -5) == timedelta_to_ns(td) - 5


def test_estimate_clock_offset_uses_tightest_bracket():
    samples = np.array([
        [1_000, 10_000, 9_000],   # slow read: bracket 8000 ns
        [20_000, 30_400, 20_200],  # tight: middle 20_100 -> offset -10_300
        [40_000, 50_000, 41_000],
    ], dtype=np.int64)
    assert estimate_clock_offset(samples) == -10_300
    with pytest.raises(ValueError):
        estimate_clock_offset(np.zeros((0, 3)))


def test_measure_clock_offset_recovers_a_known_offset():
    shift_ns = 5_000_000_000

    def shifted_clock():
        return datetime.timedelta(microseconds=(time.monotonic_ns() - shift_ns) // 1000)

    # The reference clock has microsecond resolution, so the estimate is within a few us.
    assert abs(measure_clock_offset(shifted_clock) - shift_ns) < 200_000


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="steady_clock is CLOCK_MONOTONIC on Linux only")
def test_depthai_clock_is_host_monotonic_on_linux():
    assert abs(measure_clock_offset()) < 1_000_000


# ---------------------------------------------------------------- messages
def _depth_imgframe(depth_mm: np.ndarray, t: datetime.timedelta):
    img = dai.ImgFrame()
    img.setWidth(depth_mm.shape[1])
    img.setHeight(depth_mm.shape[0])
    img.setType(dai.ImgFrame.Type.RAW16)
    img.setData(np.ascontiguousarray(depth_mm, dtype=np.uint16).view(np.uint8).ravel())
    img.setTimestamp(t)
    return img


def test_depth_frame_from_imgframe():
    rng = np.random.default_rng(0)
    depth = rng.integers(0, 4000, size=(40, 64), dtype=np.uint16)
    depth[rng.random(depth.shape) < 0.2] = 0
    k = np.array([[40.0, 0.0, 32.0], [0.0, 40.0, 20.0], [0.0, 0.0, 1.0]])
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 1.5, 0.0]
    img = _depth_imgframe(depth, datetime.timedelta(seconds=12, microseconds=345))
    frame = depth_frame_from_imgframe(img, k, c2w, clock_offset_ns=1_000, sensor="oak")
    assert isinstance(frame, DepthFrame) and frame.sensor == "oak"
    assert frame.t_ns == 12_000_345_000 + 1_000
    assert frame.depth_mm.dtype == np.uint16 and frame.depth_mm.shape == (40, 64)
    np.testing.assert_array_equal(frame.depth_mm, depth)
    np.testing.assert_array_equal(frame.camera_to_world, c2w)
    np.testing.assert_allclose(frame.cloud(), depth_to_points(depth, k))
    # The frame owns its pixels: changing the message afterwards does not change it.
    img.setData(np.zeros(depth.size * 2, dtype=np.uint8))
    np.testing.assert_array_equal(frame.depth_mm, depth)


def test_non_depth_imgframe_is_rejected():
    img = _depth_imgframe(np.zeros((4, 4), np.uint16), datetime.timedelta(0))
    img.setType(dai.ImgFrame.Type.GRAY8)
    with pytest.raises(DeviceError, match="expected RAW16"):
        depth_frame_from_imgframe(img, np.eye(3))


def test_depth_frame_from_pointcloud_drops_empty_points():
    pcd = dai.PointCloudData()
    pcd.setPoints(np.array([[0, 0, 0], [100, -200, 1500], [0, 0, 0], [-10, 20, 800]], dtype=np.float32))
    pcd.setTimestamp(datetime.timedelta(seconds=3))
    frame = depth_frame_from_pointcloud(pcd, clock_offset_ns=7)
    assert frame.t_ns == 3_000_000_007 and frame.depth_mm is None
    np.testing.assert_allclose(frame.points, [[0.1, -0.2, 1.5], [-0.01, 0.02, 0.8]], rtol=1e-6)
    assert frame.points.dtype == np.float32


def _imu_data(acc, gyro, quat_wxyz, t_s, seq):
    packet = dai.IMUPacket()
    a, g, rv = dai.IMUReportAccelerometer(), dai.IMUReportGyroscope(), dai.IMUReportRotationVectorWAcc()
    a.x, a.y, a.z = acc
    g.x, g.y, g.z = gyro
    rv.real, rv.i, rv.j, rv.k = quat_wxyz
    ts = dai.Timestamp()
    ts.sec, ts.nsec = t_s, 0
    a.timestamp = ts
    a.sequence = seq
    packet.acceleroMeter, packet.gyroscope, packet.rotationVector = a, g, rv
    data = dai.IMUData()
    data.packets = [packet]
    return data


def test_imu_packets_in_imu_axes():
    q = np.array([np.cos(0.25), 0.0, np.sin(0.25), 0.0])  # 0.5 rad about y
    data = _imu_data((0.1, 9.8, 0.2), (0.0, 0.0, 1.0), q, t_s=4, seq=11)
    (p,) = mocap_packets_from_imu(data, clock_offset_ns=-4)
    assert isinstance(p, MocapPacket) and p.device == "oak_imu" and p.decoded
    assert p.t_ns == 4_000_000_000 - 4 and p.counter.tolist() == [11]
    np.testing.assert_allclose(p.acc, [[0.1, 9.8, 0.2]], rtol=1e-6)
    np.testing.assert_allclose(p.quats, [q], atol=1e-6)


def test_imu_packets_in_camera_axes(calibration):
    r = imu_to_camera_rotation(calibration, "CAM_C")
    q = np.array([np.cos(0.25), 0.0, np.sin(0.25), 0.0])
    data = _imu_data((0.1, 9.8, 0.2), (0.0, 0.0, 1.0), q, t_s=1, seq=0)
    (p,) = mocap_packets_from_imu(data, imu_to_camera=r)
    np.testing.assert_allclose(p.acc[0], r @ [0.1, 9.8, 0.2], rtol=1e-6)
    np.testing.assert_allclose(p.gyro[0], [0.0, 0.0, 1.0], atol=1e-7)
    # Camera orientation in the IMU's world = imu orientation composed with camera-in-imu.
    np.testing.assert_allclose(quat_to_matrix(p.quats[0].astype(np.float64)), quat_to_matrix(q) @ r.T, atol=1e-6)


def test_device_aligned_imu_reports_and_the_fine_correction(calibration):
    from drivers.oak import aligned_imu_correction, imu_reports

    acc, gyro, name = imu_reports(dai)
    assert name == "calibrated"  # depthai >= 3.6: aligned to the camera axes on the device
    assert (acc, gyro) == (dai.IMUSensor.ACCELEROMETER_CALIBRATED, dai.IMUSensor.GYROSCOPE_CALIBRATED)
    # The fixture's 90 degree turn is the chip's mounting, which the aligned reports already undo.
    assert aligned_imu_correction(imu_to_camera_rotation(calibration, "CAM_C")) is None
    small = quat_to_matrix(np.array([np.cos(0.02), np.sin(0.02), 0.0, 0.0]))  # 2.3 degrees
    np.testing.assert_array_equal(aligned_imu_correction(small), small)
    assert aligned_imu_correction(None) is None


def test_imu_orientation_can_stay_the_chips_own(calibration):
    r = imu_to_camera_rotation(calibration, "CAM_C")
    q = np.array([np.cos(0.25), 0.0, np.sin(0.25), 0.0])
    (p,) = mocap_packets_from_imu(_imu_data((0.1, 9.8, 0.2), (0.0, 0.0, 1.0), q, t_s=1, seq=0),
                                  imu_to_camera=r, rotate_orientation=False)
    np.testing.assert_allclose(p.acc[0], r @ [0.1, 9.8, 0.2], rtol=1e-6)
    np.testing.assert_allclose(p.quats, [q], atol=1e-6)


def test_imu_without_rotation_vector_has_no_quats():
    data = _imu_data((0.0, 9.8, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), t_s=1, seq=0)
    (p,) = mocap_packets_from_imu(data)
    assert p.quats is None and not p.decoded and p.acc is not None


# ---------------------------------------------------------------- discovery / fail fast
def _no_oak_visible() -> bool:
    return not list_oak_devices(timeout_s=3.0)


def test_no_device_fails_fast_with_one_line():
    if not _no_oak_visible():
        pytest.skip("an OAK device is connected")
    with pytest.raises(DeviceNotFoundError) as info:
        OakSource()
    assert str(info.value) == "no OAK device found (0 devices visible over USB)"
    with pytest.raises(DeviceNotFoundError, match=r"no OAK device '1844' found \(visible: none\)"):
        find_oak_device("1844")


# ---------------------------------------------------------------- source logic with a fake session
class FakeSession:
    """Streams numbered DepthFrames; raises DeviceError on the reads listed in ``fail_on``."""

    def __init__(self, log, fail_on=(), idle=False, failed=None):
        self.log, self.fail_on, self.idle, self.failed = log, set(fail_on), idle, failed
        self.reads = 0
        self.closed = False

    def streams(self):
        return [StreamInfo("oak", "depth", {"width": 4, "height": 2})]

    def read(self, timeout_s):
        self.reads += 1
        if self.reads in self.fail_on:
            if self.failed is not None:
                self.failed.set()
            raise DeviceError("X_LINK_ERROR: device disconnected")
        if self.idle:
            threading.Event().wait(timeout_s)  # what a silent queue's get(timeout) does
            return []
        self.log.append(len(self.log))
        return [DepthFrame(t_ns=len(self.log), sensor="oak", points=np.zeros((1, 3), np.float32))]

    def close(self):
        self.closed = True


def _opener(script):
    """Opens sessions from ``script`` in order; a DeviceError entry fails that attempt."""
    produced, opened = [], []

    def opener():
        item = script.pop(0) if script else {}
        if isinstance(item, Exception):
            raise item
        s = FakeSession(produced, **item)
        opened.append(s)
        return s

    return opener, opened


def test_disconnect_is_a_gap_then_resumes():
    opener, opened = _opener([{"fail_on": [3]}, DeviceNotFoundError("gone"), DeviceNotFoundError("gone"), {}])
    src = OakSource(opener=opener, backoff_s=(0.001, 0.004))
    assert isinstance(src, Source)
    stop = threading.Event()
    got = []

    def emit(frame):
        got.append(frame)
        if len(got) == 6:
            stop.set()

    src.run(emit, stop)
    assert [f.t_ns for f in got] == [1, 2, 3, 4, 5, 6]
    assert src.counters == {"frames": 6, "imu_packets": 0, "gaps": 1, "reconnects": 1}
    assert len(opened) == 2 and all(s.closed for s in opened)


def test_reconnect_gives_up_after_timeout():
    script = [{"fail_on": [1]}] + [DeviceNotFoundError("gone")] * 1000
    opener, _ = _opener(script)
    src = OakSource(opener=opener, backoff_s=(0.0, 0.0), reconnect_timeout_s=0.0)
    with pytest.raises(DeviceError, match="did not come back within 0 s"):
        src.run(lambda f: None, threading.Event())
    assert src.counters["gaps"] == 1


def test_first_open_failure_is_raised_not_retried():
    opener, _ = _opener([DeviceError("X_LINK_DEVICE_ALREADY_IN_USE")])
    with pytest.raises(DeviceError, match="ALREADY_IN_USE"):
        OakSource(opener=opener).run(lambda f: None, threading.Event())


def test_stall_counts_as_gap():
    opener, opened = _opener([{"idle": True}, {}])
    src = OakSource(opener=opener, backoff_s=(0.001, 0.001), stall_timeout_s=0.05, read_timeout_s=0.01)
    stop = threading.Event()
    src.run(lambda f: stop.set(), stop)
    assert src.counters["gaps"] == 1 and src.counters["frames"] == 1 and len(opened) == 2


def test_stop_returns_within_one_second_even_while_reconnecting():
    failed = threading.Event()
    opener, _ = _opener([{"fail_on": [2], "failed": failed}] + [DeviceNotFoundError("gone")] * 100)
    src = OakSource(opener=opener, backoff_s=(30.0, 30.0))
    stop = threading.Event()
    t = threading.Thread(target=src.run, args=(lambda f: None, stop))
    t.start()
    assert failed.wait(5.0)  # the device went away; the source now backs off for 30 s
    t0 = time.monotonic()
    stop.set()
    t.join(1.0)
    assert not t.is_alive() and time.monotonic() - t0 < 1.0
    assert src.counters["gaps"] == 1


def test_streams_known_after_open():
    opener, _ = _opener([{}])
    with OakSource(opener=opener) as src:
        assert src.streams()[0].name == "oak"


def test_backoff_doubles_and_caps():
    assert [backoff_delay(i, 0.25, 4.0) for i in range(7)] == [0.25, 0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
