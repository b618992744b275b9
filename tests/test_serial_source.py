"""SerialSource over socket:// (a TCP peer plays the device): one packet per read with the raw
bytes, decoding equal to a replay, gaps with reconnection, prompt stop without thread leaks."""

from __future__ import annotations

import socket
import threading

import numpy as np
import pytest

from drivers.serial_source import SerialSource, decode_packet_bytes, records_to_arrays
from drivers.text_lines import encode_line
from drivers.xbus import MID_MTDATA2, encode_message, encode_mtdata2
from live.core.errors import DeviceError, DeviceNotFoundError, UserInputError
from live.core.frames import MocapPacket
from live.core.protocols import Source
from live.core.rotations import quat_normalize

WAIT = 10.0  # generous upper bound for events; tests normally finish far sooner


def xbus_stream(n: int, seed: int, sensors=(1, 2, 3)) -> tuple[bytes, np.ndarray]:
    q = quat_normalize(np.random.default_rng(seed).normal(size=(n, 4)))
    data = b"".join(encode_message(sensors[i % len(sensors)], MID_MTDATA2,
                                   encode_mtdata2(quat=q[i], counter=i, acc=[0, 9.81, 0]))
                    for i in range(n))
    return data, q


class Collector:
    """emit() target that signals when ``want`` records have arrived."""

    def __init__(self):
        self.packets: list[MocapPacket] = []
        self.records = 0
        self.want = 0
        self.reached = threading.Event()

    def expect(self, n: int) -> threading.Event:
        self.want = n
        self.reached.clear()
        if self.records >= n:
            self.reached.set()
        return self.reached

    def __call__(self, packet: MocapPacket) -> None:
        self.packets.append(packet)
        self.records += len(packet.sensors)
        if self.records >= self.want:
            self.reached.set()


@pytest.fixture()
def server():
    srv = socket.create_server(("127.0.0.1", 0))
    srv.settimeout(WAIT)
    yield srv
    srv.close()


def test_unknown_protocol_is_a_user_error():
    with pytest.raises(UserInputError):
        SerialSource("loop://", "nmea")


def test_source_protocol_and_stream_info():
    with SerialSource("loop://", "lines", name="suit", baud=921600) as src:
        assert isinstance(src, Source)
        (info,) = src.streams()
        assert (info.name, info.kind, info.meta) == ("suit", "serial",
                                                     {"protocol": "lines", "port": "loop://", "baud": 921600})


def refused_port() -> int:
    """A local TCP port nobody listens on."""
    with socket.create_server(("127.0.0.1", 0)) as srv:
        return srv.getsockname()[1]


def test_a_port_that_cannot_be_opened_fails_at_construction(tmp_path):
    with pytest.raises(DeviceNotFoundError, match="not found") as info:
        SerialSource(str(tmp_path / "no-such-port"), "xbus")
    assert "\n" not in str(info.value)
    with pytest.raises(DeviceError, match="not a serial device"):
        SerialSource("/dev/null", "lines")
    with pytest.raises(DeviceError, match="refused") as info:
        SerialSource(f"socket://127.0.0.1:{refused_port()}", "xbus")
    assert not isinstance(info.value, DeviceNotFoundError)


@pytest.mark.parametrize("baud", [0, -9600, 10**20, 16_000_001, 9600.5, True])
def test_baud_out_of_range_is_a_user_error(baud):
    with pytest.raises(UserInputError, match="baud"):
        SerialSource("loop://", "xbus", baud=baud)


def test_run_reopens_after_close_and_fails_loudly_when_the_port_is_gone(server):
    src = SerialSource(f"socket://127.0.0.1:{server.getsockname()[1]}", "lines")
    src.close()
    server.close()  # "never opened" for this run: an error, not a gap
    with pytest.raises(DeviceError, match="cannot open"):
        src.run(lambda p: None, threading.Event())
    assert src.counters["gaps"] == 0 and src.counters["connects"] == 0


def test_packets_carry_raw_bytes_and_match_replay(server):
    baseline = threading.active_count()
    data, quats = xbus_stream(300, seed=0)
    garbage = np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    cut = len(data) // 300 * 120  # frames all have the same size: insert at a boundary
    sent = data[:cut] + garbage + data[cut:]
    out = Collector()
    src = SerialSource(f"socket://127.0.0.1:{server.getsockname()[1]}", "xbus", name="xs")
    src.start(out)
    conn, _ = server.accept()
    assert src.connected.wait(WAIT)  # pyserial flushes its input while opening: send after that
    done = out.expect(300)
    for i in range(0, len(sent), 997):  # odd-sized writes: frames straddle reads
        conn.sendall(sent[i:i + 997])
    assert done.wait(WAIT)
    src.stop()
    conn.close()
    assert threading.active_count() == baseline
    assert b"".join(p.raw for p in out.packets) == sent
    t = [p.t_ns for p in out.packets]
    assert t == sorted(t) and all(p.device == "xs" for p in out.packets)
    counter = np.concatenate([p.counter for p in out.packets if len(p.sensors)])
    np.testing.assert_array_equal(counter, np.arange(300))
    q = np.concatenate([p.quats for p in out.packets])
    np.testing.assert_allclose(q, quats, atol=1e-6)
    assert src.counters["records"] == 300 and src.counters["skipped_bytes"] > 0
    replay = decode_packet_bytes([p.raw for p in out.packets], "xbus", t_ns=t, device="xs")
    for live, rep in zip(out.packets, replay):
        assert live.t_ns == rep.t_ns
        np.testing.assert_array_equal(live.sensors, rep.sensors)
        np.testing.assert_array_equal(live.quats, rep.quats)
        np.testing.assert_array_equal(live.acc if live.acc is not None else [],
                                      rep.acc if rep.acc is not None else [])


def test_gap_reconnect_and_prompt_stop(server):
    baseline = threading.active_count()
    out = Collector()
    src = SerialSource(f"socket://127.0.0.1:{server.getsockname()[1]}", "lines", backoff_start=0.01)
    thread = src.start(out)
    conn, _ = server.accept()
    assert src.connected.wait(WAIT)
    first = b"".join(encode_line(1, i, [1, 0, 0, 0]) for i in range(50))
    done = out.expect(50)
    conn.sendall(first)
    assert done.wait(WAIT)
    conn.close()  # the device goes away: a gap, then the source dials again
    conn, _ = server.accept()
    while src.counters["connects"] < 2 or not src.connected.is_set():
        src.connected.wait(0.01)  # wait for the second connection to be fully open
    done = out.expect(100)
    conn.sendall(b"".join(encode_line(1, i, [1, 0, 0, 0]) for i in range(50, 100)))
    assert done.wait(WAIT)
    c = src.counters
    assert c["gaps"] == 1 and c["records"] == 100 and c["bad_lines"] == 0
    start, end = src.gaps[0]
    assert end is not None and end >= start
    ts = np.concatenate([p.counter for p in out.packets if len(p.sensors)])
    np.testing.assert_array_equal(ts, np.arange(100))
    src.stop(timeout=1.0)
    assert not thread.is_alive()
    conn.close()
    assert threading.active_count() == baseline


def test_records_to_arrays_fills_missing_fields():
    from drivers.xbus import XbusSample

    a = XbusSample(bid=1, counter=3, quat=np.array([1.0, 0, 0, 0]), gyro=np.array([1.0, 2, 3]))
    b = XbusSample(bid=2, quat=None)
    arr = records_to_arrays([a, b])
    np.testing.assert_array_equal(arr["sensors"], [1, 2])
    np.testing.assert_array_equal(arr["counter"], [3, -1])
    assert np.isnan(arr["quats"][1]).all() and np.isnan(arr["gyro"][1]).all()
    assert arr["acc"] is None and arr["mag"] is None and arr["quats"].dtype == np.float32
    empty = records_to_arrays([])
    assert empty["sensors"].shape == (0,) and empty["quats"].shape == (0, 4)
