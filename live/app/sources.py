"""The source registry: a source string (or a replay target) -> a driver or a simulator.

The only module that imports drivers and sim together. Strings are parsed by
drivers.source_url.parse_source (the accepted forms are listed there); ``replay TARGET`` and
``--source replay:S.mcap`` / ``--source folder:DIR`` open their sources through ``open_spec``.
"""

from __future__ import annotations

from pathlib import Path

from drivers.source_url import SourceSpec, open_camera_source, parse_source
from live.core.errors import UserInputError
from live.core.protocols import Source


def open_spec(spec: SourceSpec, *, speed: float | None = 1.0) -> Source:
    """A source object for a parsed source string. ``speed`` applies to replayed sources
    (replay, folder, sim): 1.0 is recorded timing, None as fast as the pipeline takes frames."""
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
    raise UserInputError(f"source kind {spec.kind!r} cannot be opened here")


def open_source(text: str, *, speed: float | None = 1.0) -> Source:
    """A source object for a source string such as ``oak``, ``serial:/dev/ttyUSB0:xbus``,
    ``replay:S.mcap``, ``folder:DIR`` or ``sim:clip.bvh``."""
    return open_spec(parse_source(text), speed=speed)


def replay_spec(target: str | Path) -> SourceSpec:
    """What ``livecap replay TARGET`` replays: a depth folder or a session file."""
    path = Path(target)
    if path.is_dir():
        return SourceSpec("folder", str(path))
    if not path.exists():
        raise UserInputError(f"no such session or folder: {path}")
    return SourceSpec("replay", str(path))


def open_replay(target: str | Path, *, speed: float | None = 1.0) -> Source:
    """The source of ``livecap replay TARGET`` (the same code as ``--source replay:`` / ``folder:``)."""
    return open_spec(replay_spec(target), speed=speed)
