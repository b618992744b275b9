"""The Source protocol: anything that produces frames into the pipeline.

Drivers (OAK-D, RealSense, serial suits) and simulated backends (session replay, depth folders,
synthetic clips) all implement it, so live use and tests share one path. A source string names
one (``oak``, ``serial:/dev/ttyUSB0:xbus``, ``replay:S.mcap``, ``folder:DIR``, ``sim:clip.bvh``);
``open_source`` turns the string into an object.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, runtime_checkable

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


def open_source(text: str, *, speed: float | None = 1.0) -> Source:
    """A source object for a source string (see drivers.source_url for the accepted forms).

    ``speed`` applies to replayed sources (replay, folder, sim): 1.0 is recorded timing, None
    as fast as the pipeline takes frames.
    """
    from drivers.source_url import open_camera_source, parse_source

    spec = parse_source(text)
    if spec.kind in ("oak", "realsense", "realsense-bag"):
        return open_camera_source(spec)
    if spec.kind == "serial":
        from drivers.serial_source import SerialSource

        opts = spec.options
        kwargs = {"baud": int(opts["baud"])} if "baud" in opts else {}
        return SerialSource(spec.target, protocol=opts.get("protocol", "xbus"), **kwargs)
    if spec.kind == "replay":
        from sim.replay import ReplaySource

        return ReplaySource(spec.target, speed=speed)
    if spec.kind == "folder":
        from sim.depth_folder import DepthFolderSource

        return DepthFolderSource(spec.target, speed=speed)
    if spec.kind == "sim":
        from sim.synth import SimulatedSource

        return SimulatedSource.from_spec(spec.target, spec.options, speed=speed)
    from live.core.errors import UserInputError

    raise UserInputError(f"source kind {spec.kind!r} cannot be opened here")
