"""x-IMU3 recordings (x-io Technologies): the folder the x-IMU3 GUI logs, one subfolder per device.

Each device folder holds ``Quaternion.csv`` (``Timestamp (us),W,X,Y,Z``: sensor to the earth
frame, NWU by default) and usually ``Inertial.csv`` (``Timestamp (us)``, gyroscope X/Y/Z in
deg/s, accelerometer X/Y/Z in g), plus ``Command.json`` whose ping response names the device
(``{"ping": {"name": "Left Foot", "sn": "64F0EBCE"}}``). The segment is that name, else the
folder's (``left_foot_64f0ebce``, ``Left Foot 64F0EBCE (UDP)``: the last hexadecimal word is the
serial number). Devices share the logger's clock (microseconds).

``read_ximu3(path, world="NWU")`` -> live.io.imu_import.SuitRecording.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.io.imu_import import SuitRecording, SuitTrack, read_numeric_csv, to_livecap

G = 9.80665
_QUAT = ["Timestamp (us)", "W", "X", "Y", "Z"]
_INERTIAL = ["Timestamp (us)", "Gyroscope X (deg/s)", "Gyroscope Y (deg/s)", "Gyroscope Z (deg/s)",
             "Accelerometer X (g)", "Accelerometer Y (g)", "Accelerometer Z (g)"]


def device_name(folder: Path, index: int) -> tuple[str, int]:
    """(segment label, sensor id) of a device folder: Command.json's ping name and serial number
    when it has them, else the folder name's words (a trailing hexadecimal word of 6+ digits is
    the serial number), else the folder name and ``index``."""
    name, serial = None, None
    cmd = folder / "Command.json"
    if cmd.is_file():
        try:
            for entry in json.loads(cmd.read_text(encoding="utf-8")):
                ping = entry.get("ping") if isinstance(entry, dict) else None
                if isinstance(ping, dict):
                    name = ping.get("name") if isinstance(ping.get("name"), str) else None
                    sn = ping.get("sn")
                    serial = int(sn, 16) if isinstance(sn, str) and re.fullmatch(r"[0-9A-Fa-f]{1,15}", sn) else None
        except (ValueError, OSError, AttributeError, TypeError):
            pass  # a damaged Command.json: the folder name says as much
    words = [w for w in re.split(r"[\s_\-]+", re.sub(r"\(.*?\)", " ", folder.name)) if w]
    if serial is None and words and re.fullmatch(r"[0-9A-Fa-f]{6,15}", words[-1]):
        serial = int(words[-1], 16)
        words = words[:-1]
    label = name or "_".join(words) or folder.name
    return label.strip().lower().replace(" ", "_"), index if serial is None else serial


def _device_track(folder: Path, index: int, world: str) -> SuitTrack:
    label, sensor = device_name(folder, index)
    q = read_numeric_csv(folder / "Quaternion.csv", _QUAT, header_row=0)
    t = q["Timestamp (us)"] * 1e-6
    quats = np.stack([q[k] for k in ("W", "X", "Y", "Z")], axis=-1)
    acc = gyro = None
    inertial = folder / "Inertial.csv"
    if inertial.is_file():
        i = read_numeric_csv(inertial, _INERTIAL, header_row=0)
        ti = i["Timestamp (us)"] * 1e-6
        if len(ti) >= 2 and np.all(np.diff(ti) > 0):
            # Same device, its own timestamps: each column at the quaternion's times.
            gyro = np.stack([np.interp(t, ti, np.radians(i[f"Gyroscope {a} (deg/s)"])) for a in "XYZ"], -1)
            acc = np.stack([np.interp(t, ti, G * i[f"Accelerometer {a} (g)"]) for a in "XYZ"], -1)
    norms = np.linalg.norm(quats, axis=-1, keepdims=True)
    try:
        return SuitTrack(label=label, sensor=sensor, t_s=t, quats=to_livecap(quats / np.maximum(norms, 1e-12), world)
                         if np.all(norms > 0.5) else quats, acc=acc, gyro=gyro)
    except FormatError as e:
        raise FormatError(str(e), path=str(folder / "Quaternion.csv")) from None


def read_ximu3(path: str | Path, world: str = "NWU") -> SuitRecording:
    """Every device folder under ``path`` (a folder with a Quaternion.csv each) -> SuitRecording."""
    root = Path(path)
    if not root.is_dir():
        raise FormatError("an x-IMU3 recording is a folder of device folders", path=str(root))
    devices = sorted(d for d in root.iterdir() if d.is_dir() and (d / "Quaternion.csv").is_file())
    if not devices:
        raise FormatError("no device folder with a Quaternion.csv", path=str(root))
    tracks = [_device_track(d, k, world) for k, d in enumerate(devices)]
    return SuitRecording(format="ximu3", source=str(root), tracks=tracks,
                         meta={"devices": {t.label: f"{t.sensor:X}" for t in tracks}, "world": world})


__all__ = ["read_ximu3", "device_name"]
