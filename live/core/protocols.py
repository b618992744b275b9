"""The protocols that cross layers: Source (anything that produces frames), Stage (fills its part
of a FrameResult) and Sink (consumes results).

Drivers (OAK-D, RealSense, serial suits) and simulated backends (session replay, depth folders,
synthetic clips) all implement Source, so live use and tests share one path; the source registry
(live/app/sources.py) turns a source string into one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from live.core.frames import FrameResult

#: Stream kinds a source may emit.
STREAM_KINDS = ("depth", "serial", "imu", "gt")


@dataclass(frozen=True)
class StreamInfo:
    """What one stream of a source carries, known once the source is open.

    name: unique stream id within a session (``oak``, ``xsens0``); it names the export file
    (``depth_<name>.npz``, ``serial_<name>.npz``). kind: one of STREAM_KINDS.
    meta: JSON-serialisable details: for depth ``intrinsics`` (3x3 list), ``camera_to_world``
    (4x4 list), ``width``, ``height``, ``fps``; for serial ``protocol`` (xbus|lines), ``port``,
    ``baud``; for gt the ``body`` spec and ``motion`` name.
    """

    name: str
    kind: str
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in STREAM_KINDS:
            raise ValueError(f"unknown stream kind {self.kind!r}; expected one of {STREAM_KINDS}")


@runtime_checkable
class Source(Protocol):
    """A producer of DepthFrame / MocapPacket / GroundTruth objects.

    ``run`` blocks, calls ``emit(frame)`` for every frame, and returns when the stream ends or
    ``stop`` is set. Recoverable trouble (a USB gap, garbage bytes) is counted in ``counters``
    and never raised; only an unrecoverable DeviceError escapes.
    """

    name: str

    def streams(self) -> list[StreamInfo]: ...

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None: ...

    @property
    def counters(self) -> dict[str, int]: ...


class Stage(Protocol):
    """A pipeline stage. Optional: ``counters`` (event counts, reported in stats.json) and
    ``drain() -> list[FrameResult]``, called once the sources have ended: results the stage still
    holds (a lagging skeleton model's last frames), passed on like any frame's."""

    name: str

    def process(self, result: FrameResult) -> bool:
        """Fill this stage's part of ``result``; True when it produced output."""

    def observe(self, frame: object) -> None:
        """See a side frame (mocap packet, ground truth) in stream order."""


class Sink(Protocol):
    """A consumer of results; ``send`` never raises into the pipeline (it counts its own errors)."""

    def send(self, result: FrameResult) -> None: ...

    def close(self) -> None: ...
