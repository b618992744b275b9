"""Xsens Xbus (MT low-level communication protocol): message codec and MTData2 records
(the byte-stream parser and the device configurator: drivers/xbus_stream.py).

Wire format of one message (all multi-byte fields big-endian)::

    FA  BID  MID  LEN  [EXT_H EXT_L when LEN == 0xFF]  DATA...  CS

The checksum makes the sum of every byte after the preamble (BID .. CS) zero modulo 256. BID
0xFF is the master device; an Xbus Master / Awinda station puts one BID per tracker on the bus.
MTData2 (MID 0x36) payloads are a sequence of ``XDI (u16) SIZE (u8) VALUE`` items; the low two
bits of an XDI give the precision (float32, fixed 12.20, fixed 16.32, float64), bits 2-3 the
coordinate system of orientation outputs (ENU, NED, NWU).

World convention: decoded orientations are sensor-to-world quaternions (w, x, y, z) in the
livecap world (+Y up, right-handed): x = East, y = Up, z = South (-North), whatever
coordinate system the device used. Only the global frame is converted; the sensor frame is
taken as reported (a constant sensor-frame rotation is absorbed by sensor-to-segment
calibration). acc / gyro / mag stay in the sensor frame, as sent.

Rotation matrices travel column-major (a..i = R[0,0], R[1,0], R[2,0], R[0,1], ...); Euler
angles are (roll, pitch, yaw) in degrees with R = Rz(yaw) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.plausibility import (
    ImplausibleSample,
    PlausibilityLimits,
    all_finite,
    check_norm,
)
from live.core import vec3 as v3
from live.core.errors import FormatError
from live.core.rotations import matrix_to_euler, matrix_to_quat, quat_to_matrix

PREAMBLE = 0xFA
BID_MASTER = 0xFF
MAX_DATA_LEN = 2048  # the LLCP's limit for extended-length messages

# Message ids (acknowledgements are MID + 1).
MID_REQ_DID = 0x00
MID_DEVICE_ID = 0x01
MID_GOTO_MEASUREMENT = 0x10
MID_GOTO_MEASUREMENT_ACK = 0x11
MID_GOTO_CONFIG = 0x30
MID_GOTO_CONFIG_ACK = 0x31
MID_MTDATA2 = 0x36
MID_WAKEUP = 0x3E
MID_WAKEUP_ACK = 0x3F
MID_RESET = 0x40
MID_RESET_ACK = 0x41
MID_ERROR = 0x42
MID_SET_OUTPUT_CONFIGURATION = 0xC0
MID_SET_OUTPUT_CONFIGURATION_ACK = 0xC1

# Error codes carried by MID_ERROR.
ERR_INVALID_MESSAGE = 0x04
ERR_INVALID_PARAMETER = 0x21

# MTData2 data identifiers (precision and coordinate bits cleared).
XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_QUATERNION = 0x2010
XDI_ROTATION_MATRIX = 0x2020
XDI_EULER_ANGLES = 0x2030
XDI_ACCELERATION = 0x4020
XDI_RATE_OF_TURN = 0x8020
XDI_MAGNETIC_FIELD = 0xC020
XDI_STATUS_WORD = 0xE020
XDI_DEVICE_ID = 0xE080
XDI_TYPE_MASK = 0xFFF0
#: Output frequency meaning "with every packet" (counters, sample time).
FREQ_EVERY_PACKET = 0xFFFF

PRECISIONS = {"float32": 0, "fp1220": 1, "fp1632": 2, "float64": 3}
COORDS = {"enu": 0x0, "ned": 0x4, "nwu": 0x8}
ORIENTATIONS = {"quat": XDI_QUATERNION, "matrix": XDI_ROTATION_MATRIX, "euler": XDI_EULER_ANGLES}
_VALUE_SIZE = {0: 4, 1: 4, 2: 6, 3: 8}

# Coordinates of each device global frame expressed in the livecap world (columns = device axes).
_ENU_TO_WORLD = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=np.float64)
_DEVICE_TO_ENU = {
    0x0: np.eye(3),
    0x4: np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]], dtype=np.float64),  # NED -> ENU
    0x8: np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=np.float64),  # NWU -> ENU
}
#: coordinate bits -> quaternion taking device-global coordinates to livecap world coordinates.
FRAME_TO_WORLD: dict[int, tuple[float, float, float, float]] = {
    c: tuple(float(v) for v in matrix_to_quat(_ENU_TO_WORLD @ m)) for c, m in _DEVICE_TO_ENU.items()
}


# ----------------------------------------------------------------------------- messages


def checksum(body: bytes | bytearray) -> int:
    """The CS byte for ``body`` = BID .. last data byte (so that the full sum is 0 mod 256)."""
    return (-sum(body)) & 0xFF


def encode_message(bid: int, mid: int, data: bytes = b"") -> bytes:
    """One complete Xbus message (preamble .. checksum); extended length above 254 bytes."""
    n = len(data)
    if n > MAX_DATA_LEN:
        raise ValueError(f"Xbus payload of {n} bytes exceeds {MAX_DATA_LEN}")
    if n < 0xFF:
        body = bytes((bid & 0xFF, mid & 0xFF, n)) + bytes(data)
    else:
        body = bytes((bid & 0xFF, mid & 0xFF, 0xFF, n >> 8, n & 0xFF)) + bytes(data)
    return b"\xfa" + body + bytes((checksum(body),))


@dataclass(frozen=True, slots=True)
class XbusMessage:
    """A checksum-valid non-data message (acks, errors, device id, commands)."""

    bid: int
    mid: int
    data: bytes


@dataclass(slots=True)
class XbusSample:
    """One decoded MTData2 record.

    quat: (4,) float64 (w, x, y, z) sensor-to-world in the livecap world (see module doc), from
    whatever orientation representation was sent; acc (3,) m/s^2, gyro (3,) rad/s, mag (3,)
    a.u., all in the sensor frame. Fields the device did not send are None.
    """

    bid: int
    device_id: int | None = None
    counter: int | None = None
    sample_time_fine: int | None = None
    quat: np.ndarray | None = None
    acc: np.ndarray | None = None
    gyro: np.ndarray | None = None
    mag: np.ndarray | None = None
    status: int | None = None

    @property
    def sensor(self) -> int:
        """The tracker id: the DeviceId item when sent (Awinda style), else the bus id."""
        return self.device_id if self.device_id is not None else self.bid


# ----------------------------------------------------------------------------- value codecs

_SCALE_1220 = 1.0 / (1 << 20)
_SCALE_1632 = 1.0 / (1 << 32)


def _value_reader(n: int, prec: int):
    """A function (buf, offset) -> tuple of n floats for one precision."""
    if prec == 0:
        return struct.Struct(f">{n}f").unpack_from
    if prec == 3:
        return struct.Struct(f">{n}d").unpack_from
    if prec == 1:
        unpack = struct.Struct(f">{n}i").unpack_from
        return lambda buf, off: tuple(v * _SCALE_1220 for v in unpack(buf, off))
    unpack = struct.Struct(">" + "Ih" * n).unpack_from  # 16.32: fraction u32, then integer i16

    def read_1632(buf, off):
        raw = unpack(buf, off)
        return tuple((raw[i + 1] * 4294967296 + raw[i]) * _SCALE_1632 for i in range(0, 2 * n, 2))

    return read_1632


def _pack_values(values: Iterable[float], prec: int) -> bytes:
    vals = [float(v) for v in values]
    n = len(vals)
    if prec == 0:
        return struct.pack(f">{n}f", *vals)
    if prec == 3:
        return struct.pack(f">{n}d", *vals)
    if prec == 1:
        ints = [round(v * (1 << 20)) for v in vals]
        if any(not -(1 << 31) <= i < (1 << 31) for i in ints):
            raise ValueError("value out of range for fixed point 12.20")
        return struct.pack(f">{n}i", *ints)
    out = bytearray()
    for v in vals:
        raw = round(v * (1 << 32))
        if not -(1 << 47) <= raw < (1 << 47):
            raise ValueError("value out of range for fixed point 16.32")
        out += struct.pack(">Ih", raw & 0xFFFFFFFF, raw >> 32)
    return bytes(out)


def _build_handlers() -> dict[int, tuple[str, int, Any]]:
    """Full XDI (with precision/coordinate bits) -> (field, payload size, reader)."""
    table: dict[int, tuple[str, int, Any]] = {
        XDI_PACKET_COUNTER: ("counter", 2, struct.Struct(">H").unpack_from),
        XDI_SAMPLE_TIME_FINE: ("sample_time_fine", 4, struct.Struct(">I").unpack_from),
        XDI_STATUS_WORD: ("status", 4, struct.Struct(">I").unpack_from),
        XDI_DEVICE_ID: ("device_id", 4, struct.Struct(">I").unpack_from),
    }
    for prec, size in _VALUE_SIZE.items():
        for coord in COORDS.values():
            table[XDI_QUATERNION | coord | prec] = ("quat", 4 * size, _value_reader(4, prec))
            table[XDI_ROTATION_MATRIX | coord | prec] = ("matrix", 9 * size, _value_reader(9, prec))
            table[XDI_EULER_ANGLES | coord | prec] = ("euler", 3 * size, _value_reader(3, prec))
        # The coordinate bits do not apply to sensor-frame vectors; accept them anyway.
        for coord in COORDS.values():
            for xdi, name in ((XDI_ACCELERATION, "acc"), (XDI_RATE_OF_TURN, "gyro"),
                              (XDI_MAGNETIC_FIELD, "mag")):
                table[xdi | coord | prec] = (name, 3 * size, _value_reader(3, prec))
    return table


_HANDLERS = _build_handlers()
_VECTOR_FIELDS = frozenset(("acc", "gyro", "mag"))
_FLOAT_FIELDS = _VECTOR_FIELDS | {"quat", "matrix", "euler"}
_ITEM_HEADER = struct.Struct(">HB")


def _matrix_to_quat(v: tuple) -> tuple[float, float, float, float]:
    """Column-major 3x3 rotation (9 floats) -> quaternion."""
    return v3.quat_from_matrix((v[0::3], v[1::3], v[2::3]))


def _euler_to_quat(v: tuple) -> tuple[float, float, float, float]:
    """(roll, pitch, yaw) degrees, R = Rz(yaw) Ry(pitch) Rx(roll) -> quaternion."""
    h = math.pi / 360.0  # degrees -> half-angle radians
    cr, sr = math.cos(v[0] * h), math.sin(v[0] * h)
    cp, sp = math.cos(v[1] * h), math.sin(v[1] * h)
    cy, sy = math.cos(v[2] * h), math.sin(v[2] * h)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


_TO_QUAT = {"quat": lambda v: v, "matrix": _matrix_to_quat, "euler": _euler_to_quat}


def _check_matrix(v: tuple, limits: PlausibilityLimits) -> None:
    """Column-major 3x3 (9 floats): columns of unit length and mutually orthogonal."""
    a0, a1, a2, b0, b1, b2, c0, c1, c2 = v
    worst = max(abs(a0 * a0 + a1 * a1 + a2 * a2 - 1.0), abs(b0 * b0 + b1 * b1 + b2 * b2 - 1.0),
                abs(c0 * c0 + c1 * c1 + c2 * c2 - 1.0), abs(a0 * b0 + a1 * b1 + a2 * b2),
                abs(a0 * c0 + a1 * c1 + a2 * c2), abs(b0 * c0 + b1 * c1 + b2 * c2))
    if not worst <= 2.0 * limits.norm_tolerance:  # also true for NaN
        raise ImplausibleSample("implausible_norm", f"rotation matrix is {worst:.3g} off orthonormal")


def _orientation_to_world(kind: str, values: tuple, coord: int) -> tuple:
    """Device orientation values -> world quaternion tuple (w, x, y, z)."""
    try:
        return v3.quat_mul(FRAME_TO_WORLD[coord], _TO_QUAT[kind](values))
    except (ValueError, ArithmeticError):  # garbage posing as a matrix (sqrt < 0, s == 0)
        raise FormatError(f"MTData2 {kind} is not a rotation") from None


def decode_mtdata2(payload: bytes, bid: int = BID_MASTER, counters: dict[str, int] | None = None,
                   *, limits: PlausibilityLimits | None = None) -> XbusSample:
    """Decode one MTData2 payload into an XbusSample.

    Unknown XDIs are skipped by their size (counted in ``counters['unknown_xdi']``). Raises
    FormatError on a truncated item, a known XDI with the wrong size, or an orientation that is
    no rotation (norm off by more than 0.1). With ``limits``, also ImplausibleSample (a
    FormatError) for a NaN / infinite value or an orientation off unit length by more than
    ``limits.norm_tolerance`` (drivers/plausibility.py).
    """
    sample = XbusSample(bid=bid)
    n = len(payload)
    i = 0
    orient = None
    while i < n:
        if i + 3 > n:
            raise FormatError("truncated MTData2 item header")
        xdi, size = _ITEM_HEADER.unpack_from(payload, i)
        i += 3
        end = i + size
        if end > n:
            raise FormatError(f"MTData2 item 0x{xdi:04X} overruns the payload")
        handler = _HANDLERS.get(xdi)
        if handler is None:
            if counters is not None:
                counters["unknown_xdi"] = counters.get("unknown_xdi", 0) + 1
        else:
            field, expected, read = handler
            if size != expected:
                raise FormatError(f"MTData2 item 0x{xdi:04X} has {size} bytes, expected {expected}")
            values = read(payload, i)
            if field in _FLOAT_FIELDS:
                if limits is not None and not all_finite(values):
                    raise ImplausibleSample("non_finite", f"MTData2 item 0x{xdi:04X} is not finite")
                if field in _VECTOR_FIELDS:
                    setattr(sample, field, np.array(values, dtype=np.float64))
                else:
                    orient = (field, values, xdi & 0x000C)
            else:
                setattr(sample, field, values[0])
        i = end
    if orient is not None:
        if limits is not None and orient[0] == "matrix":
            _check_matrix(orient[1], limits)
        q = _orientation_to_world(*orient)
        norm = v3.quat_norm(q)
        if limits is not None:
            check_norm(norm, limits)
        elif not 0.9 < norm < 1.1:  # also rejects NaN: random bytes posing as a frame
            raise FormatError(f"MTData2 orientation is not a rotation (norm {norm:.3g})")
        sample.quat = np.array((q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm))
    return sample


def encode_mtdata2(
    *,
    quat: Iterable[float] | None = None,
    counter: int | None = None,
    sample_time_fine: int | None = None,
    acc: Iterable[float] | None = None,
    gyro: Iterable[float] | None = None,
    mag: Iterable[float] | None = None,
    status: int | None = None,
    device_id: int | None = None,
    orientation: str = "quat",
    precision: str = "float32",
    coord: str = "enu",
) -> bytes:
    """MTData2 payload (the DATA of a MID 0x36 message), symmetric with ``decode_mtdata2``.

    quat: (w, x, y, z) sensor-to-world in the livecap world; it is converted to the device frame
    ``coord`` and sent as ``orientation`` ("quat" | "matrix" | "euler") in ``precision``.
    """
    prec = PRECISIONS[precision]
    cbits = COORDS[coord]
    out = bytearray()

    def item(xdi: int, data: bytes) -> None:
        out.extend(_ITEM_HEADER.pack(xdi, len(data)))
        out.extend(data)

    if counter is not None:
        item(XDI_PACKET_COUNTER, struct.pack(">H", counter & 0xFFFF))
    if sample_time_fine is not None:
        item(XDI_SAMPLE_TIME_FINE, struct.pack(">I", sample_time_fine & 0xFFFFFFFF))
    if quat is not None:
        qw = tuple(float(v) for v in quat)
        qd = v3.quat_mul(v3.quat_conj(FRAME_TO_WORLD[cbits]), qw)
        if orientation == "quat":
            values: Iterable[float] = qd
        elif orientation == "matrix":
            values = quat_to_matrix(np.array(qd)).T.reshape(9)
        elif orientation == "euler":
            yaw, pitch, roll = matrix_to_euler(quat_to_matrix(np.array(qd)), "ZYX")
            values = np.degrees([roll, pitch, yaw])
        else:
            raise ValueError(f"unknown orientation {orientation!r}; expected {list(ORIENTATIONS)}")
        item(ORIENTATIONS[orientation] | cbits | prec, _pack_values(values, prec))
    for xdi, vec in ((XDI_ACCELERATION, acc), (XDI_RATE_OF_TURN, gyro), (XDI_MAGNETIC_FIELD, mag)):
        if vec is not None:
            item(xdi | prec, _pack_values(vec, prec))
    if status is not None:
        item(XDI_STATUS_WORD, struct.pack(">I", status & 0xFFFFFFFF))
    if device_id is not None:
        item(XDI_DEVICE_ID, struct.pack(">I", device_id & 0xFFFFFFFF))
    return bytes(out)


def output_configuration(items: Iterable[tuple[int, int]]) -> bytes:
    """SetOutputConfiguration payload from (full XDI, frequency Hz or 0xFFFF) pairs."""
    return b"".join(struct.pack(">HH", xdi, freq) for xdi, freq in items)


def parse_output_configuration(data: bytes) -> list[tuple[int, int]]:
    """Inverse of ``output_configuration``; raises FormatError on a ragged payload."""
    if len(data) % 4:
        raise FormatError("output configuration payload is not a list of (XDI, frequency)")
    return [struct.unpack_from(">HH", data, i) for i in range(0, len(data), 4)]
