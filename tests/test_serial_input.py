"""Serial input under abuse: 64-bit sensor ids end to end (suit -> record -> export), ports
that cannot be opened (one line, exit 2, no file), and flipped bits that pass the checksums
(caught by the plausibility checks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.serial_source import records_to_arrays
from drivers.text_lines import LineParser, encode_line
from drivers.xbus import MID_MTDATA2, encode_message, encode_mtdata2
from drivers.xbus_stream import XbusParser
from live.app.cli import main
from live.core.frames import MocapPacket
from live.core.rotations import quat_canonical, quat_from_axis_angle, quat_multiply
from live.io import codec
from sim.imu_device import DEVICE_ID_BASE, SimulatedSuit
from sim.imu_model import random_smooth_motion

MAC = 0x246F28A1B2C3  # an ESP32 MAC address used as a sensor id
WIDE = {MAC: 0, (1 << 40) + 7: 15, 0x7FFFFFFF: 12}  # sensor id -> joint (pelvis, head, chest)


@pytest.mark.parametrize("protocol", ["lines", "xbus"])
def test_64_bit_ids_survive_record_and_export(tmp_path, protocol):
    motion = random_smooth_motion(120, fps=60.0, seed=2)
    # Xbus: every frame carries a DeviceId item 0x00B40000 + id; 0x7F4C0001 + base >= 2^31.
    layout = WIDE if protocol == "lines" else {0x7F4C0001: 0, 0x7F4C0002: 15, 0xFF4BFFFF: 12}
    session = tmp_path / "suit.mcap"
    with SimulatedSuit(motion, protocol, rate_hz=100, layout=layout, realtime=True, loop=True,
                       xbus_addressing="device_id") as suit:
        assert main(["record", "--source", f"serial:{suit.port}:{protocol}", "--out", str(session),
                     "--seconds", "1.0", "--quiet"]) == 0
        truth = suit.truth()
    assert main(["export", str(session), "--out", str(tmp_path / "exp")]) == 0
    imu = np.load(tmp_path / "exp" / "imu_serial.npz")
    want = set(layout) if protocol == "lines" else {DEVICE_ID_BASE + s for s in layout}
    assert imu["sensor"].dtype == np.int64 and set(imu["sensor"].tolist()) == want
    assert protocol == "lines" or min(want) >= 1 << 31
    sent = {(int(s), int(c)): q for s, c, q in zip(truth.sensor, truth.counter, truth.quat)}
    assert len(imu["sensor"]) > 100
    for s, c, q in zip(imu["sensor"], imu["counter"], imu["quat"]):
        np.testing.assert_allclose(quat_canonical(q), quat_canonical(sent[(int(s), int(c))]), atol=2e-7)


def test_records_and_decoded_imu_records_keep_wide_ids():
    (rec,) = LineParser().feed(encode_line(MAC, 0, [1, 0, 0, 0]))
    arrays = records_to_arrays([rec])
    assert arrays["sensors"].dtype == np.int64 and arrays["sensors"][0] == MAC
    for ids in ([MAC, -(1 << 40), 3], [0, 1, 2]):
        packet = MocapPacket(5, "imu", sensors=np.array(ids), quats=np.tile([1.0, 0, 0, 0], (3, 1)))
        data = codec.encode_imu(packet)
        back = codec.decode_imu(data, "imu")
        assert back.sensors.dtype == np.int64 and back.sensors.tolist() == ids
    # ids that fit int32 keep the record layout older readers know (4 bytes per id, flags 0)
    assert len(data) == 10 + 5 + 3 * 4 + 3 * 32 and data[14] == 0


@pytest.mark.parametrize("command", ["record", "run"])
@pytest.mark.parametrize("source, message", [
    ("serial:{tmp}/no-such-port:xbus", "not found"),
    ("serial:/dev/null:lines", "not a serial device"),
    ("serial:socket://127.0.0.1:1:xbus", "Connection refused"),
    ("serial:/dev/ttyS0:xbus:100000000000000000000", "baud rate must be 1 to 16000000"),
])
def test_ports_that_cannot_be_opened_exit_2_with_one_line(tmp_path, capsys, command, source, message):
    out = tmp_path / ("take.mcap" if command == "record" else "run")
    argv = [command, "--source", source.format(tmp=tmp_path), "--out", str(out), "--seconds", "1", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"livecap {command}: error: ") and message in err[0]
    assert not (tmp_path / "take.mcap").exists()


# ----------------------------------------------------------------------------- flipped bits

def _turning(steps: int, sensors: int, rng: np.random.Generator) -> np.ndarray:
    """(steps, sensors, 4): each sensor turns at 2-8 rad/s about its own axis, sampled at 100 Hz."""
    axis = rng.normal(size=(sensors, 3))
    axis *= (rng.uniform(2, 8, size=sensors) / 100.0 / np.linalg.norm(axis, axis=1))[:, None]
    step = quat_from_axis_angle(axis)
    q = np.empty((steps, sensors, 4))
    q[0] = quat_from_axis_angle(rng.normal(size=(sensors, 3)))
    for t in range(1, steps):
        q[t] = quat_multiply(q[t - 1], step)
    return q


def _flip(record: bytes, bits: int, rng: np.random.Generator, keep_last: bool) -> bytes:
    buf = bytearray(record)
    for bit in rng.choice(8 * (len(buf) - keep_last), size=bits, replace=False):
        buf[bit // 8] ^= 1 << (bit % 8)
    return bytes(buf)


def _worst_error_deg(samples, quats, key) -> tuple[float, int]:
    """Largest orientation error of decoded samples against what was sent for their (sensor, t)."""
    worst, matched = 0.0, 0
    for s in samples:
        t = key(s)
        if s.quat is None or t is None or not (0 <= t < len(quats)) or not 1 <= s.sensor <= quats.shape[1]:
            continue
        matched += 1
        dot = abs(float(np.dot(s.quat, quats[t, s.sensor - 1])))
        worst = max(worst, math.degrees(2 * math.acos(min(1.0, dot))))
    return worst, matched


@pytest.mark.parametrize("protocol", ["xbus", "lines"])
def test_flipped_bits_that_pass_the_checksum_are_caught(protocol):
    """Two flipped bits per damaged record: some pass the 8-bit checksums with orientations up
    to 180 degrees off; with the plausibility checks nothing decoded is further off than a body
    turns in one sample (50 rad/s at 100 Hz = 29 degrees) plus the motion."""
    rng = np.random.default_rng(11)
    steps, sensors = 600, 5
    quats = _turning(steps, sensors, rng)
    records = []
    for t in range(steps):
        for s in range(sensors):
            if protocol == "xbus":
                rec = encode_message(s + 1, MID_MTDATA2, encode_mtdata2(
                    quat=quats[t, s], counter=t, sample_time_fine=100 * t))
            else:
                rec = encode_line(s + 1, 10_000 * t, quats[t, s], checksum=True)
            if rng.random() < 0.5:
                rec = _flip(rec, 2, rng, keep_last=protocol == "lines")
            records.append(rec)
    stream = b"".join(records)
    key = (lambda s: s.counter) if protocol == "xbus" else (lambda s: s.t_us // 10_000)
    make = XbusParser if protocol == "xbus" else LineParser
    bare = make(plausibility=None)
    worst_bare, _ = _worst_error_deg(bare.feed(stream), quats, key)
    checked = make()
    worst, matched = _worst_error_deg(checked.feed(stream), quats, key)
    assert worst_bare > 90.0  # what the checksum alone lets through
    assert worst < 35.0 and matched > 0.45 * steps * sensors
    c = checked.counters
    assert c["implausible_rate"] + c["implausible_norm"] + c["counter_jump"] > 0
