"""Xsens MVN exports (.mvnx): the XML MVN Analyze / Animate writes.

Structure (namespace ``http://www.xsens.com/mvn/mvnx``, MVN User Manual, "MVNX"):
``<mvnx><subject frameRate=.. segmentCount=..>`` holding ``<segments><segment label=.. id=..>``
(the body model's segments, in order), ``<sensors><sensor label=..>`` (the segments wearing a
sensor, in order) and ``<frames>``: first frames of type ``identity``, ``tpose`` and
``tpose-isb`` (the body model's reference poses), then one ``type="normal"`` frame per sample
with ``time`` (ms) and space-separated numbers: ``orientation`` (4 per segment: w x y z,
segment to the global frame), ``sensorOrientation`` (4 per sensor, sensor to the global frame),
among others. The global frame is z up, x forward (the subject's facing at calibration, or
north), y left: NWU axes.

``read_mvnx(path, stream="segments"|"sensors")`` -> live.io.imu_import.SuitRecording, one track
per segment (MVN's solved segment orientations) or per sensor (the raw sensor orientations),
labelled as the file labels them, with the calibration the file holds: the ``tpose`` frame says
how every segment sits in the T-pose, and a normal frame how each sensor sits on its segment,
so the recording needs no calibration pose of its own.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.heading import direction_yaw, yaw_quat
from live.core.rotations import quat_conjugate, quat_multiply, quat_normalize, quat_rotate
from live.io.imu_import import MAX_SAMPLES, SuitRecording, SuitTrack, to_livecap, world_quat

STREAMS = ("segments", "sensors")


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _numbers(elem: ET.Element | None, count: int, what: str, path: str, frame: int) -> np.ndarray:
    if elem is None or elem.text is None:
        raise FormatError(f"frame {frame}: no <{what}>", path=path)
    try:
        values = np.array(elem.text.split(), dtype=np.float64)
    except ValueError:
        raise FormatError(f"frame {frame}: <{what}> holds something that is not a number", path=path) from None
    if values.size != count:
        raise FormatError(f"frame {frame}: <{what}> has {values.size} numbers, expected {count}", path=path)
    return values


def _check_no_entities(path: Path) -> None:
    """An MVNX file never declares entities; one that does is refused before parsing (entity
    expansion could make a small file huge in memory)."""
    with open(path, "rb") as f:
        head = f.read(65536)
    if b"<!ENTITY" in head or b"<!DOCTYPE" in head:
        raise FormatError("not an MVNX file (it declares a DOCTYPE or entities)", path=str(path))


def read_mvnx(path: str | Path, stream: str = "segments") -> SuitRecording:
    p = Path(path)
    if stream not in STREAMS:
        raise FormatError(f"unknown MVNX stream {stream!r}; expected one of {STREAMS}", path=str(p))
    if not p.is_file():
        raise FormatError("no such file", path=str(p))
    _check_no_entities(p)
    segments: list[str] = []
    sensors: list[str] = []
    rate = None
    tpose: np.ndarray | None = None
    times: list[float] = []
    seg_q: list[np.ndarray] = []
    sen_q: list[np.ndarray] = []
    src = str(p)
    try:
        for _, elem in ET.iterparse(p, events=("end",)):
            tag = _local(elem.tag)
            if tag == "segment" and elem.get("label"):
                segments.append(elem.get("label", ""))
            elif tag == "sensor" and elem.get("label"):
                sensors.append(elem.get("label", ""))
            elif tag == "subject":
                rate = elem.get("frameRate")
            elif tag == "frame":
                kind = elem.get("type", "normal")
                n = len(times)
                fields = {_local(c.tag): c for c in elem}
                if kind == "tpose":
                    tpose = _numbers(fields.get("orientation"), 4 * len(segments), "orientation", src, -1).reshape(-1, 4)
                elif kind == "normal":
                    if n >= MAX_SAMPLES:
                        raise FormatError(f"more than {MAX_SAMPLES} frames", path=src)
                    try:
                        times.append(float(elem.get("time", "nan")) / 1000.0)
                    except ValueError:
                        raise FormatError(f"frame {n}: time {elem.get('time')!r} is not a number", path=src) from None
                    seg_q.append(_numbers(fields.get("orientation"), 4 * len(segments), "orientation", src, n))
                    if stream == "sensors":
                        sen_q.append(_numbers(fields.get("sensorOrientation"), 4 * len(sensors), "sensorOrientation",
                                              src, n))
                elem.clear()
    except ET.ParseError as e:
        raise FormatError(f"not valid XML ({e})", path=src) from None
    if not segments or not times:
        raise FormatError("not an MVNX file: no segments or no normal frames", path=src)
    if tpose is None:
        raise FormatError("no tpose frame (the T-pose every MVNX export starts with)", path=src)
    t = np.array(times)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        fps = _rate(rate)
        if fps is None:
            raise FormatError("frame times do not increase and the subject has no frameRate", path=src)
        t = np.arange(len(times)) / fps
    seg = np.stack(seg_q).reshape(len(t), len(segments), 4)
    if stream == "sensors" and sensors and sen_q:
        tracks, calibration = _sensor_tracks(seg, np.stack(sen_q).reshape(len(t), len(sensors), 4), segments,
                                             sensors, tpose, t, src)
    elif stream == "sensors":
        raise FormatError("the file has no sensors (<sensors> and sensorOrientation)", path=src)
    else:
        tracks, calibration = _segment_tracks(seg, segments, tpose, t, src)
    return SuitRecording(format="mvnx", source=src, tracks=tracks, calibration=calibration, pose="tpose",
                         meta={"stream": stream, "segments": segments, "sensors": sensors}, rate_hz=_rate(rate))


def _rate(text: str | None) -> float | None:
    """The subject's frameRate attribute as a rate in (0, 10000] Hz, else None."""
    try:
        value = float(text) if text is not None else float("nan")
    except ValueError:
        return None
    return value if 0.0 < value <= 10000.0 else None


def _facing(tpose: np.ndarray, segments: list[str]) -> np.ndarray:
    """(4,) yaw of the subject's facing in the T-pose frame, in the livecap world: the pelvis
    segment's x axis (MVN: forward)."""
    k = next((i for i, s in enumerate(segments) if s.lower() == "pelvis"), 0)
    forward = quat_rotate(to_livecap(tpose[k], "NWU"), np.array([1.0, 0.0, 0.0]))
    return yaw_quat(direction_yaw(forward))


def _calibration(labels: list[str], ids: list[int], q_tpose: np.ndarray, facing: np.ndarray) -> dict:
    """The calibration JSON (live.imu.calibration) of virtual or real sensors whose orientation
    in the T-pose is q_tpose (S, 4) (sensor to the livecap world): G = heading q offset with
    heading = facing^-1, offset = q_tpose^-1 facing (the T-pose is the identity)."""
    offset = quat_normalize(quat_multiply(quat_conjugate(q_tpose), facing))
    S = len(labels)
    return {"pose": "tpose", "sensors": ids, "labels": labels,
            "heading": np.broadcast_to(quat_conjugate(facing), (S, 4)).tolist(), "offset": offset.tolist(),
            "spread_deg": [0.0] * S}


def _segment_tracks(seg: np.ndarray, segments: list[str], tpose: np.ndarray, t: np.ndarray, src: str):
    facing = _facing(tpose, segments)
    q = to_livecap(seg, "NWU")
    tracks = []
    for k, label in enumerate(segments):
        try:
            tracks.append(SuitTrack(label=label, sensor=k + 1, t_s=t, quats=q[:, k]))
        except FormatError as e:
            raise FormatError(str(e), path=src) from None
    return tracks, _calibration(segments, list(range(1, len(segments) + 1)), to_livecap(tpose, "NWU"), facing)


def _sensor_tracks(seg: np.ndarray, sen: np.ndarray, segments: list[str], sensors: list[str], tpose: np.ndarray,
                   t: np.ndarray, src: str):
    facing = _facing(tpose, segments)
    index = {s.lower(): i for i, s in enumerate(segments)}
    q = to_livecap(sen, "NWU")
    tracks, q_tpose = [], []
    for k, label in enumerate(sensors):
        j = index.get(label.lower())
        if j is None:
            raise FormatError(f"sensor {label!r} is on no segment of the file", path=src)
        try:
            tracks.append(SuitTrack(label=label, sensor=k + 1, t_s=t, quats=q[:, k]))
        except FormatError as e:
            raise FormatError(str(e), path=src) from None
        # How the sensor sits on its segment, as MVN solved it (its first frame), carried to the
        # T-pose: the sensor's orientation had the segment been in the T-pose.
        mount = quat_multiply(quat_conjugate(seg[0, j]), sen[0, k])
        q_tpose.append(quat_multiply(quat_multiply(world_quat("NWU"), tpose[j]), mount))
    return tracks, _calibration(sensors, list(range(1, len(sensors) + 1)), quat_normalize(np.stack(q_tpose)), facing)


__all__ = ["read_mvnx", "STREAMS"]
