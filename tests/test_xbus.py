"""Xbus codec: exact bytes, every orientation representation / precision / frame, parser
resynchronisation and fuzzing, the configurator's ack / error / timeout handling."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from drivers import xbus
from drivers.xbus import (
    BID_MASTER,
    MID_MTDATA2,
    decode_mtdata2,
    encode_message,
    encode_mtdata2,
)
from drivers.xbus_stream import XbusConfigurator, XbusParser
from live.core.errors import DeviceError, FormatError
from live.core.rotations import quat_from_axis_angle, quat_normalize, quat_rotate

TOL = {"float32": 1e-6, "fp1220": 5e-6, "fp1632": 1e-9, "float64": 1e-12}
MAX_FRAME = xbus.MAX_DATA_LEN + 7


def same_rotation(a, b, tol):
    a, b = np.asarray(a), np.asarray(b)
    return min(np.abs(a - b).max(), np.abs(a + b).max()) < tol


def test_command_messages_exact_bytes():
    assert encode_message(0xFF, 0x30) == bytes.fromhex("FAFF3000D1")  # GoToConfig
    assert encode_message(0xFF, 0x10) == bytes.fromhex("FAFF1000F1")  # GoToMeasurement
    msg = encode_message(0x01, 0x42, b"\x04")
    assert msg == bytes.fromhex("FA014201") + b"\x04" + bytes([(-(1 + 0x42 + 1 + 4)) & 0xFF])


def test_extended_length_frame():
    data = bytes(range(256)) + bytes(44)  # 300 bytes
    msg = encode_message(0xFF, 0xC0, data)
    assert msg[:6] == bytes.fromhex("FAFFC0FF012C") and len(msg) == 6 + 300 + 1
    assert sum(msg[1:]) % 256 == 0
    with pytest.raises(ValueError):
        encode_message(0xFF, 0xC0, bytes(xbus.MAX_DATA_LEN + 1))


def test_mtdata2_items_exact_bytes():
    payload = encode_mtdata2(counter=0x1234, sample_time_fine=0x01020304, status=7,
                             acc=[1.0, -2.5, 0.0], precision="fp1632")
    assert payload == (bytes.fromhex("102002 1234") + bytes.fromhex("106004 01020304")
                       + bytes.fromhex("402212") + bytes.fromhex("00000000 0001 80000000 FFFD 00000000 0000")
                       + bytes.fromhex("E02004 00000007"))
    fp1220 = encode_mtdata2(gyro=[1.0, -0.5, 2047.0], precision="fp1220")
    assert fp1220 == bytes.fromhex("80210C 00100000 FFF80000 7FF00000")


def test_decode_hand_built_quaternion_frame_world_convention():
    # Device ENU quaternion: the sensor turned +90 deg about Up from being aligned with ENU.
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    payload = bytes.fromhex("201010") + struct.pack(">4f", c, 0, 0, s)
    frame = bytes.fromhex("FF36") + bytes([len(payload)]) + payload
    frame = b"\xfa" + frame + bytes([(-sum(frame)) & 0xFF])
    (sample,) = XbusParser().feed(frame)
    assert sample.bid == BID_MASTER and sample.sensor == BID_MASTER
    # Its x axis (East at rest) now points North = -z, its y axis West = -x, z stays Up = +y.
    np.testing.assert_allclose(quat_rotate(sample.quat, np.eye(3)), [[0, 0, -1], [-1, 0, 0], [0, 1, 0]],
                               atol=1e-6)


@pytest.mark.parametrize("coord, north, up", [("enu", 1, 2), ("ned", 0, None), ("nwu", 0, 2)])
def test_identity_device_orientation_axes(coord, north, up):
    """An identity device quaternion means the sensor axes are the device frame's axes."""
    payload = encode_mtdata2(quat=xbus.FRAME_TO_WORLD[xbus.COORDS[coord]], coord=coord)
    # The encoder converted the world quaternion back to the device frame: identity on the wire.
    assert payload[3:] == struct.pack(">4f", 1, 0, 0, 0) or same_rotation(
        struct.unpack(">4f", payload[3:]), [1, 0, 0, 0], 1e-7)
    q = decode_mtdata2(payload).quat
    axis = np.eye(3)
    np.testing.assert_allclose(quat_rotate(q, axis[north]), [0, 0, -1], atol=1e-7)  # North
    if up is not None:
        np.testing.assert_allclose(quat_rotate(q, axis[up]), [0, 1, 0], atol=1e-7)
    else:  # NED: z is down
        np.testing.assert_allclose(quat_rotate(q, axis[2]), [0, -1, 0], atol=1e-7)


@pytest.mark.parametrize("orientation", list(xbus.ORIENTATIONS))
@pytest.mark.parametrize("precision", list(xbus.PRECISIONS))
@pytest.mark.parametrize("coord", list(xbus.COORDS))
def test_round_trip_every_representation(orientation, precision, coord):
    rng = np.random.default_rng(zlib.crc32(f"{orientation}/{precision}/{coord}".encode()))
    quats = quat_normalize(rng.normal(size=(20, 4)))
    parser = XbusParser()
    stream = b"".join(
        encode_message(3, MID_MTDATA2, encode_mtdata2(
            quat=q, counter=i, sample_time_fine=1000 * i, acc=[0.1, 9.8, -0.2], gyro=[0.01, 0.02, 3.0],
            mag=[0.5, -0.8, 0.1], orientation=orientation, precision=precision, coord=coord))
        for i, q in enumerate(quats))
    samples = parser.feed(stream)
    assert len(samples) == 20 and parser.buffered == 0
    for i, (s, q) in enumerate(zip(samples, quats)):
        assert (s.bid, s.counter, s.sample_time_fine) == (3, i, 1000 * i)
        assert same_rotation(s.quat, q, TOL[precision]), (s.quat, q)
        np.testing.assert_allclose(s.acc, [0.1, 9.8, -0.2], atol=TOL[precision] * 10)
        np.testing.assert_allclose(s.gyro, [0.01, 0.02, 3.0], atol=TOL[precision] * 10)


def test_several_devices_on_one_port_and_device_ids():
    q = quat_from_axis_angle(np.array([0.3, 0.1, -0.2]))
    stream = b"".join(encode_message(bid, MID_MTDATA2, encode_mtdata2(quat=q, counter=9))
                      for bid in (1, 2, 0xFA, 14))
    stream += encode_message(BID_MASTER, MID_MTDATA2, encode_mtdata2(quat=q, device_id=0x00B40007))
    samples = XbusParser().feed(stream)
    assert [s.bid for s in samples] == [1, 2, 0xFA, 14, 0xFF]
    assert [s.sensor for s in samples] == [1, 2, 0xFA, 14, 0x00B40007]


def test_byte_by_byte_feed_equals_bulk():
    rng = np.random.default_rng(1)
    stream = b"".join(encode_message(1 + i % 3, MID_MTDATA2, encode_mtdata2(
        quat=quat_normalize(rng.normal(size=4)), counter=i, precision="fp1632")) for i in range(30))
    bulk = XbusParser().feed(stream)
    p = XbusParser()
    trickle = [s for b in stream for s in p.feed(bytes([b]))]
    assert [(s.bid, s.counter) for s in trickle] == [(s.bid, s.counter) for s in bulk]
    assert all(np.array_equal(a.quat, b.quat) for a, b in zip(trickle, bulk))


def test_unknown_items_skipped_and_bad_payloads_counted():
    q = [1.0, 0, 0, 0]
    unknown = bytes.fromhex("0810") + bytes([4]) + b"\x00\x00\x00\x00"  # temperature: not decoded
    payload = unknown + encode_mtdata2(quat=q, counter=5)
    parser = XbusParser()
    (s,) = parser.feed(encode_message(1, MID_MTDATA2, payload))
    assert s.counter == 5 and parser.counters["unknown_xdi"] == 1
    bad_size = bytes.fromhex("201008") + bytes(8)  # a quaternion item of 8 bytes
    not_unit = bytes.fromhex("201010") + struct.pack(">4f", 3, 0, 0, 0)
    truncated = bytes.fromhex("201010") + bytes(6)
    for payload in (bad_size, not_unit, truncated):
        with pytest.raises(FormatError):
            decode_mtdata2(payload)
        assert parser.feed(encode_message(1, MID_MTDATA2, payload)) == []
    assert parser.counters["bad_payload"] == 2 and parser.counters["implausible_norm"] == 1


def test_non_data_messages_go_to_the_message_queue():
    parser = XbusParser()
    stream = encode_message(0xFF, 0x31) + encode_message(0xFF, 0x42, b"\x04") + encode_message(0xFF, 0x99)
    assert parser.feed(stream) == []
    assert [(m.mid, m.data) for m in parser.messages] == [(0x31, b""), (0x42, b"\x04")]
    assert parser.counters["unknown_mid"] == 1


def _frames(n: int, rng: np.random.Generator) -> tuple[list[bytes], np.ndarray]:
    quats = quat_normalize(rng.normal(size=(n, 4)))
    bids = rng.integers(1, 16, n)
    frames = [encode_message(int(b), MID_MTDATA2, encode_mtdata2(quat=q, counter=i))
              for i, (b, q) in enumerate(zip(bids, quats))]
    return frames, quats


def test_fuzz_random_bytes_never_raise_and_stay_bounded():
    rng = np.random.default_rng(2024)
    noise = rng.integers(0, 256, 1_000_000, dtype=np.uint8).tobytes()
    parser = XbusParser()
    cuts = np.cumsum(rng.integers(1, 8192, 400))
    cuts = np.concatenate([[0], cuts[cuts < len(noise)], [len(noise)]])
    for a, b in zip(cuts[:-1], cuts[1:]):
        parser.feed(noise[a:b])
        assert parser.buffered <= MAX_FRAME
    c = parser.counters
    assert c["bad_checksum"] + c["bad_length"] > 1000  # ~1 preamble per 256 random bytes


def test_fuzz_corrupted_frames_and_garbage_recover_every_intact_frame():
    rng = np.random.default_rng(7)
    n = 20_000
    frames, quats = _frames(n, rng)
    corrupt = rng.random(n) < 0.5  # 10^4 corrupted frames
    pieces = []
    for i, f in enumerate(frames):
        if rng.random() < 0.3:  # garbage between frames, sometimes holding fake preambles
            g = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8)
            g[rng.random(g.size) < 0.02] = 0xFA
            pieces.append(g.tobytes())
        if corrupt[i]:
            b = bytearray(f)
            b[int(rng.integers(len(b)))] ^= int(rng.integers(1, 256))
            f = bytes(b)
        pieces.append(f)
    pieces.append(bytes(MAX_FRAME))  # trailing silence settles any pending fake preamble
    stream = b"".join(pieces)
    parser = XbusParser()
    cuts = np.concatenate([[0], np.sort(rng.choice(len(stream), 3000, replace=False)), [len(stream)]])
    got = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        got += parser.feed(stream[a:b])
        assert parser.buffered <= MAX_FRAME
    decoded = {s.counter for s in got}
    intact = set(np.flatnonzero(~corrupt).tolist())
    assert decoded == intact  # every intact frame, and no corrupted one
    for s in got:
        assert same_rotation(s.quat, quats[s.counter], 1e-6)
    c = parser.counters
    assert c["bad_checksum"] + c["bad_length"] + c["bad_payload"] + c["unknown_mid"] >= 0.95 * corrupt.sum()


class FakePort:
    """A serial-like object whose device answers each written command with ``reply(msg)``."""

    def __init__(self, reply):
        self.reply = reply
        self.inbox = bytearray()
        self.written: list[bytes] = []
        self.parser = XbusParser()

    def write(self, data: bytes) -> int:
        self.written.append(data)
        self.parser.feed(data)
        while self.parser.messages:
            self.inbox += self.reply(self.parser.messages.popleft())
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.inbox[:size])
        del self.inbox[:size]
        return out


def test_configurator_sends_the_documented_sequence():
    streaming = encode_message(1, MID_MTDATA2, encode_mtdata2(quat=[1, 0, 0, 0], counter=1))

    def device(msg):  # still streaming, then the ack (echoing the configuration)
        return streaming * 3 + encode_message(0xFF, msg.mid + 1, msg.data if msg.mid == 0xC0 else b"")

    port = FakePort(device)
    acked = XbusConfigurator(port, timeout=1.0).configure(60, orientation="euler", precision="fp1632",
                                                          coord="ned", extras=("acc",))
    assert [w[2] for w in port.written] == [0x30, 0xC0, 0x10]
    assert acked == [(0x1020, 0xFFFF), (0x1060, 0xFFFF), (0x2036, 60), (0x4022, 60)]
    assert port.written[1] == encode_message(0xFF, 0xC0, bytes.fromhex("1020FFFF 1060FFFF 2036003C 4022003C"))


def test_configurator_error_and_timeout():
    port = FakePort(lambda msg: encode_message(0xFF, 0x42, b"\x04"))
    with pytest.raises(DeviceError, match="error code 4"):
        XbusConfigurator(port).go_to_config()
    silent = FakePort(lambda msg: b"")
    with pytest.raises(DeviceError, match="no acknowledgement"):
        XbusConfigurator(silent, timeout=0.05).go_to_measurement()


# ----------------------------------------------------------------------------- plausibility

def _frame(bid=1, **fields) -> bytes:
    return encode_message(bid, MID_MTDATA2, encode_mtdata2(**fields))


@pytest.mark.parametrize("field", ["acc", "gyro", "mag"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_values_are_dropped_and_counted(field, bad):
    frame = _frame(quat=[1, 0, 0, 0], counter=1, **{field: [0.0, bad, 1.0]})
    parser = XbusParser()
    assert parser.feed(frame + _frame(quat=[1, 0, 0, 0], counter=2)) != []
    assert parser.counters["non_finite"] == 1 and parser.counters["samples"] == 1
    assert parser.counters["bad_payload"] == 0
    (raw,) = XbusParser(plausibility=None).feed(frame)  # the bare decoder takes what it is sent
    assert not np.isfinite(getattr(raw, field)).all()


def test_orientations_off_unit_length_are_dropped():
    nearly = struct.pack(">4f", 1.03, 0, 0, 0)  # within the bare decoder's 0.9..1.1, not a device's
    frame = encode_message(1, MID_MTDATA2, bytes.fromhex("201010") + nearly)
    parser = XbusParser()
    assert parser.feed(frame) == [] and parser.counters["implausible_norm"] == 1
    assert len(XbusParser(plausibility=None).feed(frame)) == 1
    skewed = np.eye(3)
    skewed[0, 1] = 0.05  # not orthonormal: a damaged rotation matrix
    raw = bytes.fromhex("202024") + struct.pack(">9f", *skewed.T.reshape(9))
    assert parser.feed(encode_message(1, MID_MTDATA2, raw)) == [] and parser.counters["implausible_norm"] == 2


def test_turn_rate_and_counter_continuity_per_sensor():
    ident = [1.0, 0.0, 0.0, 0.0]
    sign_flip = quat_normalize(np.array([0.6, 0.8, 0.0, 0.0]))  # what a flipped sign bit makes of (0.6, -0.8, 0, 0)
    start = quat_normalize(np.array([0.6, -0.8, 0.0, 0.0]))
    turned = quat_from_axis_angle(np.array([0.0, 0.3, 0.0]))  # 0.3 rad in 10 ms: 30 rad/s
    frames = [
        _frame(1, quat=start, counter=0, sample_time_fine=0),
        _frame(2, quat=ident, counter=0, sample_time_fine=0),
        _frame(1, quat=sign_flip, counter=1, sample_time_fine=100),  # 2.6 rad in 10 ms: dropped
        _frame(2, quat=turned, counter=1, sample_time_fine=100),  # kept
        _frame(2, quat=turned, counter=1, sample_time_fine=200),  # counter did not advance
        _frame(2, quat=turned, counter=2 + 4096, sample_time_fine=300),  # counter jumped ahead
        _frame(2, quat=turned, counter=3, sample_time_fine=100),  # clock went back
        _frame(2, quat=turned, counter=4, sample_time_fine=400),
        _frame(1, quat=start, counter=2, sample_time_fine=200),
    ]
    parser = XbusParser()
    got = parser.feed(b"".join(frames))
    assert [(s.bid, s.counter) for s in got] == [(1, 0), (2, 0), (2, 1), (2, 4), (1, 2)]
    c = parser.counters
    assert (c["implausible_rate"], c["counter_jump"], c["frames"], c["samples"]) == (1, 3, 9, 5)


def test_counters_wrap_and_a_reset_device_reanchors():
    q = [1.0, 0.0, 0.0, 0.0]
    wrap = [_frame(quat=q, counter=c, sample_time_fine=t)
            for c, t in ((65534, (1 << 32) - 200), (65535, (1 << 32) - 100), (0, 0), (1, 100))]
    parser = XbusParser()
    assert len(parser.feed(b"".join(wrap))) == 4 and parser.counters["counter_jump"] == 0
    reset = [_frame(quat=q, counter=c, sample_time_fine=100 * c) for c in (0, 1, 2)]
    assert [s.counter for s in parser.feed(b"".join(reset))] == [1, 2]  # one sample lost
    assert parser.counters["counter_jump"] == 1 and parser.counters["reanchored"] == 1


def test_device_ids_beyond_int32():
    frames = b"".join(_frame(BID_MASTER, quat=[1, 0, 0, 0], device_id=d) for d in (0x80000000, 0xFFFFFFFF))
    assert [s.sensor for s in XbusParser().feed(frames)] == [0x80000000, 0xFFFFFFFF]
