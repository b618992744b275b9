"""Damage-tolerant reading of an MCAP file: every intact record, every damaged region by offset.

The mcap library's readers stop at the first bad byte; a recording is worth more than that. A
scan walks the data section record by record and checks what it can before trusting it:

- chunks: their fields must add up to the record length, the declared uncompressed size must be
  within ``MAX_CHUNK_BYTES`` (and agree with what zstd declares) before anything is allocated, and
  the decompressed bytes must match the chunk's CRC;
- attachments: the MCAP CRC; metadata: its fields must add up (the session layer adds a CRC of
  its own to the records it writes);
- a record that fails is a damaged region: the scan goes on at the next record. When the file is
  finished and its summary passes its CRC, the summary's chunk, attachment and metadata indexes
  say where the next record starts (and how many messages a damaged chunk held); otherwise the
  scan searches forward for the next record whose fields are consistent.

An unfinished file (a recording killed before it wrote its summary) reads to its last complete
record; a partial record at its end is reported as such.
"""

from __future__ import annotations

import bisect
import io
import mmap
import re
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.summary import Summary

MAGIC = b"\x89MCAP0\r\n"
#: Ceilings checked before allocating: any top-level record, and a chunk once decompressed. A
#: 4096 x 4096 depth image (32 MiB) fits in one chunk.
MAX_RECORD_BYTES = 64 << 20
MAX_CHUNK_BYTES = 64 << 20

_HEAD = struct.Struct("<BQ")  # opcode, record length
_CHUNK_HEAD = struct.Struct("<QQQI")  # message start, end, uncompressed size, uncompressed CRC
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_FOOTER_SIZE = _HEAD.size + 20
_COMPRESSIONS = ("", "zstd", "lz4")
# A record start worth checking when resynchronising: an opcode we can validate, then a length
# below 2^24 * 256 (the five high bytes zero). Zero-width, so candidates may overlap.
_CANDIDATE = re.compile(rb"(?=[\x06\x09\x0c\x0f][\x00-\xff]{3}\x00{5})", re.DOTALL)
_NAMES = {int(op): op.name.lower().replace("_", " ") for op in Opcode}
#: Metadata records livecap writes are a few KB; a resync candidate claiming more is not one.
_MAX_METADATA_CANDIDATE = 1 << 20


@dataclass(frozen=True)
class Damage:
    """A damaged region of the file: where it starts, how many bytes were not used, why, and the
    messages lost when an index says so (None: unknown). ``repaired``: damage worked around with
    nothing lost (a chunk header the index corrects)."""

    offset: int
    length: int
    what: str
    messages: int | None = None
    repaired: bool = False

    def __str__(self) -> str:
        if self.repaired:
            return f"byte {self.offset}: {self.what} (repaired)"
        lost = "" if self.messages is None else f", {self.messages} message{'s' * (self.messages != 1)}"
        return f"byte {self.offset}: {self.what} ({self.length} bytes skipped{lost})"


@dataclass(frozen=True, slots=True)
class ScannedMessage:
    """A message from an intact chunk; ``chunk_offset`` is where its chunk starts in the file."""

    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: memoryview
    chunk_offset: int


class _Malformed(Exception):
    """A record whose fields do not add up (caught inside the scan, never raised out of it)."""


def _parse(cls, body: bytes):
    """An mcap record class's ``read`` over exactly ``body``; _Malformed unless every byte is used."""
    stream = ReadDataStream(io.BytesIO(body))
    try:
        record = cls.read(stream)
    except Exception as exc:  # noqa: BLE001 - struct, EndOfFile, UnicodeDecodeError: all malformed
        raise _Malformed(f"{type(exc).__name__}") from None
    if stream.count != len(body):
        raise _Malformed(f"fields use {stream.count} of {len(body)} bytes")
    return record


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """A chunk's records, never allocating more than ``size`` (already checked against the ceiling)."""
    if compression == "":
        out = data
    elif compression == "zstd":
        try:
            declared = zstandard.frame_content_size(data)
        except zstandard.ZstdError:
            raise _Malformed("not a zstd frame") from None
        if declared not in (-1, size):  # zstd would allocate what the frame declares
            raise _Malformed(f"zstd frame declares {declared} bytes, the chunk {size}")
        try:
            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        except zstandard.ZstdError as exc:
            raise _Malformed(f"zstd: {exc}") from None
    else:
        try:
            import lz4.frame
        except ImportError:
            raise _Malformed("lz4 compression needs the lz4 package") from None
        try:
            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)
        except RuntimeError as exc:
            raise _Malformed(f"lz4: {exc}") from None
    if len(out) != size:
        raise _Malformed(f"decompresses to {len(out)} bytes, declares {size}")
    return out


class McapScan:
    """One pass over an MCAP file (a context manager). ``records()`` yields (offset, record):
    Metadata, Attachment, Channel and ScannedMessage, in file order; ``damage`` lists what was
    skipped, ``finished`` tells a complete file (footer and closing magic) from an unfinished one,
    ``summary`` holds the file's index when it passed its CRC."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.size = self.path.stat().st_size
        self.damage: list[Damage] = []
        self.finished = False
        self.summary: Summary | None = None
        self._file = open(self.path, "rb")
        self._mm: mmap.mmap | bytes = (mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
                                       if self.size else b"")
        if self._mm[:8] != MAGIC:
            self.close()
            raise ValueError("not an MCAP file (bad magic bytes)")
        self.data_end = self.size
        self._chunk_index: dict[int, ChunkIndex] = {}
        self._known: list[int] = []  # indexed record starts, sorted
        self._read_footer()

    # -- the end of the file: footer and summary -----------------------------------------------
    def _read_footer(self) -> None:
        mm, size = self._mm, self.size
        if size < 8 + _FOOTER_SIZE + 8 or mm[size - 8:] != MAGIC:
            return  # unfinished: no footer; the scan reads to the last complete record
        fpos = size - 8 - _FOOTER_SIZE
        opcode, length = _HEAD.unpack_from(mm, fpos)
        summary_start, summary_offset_start, crc = struct.unpack_from("<QQI", mm, fpos + _HEAD.size)
        if opcode != Opcode.FOOTER or length != 20 or not (summary_start == 0 or 8 < summary_start <= fpos):
            self.damage.append(Damage(fpos, _FOOTER_SIZE, "the footer is damaged: the file's index is not used"))
            self.data_end = fpos
            return
        self.finished = True
        self.data_end = fpos
        if summary_start == 0:
            return
        if crc:
            got = zlib.crc32(mm[fpos:fpos + _HEAD.size + 16], zlib.crc32(mm[summary_start:fpos]))
            if got != crc:
                self.damage.append(Damage(summary_start, fpos - summary_start,
                                          "the summary (the file's index) fails its CRC: not used"))
                return
        try:
            self.summary = self._parse_summary(bytes(mm[summary_start:fpos]))
        except _Malformed as exc:
            self.damage.append(Damage(summary_start, fpos - summary_start, f"the summary is unreadable ({exc})"))
            return
        self.data_end = summary_start
        self._chunk_index = {c.chunk_start_offset: c for c in self.summary.chunk_indexes}
        known = set(self._chunk_index)
        known.update(a.offset for a in self.summary.attachment_indexes)
        known.update(m.offset for m in self.summary.metadata_indexes)
        self._known = sorted(k for k in known if 8 <= k < summary_start)

    @staticmethod
    def _parse_summary(buf: bytes) -> Summary:
        summary = Summary()
        kinds: dict[int, type[McapRecord]] = {
            Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.STATISTICS: Statistics,
            Opcode.CHUNK_INDEX: ChunkIndex, Opcode.ATTACHMENT_INDEX: AttachmentIndex,
            Opcode.METADATA_INDEX: MetadataIndex}
        off = 0
        while off < len(buf):
            if off + _HEAD.size > len(buf):
                raise _Malformed("record header cut short")
            opcode, length = _HEAD.unpack_from(buf, off)
            body = buf[off + _HEAD.size: off + _HEAD.size + length]
            if len(body) != length:
                raise _Malformed("record cut short")
            off += _HEAD.size + length
            cls = kinds.get(opcode)
            if cls is None:
                continue  # summary offsets and unknown records
            record = _parse(cls, body)
            if isinstance(record, Schema):
                summary.schemas[record.id] = record
            elif isinstance(record, Channel):
                summary.channels[record.id] = record
            elif isinstance(record, Statistics):
                summary.statistics = record
            elif isinstance(record, ChunkIndex):
                summary.chunk_indexes.append(record)
            elif isinstance(record, AttachmentIndex):
                summary.attachment_indexes.append(record)
            elif isinstance(record, MetadataIndex):
                summary.metadata_indexes.append(record)
        return summary

    # -- the data section ----------------------------------------------------------------------
    def records(self) -> Iterator[tuple[int, Metadata | Attachment | Channel | ScannedMessage]]:
        mm, end = self._mm, self.data_end
        pos = 8
        seen_chunk = False
        while pos < end:
            if pos + _HEAD.size > end:
                pos = self._skip(pos, f"{end - pos} bytes at the end are not a whole record header")
                continue
            opcode, length = _HEAD.unpack_from(mm, pos)
            stop = pos + _HEAD.size + length
            if pos in self._chunk_index:  # the index knows this chunk's extent, whatever its header says
                seen_chunk = True
                pos = yield from self._chunk(pos, length)
                continue
            if opcode not in _NAMES:
                pos = self._skip(pos, f"unknown record opcode 0x{opcode:02x}")
                continue
            if length > MAX_RECORD_BYTES:
                pos = self._skip(pos, f"{_NAMES[opcode]} record declares {length} bytes (limit {MAX_RECORD_BYTES})")
                continue
            if stop > end:
                what = "data section" if self.finished else "file"
                pos = self._skip(pos, f"{_NAMES[opcode]} record of {length} bytes runs past the end of the {what}",
                                 truncated=f"the file is truncated inside a {_NAMES[opcode]} record of {length} "
                                           "bytes (an unfinished recording)")
                continue
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                return
            if opcode == Opcode.CHUNK:
                seen_chunk = True
                pos = yield from self._chunk(pos, length)
                continue
            if opcode == Opcode.MESSAGE and (seen_chunk or self._chunk_index):
                # Sessions keep every message in a chunk: a lone message record in a chunked file
                # is another record whose opcode byte was hit (a message index, say), not data.
                self.damage.append(Damage(pos, stop - pos, "a message record outside the chunks of a chunked file"))
                pos = stop
                continue
            body = bytes(mm[pos + _HEAD.size: stop])
            try:
                if opcode == Opcode.METADATA:
                    yield pos, _parse(Metadata, body)
                elif opcode == Opcode.ATTACHMENT:
                    yield pos, self._attachment(body)
                elif opcode == Opcode.CHANNEL:
                    yield pos, _parse(Channel, body)
                elif opcode == Opcode.MESSAGE:
                    if length < _MESSAGE_HEAD.size:
                        raise _Malformed("message shorter than its header")
                    channel, seq, log_time, publish_time = _MESSAGE_HEAD.unpack_from(body)
                    yield pos, ScannedMessage(channel, seq, log_time, publish_time,
                                              memoryview(body)[_MESSAGE_HEAD.size:], pos)
            except _Malformed as exc:
                pos = self._skip(pos, f"{_NAMES[opcode]} record: {exc}")
                continue
            pos = stop

    def _attachment(self, body: bytes) -> Attachment:
        if len(body) < 4:
            raise _Malformed("too short")
        (crc,) = struct.unpack_from("<I", body, len(body) - 4)
        if crc and zlib.crc32(memoryview(body)[:-4]) != crc:
            raise _Malformed("CRC mismatch")
        return _parse(Attachment, body)

    def _chunk(self, pos: int, length: int):
        """Yields the chunk's records; returns where the next record starts."""
        mm = self._mm
        index = self._chunk_index.get(pos)
        repaired = False
        if index is not None and (index.chunk_length != _HEAD.size + length or mm[pos] != Opcode.CHUNK):
            # The record header disagrees with the (CRC-checked) index: the index is right.
            length, repaired = index.chunk_length - _HEAD.size, True
        stop = pos + _HEAD.size + length
        body = bytes(mm[pos + _HEAD.size: stop])
        try:
            fields = self._chunk_fields(body)
        except _Malformed as exc:
            return self._skip(pos, f"chunk record: {exc}")
        compression, data_start, usize, crc = fields
        try:
            if usize > MAX_CHUNK_BYTES:
                raise _Malformed(f"declares {usize} bytes uncompressed (limit {MAX_CHUNK_BYTES})")
            raw = _decompress(compression, body[data_start:], usize)
            if crc and zlib.crc32(raw) != crc:
                raise _Malformed("CRC mismatch")
        except _Malformed as exc:
            self.damage.append(Damage(pos, stop - pos, f"chunk {exc}", self._messages_in_chunk(pos, stop)))
            return stop
        del body
        if repaired:
            self.damage.append(Damage(pos, 0, "the chunk's record header is damaged; its extent is taken from "
                                              "the index", repaired=True))
        try:
            yield from self._chunk_records(raw, pos)
        except _Malformed as exc:
            self.damage.append(Damage(pos, stop - pos, f"chunk holds a malformed record ({exc}); the rest of it "
                                                       "is skipped"))
        return stop

    @staticmethod
    def _chunk_fields(buf, at: int = 0, length: int | None = None) -> tuple[str, int, int, int]:
        """(compression, offset of the compressed data from ``at``, uncompressed size, CRC) of the
        chunk body of ``length`` bytes at ``buf[at:]``, whose fields add up to its length;
        _Malformed otherwise. Reads only the fields (not the data)."""
        length = len(buf) - at if length is None else length
        head = _CHUNK_HEAD.size
        if length < head + 4:
            raise _Malformed("shorter than its fields")
        _, _, usize, crc = _CHUNK_HEAD.unpack_from(buf, at)
        (clen,) = struct.unpack_from("<I", buf, at + head)
        if clen > 8 or length < head + 4 + clen + 8:
            raise _Malformed("its fields do not add up")
        try:
            compression = bytes(buf[at + head + 4: at + head + 4 + clen]).decode("ascii")
        except UnicodeDecodeError:
            raise _Malformed("compression name is not text") from None
        (dlen,) = struct.unpack_from("<Q", buf, at + head + 4 + clen)
        start = head + 4 + clen + 8
        if compression not in _COMPRESSIONS or start + dlen != length:
            raise _Malformed("its fields do not add up")
        return compression, start, usize, crc

    @staticmethod
    def _chunk_records(raw: bytes, chunk_offset: int) -> Iterator[tuple[int, Channel | ScannedMessage]]:
        view = memoryview(raw)
        off, n = 0, len(raw)
        while off < n:
            if off + _HEAD.size > n:
                raise _Malformed(f"record header cut short at +{off}")
            opcode, length = _HEAD.unpack_from(raw, off)
            start = off + _HEAD.size
            if start + length > n:
                raise _Malformed(f"record at +{off} runs past the chunk")
            if opcode == Opcode.MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    raise _Malformed(f"message at +{off} shorter than its header")
                channel, seq, log_time, publish_time = _MESSAGE_HEAD.unpack_from(raw, start)
                yield chunk_offset, ScannedMessage(channel, seq, log_time, publish_time,
                                                   view[start + _MESSAGE_HEAD.size: start + length], chunk_offset)
            elif opcode == Opcode.CHANNEL:
                yield chunk_offset, _parse(Channel, raw[start: start + length])
            off = start + length

    def _messages_in_chunk(self, pos: int, stop: int) -> int | None:
        """How many messages a damaged chunk held, from the message index records the writer put
        after it (where the summary's index says, else right after the chunk); None if unreadable."""
        index = self._chunk_index.get(pos)
        offsets = sorted(index.message_index_offsets.values()) if index is not None else []
        mm, total, off = self._mm, 0, offsets[0] if offsets else stop
        while off + _HEAD.size + 6 <= self.data_end:
            opcode, length = _HEAD.unpack_from(mm, off)
            if opcode != Opcode.MESSAGE_INDEX or off + _HEAD.size + length > self.data_end:
                break
            (records_length,) = struct.unpack_from("<I", mm, off + _HEAD.size + 2)
            if records_length % 16 or records_length + 6 != length:
                return None
            total += records_length // 16
            off += _HEAD.size + length
        return total if off > (offsets[0] if offsets else stop) else None

    # -- damage and resynchronisation ----------------------------------------------------------
    def _skip(self, pos: int, why: str, *, truncated: str | None = None) -> int:
        """Record the region from ``pos`` to the next trustworthy record as damaged; returns its
        start. ``truncated``: what to say instead when no record follows in an unfinished file."""
        nxt = self._next_record(pos)
        if nxt is None:
            if truncated and not self.finished:
                why = truncated
            self.damage.append(Damage(pos, self.data_end - pos, why))
            return self.data_end
        self.damage.append(Damage(pos, nxt - pos, why))
        return nxt

    def _next_record(self, pos: int) -> int | None:
        if self._known:
            i = bisect.bisect_right(self._known, pos)
            if i < len(self._known):
                return self._known[i]
        for match in _CANDIDATE.finditer(self._mm, pos + 1, self.data_end):
            if self._plausible(match.start()):
                return match.start()
        return None

    def _plausible(self, pos: int) -> bool:
        """A record starts at ``pos`` whose fields add up (and, for an attachment, its CRC holds)."""
        opcode, length = _HEAD.unpack_from(self._mm, pos)
        stop = pos + _HEAD.size + length
        if stop > self.data_end:
            return False
        if opcode == Opcode.DATA_END:
            return length == 4
        try:
            if opcode == Opcode.CHUNK:
                self._chunk_fields(self._mm, pos + _HEAD.size, length)
                return True
            if opcode == Opcode.ATTACHMENT and not self._attachment_fields_add_up(pos + _HEAD.size, length):
                return False
            if opcode == Opcode.METADATA and length > _MAX_METADATA_CANDIDATE:
                return False
            body = bytes(self._mm[pos + _HEAD.size: stop])
            if opcode == Opcode.METADATA:
                _parse(Metadata, body)
            else:
                self._attachment(body)
        except (_Malformed, struct.error):
            return False
        return True

    def _attachment_fields_add_up(self, at: int, length: int) -> bool:
        """Whether an attachment body's strings and data fill exactly ``length`` bytes (cheap:
        checked before its CRC is computed)."""
        mm, off = self._mm, at + 16  # log time, create time
        for _ in range(2):  # name, media type
            (n,) = struct.unpack_from("<I", mm, off)
            off += 4 + n
            if off > at + length:
                return False
        (n,) = struct.unpack_from("<Q", mm, off)
        return off + 8 + n + 4 == at + length

    def close(self) -> None:
        if isinstance(self._mm, mmap.mmap):
            self._mm.close()
        self._file.close()

    def __enter__(self) -> McapScan:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
