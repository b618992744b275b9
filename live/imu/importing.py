"""``livecap import FORMAT PATH --out S.mcap``: a recorded suit turned into a session that
``livecap replay`` runs like a live one.

The readers of live/io (x-IMU3 folders, Xsens MVNX, Xsens DOT CSV) give each sensor's samples
and segment label; here the labels become a suit layout (``live.imu.layout.segment_from_label``,
or a ``--layout`` that maps the file's sensor ids or labels to segments), the samples are put on
one time grid (slerp; gaps longer than ``MAX_GAP_S`` stay gaps), and the calibration comes from
the file when it says (MVNX: its T-pose frame and its sensors' mountings) or from the take
itself (``live.imu.take_calibration``: the still hold it starts with, each sensor's facing from
how the legs move, per-sensor headings). The session holds one ``imu`` stream (decoded samples,
``livecap.imu.v1``) whose metadata carries the layout, the rate, the calibration and where it
came from; ``live.imu.stage.suit_options_from_stream`` reads them back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from live.core.errors import FormatError, UserInputError
from live.core.frames import MocapPacket
from live.core.protocols import StreamInfo
from live.core.rotations import quat_slerp
from live.core.skeleton import JOINT_NAMES, default_rest_joints
from live.imu.layout import SuitLayout, load_suit_layout, parse_suit_layout, segment_from_label
from live.imu.take_calibration import facing_from_motion, find_still, take_mounting
from live.io.imu_import import SuitRecording, SuitTrack

FORMATS = ("ximu3", "mvnx", "xsens-dot")
#: Samples further apart than this are not interpolated across (the sensor was silent).
MAX_GAP_S = 0.2
#: Session time of the first sample (room before it, like synthetic sessions).
START_NS = 1_000_000_000


def read_recording(fmt: str, paths: list[Path], *, stream: str = "segments") -> SuitRecording:
    if fmt == "ximu3":
        from live.io.imu_import_ximu3 import read_ximu3

        if len(paths) != 1:
            raise UserInputError("ximu3 takes one folder (the recording, one device folder per sensor)")
        return read_ximu3(paths[0])
    if fmt == "mvnx":
        from live.io.imu_import_mvnx import read_mvnx

        if len(paths) != 1:
            raise UserInputError("mvnx takes one .mvnx file")
        return read_mvnx(paths[0], stream=stream)
    if fmt == "xsens-dot":
        from live.io.imu_import_dot import read_dot

        return read_dot(list(paths))
    raise UserInputError(f"unknown format {fmt!r}; expected one of {FORMATS}")


def layout_for(recording: SuitRecording, layout: str | Path | dict | None = None
               ) -> tuple[SuitLayout, list[int], list[str]]:
    """(layout, the tracks it keeps in layout order, labels of the tracks it leaves out). Without
    a layout the labels name the segments; a layout file may key sensors by id or by label."""
    by_label = {t.label: t for t in recording.tracks}
    by_id = {t.sensor: t for t in recording.tracks}
    if layout is None:
        mapping, dropped, taken = {}, [], set()
        for t in recording.tracks:
            j = segment_from_label(t.label)
            if j is None or j in taken:
                dropped.append(t.label)
                continue
            taken.add(j)
            mapping[str(t.sensor)] = JOINT_NAMES[j]
        if not mapping:
            raise FormatError("no sensor label names a segment (labels: "
                              + ", ".join(repr(t.label) for t in recording.tracks[:8]) + "); give --layout",
                              path=recording.source)
        suit = parse_suit_layout({"name": Path(recording.source).stem, "sensors": mapping})
    else:
        obj = layout if isinstance(layout, dict) else None
        if obj is None:
            from live.core.jsonfile import read_json

            obj = read_json(Path(layout))
        sensors = obj.get("sensors") if isinstance(obj, dict) else None
        if isinstance(sensors, dict):
            keyed = {}
            for key, seg in sensors.items():
                track = by_label.get(key) or (by_id.get(int(key)) if str(key).lstrip("-").isdigit() else None)
                if track is None:
                    raise UserInputError(f"--layout names sensor {key!r}, which the recording does not have "
                                         f"(it has {', '.join(repr(t.label) for t in recording.tracks[:8])})")
                keyed[str(track.sensor)] = seg
            obj = {**obj, "sensors": keyed}
        suit = load_suit_layout(obj)
        dropped = [t.label for t in recording.tracks if t.sensor not in set(suit.sensors.tolist())]
    rows = [recording.tracks.index(by_id[int(s)]) for s in suit.sensors]
    return suit, rows, dropped


def resample(tracks: list[SuitTrack], rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Tracks on one grid at rate_hz over the time all of them cover -> (t (N,), quats (N, S, 4),
    gyro (N, S, 3) or None); NaN where a sensor was silent for more than MAX_GAP_S."""
    start = max(t.t_s[0] for t in tracks)
    end = min(t.t_s[-1] for t in tracks)
    if end - start < 2.0 / rate_hz:
        raise FormatError("the sensors' recordings do not overlap in time")
    grid = start + np.arange(int(np.floor((end - start) * rate_hz)) + 1) / rate_hz
    quats = np.full((len(grid), len(tracks), 4), np.nan)
    gyro = None if any(t.gyro is None for t in tracks) else np.full((len(grid), len(tracks), 3), np.nan)
    for s, track in enumerate(tracks):
        i1 = np.clip(np.searchsorted(track.t_s, grid, side="right"), 1, len(track.t_s) - 1)
        i0 = i1 - 1
        span = track.t_s[i1] - track.t_s[i0]
        u = np.clip((grid - track.t_s[i0]) / span, 0.0, 1.0)
        q = quat_slerp(track.quats[i0], track.quats[i1], u[:, None])
        ok = span <= MAX_GAP_S
        quats[ok, s] = q[ok]
        if gyro is not None:
            g = (1 - u)[:, None] * track.gyro[i0] + u[:, None] * track.gyro[i1]
            gyro[ok, s] = g[ok]
    return grid, quats, gyro


@dataclass
class ImportReport:
    format: str
    source: str
    out: str
    sensors: list[tuple[int, str, str]]  # (id, label in the file, canonical segment)
    dropped: list[str]
    rate_hz: float
    seconds: float
    packets: int
    calibration: str  # how: "file" or "take"
    still_s: tuple[float, float] | None = None
    facing: dict[str, str] = field(default_factory=dict)  # label -> how its heading was found

    def lines(self) -> list[str]:
        out = [f"{len(self.sensors)} sensors, {self.seconds:.1f} s at {self.rate_hz:g} Hz -> {self.out} "
               f"({self.packets} samples)"]
        for _, label, seg in self.sensors:
            how = self.facing.get(label, "")
            out.append(f"  {label:<22} -> {seg:<15} {how}")
        if self.dropped:
            out.append("  left out (no segment of the 22-joint skeleton, or a second sensor on one): "
                       + ", ".join(self.dropped))
        if self.calibration == "file":
            out.append("  calibration: the file's (its T-pose and sensor mountings)")
        elif self.still_s is not None:
            out.append(f"  calibration: the still hold at {self.still_s[0]:.2f}-{self.still_s[1]:.2f} s, "
                       "each sensor's facing from the take")
        return out


def import_session(fmt: str, paths: list[Path], out: Path, *, layout=None, pose: str | None = None,
                   rate_hz: float | None = None, stream: str = "segments", height: float = 1.75) -> ImportReport:
    from live.io.session import SessionWriter

    recording = read_recording(fmt, paths, stream=stream)
    suit, rows, dropped = layout_for(recording, layout)
    tracks = [recording.tracks[r] for r in rows]
    rate = float(rate_hz or recording.rate_hz or round(float(np.median([t.rate_hz for t in tracks])), 3))
    if not 1.0 <= rate <= 2000.0:
        raise UserInputError(f"--rate {rate:g} Hz is out of range (1-2000)")
    t, quats, gyro = resample(tracks, rate)
    pose = pose or recording.pose or "npose"
    report = ImportReport(format=fmt, source=recording.source, out=str(out),
                          sensors=[(int(s), tr.label, JOINT_NAMES[int(j)]) for s, j, tr in zip(suit.sensors, suit.joints, tracks)],
                          dropped=dropped, rate_hz=rate, seconds=float(t[-1] - t[0]), packets=len(t),
                          calibration="file" if recording.calibration is not None else "take")
    meta: dict = {"rate_hz": rate, "imported": {"format": fmt, "source": Path(recording.source).name,
                                                **{k: v for k, v in recording.meta.items() if k in ("world", "synced", "stream", "start")}}}
    if recording.calibration is not None:
        meta["calibration"] = {"pose": recording.calibration["pose"],
                               "calibration": _file_calibration(recording.calibration, rows, suit, height)}
    else:
        still = find_still(quats, t)
        if still is None:
            raise FormatError("no still calibration pose in the first 30 s of the take (every sensor still for "
                              "0.5 s); record one at the start", path=recording.source)
        facing = facing_from_motion(quats, t, suit.joints, still)
        suit = SuitLayout(name=suit.name, sensors=suit.sensors, joints=suit.joints,
                          mounting=take_mounting(quats, suit.joints, still, facing, pose))
        hold = (float(t[still[0]] - t[0]), float(t[still[1]] - t[0]))
        report.still_s = hold
        report.facing = {tr.label: f"facing: {m}" + (f" (hinge {h:.2f})" if m == "hinge" else "")
                         for tr, m, h in zip(tracks, facing.method, facing.hinge_share)}
        meta["calibration"] = {"pose": pose, "hold_s": round(hold[1] - hold[0], 4),
                               "window_ns": [START_NS + int(round(v * 1e9)) for v in hold], "per_sensor_heading": True}
    meta["layout"] = suit.to_json()
    stream_info = StreamInfo("suit", "imu", meta)
    with SessionWriter(out, [stream_info], start_wall_time_ns=0) as writer:
        for k in range(len(t)):
            ok = np.all(np.isfinite(quats[k]), axis=1)
            if not ok.any():
                continue
            t_ns = START_NS + int(round((t[k] - t[0]) * 1e9))
            writer.write(MocapPacket(t_ns=t_ns, device="suit", sensors=suit.sensors[ok].copy(), quats=quats[k, ok],
                                     gyro=None if gyro is None or not np.all(np.isfinite(gyro[k, ok])) else gyro[k, ok]))
    return report


def _file_calibration(cal: dict, rows: list[int], suit: SuitLayout, height: float) -> dict:
    """The file's calibration (per track) -> the Calibration JSON of the layout's sensors."""
    return {"pose": cal["pose"], "sensors": [int(s) for s in suit.sensors],
            "segments": [JOINT_NAMES[int(j)] for j in suit.joints],
            "heading": [cal["heading"][r] for r in rows], "offset": [cal["offset"][r] for r in rows],
            "spread_deg": [0.0] * len(rows), "rest_joints": default_rest_joints(height).tolist(), "t_ns": [0, 0]}


__all__ = ["import_session", "read_recording", "layout_for", "resample", "ImportReport", "FORMATS"]
