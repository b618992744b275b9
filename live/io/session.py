"""Sessions: every stream of a capture recorded into one MCAP file, and read back.

Layout of a livecap session:
- profile ``livecap``; one metadata record ``livecap.session`` written first (version, start wall
  time, streams as JSON), so even a truncated file says what it holds;
- one channel per stream, topic ``/<kind>/<name>``: ``depth`` (codec.encode_depth), ``serial``
  (the raw bytes of each read, exactly as they arrived, so a replay goes through the real
  parser), ``imu`` (decoded samples for devices that only give decoded data), ``gt`` (ground
  truth of synthetic sessions);
- the body of a synthetic session as attachment ``body.npz``;
- zstd-compressed chunks; message log_time = the sample's host timestamp (ns).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Attachment, Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from live import __version__
from live.core.errors import SessionError, UserInputError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.io import codec

PROFILE = "livecap"
SESSION_METADATA = "livecap.session"
BODY_ATTACHMENT = "body.npz"
_ENCODING = {"depth": "livecap.depth.v1", "serial": "raw", "imu": "livecap.imu.v1", "gt": "livecap.gt.v1"}
_SCHEMA_DOC = {
    "depth": b"livecap depth frame: see live/io/codec.py encode_depth",
    "serial": b"raw bytes of one serial read, as they arrived",
    "imu": b"livecap decoded IMU samples: see live/io/codec.py encode_imu",
    "gt": b"livecap ground truth: joints (22,3) f32, rotations (22,4) f32, root (3) f32",
}
# Small chunks bound what a crash can lose (an unfinished chunk) at a small cost in ratio.
_CHUNK_SIZE = 256 * 1024

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


class SessionWriter:
    """Writes frames into an MCAP session; a context manager that always finishes the file."""

    def __init__(self, path: str | Path, streams: Sequence[StreamInfo] = (), *, extra: dict | None = None,
                 chunk_size: int = _CHUNK_SIZE, start_wall_time_ns: int | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"livecap {__version__}")
        self._channels: dict[tuple[str, str], int] = {}
        self._schemas: dict[str, int] = {}
        self._sequence = 0
        self.messages = 0
        self._closed = False
        meta = {
            "livecap_version": __version__,
            "start_wall_time_ns": str(time.time_ns() if start_wall_time_ns is None else start_wall_time_ns),
            # Maps the host monotonic timestamps of the messages to wall time (0: not a live capture).
            "start_monotonic_ns": str(time.monotonic_ns() if start_wall_time_ns is None else 0),
            "streams": json.dumps([{"name": s.name, "kind": s.kind, "meta": s.meta} for s in streams]),
        }
        for key, value in (extra or {}).items():
            meta[key] = value if isinstance(value, str) else json.dumps(value)
        self._writer.add_metadata(SESSION_METADATA, meta)
        for s in streams:
            self._channel(s.kind, s.name, s.meta)

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
        return self._channels[key]

    def write(self, frame: object) -> None:
        kind, name = stream_of(frame)
        if isinstance(frame, DepthFrame):
            data = codec.encode_depth(frame)
        elif isinstance(frame, MocapPacket):
            data = bytes(frame.raw) if kind == "serial" else codec.encode_imu(frame)
        else:
            assert isinstance(frame, GroundTruth)  # stream_of refused every other type
            data = codec.encode_truth(frame)
        t_ns = int(frame.t_ns)
        self._writer.add_message(self._channel(kind, name), log_time=t_ns, data=data,
                                 publish_time=t_ns, sequence=self._sequence)
        self._sequence += 1
        self.messages += 1

    def attach(self, name: str, data: bytes, media_type: str = "application/octet-stream",
               create_time_ns: int | None = None) -> None:
        now = time.time_ns() if create_time_ns is None else create_time_ns
        self._writer.add_attachment(create_time=now, log_time=0, name=name, media_type=media_type, data=data)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class SessionInfo:
    path: Path
    version: str = ""
    start_wall_time_ns: int = 0
    streams: list[StreamInfo] = field(default_factory=list)
    extra: dict[str, str] = field(default_factory=dict)


class SessionReader:
    """Reads a session front to back with CRC checks, tolerant of damage.

    ``frames()`` yields (StreamInfo, frame) in file order. If the file is truncated or
    corrupted, iteration ends after the last intact record and ``error`` holds one line saying
    where and why it stopped (the caller prints it); nothing raised mid-replay.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise UserInputError(f"no such session file: {self.path}")
        with open(self.path, "rb") as f:
            if f.read(8) != b"\x89MCAP0\r\n":
                raise SessionError("not an MCAP file (bad magic bytes)", path=str(self.path))
        self.error: str | None = None
        self.info = SessionInfo(path=self.path)
        self.attachments: dict[str, bytes] = {}
        self._read_header_metadata()

    def _read_header_metadata(self) -> None:
        # The session metadata is written right after the header, so it survives truncation.
        for record in self._records(stop_at_first_message=True):
            if isinstance(record, Metadata) and record.name == SESSION_METADATA:
                self._set_info(record.metadata)
                return

    def _set_info(self, meta: dict[str, str]) -> None:
        info = self.info
        info.version = meta.get("livecap_version", "")
        info.start_wall_time_ns = int(meta.get("start_wall_time_ns", "0") or 0)
        streams = json.loads(meta.get("streams", "[]"))
        info.streams = [StreamInfo(s["name"], s["kind"], s.get("meta", {})) for s in streams]
        info.extra = {k: v for k, v in meta.items()
                      if k not in ("livecap_version", "start_wall_time_ns", "start_monotonic_ns", "streams")}

    def _records(self, stop_at_first_message: bool = False) -> Iterator[object]:
        with open(self.path, "rb") as f:
            reader = StreamReader(f, validate_crcs=True, record_size_limit=1 << 30)
            try:
                for record in reader.records:
                    if stop_at_first_message and isinstance(record, Message):
                        return
                    yield record
            # Hostile bytes can fail in the mcap reader, struct or zstd with many exception
            # types; whatever it is, replay keeps what came before and reports where it stopped.
            except Exception as exc:  # noqa: BLE001
                if not stop_at_first_message:
                    offset, size = f.tell(), self.path.stat().st_size
                    if offset >= size:
                        reason = "the file ends in the middle of a record (truncated recording)"
                    else:
                        reason = f"{type(exc).__name__}: {exc}"
                    self.error = f"{self.path.name}: replay stopped near byte {offset} of {size}: {reason}"


    def frames(self) -> Iterator[tuple[StreamInfo, SessionFrame]]:
        channels: dict[int, StreamInfo] = {}
        count = 0
        for record in self._records():
            if isinstance(record, Channel):
                meta = json.loads(record.metadata.get("meta", "{}"))
                channels[record.id] = StreamInfo(record.metadata.get("name", record.topic),
                                                 record.metadata.get("kind", "depth"), meta)
            elif isinstance(record, Attachment):
                self.attachments[record.name] = record.data
            elif isinstance(record, Message):
                stream = channels.get(record.channel_id)
                if stream is None:
                    self.error = f"{self.path.name}: message {count} refers to unknown channel {record.channel_id}"
                    return
                try:
                    frame = _decode(stream, record)
                except SessionError as exc:
                    self.error = f"{self.path.name}: replay stopped at message {count}: {exc}"
                    return
                count += 1
                yield stream, frame

    def body_npz(self) -> bytes | None:
        """The attached body file of a synthetic session (reads the file's attachments)."""
        if BODY_ATTACHMENT not in self.attachments:
            for record in self._records():
                if isinstance(record, Attachment):
                    self.attachments[record.name] = record.data
        return self.attachments.get(BODY_ATTACHMENT)


def _decode(stream: StreamInfo, message: Message) -> SessionFrame:
    if stream.kind == "depth":
        return codec.decode_depth(message.data, stream.name)
    if stream.kind == "serial":
        return MocapPacket(t_ns=message.log_time, device=stream.name, raw=bytes(message.data))
    if stream.kind == "imu":
        return codec.decode_imu(message.data, stream.name)
    if stream.kind == "gt":
        return codec.decode_truth(message.data)
    raise SessionError(f"unknown stream kind {stream.kind!r}")
