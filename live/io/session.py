"""Sessions: every stream of a capture recorded into one MCAP file, and read back.

Layout of a livecap session (the contract is in docs/conventions.md):
- profile ``livecap``; one metadata record ``livecap.session`` written first (version, start wall
  time, streams and their channel ids as JSON), so even an unfinished file says what it holds;
- one channel per stream, topic ``/<kind>/<name>``: ``depth`` (codec.encode_depth), ``serial``
  (the raw bytes of each read, exactly as they arrived, so a replay goes through the real
  parser), ``imu`` (decoded samples for devices that only give decoded data), ``gt`` (ground
  truth of synthetic sessions);
- the body of a synthetic session as attachment ``body.npz`` (under MCAP's attachment CRC);
- a live recording also stores ``livecap.gap`` records (a stream silent for a while),
  ``livecap.status`` records (a source's state changed) and ``livecap.session.end`` (per-stream
  counts and the sources' last state) when it closes;
- every metadata record livecap writes carries ``crc32``, a CRC of its other keys;
- zstd-compressed chunks; message log_time = the sample's host timestamp (ns). A live recording
  also closes the open chunk every ``flush_interval_s`` and flushes it to the file, so a
  process killed at any moment loses at most that much.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Attachment, Channel, Metadata
from mcap.writer import CompressionType, Writer

from live import __version__
from live.core.errors import SessionError, UserInputError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.io import codec
from live.io.mcap_scan import Damage, McapScan, ScannedMessage
from live.io.recording import Gap, RecordingSummary, StreamTally, summarise

log = logging.getLogger("livecap.session")

PROFILE = "livecap"
SESSION_METADATA = "livecap.session"
GAP_METADATA = "livecap.gap"
STATUS_METADATA = "livecap.status"
END_METADATA = "livecap.session.end"
BODY_ATTACHMENT = "body.npz"
KINDS = ("depth", "serial", "imu", "gt")
_ENCODING = {"depth": "livecap.depth.v1", "serial": "raw", "imu": "livecap.imu.v1", "gt": "livecap.gt.v1"}
_SCHEMA_DOC = {
    "depth": b"livecap depth frame: see live/io/codec.py encode_depth",
    "serial": b"raw bytes of one serial read, as they arrived",
    "imu": b"livecap decoded IMU samples: see live/io/codec.py encode_imu",
    "gt": b"livecap ground truth: joints (22,3) f32, rotations (22,4) f32, root (3) f32",
}
_CHUNK_SIZE = 256 * 1024
#: A live recording's chunk interval and fsync interval (seconds).
FLUSH_INTERVAL_S = 0.5
FSYNC_INTERVAL_S = 1.0
#: Damaged regions kept in detail (more are counted).
_MAX_DAMAGE_LISTED = 1000

# What a session holds: depth frames, serial reads or decoded IMU samples (MocapPacket), ground truth.
SessionFrame = DepthFrame | MocapPacket | GroundTruth


def stream_of(frame: object) -> tuple[str, str]:
    """(kind, stream name) a frame belongs to."""
    if isinstance(frame, DepthFrame):
        return "depth", frame.sensor
    if isinstance(frame, MocapPacket):
        return ("serial" if frame.raw else "imu"), frame.device
    if isinstance(frame, GroundTruth):
        return "gt", "gt"
    raise TypeError(f"cannot record a {type(frame).__name__}")


def seal(meta: dict[str, str]) -> dict[str, str]:
    """``meta`` with ``crc32``: the CRC-32 (8 hex digits) of its other keys as sorted, compact JSON."""
    body = {k: v for k, v in meta.items() if k != "crc32"}
    crc = zlib.crc32(json.dumps(body, sort_keys=True, separators=(",", ":")).encode())
    return {**body, "crc32": f"{crc:08x}"}


def sealed_ok(meta: dict[str, str]) -> bool | None:
    """True when ``crc32`` matches, False when it does not, None when the record has none."""
    if "crc32" not in meta:
        return None
    return seal(meta)["crc32"] == meta["crc32"]


class SessionWriter:
    """Writes frames into an MCAP session; a context manager that always finishes the file.

    ``flush_interval_s`` (live recordings): a thread closes the open chunk that often, writes it
    out and stores gap and status records; ``fsync_interval_s``: how often it also asks the OS to
    put the file on disk (None: never; a killed process loses nothing the OS already has, a
    power cut does). Without a flush interval, chunks close by size only and the same frames
    give the same bytes. ``status``: a callable giving the sources' state (see
    live.io.recording.summarise), polled by the flush thread and read at close.
    """

    def __init__(self, path: str | Path, streams: Sequence[StreamInfo] = (), *, extra: dict | None = None,
                 chunk_size: int = _CHUNK_SIZE, start_wall_time_ns: int | None = None,
                 flush_interval_s: float | None = None, fsync_interval_s: float | None = None,
                 status: Callable[[], dict[str, dict]] | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"livecap {__version__}")
        # mcap-python closes chunks by size only; a live recording also closes one on a timer
        # (its chunk method is private: tests/test_record_kill.py fails if it goes away).
        self._cut_chunk: Callable[[], None] | None = getattr(self._writer, "_Writer__finalize_chunk", None)
        self._channels: dict[tuple[str, str], int] = {}
        self._schemas: dict[str, int] = {}
        self._tallies: dict[tuple[str, str], StreamTally] = {}
        self._sequence = 0
        self.messages = 0
        self._closed = False
        self._lock = threading.Lock()
        self._status = status
        self._last_status: dict | None = None
        self.summary: RecordingSummary | None = None
        for s in streams:
            self._channel(s.kind, s.name, s.meta)
        meta = {
            "livecap_version": __version__,
            "start_wall_time_ns": str(time.time_ns() if start_wall_time_ns is None else start_wall_time_ns),
            # Maps the host monotonic timestamps of the messages to wall time (0: not a live capture).
            "start_monotonic_ns": str(time.monotonic_ns() if start_wall_time_ns is None else 0),
            "streams": json.dumps([{"name": s.name, "kind": s.kind, "meta": s.meta,
                                    "channel_id": self._channels[(s.kind, s.name)]} for s in streams]),
        }
        for key, value in (extra or {}).items():
            meta[key] = value if isinstance(value, str) else json.dumps(value)
        self._writer.add_metadata(SESSION_METADATA, seal(meta))
        self._file.flush()
        self._flush_interval = flush_interval_s
        self._fsync_interval = fsync_interval_s
        self._stop_flushing = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_interval_s is not None:
            if self._cut_chunk is None:
                log.warning("this mcap version cannot close chunks on demand: a crash may lose a whole chunk")
            self._flusher = threading.Thread(target=self._flush_loop, name="session-flush", daemon=True)
            self._flusher.start()

    def _channel(self, kind: str, name: str, meta: dict | None = None) -> int:
        key = (kind, name)
        if key not in self._channels:
            if kind not in self._schemas:
                self._schemas[kind] = self._writer.register_schema(f"livecap.{kind}", "text", _SCHEMA_DOC[kind])
            self._channels[key] = self._writer.register_channel(
                topic=f"/{kind}/{name}",
                message_encoding=_ENCODING[kind],
                schema_id=self._schemas[kind],
                metadata={"kind": kind, "name": name, "meta": json.dumps(meta or {})},
            )
            self._tallies[key] = StreamTally(name, kind)
        return self._channels[key]

    def write(self, frame: object) -> None:
        kind, name = stream_of(frame)
        try:
            if isinstance(frame, DepthFrame):
                data = codec.encode_depth(frame)
            elif isinstance(frame, MocapPacket):
                data = bytes(frame.raw) if kind == "serial" else codec.encode_imu(frame)
            else:
                assert isinstance(frame, GroundTruth)  # stream_of refused every other type
                data = codec.encode_truth(frame)
        except SessionError:
            # Over the codec's size limits: a reader would refuse it; counted, not written.
            with self._lock:
                if not self._closed:
                    self._channel(kind, name)
                    self._tallies[(kind, name)].refused += 1
            return
        t_ns = int(frame.t_ns)
        with self._lock:
            if self._closed:
                return
            channel = self._channel(kind, name)
            self._writer.add_message(channel, log_time=t_ns, data=data, publish_time=t_ns, sequence=self._sequence)
            self._sequence += 1
            self.messages += 1
            gap = self._tallies[(kind, name)].arrived(t_ns, len(data), time.monotonic_ns())
            if gap is not None and self._flush_interval is not None:
                self._writer.add_metadata(GAP_METADATA, seal(gap.as_meta()))

    def attach(self, name: str, data: bytes, media_type: str = "application/octet-stream",
               create_time_ns: int | None = None) -> None:
        now = time.time_ns() if create_time_ns is None else create_time_ns
        with self._lock:
            self._writer.add_attachment(create_time=now, log_time=0, name=name, media_type=media_type, data=data)

    # -- live recordings: the flush thread ------------------------------------------------------
    def _flush_loop(self) -> None:
        assert self._flush_interval is not None
        last_sync = time.monotonic()
        while not self._stop_flushing.wait(self._flush_interval):
            with self._lock:
                if self._closed:
                    return
                self._flush_locked()
            if self._fsync_interval is not None and time.monotonic() - last_sync >= self._fsync_interval:
                last_sync = time.monotonic()
                os.fsync(self._file.fileno())  # outside the lock: writers go on meanwhile

    def _flush_locked(self) -> None:
        if self._cut_chunk is not None:
            self._cut_chunk()
        now = time.monotonic_ns()
        for tally in self._tallies.values():
            gap = tally.open_gap_at(now)
            if gap is not None:
                self._writer.add_metadata(GAP_METADATA, seal(gap.as_meta()))
        status = self._poll_status()
        if status is not None and status != self._last_status:
            self._last_status = status
            self._writer.add_metadata(STATUS_METADATA, seal({"monotonic_ns": str(now), "sources": json.dumps(status)}))
        self._file.flush()

    def _poll_status(self) -> dict | None:
        if self._status is None:
            return None
        try:
            return self._status()
        except Exception as exc:  # noqa: BLE001 - the sources' state is informative; recording goes on
            log.warning("source status unavailable: %s", exc)
            return None

    def close(self) -> RecordingSummary:
        """Finish the file; returns what the recording went through (also stored in it when live)."""
        if self.summary is not None:
            return self.summary
        self._stop_flushing.set()
        if self._flusher is not None:
            self._flusher.join()
        with self._lock:
            self._closed = True
            try:
                sources = self._poll_status() or {}
                self.summary = summarise(str(self.path), list(self._tallies.values()), sources, time.monotonic_ns())
                if self._flush_interval is not None:
                    self._writer.add_metadata(END_METADATA, seal({
                        "end_wall_time_ns": str(time.time_ns()), "messages": str(self.summary.messages),
                        "streams": json.dumps(self.summary.streams), "sources": json.dumps(sources),
                        "problems": json.dumps(self.summary.problems)}))
                self._writer.finish()
                self._file.flush()
                if self._fsync_interval is not None:
                    os.fsync(self._file.fileno())
            finally:
                self._file.close()
        return self.summary

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------------------------------
# Reading


@dataclass
class RecordingLog:
    """What a live recording stored about itself: gaps, the sources' last state, its end record
    (None: the recorder never closed the file)."""

    gaps: list[Gap] = field(default_factory=list)
    status: dict = field(default_factory=dict)
    end: dict | None = None


@dataclass
class SessionInfo:
    path: Path
    version: str = ""
    start_wall_time_ns: int = 0
    streams: list[StreamInfo] = field(default_factory=list)
    extra: dict[str, str] = field(default_factory=dict)
    recording: RecordingLog = field(default_factory=RecordingLog)


class SessionReader:
    """Reads a session front to back, tolerant of damage.

    ``frames()`` yields (StreamInfo, frame) in file order from every intact chunk; a damaged
    chunk, record or message is skipped and listed in ``damage`` (live.io.mcap_scan.Damage: byte
    offset, bytes skipped, why), and ``error`` sums it up in one line (None when nothing was
    skipped). ``finished`` is False for a file its writer never closed (a killed recording):
    it reads to its last complete record. Nothing is raised mid-replay.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise UserInputError(f"no such session file: {self.path}")
        self.damage: list[Damage] = []
        self.damage_count = 0  # regions skipped (damage lists at most _MAX_DAMAGE_LISTED of them)
        self.info = SessionInfo(path=self.path)
        self.attachments: dict[str, bytes] = {}
        self.finished = False
        self.message_counts: dict[int, int] = {}  # per channel, from an intact summary
        self._channels: dict[int, StreamInfo] = {}
        try:
            self._read_header()
        except ValueError as exc:
            raise SessionError(str(exc), path=str(self.path)) from None

    # -- what the file says it holds -----------------------------------------------------------
    def _read_header(self) -> None:
        with McapScan(self.path) as scan:
            self.finished = scan.finished
            if scan.summary is not None:
                for cid, channel in scan.summary.channels.items():
                    self._channels[cid] = _stream_of_channel(channel)
                if scan.summary.statistics is not None:
                    self.message_counts = dict(scan.summary.statistics.channel_message_counts)
            found = False
            for _, record in scan.records():
                if isinstance(record, Metadata) and record.name == SESSION_METADATA and not found:
                    found = self._set_info(record.metadata)
                elif isinstance(record, Channel):
                    self._channels.setdefault(record.id, _stream_of_channel(record))
                elif isinstance(record, ScannedMessage):
                    break
        if not found:
            # Damaged or missing: what the channel records say is the next best thing.
            self.info.streams = list({(s.kind, s.name): s for s in self._channels.values()}.values())

    def _set_info(self, meta: dict[str, str]) -> bool:
        if sealed_ok(meta) is False:
            return False
        try:
            streams = json.loads(meta.get("streams", "[]"))
            parsed = [(StreamInfo(str(s["name"]), _kind(s["kind"]), _meta(s.get("meta", {}))), s.get("channel_id"))
                      for s in streams]
            start = int(meta.get("start_wall_time_ns", "0") or 0)
        except (ValueError, TypeError, KeyError, AttributeError):
            return False
        info = self.info
        info.version = str(meta.get("livecap_version", ""))
        info.start_wall_time_ns = start
        info.streams = [s for s, _ in parsed]
        for stream, cid in parsed:
            if isinstance(cid, int):
                self._channels.setdefault(cid, stream)
        info.extra = {k: v for k, v in meta.items() if k not in
                      ("livecap_version", "start_wall_time_ns", "start_monotonic_ns", "streams", "crc32")}
        return True

    @property
    def error(self) -> str | None:
        """One line summing up the damaged regions skipped (None: nothing skipped)."""
        lost = [d for d in self.damage if not d.repaired]
        if not lost:
            return None
        count = self.damage_count
        known = [d.messages for d in lost if d.messages is not None]
        messages = f", {sum(known)} messages lost" + ("" if len(known) == len(lost) else " or more") if known else ""
        shown = "; ".join(str(d) for d in lost[:3]) + (f"; and {count - 3} more" if count > 3 else "")
        return f"{self.path.name}: {count} damaged region{'s' * (count != 1)} skipped{messages}: {shown}"

    def _damaged(self, damage: Damage) -> None:
        self.damage_count += not damage.repaired
        if len(self.damage) < _MAX_DAMAGE_LISTED:
            self.damage.append(damage)

    # -- the frames ----------------------------------------------------------------------------
    def frames(self) -> Iterator[tuple[StreamInfo, SessionFrame]]:
        self.damage, self.damage_count = [], 0
        self.info.recording = RecordingLog()
        channels = dict(self._channels)
        bad_chunk_messages: dict[int, list] = {}
        with McapScan(self.path) as scan:
            seen = 0
            try:
                for offset, record in scan.records():
                    for d in scan.damage[seen:]:
                        self._damaged(d)
                    seen = len(scan.damage)
                    if isinstance(record, ScannedMessage):
                        stream = channels.get(record.channel_id)
                        try:
                            if stream is None:
                                raise SessionError(f"unknown channel {record.channel_id}")
                            frame = _decode(stream, record)
                        except SessionError as exc:
                            bad_chunk_messages.setdefault(record.chunk_offset, []).append((len(record.data), str(exc)))
                            continue
                        yield stream, frame
                    elif isinstance(record, Channel):
                        channels[record.id] = _stream_of_channel(record)
                    elif isinstance(record, Attachment):
                        self.attachments[record.name] = record.data
                    elif isinstance(record, Metadata):
                        self._metadata(offset, record)
            finally:
                for d in scan.damage[seen:]:
                    self._damaged(d)
                for offset, bad in bad_chunk_messages.items():
                    self._damaged(Damage(offset, sum(n for n, _ in bad), f"{len(bad)} undecodable message"
                                         f"{'s' * (len(bad) != 1)} in a chunk: {bad[0][1]}", len(bad)))
                self.damage.sort(key=lambda d: d.offset)

    def _metadata(self, offset: int, record: Metadata) -> None:
        meta = record.metadata
        if record.name.startswith("livecap.") and sealed_ok(meta) is False:
            self._damaged(Damage(offset, 0, f"metadata record {record.name!r} fails its CRC: not used"))
            return
        log_ = self.info.recording
        try:
            if record.name == GAP_METADATA:
                gap = Gap.from_meta(meta)
                log_.gaps = [g for g in log_.gaps if not (g.stream == gap.stream and g.after_t_ns == gap.after_t_ns)]
                log_.gaps.append(gap)
            elif record.name == STATUS_METADATA:
                log_.status = json.loads(meta["sources"])
            elif record.name == END_METADATA:
                log_.end = {k: v if k in ("end_wall_time_ns", "messages") else json.loads(v)
                            for k, v in meta.items() if k != "crc32"}
                # The end record has every gap with its final length.
                log_.gaps = [Gap(**g) for s in log_.end["streams"] for g in s["gaps"]]
        except (ValueError, KeyError, TypeError) as exc:
            self._damaged(Damage(offset, 0, f"metadata record {record.name!r} is unreadable ({exc})"))

    def body_npz(self) -> bytes | None:
        """The attached body file of a synthetic session (None when absent or damaged)."""
        if BODY_ATTACHMENT not in self.attachments:
            with McapScan(self.path) as scan:
                for _, record in scan.records():
                    if isinstance(record, Attachment):
                        self.attachments[record.name] = record.data
                    elif isinstance(record, ScannedMessage) and BODY_ATTACHMENT in self.attachments:
                        break
        return self.attachments.get(BODY_ATTACHMENT)


def _kind(value: object) -> str:
    if value not in KINDS:
        raise ValueError(f"unknown stream kind {value!r}")
    return str(value)


def _meta(value: object) -> dict:
    if not isinstance(value, dict):
        raise ValueError("stream meta is not an object")
    return value


def _stream_of_channel(channel: Channel) -> StreamInfo:
    md = channel.metadata
    try:
        meta = _meta(json.loads(md.get("meta", "{}")))
    except ValueError:
        meta = {}
    kind = md.get("kind", "")
    if kind not in KINDS:
        kind = next((k for k in KINDS if channel.topic.startswith(f"/{k}/")), "depth")
    return StreamInfo(md.get("name", channel.topic), kind, meta)


def _decode(stream: StreamInfo, message: ScannedMessage) -> SessionFrame:
    if stream.kind == "depth":
        return codec.decode_depth(message.data, stream.name)
    if stream.kind == "serial":
        return MocapPacket(t_ns=message.log_time, device=stream.name, raw=bytes(message.data))
    if stream.kind == "imu":
        return codec.decode_imu(message.data, stream.name)
    if stream.kind == "gt":
        return codec.decode_truth(message.data)
    raise SessionError(f"unknown stream kind {stream.kind!r}")
