"""Serial motion-capture transport: a Source that reads a port and emits MocapPackets.

Every read (whatever bytes arrived) becomes one ``live.core.frames.MocapPacket`` stamped with
time.monotonic_ns(): ``raw`` holds the bytes exactly as they arrived (what a session records)
and the arrays hold the records the protocol parser completed with them. Replaying recorded raw
chunks through ``decode_packet_bytes`` gives the same records. The port is opened with
``serial.serial_for_url``, so ``/dev/ttyUSB0``, ``loop://``, ``socket://host:port`` and
``rfc2217://host:port`` all work. The constructor opens the port, so a port that cannot be
opened (missing, not a serial device, a refused socket) is a DeviceError / DeviceNotFoundError
before anything runs. An I/O error after that (cable pulled, pty closed) is a gap: counted,
timed, and retried with bounded exponential backoff until the port comes back. Source strings
(``serial:/dev/ttyUSB0:xbus[:baud]``) are parsed by drivers/source_url.py.
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import serial

from drivers.source_url import MAX_BAUD
from drivers.text_lines import LineParser
from drivers.xbus_stream import XbusConfigurator, XbusParser
from live.core.errors import DeviceError, DeviceNotFoundError, UserInputError
from live.core.frames import MocapPacket
from live.core.protocols import StreamInfo

PROTOCOLS = ("xbus", "lines")
DEFAULT_BAUD = {"xbus": 115200, "lines": 115200}


def make_parser(protocol: str, **options) -> XbusParser | LineParser:
    """A fresh incremental parser for ``protocol`` ("xbus" | "lines")."""
    if protocol == "xbus":
        return XbusParser(**options)
    if protocol == "lines":
        return LineParser(**options)
    raise UserInputError(f"unknown serial protocol {protocol!r}; expected one of {PROTOCOLS}")


def _stack(values: list, width: int) -> np.ndarray | None:
    """Per-record optional vectors -> (S, width) float32 with NaN rows for missing ones."""
    if all(v is None for v in values):
        return None
    out = np.full((len(values), width), np.nan, dtype=np.float32)
    for i, v in enumerate(values):
        if v is not None:
            out[i] = v
    return out


def records_to_arrays(records: Sequence) -> dict[str, np.ndarray | None]:
    """XbusSample / LineSample records -> MocapPacket arrays.

    sensors (S,) int64; quats (S, 4) float32 (NaN where a record had no orientation); counter
    (S,) int64 (-1 where missing) or None; acc / gyro / mag (S, 3) float32 or None.
    """
    sensors = np.fromiter((r.sensor for r in records), dtype=np.int64, count=len(records))
    quats = _stack([r.quat for r in records], 4)
    if quats is None:
        quats = np.full((len(records), 4), np.nan, dtype=np.float32)
    counters = [r.counter for r in records]
    # An empty read still gets an (empty) counter array, so consumers can zip the fields.
    counter = None if counters and all(c is None for c in counters) else np.array(
        [-1 if c is None else c for c in counters], dtype=np.int64)
    return {"sensors": sensors, "quats": quats, "counter": counter,
            "acc": _stack([r.acc for r in records], 3), "gyro": _stack([r.gyro for r in records], 3),
            "mag": _stack([r.mag for r in records], 3)}


def packet_from_records(t_ns: int, device: str, raw: bytes, records: Sequence) -> MocapPacket:
    return MocapPacket(t_ns=t_ns, device=device, raw=raw, **records_to_arrays(records))


def decode_packet_bytes(raw_chunks: Iterable[bytes], protocol: str, *, t_ns: Iterable[int] | None = None,
                        device: str = "serial", **parser_options) -> list[MocapPacket]:
    """Replay: run recorded raw reads through a fresh parser, one MocapPacket per chunk.

    t_ns: the recorded stamps (one per chunk); defaults to 0, 1, 2, ...
    """
    parser = make_parser(protocol, **parser_options)
    stamps = iter(t_ns) if t_ns is not None else iter(range(1 << 62))
    return [packet_from_records(int(next(stamps)), device, bytes(raw), parser.feed(bytes(raw)))
            for raw in raw_chunks]


def _open_error(url: str, exc: BaseException) -> DeviceError:
    """One line for a port that would not open; DeviceNotFoundError when it does not exist."""
    text = " ".join(str(exc).split())
    if getattr(exc, "errno", None) == errno.ENOENT or "No such file" in text:
        return DeviceNotFoundError(f"serial port {url} not found")
    if "Inappropriate ioctl" in text:
        return DeviceError(f"cannot open serial port {url}: not a serial device")
    # pyserial nests the OS message: "could not open port X: [Errno 111] Connection refused"
    reason = text.rsplit("] ", 1)[-1] if "[Errno" in text else text
    return DeviceError(f"cannot open serial port {url}: {reason}")


class SerialSource:
    """Source over a serial port. ``run(emit, stop)`` blocks; ``start(emit)`` / ``stop()`` run it
    on one thread of its own.

    url: anything ``serial.serial_for_url`` opens; protocol: "xbus" | "lines"; name: stream
    name; baud: line rate (1 .. MAX_BAUD); xbus_config: keyword arguments of
    ``XbusConfigurator.configure`` sent on every (re)connect (Xbus only); parser_options: passed
    to the parser. The port is opened (and configured) here: DeviceNotFoundError when it does
    not exist, DeviceError when it cannot be opened or configured. ``close()`` (or leaving a
    ``with`` block) releases a port that was never run.
    """

    def __init__(self, url: str, protocol: str = "xbus", *, name: str = "serial", baud: int | None = None,
                 read_timeout: float = 0.05, backoff_start: float = 0.05, backoff_max: float = 1.0,
                 xbus_config: dict | None = None, parser_options: dict | None = None):
        self.parser = make_parser(protocol, **(parser_options or {}))
        if xbus_config is not None and protocol != "xbus":
            raise UserInputError("xbus_config only applies to the xbus protocol")
        self.url = url
        self.protocol = protocol
        self.name = name
        self.baud = baud if baud is not None else DEFAULT_BAUD[protocol]
        if isinstance(self.baud, bool) or not isinstance(self.baud, int) or not 0 < self.baud <= MAX_BAUD:
            raise UserInputError(f"baud rate {baud!r} out of range: 1 to {MAX_BAUD}")
        self.read_timeout = read_timeout
        self.backoff_start, self.backoff_max = backoff_start, backoff_max
        self.xbus_config = xbus_config
        #: (start_ns, end_ns or None while the gap lasts), one per lost connection.
        self.gaps: list[list[int | None]] = []
        self._counters = {"reads": 0, "bytes": 0, "records": 0, "gaps": 0, "open_failures": 0,
                          "connects": 0}
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self.error: BaseException | None = None
        #: Set while the port is open (cleared during a gap).
        self.connected = threading.Event()
        self._port = self._open()  # the first open: failing here is an error, not a gap

    def streams(self) -> list[StreamInfo]:
        return [StreamInfo(self.name, "serial",
                           meta={"protocol": self.protocol, "port": self.url, "baud": self.baud})]

    @property
    def counters(self) -> dict[str, int]:
        merged = dict(self.parser.counters)
        merged.update(self._counters)
        return merged

    # ------------------------------------------------------------------ port handling
    def _open(self):
        try:
            port = serial.serial_for_url(self.url, baudrate=self.baud, timeout=self.read_timeout)
        except (serial.SerialException, OSError, ValueError, OverflowError) as e:
            raise _open_error(self.url, e) from None
        try:
            if self.xbus_config is not None:
                XbusConfigurator(port, timeout=1.0).configure(**self.xbus_config)
        except BaseException:
            port.close()
            raise
        return port

    def _reconnect(self, stop: threading.Event):
        """Retry opening until it works (returns the port) or ``stop`` is set (returns None)."""
        backoff = self.backoff_start
        while not stop.wait(backoff):
            try:
                port = self._open()
            except DeviceError:
                self._counters["open_failures"] += 1
                backoff = min(2 * backoff, self.backoff_max)
                continue
            return port
        return None

    def close(self) -> None:
        """Release the port opened by the constructor when ``run`` never took it."""
        port, self._port = self._port, None
        if port is not None:
            port.close()

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        """Read until ``stop``, reconnecting after a gap. DeviceError only when the port cannot
        be opened at the start (a source run again after ``run`` returned opens it anew)."""
        port, self._port = self._port, None
        if port is None:
            port = self._open()
        try:
            while port is not None and not stop.is_set():
                self._counters["connects"] += 1
                self.connected.set()
                try:
                    self._read_loop(port, emit, stop)
                except OSError:  # SerialException is an OSError: unplugged, pty closed, ...
                    self.connected.clear()
                    self._counters["gaps"] += 1
                    self.gaps.append([time.monotonic_ns(), None])
                self.connected.clear()
                port.close()
                port = None
                if stop.is_set():
                    break
                port = self._reconnect(stop)
                if port is not None and self.gaps and self.gaps[-1][1] is None:
                    self.gaps[-1][1] = time.monotonic_ns()
        finally:
            self.connected.clear()
            if port is not None:
                port.close()

    def _read_loop(self, port, emit: Callable[[object], None], stop: threading.Event) -> None:
        c = self._counters
        while not stop.is_set():
            data = self._read_available(port)
            if not data:
                continue
            t_ns = time.monotonic_ns()
            records = self.parser.feed(data)
            c["reads"] += 1
            c["bytes"] += len(data)
            c["records"] += len(records)
            emit(packet_from_records(t_ns, self.name, data, records))

    def _read_available(self, port) -> bytes:
        """Wait up to read_timeout for a byte (so ``stop`` is seen promptly), then take every
        byte already there without waiting."""
        data = port.read(1)
        if not data:
            return data
        if isinstance(port, serial.Serial):  # a real or pty port: in_waiting is exact
            waiting = port.in_waiting
            return data + port.read(waiting) if waiting else data
        # URL handlers (socket://, loop://, rfc2217://) report in_waiting as a readiness flag or
        # a queue size: drain non-blockingly instead.
        port.timeout = 0
        try:
            return data + port.read(1 << 16)
        finally:
            port.timeout = self.read_timeout

    # ------------------------------------------------------------------ own thread
    def start(self, emit: Callable[[object], None]) -> threading.Thread:
        """Run on a background thread; a failure to open is kept in ``error``."""
        if self._thread is not None:
            raise RuntimeError("this SerialSource is already running")
        self._stop_event.clear()

        def target() -> None:
            try:
                self.run(emit, self._stop_event)
            except BaseException as e:  # handed to the owner through .error, not lost
                self.error = e

        self._thread = threading.Thread(target=target, name=f"serial-{self.name}", daemon=True)
        self._thread.start()
        return self._thread

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the background thread (returns within about read_timeout)."""
        self._stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def __enter__(self) -> SerialSource:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.close()
