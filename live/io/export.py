"""``livecap export``: a session -> one .npz per stream (file contracts in CONVENTIONS.md)."""

from __future__ import annotations

import io
from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.io.session import SessionReader

if TYPE_CHECKING:  # annotations only: the drivers load when a serial stream needs decoding
    from drivers.text_lines import LineParser
    from drivers.xbus import XbusParser


def _stack(values: list, dtype, shape: tuple[int, ...]) -> np.ndarray:
    return np.asarray(values, dtype=dtype).reshape((len(values),) + shape)


def export_session(path: str | Path, out_dir: str | Path) -> tuple[list[Path], str | None]:
    """Write DIR/gt.npz, DIR/depth_<s>.npz, DIR/serial_<d>.npz, DIR/imu_<d>.npz.

    Returns the files written and the reader's damage message (None for an intact session).
    Serial streams with a known protocol are also decoded into imu_<d>.npz by the real parser.
    """
    reader = SessionReader(path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    depth: dict[str, dict] = defaultdict(lambda: {"t": [], "pts": [], "K": None, "c2w": None})
    serial: dict[str, dict] = defaultdict(lambda: {"t": [], "data": []})
    imu: dict[str, dict] = defaultdict(lambda: defaultdict(list))
    gt: dict[str, list] = {"t": [], "joints": [], "rotations": [], "root": []}
    decoders: dict[str, XbusParser | LineParser] = {}
    streams: dict[str, StreamInfo] = {}
    for stream, frame in reader.frames():
        streams[stream.name] = stream
        if isinstance(frame, DepthFrame):
            d = depth[stream.name]
            d["t"].append(frame.t_ns)
            d["pts"].append(frame.cloud())
            d["K"] = frame.intrinsics if frame.intrinsics is not None else d["K"]
            d["c2w"] = frame.camera_to_world
        elif isinstance(frame, MocapPacket) and stream.kind == "serial":
            serial[stream.name]["t"].append(frame.t_ns)
            serial[stream.name]["data"].append(frame.raw)
            protocol = stream.meta.get("protocol")
            if protocol:
                from drivers.serial_source import make_parser, packet_from_records

                if stream.name not in decoders:
                    decoders[stream.name] = make_parser(protocol)
                records = decoders[stream.name].feed(frame.raw)
                _append_imu(imu[stream.name], packet_from_records(frame.t_ns, stream.name, frame.raw, records))
        elif isinstance(frame, MocapPacket):
            _append_imu(imu[stream.name], frame)
        elif isinstance(frame, GroundTruth):
            gt["t"].append(frame.t_ns)
            gt["joints"].append(frame.joints)
            gt["rotations"].append(frame.rotations)
            gt["root"].append(frame.root)
    written: list[Path] = []
    for name, d in depth.items():
        counts = [len(p) for p in d["pts"]]
        offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        offsets[1:] = np.cumsum(counts)
        pts = np.concatenate(d["pts"]).astype(np.float32) if counts else np.zeros((0, 3), np.float32)
        k = d["K"] if d["K"] is not None else np.asarray(streams[name].meta.get("intrinsics", np.zeros((3, 3))))
        p = out / f"depth_{name}.npz"
        np.savez_compressed(p, t_ns=np.asarray(d["t"], np.int64), points=pts, offsets=offsets,
                            intrinsics=np.asarray(k, np.float64), camera_to_world=np.asarray(d["c2w"], np.float64))
        written.append(p)
    for name, s in serial.items():
        lens = [len(b) for b in s["data"]]
        offsets = np.zeros(len(lens) + 1, dtype=np.int64)
        offsets[1:] = np.cumsum(lens)
        data = np.frombuffer(b"".join(s["data"]), dtype=np.uint8)
        p = out / f"serial_{name}.npz"
        np.savez_compressed(p, t_ns=np.asarray(s["t"], np.int64), data=data, offsets=offsets)
        written.append(p)
    for name, rec in imu.items():
        if not rec["t_ns"]:
            continue
        arrays: dict[str, np.ndarray] = {
            "t_ns": np.asarray(rec["t_ns"], np.int64), "sensor": np.asarray(rec["sensor"], np.int64),
            "quat": np.asarray(rec["quat"], np.float64).reshape(-1, 4)}
        for key in ("counter", "acc", "gyro", "mag"):
            if rec[key] and len(rec[key]) == len(rec["t_ns"]):
                arrays[key] = np.asarray(rec[key], np.int64 if key == "counter" else np.float64)
        p = out / f"imu_{name}.npz"
        np.savez_compressed(p, allow_pickle=False, **arrays)
        written.append(p)
    if gt["t"]:
        arrays = {"t_ns": np.asarray(gt["t"], np.int64), "joints": np.asarray(gt["joints"], np.float32),
                  "rotations": np.asarray(gt["rotations"], np.float32), "root": np.asarray(gt["root"], np.float32)}
        body = reader.body_npz()
        if body is not None:
            with np.load(io.BytesIO(body), allow_pickle=False) as z:
                for key in ("vertices", "faces", "rest_joints", "weights"):
                    if key in z.files:
                        arrays[f"body_{key}"] = z[key]
        p = out / "gt.npz"
        np.savez_compressed(p, allow_pickle=False, **arrays)
        written.append(p)
    return written, reader.error


def _append_imu(rec: dict, packet) -> None:
    if packet.sensors is None or packet.quats is None:
        return
    n = len(packet.sensors)
    rec["t_ns"].extend([packet.t_ns] * n)
    rec["sensor"].extend(np.asarray(packet.sensors).tolist())
    rec["quat"].extend(np.asarray(packet.quats, np.float64).reshape(n, 4).tolist())
    for key in ("counter", "acc", "gyro", "mag"):
        value = getattr(packet, key)
        if value is not None:
            arr = np.asarray(value)
            rec[key].extend(arr.reshape(n, -1).tolist() if arr.ndim > 1 else arr.tolist())
