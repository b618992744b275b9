"""RealSense through open3d without hardware: conversions from in-memory open3d frames and
metadata, the device clock mapping, and the live / bag sources driven by in-memory fakes."""

import threading

import numpy as np
import pytest

o3d = pytest.importorskip("open3d")

from drivers.realsense import (  # noqa: E402
    DeviceClock,
    RealSenseBagSource,
    RealSenseSource,
    depth_frame_from_rgbd,
    depth_mm_from_image,
    intrinsics_from_metadata,
    list_realsense_devices,
)
from live.core.depth import depth_to_points  # noqa: E402
from live.core.errors import DeviceError, DeviceNotFoundError, FormatError, UserInputError  # noqa: E402
from live.core.protocols import Source  # noqa: E402

W, H = 64, 48


def _metadata(depth_scale=1000.0):
    m = o3d.t.io.RGBDVideoMetadata()
    m.intrinsics = o3d.camera.PinholeCameraIntrinsic(W, H, 50.0, 51.0, 31.5, 23.5)
    m.depth_scale = depth_scale
    m.width, m.height, m.fps = W, H, 30.0
    m.serial_number, m.device_name = "213622078112", "Intel RealSense D435"
    return m


def _rgbd(depth_raw):
    depth = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(depth_raw)[..., None]))
    color = o3d.t.geometry.Image(o3d.core.Tensor(np.zeros((H, W, 3), np.uint8)))
    return o3d.t.geometry.RGBDImage(color, depth)


def _depth(seed):
    rng = np.random.default_rng(seed)
    d = rng.integers(300, 5000, size=(H, W), dtype=np.uint16)
    d[rng.random(d.shape) < 0.1] = 0
    return d


# ---------------------------------------------------------------- conversions
def test_depth_in_millimetres_is_copied_unchanged():
    d = _depth(0)
    out = depth_mm_from_image(o3d.t.geometry.Image(o3d.core.Tensor(d[..., None])), 1000.0)
    assert out.dtype == np.uint16 and out.shape == (H, W)
    np.testing.assert_array_equal(out, d)


def test_depth_in_other_units_is_converted():
    quarter_mm = np.array([[4000, 1, 2, 0]], dtype=np.uint16)  # L515: 4000 units per metre
    np.testing.assert_array_equal(depth_mm_from_image(quarter_mm, 4000.0), [[1000, 0, 0, 0]])
    metres = np.array([[1.2344, np.nan, 70.0, 0.0]], dtype=np.float32)
    np.testing.assert_array_equal(depth_mm_from_image(metres, 1.0), [[1234, 0, 65535, 0]])
    with pytest.raises(FormatError):
        depth_mm_from_image(quarter_mm, 0.0)


def test_intrinsics_from_metadata():
    k = intrinsics_from_metadata(_metadata())
    np.testing.assert_allclose(k, [[50.0, 0.0, 31.5], [0.0, 51.0, 23.5], [0.0, 0.0, 1.0]])
    with pytest.raises(FormatError, match="no intrinsics"):
        intrinsics_from_metadata(o3d.t.io.RGBDVideoMetadata())


def test_depth_frame_from_rgbd():
    d = _depth(1)
    c2w = np.eye(4)
    c2w[1, 3] = 1.2
    frame = depth_frame_from_rgbd(_rgbd(d), _metadata(), 123, c2w, sensor="rs")
    assert frame.t_ns == 123 and frame.sensor == "rs"
    np.testing.assert_array_equal(frame.depth_mm, d)
    np.testing.assert_array_equal(frame.camera_to_world, c2w)
    np.testing.assert_allclose(frame.cloud(), depth_to_points(d, intrinsics_from_metadata(_metadata())))


def test_device_clock_keeps_least_latency():
    clock = DeviceClock()
    # device us, host arrival ns (true offset 1_000_000 ns; latencies 5, 2, 9 ms)
    assert clock.to_host_ns(0, 1_000_000 + 5_000_000) == 5_000_000 + 1_000_000
    assert clock.to_host_ns(33_000, 33_000_000 + 1_000_000 + 2_000_000) == 33_000_000 + 3_000_000
    assert clock.to_host_ns(66_000, 66_000_000 + 1_000_000 + 9_000_000) == 66_000_000 + 3_000_000
    assert clock.offset_ns == 3_000_000


# ---------------------------------------------------------------- sources with in-memory fakes
class FakeReader:
    """RSBagReader-like: frames at the given bag timestamps (us); None = an empty frame."""

    def __init__(self, stamps_us):
        self.metadata = _metadata()
        self.items = [(t, _rgbd(_depth(i)) if t is not None else o3d.t.geometry.RGBDImage()) for i, t in enumerate(stamps_us)]
        self.ts = 0

    def is_eof(self):
        return not self.items

    def next_frame(self):
        t, rgbd = self.items.pop(0)
        self.ts = t if t is not None else self.ts
        return rgbd

    def get_timestamp(self):
        return self.ts


def test_bag_source_keeps_recorded_spacing():
    src = RealSenseBagSource("take.bag", reader=FakeReader([1_000_000, 1_033_000, None, 1_066_500]), realtime=False)
    assert isinstance(src, Source)
    (info,) = src.streams()
    assert info.kind == "depth" and info.meta["width"] == W and info.meta["serial"] == "213622078112"
    got = []
    src.run(got.append, threading.Event())
    assert [f.t_ns - got[0].t_ns for f in got] == [0, 33_000_000, 66_500_000]
    np.testing.assert_array_equal(got[2].depth_mm, _depth(3))
    assert src.counters == {"frames": 3, "empty": 1}


def test_bag_source_stop_interrupts_realtime_pacing():
    src = RealSenseBagSource("take.bag", reader=FakeReader([0, 600_000_000]), realtime=True)
    stop = threading.Event()
    done = threading.Event()

    def emit(frame):
        stop.set()  # the next frame is due in 600 s; stop must end the wait at once

    t = threading.Thread(target=lambda: (src.run(emit, stop), done.set()))
    t.start()
    assert done.wait(5.0)
    assert src.counters["frames"] == 1


class FakeSensor:
    """RealSenseSensor-like: device timestamps in us; None = an empty frame; an exception is raised."""

    def __init__(self, script):
        self.script = list(script)
        self.ts = 0
        self.started = self.stopped = False

    def start_capture(self, record):
        self.started = True
        return True

    def stop_capture(self):
        self.stopped = True

    def get_metadata(self):
        return _metadata()

    def capture_frame(self, wait, align):
        item = self.script.pop(0)
        if isinstance(item, Exception):
            raise item
        if item is None:
            return o3d.t.geometry.RGBDImage()
        self.ts = item
        return _rgbd(_depth(item % 7))

    def get_timestamp(self):
        return self.ts


def test_live_source_maps_device_time_and_counts_empty_frames():
    device_us = [5_000_000, None, 5_033_000, 5_066_000, 5_099_000]
    latency_ns = [8_000_000, 0, 3_000_000, 6_000_000, 3_000_000]
    offset_ns = 10**12  # device epoch -> host monotonic
    arrivals = iter(offset_ns + (d or 0) * 1000 + lat for d, lat in zip(device_us, latency_ns))
    sensor = FakeSensor(device_us)
    src = RealSenseSource(sensor=sensor, name="rs0", host_clock=lambda: next(arrivals))
    stop = threading.Event()
    got = []

    def emit(frame):
        got.append(frame)
        if len(got) == 4:
            stop.set()

    src.run(emit, stop)
    assert [f.sensor for f in got] == ["rs0"] * 4
    # Each frame is placed with the least latency seen so far: 8 ms, then 3 ms from frame 2 on.
    expected = [offset_ns + d * 1000 + lat for d, lat in zip([5_000_000, 5_033_000, 5_066_000, 5_099_000],
                                                              [8_000_000, 3_000_000, 3_000_000, 3_000_000])]
    assert [f.t_ns for f in got] == expected
    assert src.counters == {"frames": 4, "empty": 1}
    assert sensor.started and sensor.stopped


def test_live_source_sensor_error_is_a_device_error():
    src = RealSenseSource(sensor=FakeSensor([RuntimeError("Frame didn't arrive within 15000")]))
    with pytest.raises(DeviceError, match="didn't arrive"):
        src.run(lambda f: None, threading.Event())


# ---------------------------------------------------------------- no hardware
def test_no_device_fails_fast_with_one_line():
    if list_realsense_devices():
        pytest.skip("a RealSense camera is connected")
    with pytest.raises(DeviceNotFoundError) as info:
        RealSenseSource()
    assert str(info.value) == "no RealSense device found (0 devices visible over USB)"


def test_missing_and_unreadable_bags(tmp_path):
    with pytest.raises(UserInputError, match="does not exist"):
        RealSenseBagSource(tmp_path / "none.bag")
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"not a rosbag")
    with pytest.raises(FormatError, match="bad.bag: not a readable RealSense .bag"):
        RealSenseBagSource(bad).streams()
