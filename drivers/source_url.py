"""Source strings -> SourceSpec: the one parser for every ``--source`` value.

Accepted forms (the ``kind`` of the resulting SourceSpec in brackets):

    oak | oak:<mxid|name>                     [oak]       target "" = first device found
    realsense | realsense:<serial>            [realsense]
    realsense-bag:FILE.bag                    [realsense-bag]
    serial:<port|URL>:<xbus|lines>[:baud]     [serial]    options {"protocol", "baud"?}
    replay:S.mcap | S.mcap                    [replay]
    FILE.bag                                  [realsense-bag]
    folder:DIR | DIR (an existing directory)  [folder]
    sim:CLIP.bvh[?body=NAME&k=v]              [sim]       options from the query string

The serial port may contain colons itself (``socket://host:1234``, ``rfc2217://host:2217``,
``COM3``), so a serial string is parsed from the right. ``open_camera_source`` turns an oak /
realsense / realsense-bag spec into a driver object; the other kinds belong to live/core/sources.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl

from live.core.errors import UserInputError

KINDS = ("oak", "realsense", "realsense-bag", "serial", "replay", "folder", "sim")
SERIAL_PROTOCOLS = ("xbus", "lines")
#: Highest accepted line rate (FTDI / CP210x USB-UARTs top out at 12 Mbaud).
MAX_BAUD = 16_000_000

ACCEPTED_FORMS = (
    "oak[:MXID|NAME], realsense[:SERIAL], realsense-bag:FILE.bag, "
    "serial:PORT|URL:xbus|lines[:BAUD], replay:S.mcap, folder:DIR, sim:CLIP.bvh[?body=NAME], "
    "or a path to a .mcap file or a depth folder"
)


@dataclass(frozen=True)
class SourceSpec:
    """A parsed source string. kind: one of KINDS; target: device id, port or path ("" = any
    device); options: extra settings (serial protocol/baud, sim query parameters)."""

    kind: str
    target: str = ""
    options: dict[str, Any] = field(default_factory=dict)

    def __str__(self) -> str:
        return format_source(self)


def _bad(text: str, why: str) -> UserInputError:
    return UserInputError(f"bad source {text!r}: {why}; accepted: {ACCEPTED_FORMS}")


def _parse_serial(text: str, rest: str) -> SourceSpec:
    # From the right: an optional all-digit baud, then the protocol; the rest is the port.
    parts = rest.rsplit(":", 2)
    baud: int | None = None
    if len(parts) == 3 and parts[2].isascii() and parts[2].isdigit():
        baud = int(parts[2])
        port, protocol = parts[0], parts[1]
    else:
        head, _, protocol = rest.rpartition(":")
        port = head
    if protocol not in SERIAL_PROTOCOLS:
        raise _bad(text, f"the serial protocol must be one of {'|'.join(SERIAL_PROTOCOLS)}")
    if not port:
        raise _bad(text, "the serial port is missing")
    if baud is not None and not 0 < baud <= MAX_BAUD:
        raise _bad(text, f"the baud rate must be 1 to {MAX_BAUD}")
    options: dict[str, Any] = {"protocol": protocol}
    if baud is not None:
        options["baud"] = baud
    return SourceSpec("serial", port, options)


def _parse_sim(text: str, rest: str) -> SourceSpec:
    path, _, query = rest.partition("?")
    if not path:
        raise _bad(text, "the clip path is missing")
    options: dict[str, Any] = {}
    if query:
        try:
            pairs = parse_qsl(query, keep_blank_values=False, strict_parsing=True)
        except ValueError:
            raise _bad(text, "the query must look like ?body=NAME&key=value") from None
        options = dict(pairs)
    return SourceSpec("sim", path, options)


def parse_source(text: str) -> SourceSpec:
    """Parse one source string (see the module docstring) into a SourceSpec.

    Raises UserInputError with one line naming the accepted forms when the string is not one.
    """
    text = str(text).strip()
    if not text:
        raise _bad(text, "empty")
    if text in ("oak", "realsense"):
        return SourceSpec(text, "")
    kind, sep, rest = text.partition(":")
    if sep and kind in KINDS:
        if kind == "serial":
            return _parse_serial(text, rest)
        if kind == "sim":
            return _parse_sim(text, rest)
        if not rest:
            raise _bad(text, f"nothing after '{kind}:'")
        if kind == "realsense-bag" and not rest.lower().endswith(".bag"):
            raise _bad(text, "a RealSense recording must be a .bag file")
        return SourceSpec(kind, rest)
    # A bare path: a session file or a depth folder (checked on disk, so typos fail here).
    if text.lower().endswith(".mcap"):
        return SourceSpec("replay", text)
    if text.lower().endswith(".bag"):
        return SourceSpec("realsense-bag", text)
    if Path(text).is_dir():
        return SourceSpec("folder", text)
    raise _bad(text, "unknown source kind")


def format_source(spec: SourceSpec) -> str:
    """The canonical source string of a SourceSpec (parse_source(format_source(s)) == s)."""
    if spec.kind in ("oak", "realsense") and not spec.target:
        return spec.kind
    if spec.kind == "serial":
        text = f"serial:{spec.target}:{spec.options['protocol']}"
        if "baud" in spec.options:
            text += f":{spec.options['baud']}"
        return text
    if spec.kind == "sim" and spec.options:
        query = "&".join(f"{k}={v}" for k, v in spec.options.items())
        return f"sim:{spec.target}?{query}"
    return f"{spec.kind}:{spec.target}"


def open_camera_source(spec: SourceSpec, **kwargs: Any):
    """An oak / realsense / realsense-bag SourceSpec -> its driver Source (opened lazily;
    a missing device raises DeviceNotFoundError here). kwargs go to the driver constructor."""
    if spec.kind == "oak":
        from drivers.oak import OakSource

        return OakSource(device_id=spec.target or None, **kwargs)
    if spec.kind == "realsense":
        from drivers.realsense import RealSenseSource

        return RealSenseSource(serial=spec.target or None, **kwargs)
    if spec.kind == "realsense-bag":
        from drivers.realsense import RealSenseBagSource

        return RealSenseBagSource(spec.target, **kwargs)
    raise UserInputError(f"{spec.kind!r} is not a camera source (expected oak, realsense or realsense-bag)")
