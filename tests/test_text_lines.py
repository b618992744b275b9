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
    b"hello world", b"1,2,3", b"1,2,nan,0,0,0", b"1,2,0,0,0,0", b"1,2,1,0,0,0,1,2",
    b"x,2,1,0,0,0", b'{"t_us":1,"sensor":2,"q":[1,0,0]}', b'{"t_us":1,"sensor":true,"q":[1,0,0,0]}',
    b"[1,2,3]", b'{"t_us":1', b"1,2,1,0,0,0,1,2,inf", b'{"t_us":1,"sensor":2,"q":[1,0,0,0],"acc":[1]}',
    b"\xff\xfe,1,1,0,0,0",
])
def test_bad_lines_are_counted(line):
    p = LineParser()
    assert p.feed(line + b"\n" + b"9,9,1,0,0,0\n")[0].t_us == 9
    assert p.counters["bad_lines"] == 1 and p.counters["samples"] == 1


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
        line = bytearray(encode_line(i % 15 + 1, i, quats[i], fmt="json" if i % 3 == 0 else "csv",
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
    assert {s.t_us for s in got} == set(np.flatnonzero(~corrupt).tolist())
    for s in got:
        np.testing.assert_allclose(s.quat, quats[s.t_us], atol=1e-12)
    c = p.counters
    assert c["bad_checksum"] + c["bad_lines"] + c["too_long"] >= corrupt.sum()
