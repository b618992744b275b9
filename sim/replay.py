"""Replay a recorded session into the pipeline, at recorded timing or as fast as possible.

The replay publishes into the same rings that live drivers use. Serial streams are replayed as
the raw bytes that arrived and decoded here by the same parser a live port uses, so a replay
exercises the real protocol code.

At recorded timing, a jump between consecutive timestamps of more than ``MAX_JUMP_S`` (either
way: a stamp from another clock, a corrupted one, a recording paused for long) is not waited
for: the replay's clock restarts at the frame after it, and the jump is counted in
``time_jumps``. Damaged parts of the session are skipped by the reader; ``error`` sums them up.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

from live.core.frames import MocapPacket
from live.core.protocols import StreamInfo
from live.core.timing import seconds_between
from live.io.session import SessionReader

#: Largest step between consecutive timestamps a timed replay waits for (seconds of recording).
MAX_JUMP_S = 5.0


class ReplaySource:
    """Source over a session file. ``speed``: 1.0 = recorded timing, 2.0 twice as fast,
    None = as fast as the pipeline takes frames. ``only``: kinds to replay (e.g. {"depth", "gt"})."""

    def __init__(self, path: str | Path, *, speed: float | None = None, only: set[str] | None = None,
                 name: str = "replay"):
        self.reader = SessionReader(path)
        self.path = self.reader.path
        self.name = name
        self.speed = speed
        self.only = only
        self._counters: dict[str, int] = {"frames": 0, "time_jumps": 0}
        self.error: str | None = None
        self._decoders: dict[str, object] = {}

    def streams(self) -> list[StreamInfo]:
        return [s for s in self.reader.info.streams if self.only is None or s.kind in self.only]

    @property
    def counters(self) -> dict[str, int]:
        out = dict(self._counters)
        for name, dec in self._decoders.items():
            for key, value in getattr(dec, "counters", {}).items():
                out[f"{name}.{key}"] = int(value)
        return out

    def _decode_serial(self, stream: StreamInfo, packet: MocapPacket) -> MocapPacket:
        protocol = stream.meta.get("protocol")
        if protocol is None:
            return packet
        from drivers.serial_source import make_parser, packet_from_records

        parser = self._decoders.get(stream.name)
        if parser is None:
            parser = self._decoders[stream.name] = make_parser(protocol)
        return packet_from_records(packet.t_ns, stream.name, packet.raw, parser.feed(packet.raw))

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        start_wall = start_t = last_t = None
        for stream, frame in self.reader.frames():
            if stop.is_set():
                break
            if self.only is not None and stream.kind not in self.only:
                continue
            if self.speed:
                t = frame.t_ns
                if start_wall is None or start_t is None or last_t is None:
                    start_wall, start_t = time.monotonic(), t
                elif abs(seconds_between(last_t, t)) > MAX_JUMP_S:
                    # Not waited for: the clock restarts here (the frame is due at once).
                    self._counters["time_jumps"] += 1
                    start_wall, start_t = start_wall + seconds_between(start_t, last_t) / self.speed, t
                last_t = t
                due = start_wall + seconds_between(start_t, t) / self.speed
                delay = due - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
            if stream.kind == "serial":
                frame = self._decode_serial(stream, frame)
            self._counters["frames"] += 1
            emit(frame)
        if self.reader.error:
            self.error = self.reader.error
            self._counters["damaged_regions"] = self.reader.damage_count
