"""Sessions: codecs round-trip, files open with the mcap reader (CRCs on), damage is reported."""


import numpy as np
import pytest
from mcap.reader import make_reader

from live.core.errors import SessionError, UserInputError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.io import codec
from live.io.session import SessionReader, SessionWriter

K = np.array([[400.0, 0, 320], [0, 400.0, 200], [0, 0, 1]])


def _frames(n=30, seed=0):
    rng = np.random.default_rng(seed)
    c2w = np.eye(4)
    c2w[:3, 3] = (0.1, 1.2, -3.0)
    out = []
    for i in range(n):
        t = 1_000_000_000 + i * 33_333_333
        out.append(GroundTruth(t, rng.normal(size=(22, 3)).astype(np.float32),
                               rng.normal(size=(22, 4)).astype(np.float32), rng.normal(size=3).astype(np.float32)))
        img = rng.integers(0, 5000, size=(40, 64)).astype(np.uint16)
        out.append(DepthFrame(t, "cam", camera_to_world=c2w, depth_mm=img, intrinsics=K))
        out.append(DepthFrame(t, "cloud", camera_to_world=c2w,
                              points=rng.uniform(-3, 3, size=(100 + i, 3)).astype(np.float32)))
        out.append(MocapPacket(t, "suit", raw=rng.integers(0, 256, size=17 + i).astype(np.uint8).tobytes()))
    return out


def _write(path, frames):
    streams = [StreamInfo("cam", "depth", {"fps": 30}), StreamInfo("suit", "serial", {"protocol": "lines"})]
    with SessionWriter(path, streams, chunk_size=16 * 1024) as w:
        for f in frames:
            w.write(f)
        w.attach("body.npz", b"not really a body")


def test_codec_round_trip_exact():
    for f in _frames(3):
        if isinstance(f, DepthFrame):
            back = codec.decode_depth(codec.encode_depth(f), f.sensor)
            assert back.t_ns == f.t_ns
            np.testing.assert_array_equal(back.camera_to_world, f.camera_to_world)
            if f.depth_mm is not None:
                np.testing.assert_array_equal(back.depth_mm, f.depth_mm)
                np.testing.assert_array_equal(back.intrinsics, K)
            else:
                assert np.abs(back.points - f.points).max() <= 0.0005 + 1e-6  # int16 mm quantisation
        elif isinstance(f, GroundTruth):
            back = codec.decode_truth(codec.encode_truth(f))
            np.testing.assert_array_equal(back.joints, f.joints)
            np.testing.assert_array_equal(back.rotations, f.rotations)


def test_imu_codec_round_trip():
    p = MocapPacket(5, "oak_imu", sensors=np.array([0, 1], np.int32), quats=np.eye(4)[:2],
                    counter=np.array([7, 8]), gyro=np.ones((2, 3)))
    back = codec.decode_imu(codec.encode_imu(p), "oak_imu")
    np.testing.assert_array_equal(back.quats, p.quats)
    np.testing.assert_array_equal(back.counter, p.counter)
    assert back.acc is None and back.gyro.shape == (2, 3)


def test_imu_codec_round_trip_without_orientations():
    # An IMU without on-chip fusion (the OAK's BMI270, a simulated camera IMU): acc and gyro only.
    p = MocapPacket(5, "oak_imu", sensors=np.zeros(1, np.int32), counter=np.array([9]),
                    acc=np.array([[0.1, -9.8, 0.2]]), gyro=np.array([[0.0, 0.01, 0.0]]))
    back = codec.decode_imu(codec.encode_imu(p), "oak_imu")
    assert back.quats is None and not back.decoded
    np.testing.assert_array_equal(back.acc, p.acc)
    np.testing.assert_array_equal(back.gyro, p.gyro)
    np.testing.assert_array_equal(back.counter, p.counter)


def test_codec_rejects_garbage():
    with pytest.raises(SessionError):
        codec.decode_truth(b"G\x01" + b"\x00" * 5)
    with pytest.raises(SessionError):
        codec.decode_depth(b"X\x01" + b"\x00" * 300, "cam")


def test_session_round_trip_and_mcap_reader_with_crcs(tmp_path):
    frames = _frames()
    path = tmp_path / "s.mcap"
    _write(path, frames)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        n = sum(1 for _ in reader.iter_messages())
        assert n == len(frames)
        assert reader.get_header().profile == "livecap"
    r = SessionReader(path)
    assert {s.name for s in r.info.streams} >= {"cam", "suit"}
    back = [f for _, f in r.frames()]
    assert r.error is None
    assert [type(f) for f in back] == [type(f) for f in frames]
    assert [f.t_ns for f in back] == [f.t_ns for f in frames]
    serial = [f.raw for f in back if isinstance(f, MocapPacket)]
    assert serial == [f.raw for f in frames if isinstance(f, MocapPacket)]
    assert r.body_npz() == b"not really a body"


@pytest.mark.parametrize("cut", [0.3, 0.6, 0.95])
def test_truncated_session_replays_what_came_before(tmp_path, cut):
    frames = _frames(60)
    path = tmp_path / "s.mcap"
    _write(path, frames)
    data = path.read_bytes()
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(data[: int(len(data) * cut)])
    r = SessionReader(bad)
    back = [f for _, f in r.frames()]
    assert r.error is not None and "\n" not in r.error and "truncated" in r.error
    assert 0 < len(back) < len(frames) or cut < 0.35
    # Everything replayed is exactly what was recorded, in order.
    assert [f.t_ns for f in back] == [f.t_ns for f in frames[: len(back)]]


def test_corrupted_session_skips_the_damaged_chunk_and_goes_on(tmp_path):
    frames = _frames(60)
    path = tmp_path / "s.mcap"
    _write(path, frames)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    r = SessionReader(bad)
    back = [f for _, f in r.frames()]
    assert r.error is not None and "\n" not in r.error
    # What is read is what was recorded, in order, missing only the damaged chunk's frames.
    stamps = [(type(f), f.t_ns) for f in frames]
    got = [(type(f), f.t_ns) for f in back]
    it = iter(stamps)
    assert all(g in it for g in got)
    assert len(frames) - 20 < len(back) < len(frames)


def test_not_a_session(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not mcap")
    with pytest.raises(SessionError):
        SessionReader(p)
    with pytest.raises(UserInputError):
        SessionReader(tmp_path / "missing.mcap")
