"""Text-line protocol: exact bytes, CSV / JSON round trips, checksums, partial and overlong
lines, bad-line counting and fuzzing."""

from __future__ import annotations

import json
from functools import reduce

import numpy as np
import pytest

from drivers.text_lines import LineParser, encode_line, line_checksum
from drivers.xbus import FRAME_TO_WORLD
from live.core.rotations import quat_normalize


def test_exact_bytes_world_frame():
    assert encode_line(3, 1000, [1.0, 0.0, 0.0, 0.0], frame="world") == b"1000,3,1.0,0.0,0.0,0.0\n"
    line = encode_line(3, 1000, [1.0, 0.0, 0.0, 0.0], acc=[0, 0, 9.5], frame="world", checksum=True)
    body = b"1000,3,1.0,0.0,0.0,0.0,0.0,0.0,9.5"
    assert line == body + b"*%02X\n" % reduce(lambda a, b: a ^ b, body)
    js = encode_line(7, 5, [1, 0, 0, 0], gyro=[0.5, 0, 0], fmt="json", frame="world")
    assert json.loads(js) == {"t_us": 5, "sensor": 7, "q": [1.0, 0.0, 0.0, 0.0], "gyro": [0.5, 0.0, 0.0]}


def test_enu_lines_match_the_xbus_world_convention():
    (s,) = LineParser().feed(b"0,1,1,0,0,0\n")  # identity in ENU
    np.testing.assert_allclose(s.quat, FRAME_TO_WORLD[0], atol=1e-15)
    (w,) = LineParser(frame="world").feed(b"0,1,1,0,0,0\n")
    np.testing.assert_allclose(w.quat, [1, 0, 0, 0])


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_round_trip_is_exact(fmt):
    rng = np.random.default_rng(3)
    quats = quat_normalize(rng.normal(size=(50, 4)))
    acc, gyro, mag = rng.normal(size=(3, 50, 3))
    stream = b"".join(encode_line(i % 15 + 1, 10_000 * i, q, acc=acc[i], gyro=gyro[i],
                                  mag=mag[i] if fmt == "json" else None, fmt=fmt, checksum=i % 2 == 0)
                      for i, q in enumerate(quats))
    samples = LineParser().feed(stream.replace(b"\n", b"\r\n", 5))
    assert len(samples) == 50
    for i, s in enumerate(samples):
        assert (s.sensor, s.t_us, s.counter) == (i % 15 + 1, 10_000 * i, 10_000 * i)
        np.testing.assert_allclose(s.quat, quats[i], atol=1e-15)
        np.testing.assert_array_equal(s.acc, acc[i])
        np.testing.assert_array_equal(s.gyro, gyro[i])
        if fmt == "json":
            np.testing.assert_array_equal(s.mag, mag[i])


def test_partial_lines_byte_by_byte():
    stream = b"".join(encode_line(2, t, [1, 0, 0, 0], fmt=f) for t, f in enumerate(["csv", "json"] * 5))
    p = LineParser()
    got = [s for b in stream for s in p.feed(bytes([b]))]
    assert [s.t_us for s in got] == list(range(10)) and p.buffered == 0


@pytest.mark.parametrize("line", [
    b"hello world", b"1,2,3", b"1,2,1,0,0,0,1,2",
    b"x,2,1,0,0,0", b'{"t_us":1,"sensor":2,"q":[1,0,0]}', b'{"t_us":1,"sensor":true,"q":[1,0,0,0]}',
    b"[1,2,3]", b'{"t_us":1', b'{"t_us":1,"sensor":2,"q":[1,0,0,0],"acc":[1]}',
    b"\xff\xfe,1,1,0,0,0", b"-1,2,1,0,0,0", b"1,%d,1,0,0,0" % (1 << 63), b"%d,2,1,0,0,0" % (1 << 63),
    b'{"t_us":true,"sensor":2,"q":[1,0,0,0]}', b"1,0x,1,0,0,0",
])
def test_bad_lines_are_counted(line):
    p = LineParser()
    assert p.feed(line + b"\n" + b"9,9,1,0,0,0\n")[0].t_us == 9
    assert p.counters["bad_lines"] == 1 and p.counters["samples"] == 1


@pytest.mark.parametrize("line, reason", [
    (b"1,2,nan,0,0,0", "non_finite"), (b"1,2,1,0,0,0,1,2,inf", "non_finite"),
    (b'{"t_us":1,"sensor":2,"q":[1,0,0,0],"mag":[1,NaN,0]}', "non_finite"),
    (b'{"t_us":1,"sensor":2,"q":[1,0,0,0],"gyro":[1e999,0,0]}', "non_finite"),
    (b"1,2,0,0,0,0", "implausible_norm"), (b"1,2,1.02,0,0,0", "implausible_norm"),
    (b"1,2,0.7,0.7,0.7,0", "implausible_norm"),
])
def test_implausible_values_are_dropped_and_counted_by_reason(line, reason):
    p = LineParser()
    assert [s.t_us for s in p.feed(line + b"\n" + b"9,9,1,0,0,0\n")] == [9]
    assert p.counters[reason] == 1 and p.counters["bad_lines"] == 0 and p.counters["samples"] == 1


def test_64_bit_sensor_ids():
    mac = 0x246F28A1B2C3  # an ESP32 MAC as the id, decimal or hex
    p = LineParser()
    got = p.feed(b"0,%d,1,0,0,0\n10000,0x246f28a1b2c3,1,0,0,0\n" % mac
                 + b'{"t_us":20000,"sensor":%d,"q":[1,0,0,0]}\n' % ((1 << 63) - 1))
    assert [s.sensor for s in got] == [mac, mac, (1 << 63) - 1]
    assert encode_line(mac, 5, [1, 0, 0, 0]).split(b",")[1] == str(mac).encode()


def test_clock_continuity_and_turn_rate_per_sensor():
    """t_us must advance (by at most 5 s) and a sensor may not turn faster than 50 rad/s."""
    flipped = [0.0, 0.0, 0.0, 1.0]  # 180 degrees away from identity
    small = [np.cos(0.1), np.sin(0.1), 0, 0]  # 0.2 rad: 20 rad/s over 10 ms
    lines = [(1, 0, [1, 0, 0, 0]), (2, 0, [1, 0, 0, 0]), (1, 10_000, flipped), (1, 20_000, small),
             (1, 20_000, small), (1, 15_000, small), (2, 10_000, flipped), (1, 30_000, small)]
    p = LineParser(frame="world")
    got = p.feed(b"".join(encode_line(s, t, q, frame="world") for s, t, q in lines))
    # dropped: sensor 1's 180-degree flip in 10 ms, its repeated and its backwards stamp, and
    # sensor 2's flip (each sensor is judged against its own previous sample)
    assert [(s.sensor, s.t_us) for s in got] == [(1, 0), (2, 0), (1, 20_000), (1, 30_000)]
    c = p.counters
    assert (c["implausible_rate"], c["counter_jump"], c["samples"]) == (2, 2, 4)


def test_a_real_discontinuity_reanchors_after_one_sample():
    """A device reset (clock back to 0) or a long pause costs one sample, not the sensor."""
    p = LineParser(frame="world")
    q = [1.0, 0.0, 0.0, 0.0]
    stamps = [5_000_000, 5_010_000, 0, 10_000, 20_000, 60_000_000, 60_010_000]
    got = p.feed(b"".join(encode_line(1, t, q, frame="world") for t in stamps))
    assert [s.t_us for s in got] == [5_000_000, 5_010_000, 10_000, 20_000, 60_010_000]
    assert p.counters["counter_jump"] == 2 and p.counters["reanchored"] == 2


def test_a_32_bit_microsecond_clock_may_wrap():
    p = LineParser(frame="world")
    got = p.feed(b"".join(encode_line(1, t, [1, 0, 0, 0], frame="world")
                          for t in ((1 << 32) - 10_000, 0, 10_000)))
    assert len(got) == 3 and p.counters["counter_jump"] == 0


def test_checks_off_decodes_what_the_syntax_allows():
    p = LineParser(plausibility=None)
    got = p.feed(b"0,1,1.2,0,0,0\n0,1,0,0,0,1\n")
    assert len(got) == 2 and "implausible_rate" not in p.counters


def test_checksums():
    good = encode_line(1, 1, [1, 0, 0, 0], checksum=True)
    bad = good[:-3] + (b"00" if good[-3:-1] != b"00" else b"01") + b"\n"
    p = LineParser()
    assert len(p.feed(good + bad)) == 1 and p.counters["bad_checksum"] == 1
    strict = LineParser(require_checksum=True)
    assert strict.feed(encode_line(1, 1, [1, 0, 0, 0]) + good) and strict.counters["bad_checksum"] == 1
    assert line_checksum(b"") == 0


def test_overlong_lines_are_bounded_and_dropped():
    p = LineParser(max_line=100)
    for _ in range(100):
        assert p.feed(b"7" * 1000) == [] and p.buffered <= 100
    got = p.feed(b"\n" + encode_line(4, 4, [1, 0, 0, 0]))
    assert [s.sensor for s in got] == [4] and p.counters["too_long"] == 1
    got = p.feed(b"1" * 150 + b"\n" + encode_line(5, 5, [1, 0, 0, 0]))
    assert [s.sensor for s in got] == [5] and p.counters["too_long"] == 2


def test_fuzz_random_bytes_never_raise():
    rng = np.random.default_rng(11)
    noise = rng.integers(0, 256, 1_000_000, dtype=np.uint8)
    noise[rng.random(noise.size) < 0.01] = ord("\n")
    noise[rng.random(noise.size) < 0.05] = ord(",")
    data = noise.tobytes()
    p = LineParser()
    cuts = np.concatenate([[0], np.sort(rng.choice(len(data), 500, replace=False)), [len(data)]])
    for a, b in zip(cuts[:-1], cuts[1:]):
        p.feed(data[a:b])
        assert p.buffered <= p.max_line
    assert p.counters["bad_lines"] + p.counters["too_long"] + p.counters["bad_checksum"] > 1000


def test_fuzz_corrupted_lines_recover_every_intact_line():
    rng = np.random.default_rng(5)
    n = 20_000
    quats = quat_normalize(rng.normal(size=(n, 4)))
    corrupt = rng.random(n) < 0.5
    pieces = []
    for i in range(n):
        if rng.random() < 0.2:  # line noise; the next intact line starts after its newline
            pieces.append(rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8).tobytes() + b"\n")
        # 150 ms between two lines of a sensor: random orientations are plausible turns
        line = bytearray(encode_line(i % 15 + 1, 10_000 * i, quats[i], fmt="json" if i % 3 == 0 else "csv",
                                     checksum=True))
        if corrupt[i]:
            j = int(rng.integers(len(line) - 1))
            flip = int(rng.integers(1, 256))
            line[j] ^= flip if line[j] ^ flip != 0x0A else flip ^ 1
        pieces.append(bytes(line))
    stream = b"".join(pieces)
    p = LineParser(require_checksum=True)
    cuts = np.concatenate([[0], np.sort(rng.choice(len(stream), 3000, replace=False)), [len(stream)]])
    got = [s for a, b in zip(cuts[:-1], cuts[1:]) for s in p.feed(stream[a:b])]
    assert {s.t_us // 10_000 for s in got} == set(np.flatnonzero(~corrupt).tolist())
    for s in got:
        np.testing.assert_allclose(s.quat, quats[s.t_us // 10_000], atol=1e-12)
    c = p.counters
    assert c["bad_checksum"] + c["bad_lines"] + c["too_long"] >= corrupt.sum()
