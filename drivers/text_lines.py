"""Text-line protocol for DIY IMU suits (ESP32 / Arduino + BNO08x / BNO055), codec and parser.

One sample per line, terminated by ``\\n`` (a ``\\r`` before it is ignored), in either form::

    <t_us>,<sensor>,<qw>,<qx>,<qy>,<qz>[,<ax>,<ay>,<az>[,<gx>,<gy>,<gz>]]
    {"t_us": 123, "sensor": 3, "q": [w, x, y, z], "acc": [..], "gyro": [..], "mag": [..]}

t_us: the device's microsecond clock (integer, 0 <= t_us < 2^63); sensor: integer id in the
int64 range (a 48-bit MAC fits; the CSV form also takes ``0x``-prefixed hex); q: sensor-to-world
unit quaternion; acc m/s^2, gyro rad/s, mag a.u. in the sensor frame. Either form may end with an
NMEA-style checksum ``*HH`` (two hex digits, XOR of every byte before the ``*``); when present it
is verified. By default quaternions are taken as ENU (what the BNO08x rotation vector reports)
and converted to the livecap world exactly like Xbus ENU data (drivers.xbus); ``frame="world"``
passes them through for firmware that already sends livecap world orientations. Decoded samples
go through the plausibility checks of drivers/plausibility.py (NaN / inf, unit norm, t_us
continuity and turn rate per sensor), which drop and count implausible ones.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drivers.plausibility import (
    LINE_LIMITS,
    ContinuityFilter,
    ImplausibleSample,
    PlausibilityLimits,
    all_finite,
    check_norm,
    new_counters,
)
from drivers.xbus import FRAME_TO_WORLD
from live.core import vec3 as v3

MAX_LINE = 512
INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1
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


def _floats(values, n: int) -> tuple[float, ...]:
    v = tuple(float(x) for x in values)
    if len(v) != n:
        raise ValueError(f"expected {n} numbers")
    return v


def _int_field(value: str) -> int:
    """A CSV integer field: decimal, or hex with a 0x prefix (a MAC address as a sensor id)."""
    value = value.strip()
    return int(value[2:], 16) if value[:2].lower() == "0x" else int(value)


def _check_ids(sensor: int, t_us: int) -> None:
    if not INT64_MIN <= sensor <= INT64_MAX:
        raise ValueError("the sensor id does not fit in 64 bits")
    if not 0 <= t_us <= INT64_MAX:
        raise ValueError("t_us must be a non-negative 64-bit integer")


def _array(v: tuple[float, ...] | None) -> np.ndarray | None:
    return None if v is None else np.array(v, dtype=np.float64)


class LineParser:
    """Incremental text-line decoder: ``feed(bytes) -> [LineSample]``, never raises.

    Lines longer than ``max_line`` bytes (a lost terminator, binary noise) are discarded up to
    the next newline without buffering them; bad lines are counted, never raised.
    require_checksum: reject lines without a ``*HH`` suffix (noisy links; a line cut short by a
    lost byte could otherwise still parse). plausibility: the checks of drivers/plausibility.py,
    counted by reason (None: only the syntax and a norm within 0.5 of 1 are checked).
    """

    def __init__(self, *, max_line: int = MAX_LINE, frame: str = "enu", require_checksum: bool = False,
                 plausibility: PlausibilityLimits | None = LINE_LIMITS):
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
        self.limits = plausibility
        self._continuity: ContinuityFilter | None = None
        if plausibility is not None:
            self.counters.update(new_counters())
            # t_us is the clock (a 32-bit micros() that wraps, or a 64-bit one); no packet counter.
            self._continuity = ContinuityFilter(plausibility, self.counters, clock_hz=1e6)

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
            sample = self._parse(line)
        except ImplausibleSample as e:
            self.counters[e.reason] += 1
            return
        except (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError):
            self.counters["bad_lines"] += 1
            return
        continuity = self._continuity
        if continuity is None or continuity.accept(sample.sensor, None, sample.t_us, sample.quat.tolist()):
            out.append(sample)

    def _parse(self, line: bytes) -> LineSample:
        text = line.decode("ascii").strip()
        acc = gyro = mag = None
        if text.startswith("{"):
            obj = json.loads(text)
            if not isinstance(obj, dict):
                raise ValueError("a JSON line must be an object")
            t_us, sensor, q = obj["t_us"], obj["sensor"], obj["q"]
            if any(not isinstance(v, int) or isinstance(v, bool) for v in (t_us, sensor)):
                raise ValueError("t_us and sensor must be integers")
            if not isinstance(q, list) or len(q) != 4:
                raise ValueError("q must be a list of four numbers")
            qv = _floats(q, 4)
            acc = _floats(obj["acc"], 3) if "acc" in obj else None
            gyro = _floats(obj["gyro"], 3) if "gyro" in obj else None
            mag = _floats(obj["mag"], 3) if "mag" in obj else None
        else:
            parts = text.split(",")
            if len(parts) not in (6, 9, 12):
                raise ValueError(f"a CSV line has 6, 9 or 12 fields, not {len(parts)}")
            t_us, sensor = int(parts[0]), _int_field(parts[1])
            qv = _floats(parts[2:6], 4)
            if len(parts) >= 9:
                acc = _floats(parts[6:9], 3)
            if len(parts) == 12:
                gyro = _floats(parts[9:12], 3)
        _check_ids(sensor, t_us)
        limits = self.limits
        if limits is not None:
            if not all(all_finite(v) for v in (qv, acc, gyro, mag) if v is not None):
                raise ImplausibleSample("non_finite", "a value is NaN or infinite")
            norm = v3.quat_norm(qv)
            check_norm(norm, limits)
        else:
            norm = v3.quat_norm(qv)
            if not 0.5 < norm < 1.5:  # also false for NaN
                raise ValueError("q is not a rotation")
            if not all(all_finite(v) for v in (acc, gyro, mag) if v is not None):
                raise ValueError("expected finite numbers")
        qw = v3.quat_mul(self._to_world, qv)
        quat = np.array(qw, dtype=np.float64) / norm
        return LineSample(sensor=sensor, t_us=t_us, quat=quat, acc=_array(acc), gyro=_array(gyro),
                          mag=_array(mag))
