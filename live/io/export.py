"""``livecap export``: a session -> one .npz per stream (file contracts in docs/conventions.md).

Streams are exported as they are read: each array's rows go to a spool file in a temporary
folder inside the output folder (live.io.npz_stream) and each .npz is assembled from its spools
at the end, so memory holds one frame at a time whatever the session's length.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from live.core.errors import UserInputError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.core.text import safe_filename
from live.io.npz_stream import ColumnSpool, load_npz_checked, write_npz
from live.io.session import BODY_ATTACHMENT, SessionReader

if TYPE_CHECKING:  # annotations only: the drivers load when a serial stream needs decoding
    from drivers.text_lines import LineParser
    from drivers.xbus_stream import XbusParser

BODY_ARRAYS = ("vertices", "faces", "rest_joints", "weights")
#: Streams one export writes (each holds a few spool files open); a session naming more is hostile.
MAX_STREAMS = 256
_IMU_OPTIONAL = {"counter": (np.int64, ()), "acc": (np.float64, (3,)), "gyro": (np.float64, (3,)),
                 "mag": (np.float64, (3,))}


def _file_name(prefix: str, name: str) -> str:
    # Stream names come from the file: never a path (live.core.text.safe_filename).
    return f"{prefix}_{safe_filename(name)}.npz"


class _DepthExport:
    def __init__(self, spool: Path, stream: StreamInfo):
        self.stream = stream
        self.t_ns = ColumnSpool(spool, "t_ns", np.int64)
        self.points = ColumnSpool(spool, "points", np.float32, (3,))
        self.offsets = ColumnSpool(spool, "offsets", np.int64)
        self.offsets.append(np.zeros(1, np.int64))
        self.total = 0
        self.intrinsics: np.ndarray | None = None
        self.camera_to_world: np.ndarray | None = None

    def add(self, frame: DepthFrame) -> None:
        cloud = frame.cloud()
        self.t_ns.append(np.array([frame.t_ns], np.int64))
        self.points.append(cloud)
        self.total += len(cloud)
        self.offsets.append(np.array([self.total], np.int64))
        if frame.intrinsics is not None:
            self.intrinsics = frame.intrinsics
        self.camera_to_world = frame.camera_to_world

    def write(self, out: Path) -> Path:
        k = self.intrinsics if self.intrinsics is not None else self.stream.meta.get("intrinsics", np.zeros((3, 3)))
        return write_npz(out / _file_name("depth", self.stream.name), [
            ("t_ns", self.t_ns), ("points", self.points), ("offsets", self.offsets),
            ("intrinsics", np.asarray(k, np.float64)), ("camera_to_world", np.asarray(self.camera_to_world, np.float64))])


class _SerialExport:
    def __init__(self, spool: Path, stream: StreamInfo):
        self.stream = stream
        self.t_ns = ColumnSpool(spool, "t_ns", np.int64)
        self.data = ColumnSpool(spool, "data", np.uint8)
        self.offsets = ColumnSpool(spool, "offsets", np.int64)
        self.offsets.append(np.zeros(1, np.int64))
        self.total = 0

    def add(self, packet: MocapPacket) -> None:
        self.t_ns.append(np.array([packet.t_ns], np.int64))
        self.data.append(packet.raw)
        self.total += len(packet.raw)
        self.offsets.append(np.array([self.total], np.int64))

    def write(self, out: Path) -> Path:
        return write_npz(out / _file_name("serial", self.stream.name),
                         [("t_ns", self.t_ns), ("data", self.data), ("offsets", self.offsets)])


class _ImuExport:
    """Decoded samples; an optional field is kept when every packet with samples had it."""

    def __init__(self, spool: Path, stream: StreamInfo):
        self.stream = stream
        self.t_ns = ColumnSpool(spool, "t_ns", np.int64)
        self.sensor = ColumnSpool(spool, "sensor", np.int64)
        self.quat = ColumnSpool(spool, "quat", np.float64, (4,))
        self.optional = {k: ColumnSpool(spool, k, dtype, shape) for k, (dtype, shape) in _IMU_OPTIONAL.items()}
        self.everywhere = dict.fromkeys(_IMU_OPTIONAL, True)

    def add(self, packet: MocapPacket) -> None:
        if packet.sensors is None or packet.quats is None:
            return
        n = len(packet.sensors)
        self.t_ns.append(np.full(n, packet.t_ns, np.int64))
        self.sensor.append(np.asarray(packet.sensors).reshape(n))
        self.quat.append(np.asarray(packet.quats, np.float64).reshape(n, 4))
        for key, spool in self.optional.items():
            value = getattr(packet, key)
            if value is None:
                self.everywhere[key] &= n == 0
            elif self.everywhere[key]:
                spool.append(np.asarray(value).reshape((n, *spool.row_shape)))

    def write(self, out: Path) -> Path | None:
        if not self.t_ns.rows:
            return None
        arrays: list[tuple[str, np.ndarray | ColumnSpool]] = [
            ("t_ns", self.t_ns), ("sensor", self.sensor), ("quat", self.quat)]
        arrays += [(k, s) for k, s in self.optional.items() if self.everywhere[k] and s.rows == self.t_ns.rows]
        return write_npz(out / _file_name("imu", self.stream.name), arrays)


class _TruthExport:
    def __init__(self, spool: Path):
        self.t_ns = ColumnSpool(spool, "t_ns", np.int64)
        self.joints = ColumnSpool(spool, "joints", np.float32, (22, 3))
        self.rotations = ColumnSpool(spool, "rotations", np.float32, (22, 4))
        self.root = ColumnSpool(spool, "root", np.float32, (3,))

    def add(self, gt: GroundTruth) -> None:
        self.t_ns.append(np.array([gt.t_ns], np.int64))
        self.joints.append(gt.joints)
        self.rotations.append(gt.rotations)
        self.root.append(gt.root)

    def write(self, out: Path, body: dict[str, np.ndarray]) -> Path:
        arrays: list[tuple[str, np.ndarray | ColumnSpool]] = [
            ("t_ns", self.t_ns), ("joints", self.joints), ("rotations", self.rotations), ("root", self.root)]
        arrays += [(f"body_{k}", body[k]) for k in BODY_ARRAYS if k in body]
        return write_npz(out / "gt.npz", arrays)


def export_session(path: str | Path, out_dir: str | Path) -> tuple[list[Path], str | None]:
    """Write DIR/gt.npz, DIR/depth_<s>.npz, DIR/serial_<d>.npz, DIR/imu_<d>.npz.

    Returns the files written and one line about what was skipped (None for an intact session):
    the reader's damage summary, and a body attachment that could not be read.
    Serial streams with a known protocol are also decoded into imu_<d>.npz by the real parser.
    """
    reader = SessionReader(path)
    out = Path(out_dir)
    if reader.path.suffix == ".npz" and reader.path.resolve().parent == out.resolve():
        raise UserInputError(f"the export into {out} could overwrite its own session {reader.path.name}")
    out.mkdir(parents=True, exist_ok=True)
    spool = Path(tempfile.mkdtemp(prefix=".livecap-export-", dir=out))
    try:
        depth: dict[str, _DepthExport] = {}
        serial: dict[str, _SerialExport] = {}
        imu: dict[str, _ImuExport] = {}
        truth: _TruthExport | None = None
        decoders: dict[str, XbusParser | LineParser] = {}
        exported: set[str] = set()
        ignored: set[str] = set()
        for stream, frame in reader.frames():
            if stream.name not in exported:
                if len(exported) >= MAX_STREAMS:
                    ignored.add(stream.name)
                    continue
                exported.add(stream.name)
            if isinstance(frame, DepthFrame):
                if stream.name not in depth:
                    depth[stream.name] = _DepthExport(spool, stream)
                depth[stream.name].add(frame)
            elif isinstance(frame, MocapPacket) and stream.kind == "serial":
                if stream.name not in serial:
                    serial[stream.name] = _SerialExport(spool, stream)
                serial[stream.name].add(frame)
                protocol = stream.meta.get("protocol")
                if protocol:
                    from drivers.serial_source import make_parser, packet_from_records

                    if stream.name not in decoders:
                        decoders[stream.name] = make_parser(protocol)
                    records = decoders[stream.name].feed(frame.raw)
                    _imu_of(imu, spool, stream).add(packet_from_records(frame.t_ns, stream.name, frame.raw, records))
            elif isinstance(frame, MocapPacket):
                _imu_of(imu, spool, stream).add(frame)
            elif isinstance(frame, GroundTruth):
                truth = truth or _TruthExport(spool)
                truth.add(frame)
        written: list[Path | None] = [e.write(out) for e in depth.values()]
        written += [e.write(out) for e in serial.values()]
        written += [e.write(out) for e in imu.values()]
        problems = [reader.error] if reader.error else []
        if ignored:
            problems.append(f"{len(ignored)} streams beyond the first {MAX_STREAMS} were not exported")
        if truth is not None:
            body: dict[str, np.ndarray] = {}
            data = reader.body_npz()
            if data is not None:
                try:
                    body = load_npz_checked(data, BODY_ARRAYS)
                except ValueError as exc:
                    problems.append(f"the {BODY_ATTACHMENT} attachment is unreadable, gt.npz has no body: {exc}")
            written.append(truth.write(out, body))
        return [p for p in written if p is not None], "; ".join(problems) or None
    finally:
        shutil.rmtree(spool, ignore_errors=True)


def _imu_of(imu: dict[str, _ImuExport], spool: Path, stream: StreamInfo) -> _ImuExport:
    if stream.name not in imu:
        imu[stream.name] = _ImuExport(spool, stream)
    return imu[stream.name]
