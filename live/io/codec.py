"""Binary encodings of the records a session stores, one encode/decode pair per record type.

Each payload starts with a 1-byte tag and a 1-byte version; numbers are little-endian. Clouds are
quantised to int16 millimetres in the camera frame (±32.7 m, 0.5 mm rounding); depth images keep
their uint16 millimetres. Compression happens at the MCAP chunk level (zstd), not here.

Sizes a record declares are checked against ceilings before anything is allocated: a depth
image at most ``MAX_IMAGE_SIDE`` pixels a side, a cloud at most ``MAX_POINTS`` points, an IMU
record at most ``MAX_IMU_SAMPLES`` samples. The encoders refuse what the decoders would.
"""

from __future__ import annotations

import struct

import numpy as np

from live.core.errors import SessionError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.skeleton import NUM_JOINTS

_VERSION = 1
TAG_CLOUD = ord("C")
TAG_DEPTH_IMAGE = ord("I")
TAG_GT = ord("G")
TAG_IMU = ord("U")

MAX_IMAGE_SIDE = 4096
MAX_POINTS = 4_000_000
MAX_IMU_SAMPLES = 65_536

Buffer = bytes | memoryview
_HEAD = struct.Struct("<BBq")  # tag, version, t_ns
_MATS = struct.Struct("<16d9d")  # camera_to_world, intrinsics (zeros when absent)
_COUNT = struct.Struct("<I")
_SIZE = struct.Struct("<HH")


def _check_head(buf: Buffer, tag: int) -> int:
    if len(buf) < _HEAD.size:
        raise SessionError(f"record too short ({len(buf)} bytes)")
    got_tag, version, t_ns = _HEAD.unpack_from(buf, 0)
    if got_tag != tag:
        raise SessionError(f"record tag {chr(got_tag)!r} where {chr(tag)!r} was expected")
    if version != _VERSION:
        raise SessionError(f"record version {version} is not supported (expected {_VERSION})")
    return t_ns


def _take(buf: Buffer, offset: int, dtype, count: int) -> np.ndarray:
    size = np.dtype(dtype).itemsize * count
    if offset + size > len(buf):
        raise SessionError(f"record truncated: needs {offset + size} bytes, has {len(buf)}")
    return np.frombuffer(buf, dtype=dtype, count=count, offset=offset)


def encode_depth(frame: DepthFrame) -> bytes:
    """A DepthFrame -> bytes: the depth image when there is one, else the int16 mm cloud."""
    k = frame.intrinsics if frame.intrinsics is not None else np.zeros((3, 3))
    mats = _MATS.pack(*np.asarray(frame.camera_to_world, np.float64).ravel(), *np.asarray(k, np.float64).ravel())
    if frame.depth_mm is not None:
        img = np.ascontiguousarray(frame.depth_mm, dtype="<u2")
        h, w = img.shape
        _check_image(h, w)
        return b"".join([_HEAD.pack(TAG_DEPTH_IMAGE, _VERSION, frame.t_ns), mats, _SIZE.pack(h, w), img.tobytes()])
    points = np.asarray(frame.points, np.float64).reshape(-1, 3)
    _check_points(len(points))
    mm = np.rint(points * 1000.0)
    q = np.clip(mm, -32767, 32767).astype("<i2")
    return b"".join([_HEAD.pack(TAG_CLOUD, _VERSION, frame.t_ns), mats, _COUNT.pack(len(q)), q.tobytes()])


def decode_depth(buf: Buffer, sensor: str) -> DepthFrame:
    tag = buf[0] if buf else -1
    t_ns = _check_head(buf, TAG_DEPTH_IMAGE if tag == TAG_DEPTH_IMAGE else TAG_CLOUD)
    off = _HEAD.size
    mats = _take(buf, off, "<f8", 25)
    off += _MATS.size
    c2w = mats[:16].reshape(4, 4).copy()
    k = mats[16:].reshape(3, 3).copy()
    intrinsics = k if k[2, 2] != 0 else None
    if tag == TAG_DEPTH_IMAGE:
        h, w = _SIZE.unpack_from(_take(buf, off, "u1", _SIZE.size).tobytes())
        off += _SIZE.size
        _check_image(h, w)
        img = _take(buf, off, "<u2", h * w).reshape(h, w).astype(np.uint16)
        return DepthFrame(t_ns=t_ns, sensor=sensor, camera_to_world=c2w, depth_mm=img, intrinsics=intrinsics)
    (n,) = _COUNT.unpack_from(_take(buf, off, "u1", 4).tobytes())
    off += _COUNT.size
    _check_points(n)
    pts = _take(buf, off, "<i2", 3 * n).reshape(n, 3).astype(np.float32) * np.float32(0.001)
    return DepthFrame(t_ns=t_ns, sensor=sensor, camera_to_world=c2w, points=pts, intrinsics=intrinsics)


def _check_image(h: int, w: int) -> None:
    if not (0 < h <= MAX_IMAGE_SIDE and 0 < w <= MAX_IMAGE_SIDE):
        raise SessionError(f"depth image of {w} x {h} pixels (at most {MAX_IMAGE_SIDE} a side)")


def _check_points(n: int) -> None:
    if n > MAX_POINTS:
        raise SessionError(f"cloud of {n} points (at most {MAX_POINTS})")


def encode_truth(gt: GroundTruth) -> bytes:
    arrays = [np.asarray(gt.joints, "<f4"), np.asarray(gt.rotations, "<f4"), np.asarray(gt.root, "<f4")]
    return _HEAD.pack(TAG_GT, _VERSION, gt.t_ns) + b"".join(a.tobytes() for a in arrays)


def decode_truth(buf: Buffer) -> GroundTruth:
    t_ns = _check_head(buf, TAG_GT)
    n = NUM_JOINTS
    vals = _take(buf, _HEAD.size, "<f4", n * 3 + n * 4 + 3)
    return GroundTruth(
        t_ns=t_ns,
        joints=vals[: n * 3].reshape(n, 3).copy(),
        rotations=vals[n * 3 : n * 7].reshape(n, 4).copy(),
        root=vals[n * 7 :].copy(),
    )


_IMU_FIELDS = ("counter", "acc", "gyro", "mag")  # flag bits 0-3: present
_NO_QUATS = 1 << 4
_WIDE_IDS = 1 << 5  # sensor ids stored as int64 (only when one does not fit in int32)
_INT32 = np.iinfo(np.int32)


def encode_imu(packet: MocapPacket) -> bytes:
    """Decoded IMU samples (for devices that hand us decoded data, e.g. the OAK's own IMU).
    A packet without orientations (an IMU without on-chip fusion) sets flag bit 4 and stores none.
    Sensor ids beyond int32 (a MAC address, an Xsens DeviceId >= 2^31) set flag bit 5 and are
    stored as int64; other records keep the int32 ids they always had."""
    sensors = np.asarray(packet.sensors, np.int64)
    n = len(sensors)
    if n > MAX_IMU_SAMPLES:
        raise SessionError(f"IMU record of {n} samples (at most {MAX_IMU_SAMPLES})")
    flags = 0
    if n and (sensors.min() < _INT32.min or sensors.max() > _INT32.max):
        flags |= _WIDE_IDS
        sensors = sensors.astype("<i8")
    else:
        sensors = sensors.astype("<i4")
    parts = [sensors.tobytes()]
    if packet.quats is None:
        flags |= _NO_QUATS
    else:
        parts.append(np.asarray(packet.quats, "<f8").reshape(n, 4).tobytes())
    for bit, name in enumerate(_IMU_FIELDS):
        value = getattr(packet, name)
        if value is not None:
            flags |= 1 << bit
            dtype, width = ("<i8", 1) if name == "counter" else ("<f8", 3)
            parts.append(np.asarray(value, dtype).reshape(n, width).tobytes())
    return _HEAD.pack(TAG_IMU, _VERSION, packet.t_ns) + struct.pack("<IB", n, flags) + b"".join(parts)


def decode_imu(buf: Buffer, device: str) -> MocapPacket:
    t_ns = _check_head(buf, TAG_IMU)
    off = _HEAD.size
    if off + 5 > len(buf):
        raise SessionError("IMU record truncated")
    n, flags = struct.unpack_from("<IB", buf, off)
    off += 5
    if n > MAX_IMU_SAMPLES:
        raise SessionError(f"IMU record of {n} samples (at most {MAX_IMU_SAMPLES})")
    id_dtype = "<i8" if flags & _WIDE_IDS else "<i4"
    sensors = _take(buf, off, id_dtype, n).astype(np.int64)
    off += np.dtype(id_dtype).itemsize * n
    quats: np.ndarray | None = None
    if not flags & _NO_QUATS:
        quats = _take(buf, off, "<f8", 4 * n).reshape(n, 4).copy()
        off += 32 * n
    extra: dict[str, np.ndarray] = {}
    for bit, name in enumerate(_IMU_FIELDS):
        if flags & (1 << bit):
            dtype, width = ("<i8", 1) if name == "counter" else ("<f8", 3)
            arr = _take(buf, off, dtype, n * width)
            extra[name] = arr.copy() if width == 1 else arr.reshape(n, width).copy()
            off += 8 * n * width
    return MocapPacket(t_ns=t_ns, device=device, sensors=sensors, quats=quats, counter=extra.get("counter"),
                       acc=extra.get("acc"), gyro=extra.get("gyro"), mag=extra.get("mag"))
