"""Recorded IMU suits in the files other software writes: what the readers hand on.

A reader (``imu_import_ximu3``, ``imu_import_mvnx``, ``imu_import_dot``) turns a recording into a
``SuitRecording``: one ``SuitTrack`` per sensor, its samples on the file's own clock, its
orientations turned into the livecap world (+y up; the file's world axes named in ``WORLDS``),
its segment as the file names it (a folder name, an MVN segment label, a DOT device tag). Which
canonical joint that segment is, the calibration and the session are live.imu.importing's job.

Every reader refuses a file it cannot use with a one-line ``FormatError`` naming the file (and
the line, for text files).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.rotations import matrix_to_quat, quat_multiply, quat_normalize

#: Largest recording a reader takes (samples per sensor): a day at 100 Hz.
MAX_SAMPLES = 10_000_000

#: Earth frames of the formats -> the livecap world (x East, y Up, z South: the simulated suit's).
#: Rows: livecap axes in the file's axes. NWU (x-IMU3 default, MVN's global frame: x north or
#: forward, y west or left, z up) and ENU (Xsens DOT, MTw: x east, y north, z up).
WORLDS = {
    "NWU": np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]),
    "ENU": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
}


def world_quat(world: str) -> np.ndarray:
    """(4,) the rotation taking the file's world axes to the livecap world."""
    return matrix_to_quat(WORLDS[world])


def to_livecap(quats: np.ndarray, world: str) -> np.ndarray:
    """Sensor-to-file-world quaternions (..., 4) (w, x, y, z) -> sensor-to-livecap-world."""
    return quat_normalize(quat_multiply(world_quat(world), np.asarray(quats, np.float64)))


@dataclass(frozen=True)
class SuitTrack:
    """One sensor of a recording: T samples. label: its segment as the file names it; sensor:
    an integer id (a serial number, a MAC address, an index); t_s (T,) seconds on the file's
    clock, increasing; quats (T, 4) sensor-to-livecap-world; acc (T, 3) m/s^2 and gyro (T, 3)
    rad/s in the sensor's axes, or None when the file has none."""

    label: str
    sensor: int
    t_s: np.ndarray
    quats: np.ndarray
    acc: np.ndarray | None = None
    gyro: np.ndarray | None = None

    def __post_init__(self) -> None:
        T = len(self.t_s)
        if T < 2:
            raise FormatError(f"sensor {self.label!r}: fewer than two samples")
        if self.quats.shape != (T, 4) or any(a is not None and a.shape != (T, 3) for a in (self.acc, self.gyro)):
            raise FormatError(f"sensor {self.label!r}: columns of different lengths")
        if not np.all(np.isfinite(self.t_s)) or np.any(np.diff(self.t_s) <= 0):
            raise FormatError(f"sensor {self.label!r}: timestamps do not increase")
        norms = np.linalg.norm(self.quats, axis=-1)
        if not np.all(np.isfinite(norms)) or np.any(np.abs(norms - 1.0) > 0.05):
            raise FormatError(f"sensor {self.label!r}: orientations are not unit quaternions")

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_s)))


@dataclass(frozen=True)
class SuitRecording:
    """A recorded suit: its tracks, the format and file it came from. calibration: a ready
    live.imu.calibration JSON object when the file says how each segment sits (MVNX segments),
    else None; pose: the calibration pose the file names, if any; meta: what else the file says
    (device tags, firmware, start time) for the session's metadata; rate_hz: the sample rate the
    file states, if it does."""

    format: str
    source: str
    tracks: list[SuitTrack]
    calibration: dict | None = None
    pose: str | None = None
    meta: dict = field(default_factory=dict)
    rate_hz: float | None = None

    def __post_init__(self) -> None:
        if not self.tracks:
            raise FormatError("no sensor in the recording", path=self.source)
        ids = [t.sensor for t in self.tracks]
        if len(set(ids)) != len(ids):
            raise FormatError("two sensors with the same id", path=self.source)


def read_numeric_csv(path: Path, columns: list[str], *, header_row: int, delimiter: str = ",",
                     optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The named columns of a CSV file whose header is line ``header_row`` (0-based) -> {name:
    (N,) float64}. Names are matched case-insensitively; ``optional`` ones may be missing.
    FormatError (with the line) on a missing column, a short row or a value that is not a number."""
    try:
        with open(path, encoding="utf-8-sig", errors="strict") as f:
            lines = f.read().splitlines()
    except UnicodeDecodeError:
        raise FormatError("not a text file", path=str(path)) from None
    if len(lines) <= header_row:
        raise FormatError("no header line", path=str(path))
    header = [h.strip().lower() for h in lines[header_row].split(delimiter)]
    index = {}
    for name in columns:
        key = name.lower()
        if key in header:
            index[name] = header.index(key)
        elif name not in optional:
            raise FormatError(f"no column {name!r} (header: {lines[header_row].strip()[:120]!r})",
                              path=str(path), line=header_row + 1)
    rows = [(n, line) for n, line in enumerate(lines[header_row + 1:], header_row + 2) if line.strip()]
    if len(rows) > MAX_SAMPLES:
        raise FormatError(f"more than {MAX_SAMPLES} rows", path=str(path))
    out = {name: np.empty(len(rows)) for name in index}
    width = max(index.values()) + 1 if index else 0
    for r, (n, line) in enumerate(rows):
        cells = line.split(delimiter)
        if len(cells) < width:
            raise FormatError(f"{len(cells)} values, expected {len(header)}", path=str(path), line=n)
        for name, c in index.items():
            try:
                out[name][r] = float(cells[c])
            except ValueError:
                raise FormatError(f"{name} is not a number: {cells[c].strip()[:40]!r}", path=str(path), line=n) from None
    return out


__all__ = ["SuitTrack", "SuitRecording", "WORLDS", "world_quat", "to_livecap", "read_numeric_csv", "MAX_SAMPLES"]
