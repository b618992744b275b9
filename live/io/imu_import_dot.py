"""Xsens DOT (Movella DOT) CSV exports: one file per sensor, as the Xsens DOT app writes them.

A file starts with ``key:,value`` lines (``sep=,``, ``DeviceTag:,<tag>``, ``FirmwareVersion:``,
``SyncStatus:,Synced``, ``OutputRate:,60Hz``, ``StartTime: ,...``, a copyright line), then the
header row and the samples. Columns used: ``PacketCounter``, ``SampleTimeFine`` (microseconds,
a 32-bit counter that wraps), the orientation as ``Quat_W..Quat_Z`` (sensor to the local earth
frame, ENU) or ``Euler_X..Euler_Z`` (roll, pitch, yaw in degrees, applied z-y-x), and when
exported ``Acc_X..Acc_Z`` (m/s^2) and ``Gyr_X..Gyr_Z`` (deg/s). Dropped packets are simply
missing rows.

The segment is the device tag (``Pelvis``, ``LFemur``), else the file name's first word
(``LFemur_20210820_202113_831.csv``, ``bei_D4CA6EF17860_20210830_170505.csv``); the sensor id is
the MAC address in the file name when there is one. Synced sensors share SampleTimeFine; files
that say they are not synced are aligned on their first sample.

``read_dot(paths)`` (files, or a folder of them) -> live.io.imu_import.SuitRecording.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.rotations import quat_from_axis_angle, quat_multiply
from live.io.imu_import import SuitRecording, SuitTrack, read_numeric_csv, to_livecap

_WRAP = 2 ** 32
_QUAT = ["Quat_W", "Quat_X", "Quat_Y", "Quat_Z"]
_EULER = ["Euler_X", "Euler_Y", "Euler_Z"]
_ACC = ["Acc_X", "Acc_Y", "Acc_Z"]
_GYR = ["Gyr_X", "Gyr_Y", "Gyr_Z"]
_MAX_HEADER_LINES = 40


def read_preamble(path: Path) -> tuple[dict[str, str], int]:
    """({key: value} of the ``key:,value`` lines, 0-based index of the header row: the first line
    starting with PacketCounter or SampleTimeFine)."""
    meta: dict[str, str] = {}
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            for n, line in enumerate(f):
                if n >= _MAX_HEADER_LINES:
                    break
                cells = [c.strip() for c in line.rstrip("\r\n").split(",")]
                if cells[0] in ("PacketCounter", "SampleTimeFine"):
                    return meta, n
                if cells[0].endswith(":") and len(cells) > 1:
                    meta[cells[0][:-1].strip()] = cells[1]
    except OSError as e:
        raise FormatError(f"cannot read: {e.strerror}", path=str(path)) from None
    raise FormatError("not an Xsens DOT export: no PacketCounter / SampleTimeFine header row in its first "
                      f"{_MAX_HEADER_LINES} lines", path=str(path))


def euler_to_quat(roll_pitch_yaw_deg: np.ndarray) -> np.ndarray:
    """Xsens Euler angles (N, 3) degrees (x roll, y pitch, z yaw; R = Rz(yaw) Ry(pitch) Rx(roll))
    -> (N, 4) quaternions."""
    a = np.radians(np.asarray(roll_pitch_yaw_deg, np.float64))
    ex, ey, ez = (np.zeros_like(a) for _ in range(3))
    ex[:, 0], ey[:, 1], ez[:, 2] = a[:, 0], a[:, 1], a[:, 2]
    return quat_multiply(quat_multiply(quat_from_axis_angle(ez), quat_from_axis_angle(ey)), quat_from_axis_angle(ex))


def unwrap_time(ticks: np.ndarray) -> np.ndarray:
    """SampleTimeFine (uint32 microseconds, wrapping) -> seconds, increasing across wraps."""
    t = np.asarray(ticks, np.float64)
    steps = np.diff(t)
    steps = np.where(steps < -_WRAP / 2, steps + _WRAP, steps)
    return np.concatenate([[t[0]], t[0] + np.cumsum(steps)]) * 1e-6


def sensor_from_name(path: Path, index: int) -> tuple[str, int]:
    """(first word of the file name, sensor id: the 12-hex-digit MAC address in it, else index)."""
    words = path.stem.split("_")
    mac = next((w for w in words if re.fullmatch(r"[0-9A-Fa-f]{12}", w)), None)
    return words[0], int(mac, 16) if mac else index


def read_dot_file(path: Path, index: int = 0) -> tuple[SuitTrack, dict[str, str]]:
    meta, header = read_preamble(path)
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        names = [c.strip() for c in f.read().splitlines()[header].split(",")]
    has_quat = all(c in names for c in _QUAT)
    if not has_quat and not all(c in names for c in _EULER):
        raise FormatError("no orientation columns (Quat_W..Quat_Z or Euler_X..Euler_Z)", path=str(path),
                          line=header + 1)
    wanted = ["SampleTimeFine"] + (_QUAT if has_quat else _EULER) + _ACC + _GYR
    cols = read_numeric_csv(path, wanted, header_row=header, optional=tuple(_ACC + _GYR))
    if len(cols["SampleTimeFine"]) < 2:
        raise FormatError("fewer than two samples", path=str(path))
    t = unwrap_time(cols["SampleTimeFine"])
    quats = np.stack([cols[c] for c in _QUAT], -1) if has_quat else euler_to_quat(np.stack([cols[c] for c in _EULER], -1))
    norms = np.linalg.norm(quats, axis=-1, keepdims=True)
    acc = np.stack([cols[c] for c in _ACC], -1) if all(c in cols for c in _ACC) else None
    gyro = np.radians(np.stack([cols[c] for c in _GYR], -1)) if all(c in cols for c in _GYR) else None
    label, sensor = sensor_from_name(path, index)
    label = meta.get("DeviceTag") or label
    try:
        track = SuitTrack(label=label, sensor=sensor, t_s=t,
                          quats=to_livecap(quats / np.maximum(norms, 1e-12), "ENU") if np.all(norms > 0.5) else quats,
                          acc=acc, gyro=gyro)
    except FormatError as e:
        raise FormatError(str(e), path=str(path)) from None
    return track, meta


def read_dot(paths: str | Path | list) -> SuitRecording:
    """Xsens DOT CSV files (a list, one file, or a folder: every .csv in it) -> SuitRecording."""
    items = [Path(p) for p in (paths if isinstance(paths, (list, tuple)) else [paths])]
    files: list[Path] = []
    for p in items:
        if p.is_dir():
            files += sorted(f for f in p.iterdir() if f.suffix.lower() == ".csv")
        elif p.is_file():
            files.append(p)
        else:
            raise FormatError("no such file or folder", path=str(p))
    if not files:
        raise FormatError("no .csv file", path=str(items[0]))
    read = [read_dot_file(f, k) for k, f in enumerate(files)]
    synced = all(m.get("SyncStatus", "").lower() == "synced" for _, m in read)
    tracks = []
    for track, _ in read:
        if not synced:  # unrelated clocks: every sensor starts together
            track = SuitTrack(track.label, track.sensor, track.t_s - track.t_s[0], track.quats, track.acc, track.gyro)
        tracks.append(track)
    source = str(items[0]) if len(items) == 1 else str(items[0].parent)
    rates = {m.get("OutputRate", "").strip().lower().removesuffix("hz") for _, m in read}
    stated = rates.pop() if len(rates) == 1 else ""
    rate = float(stated) if re.fullmatch(r"\d{1,4}(\.\d+)?", stated) and float(stated) > 0 else None
    return SuitRecording(format="xsens-dot", source=source, tracks=tracks, rate_hz=rate,
                         meta={"synced": synced, "devices": {t.label: m.get("DeviceTag", "") for t, (_, m) in zip(tracks, read)},
                               "start": read[0][1].get("StartTime", "")})


__all__ = ["read_dot", "read_dot_file", "euler_to_quat", "unwrap_time"]
