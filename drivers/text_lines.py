"""Text-line protocol for DIY IMU suits (ESP32 / Arduino + BNO08x / BNO055), codec and parser.

One sample per line, terminated by ``\\n`` (a ``\\r`` before it is ignored), in either form::

    <t_us>,<sensor>,<qw>,<qx>,<qy>,<qz>[,<ax>,<ay>,<az>[,<gx>,<gy>,<gz>]]
    {"t_us": 123, "sensor": 3, "q": [w, x, y, z], "acc": [..], "gyro": [..], "mag": [..]}

t_us: the device's microsecond clock (integer); sensor: integer id; q: sensor-to-world unit
quaternion; acc m/s^2, gyro rad/s, mag a.u. in the sensor frame. Either form may end with an
NMEA-style checksum ``*HH`` (two hex digits, XOR of every byte before the ``*``); when present it
is verified. By default quaternions are taken as ENU (what the BNO08x rotation vector reports)
and converted to the livecap world exactly like Xbus ENU data (drivers.xbus); ``frame="world"``
passes them through for firmware that already sends livecap world orientations.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drivers.xbus import FRAME_TO_WORLD
from live.core import vec3 as v3

MAX_LINE = 512
FRAMES = ("enu", "world")
_IDENTITY = (1.0, 0.0, 0.0, 0.0)


@dataclass(slots=True)
class LineSample:
    """One decoded line. quat (4,) float64 (w, x, y, z) sensor-to-world (livecap world)."""

    sensor: int
    t_us: int
    quat: np.ndarray
    acc: np.ndarray | None = None
    gyro: np.ndarray | None = None
    mag: np.ndarray | None = None

    @property
    def counter(self) -> int:
        """The device clock stands in for a packet counter (see MocapPacket.counter)."""
        return self.t_us


def line_checksum(body: bytes) -> int:
    """XOR of every byte of ``body`` (NMEA style)."""
    c = 0
    for b in body:
        c ^= b
    return c


def _to_device(quat: Iterable[float], frame: str) -> tuple:
    q = tuple(float(v) for v in quat)
    return v3.quat_mul(v3.quat_conj(FRAME_TO_WORLD[0x0]), q) if frame == "enu" else q


def encode_line(sensor: int, t_us: int, quat: Iterable[float], *, acc: Iterable[float] | None = None,
                gyro: Iterable[float] | None = None, mag: Iterable[float] | None = None,
                fmt: str = "csv", frame: str = "enu", checksum: bool = False) -> bytes:
    """One line (with ``\\n``) for a world quaternion, symmetric with ``LineParser``.

    CSV carries acc and gyro (gyro only after acc); JSON carries all of acc, gyro, mag. Floats
    are written with repr precision, so decoding gives back the same float64 values.
    """
    q = _to_device(quat, frame)
    if fmt == "csv":
        fields = [str(int(t_us)), str(int(sensor))] + [repr(v) for v in q]
        if gyro is not None and acc is None:
            raise ValueError("the CSV line form carries gyro only after acc")
        for vec in (acc, gyro):
            if vec is not None:
                fields += [repr(float(v)) for v in vec]
        body = ",".join(fields).encode("ascii")
    elif fmt == "json":
        obj: dict = {"t_us": int(t_us), "sensor": int(sensor), "q": list(q)}
        for key, vec in (("acc", acc), ("gyro", gyro), ("mag", mag)):
            if vec is not None:
                obj[key] = [float(v) for v in vec]
        body = json.dumps(obj, separators=(",", ":")).encode("ascii")
    else:
        raise ValueError(f"unknown line format {fmt!r}; expected 'csv' or 'json'")
    if checksum:
        body += b"*%02X" % line_checksum(body)
    return body + b"\n"


def _vec3(values) -> np.ndarray:
    v = np.array([float(x) for x in values], dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError("expected three finite numbers")
    return v


class LineParser:
    """Incremental text-line decoder: ``feed(bytes) -> [LineSample]``, never raises.

    Lines longer than ``max_line`` bytes (a lost terminator, binary noise) are discarded up to
    the next newline without buffering them; bad lines are counted, never raised.
    require_checksum: reject lines without a ``*HH`` suffix (noisy links; a line cut short by a
    lost byte could otherwise still parse).
    """

    def __init__(self, *, max_line: int = MAX_LINE, frame: str = "enu", require_checksum: bool = False):
        if frame not in FRAMES:
            raise ValueError(f"unknown frame {frame!r}; expected one of {FRAMES}")
        self.max_line = max_line
        self.require_checksum = require_checksum
        self._to_world = FRAME_TO_WORLD[0x0] if frame == "enu" else _IDENTITY
        self._buf = bytearray()
        self._discarding = False
        self.counters: dict[str, int] = {
            "lines": 0, "samples": 0, "bad_lines": 0, "bad_checksum": 0, "too_long": 0,
        }

    def feed(self, data: bytes) -> list[LineSample]:
        out: list[LineSample] = []
        buf = self._buf
        start = 0
        while True:
            nl = data.find(b"\n", start)
            if nl < 0:
                break
            piece = data[start:nl]
            start = nl + 1
            if self._discarding:
                self._discarding = False
                buf.clear()
                continue
            if buf:
                buf += piece
                line = bytes(buf)
                buf.clear()
            else:
                line = piece
            if len(line) > self.max_line:
                self.counters["too_long"] += 1
                continue
            self._line(line, out)
        rest = data[start:]
        if not self._discarding:
            buf += rest
            if len(buf) > self.max_line:
                self.counters["too_long"] += 1
                self._discarding = True
                buf.clear()
        self.counters["samples"] += len(out)
        return out

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def _line(self, line: bytes, out: list[LineSample]) -> None:
        line = line.rstrip(b"\r")
        if not line.strip():
            return
        self.counters["lines"] += 1
        if len(line) >= 3 and line[-3:-2] == b"*":
            try:
                expected = int(line[-2:], 16)
            except ValueError:
                expected = -1
            line = line[:-3]
            if expected != line_checksum(line):
                self.counters["bad_checksum"] += 1
                return
        elif self.require_checksum:
            self.counters["bad_checksum"] += 1
            return
        try:
            out.append(self._parse(line))
        except (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError):
            self.counters["bad_lines"] += 1

    def _parse(self, line: bytes) -> LineSample:
        text = line.decode("ascii").strip()
        acc = gyro = mag = None
        if text.startswith("{"):
            obj = json.loads(text)
            if not isinstance(obj, dict):
                raise ValueError("a JSON line must be an object")
            t_us, sensor, q = obj["t_us"], obj["sensor"], obj["q"]
            if not isinstance(t_us, int) or not isinstance(sensor, int) or isinstance(sensor, bool):
                raise ValueError("t_us and sensor must be integers")
            if not isinstance(q, list) or len(q) != 4:
                raise ValueError("q must be a list of four numbers")
            qv = tuple(float(v) for v in q)
            acc = _vec3(obj["acc"]) if "acc" in obj else None
            gyro = _vec3(obj["gyro"]) if "gyro" in obj else None
            mag = _vec3(obj["mag"]) if "mag" in obj else None
        else:
            parts = text.split(",")
            if len(parts) not in (6, 9, 12):
                raise ValueError(f"a CSV line has 6, 9 or 12 fields, not {len(parts)}")
            t_us, sensor = int(parts[0]), int(parts[1])
            qv = tuple(float(v) for v in parts[2:6])
            if len(parts) >= 9:
                acc = _vec3(parts[6:9])
            if len(parts) == 12:
                gyro = _vec3(parts[9:12])
        norm = v3.quat_norm(qv)
        if not 0.5 < norm < 1.5:  # also false for NaN
            raise ValueError("q is not a rotation")
        qw = v3.quat_mul(self._to_world, qv)
        quat = np.array(qw, dtype=np.float64) / norm
        return LineSample(sensor=sensor, t_us=t_us, quat=quat, acc=acc, gyro=gyro, mag=mag)
