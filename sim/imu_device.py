"""A simulated IMU suit on a pseudo-terminal: open ``suit.port`` with pyserial like a real one.

The suit streams the orientations of its sensors (sim.imu_model) for a motion, either as Xsens
MTData2 frames (one bus id per sensor, or BID 0xFF plus a DeviceId item per sensor, like an
Awinda station) or as text lines (drivers.text_lines). In Xbus mode it also answers GoToConfig,
SetOutputConfiguration, GoToMeasurement and ReqDID like an MTi. ``close()`` / ``reopen()``
unplug and replug it: ``port`` is a symlink that disappears while unplugged and then points to
a fresh pty. ``truth()`` returns exactly what was sent, for tests.
"""

from __future__ import annotations

import os
import select
import struct
import tempfile
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers import xbus, xbus_stream
from drivers.text_lines import encode_line
from live.imu.layout import load_suit_layout
from sim.imu_model import ImuNoise, ImuTrack, random_mounting, simulate_imus

PROTOCOLS = ("xbus", "lines")
DEVICE_ID_BASE = 0x00B40000  # Awinda-style tracker ids: base + sensor id


@dataclass(frozen=True)
class SentTruth:
    """Every record the suit wrote, in order. N records.

    step (N,) sample index; sensor (N,) id as decoded (BID or DeviceId for Xbus, the line's
    sensor field); counter (N,) what decoding yields as MocapPacket.counter (the 16-bit packet
    counter for Xbus, t_us for lines); quat (N, 4) world quaternion handed to the encoder;
    intact (N,) False when the record's bytes were corrupted or partly dropped.
    """

    step: np.ndarray
    sensor: np.ndarray
    counter: np.ndarray
    quat: np.ndarray
    intact: np.ndarray


class SimulatedSuit:
    """Streams a motion's IMU orientations on a pty; a context manager (see module doc).

    protocol: "xbus" | "lines"; rate_hz: samples per second per sensor; layout: a layout file
    path or {sensor id: joint index} (default: drivers/layouts/full_body.json); mounting_seed:
    seed of the random sensor-to-segment rotations (None: identity); realtime: pace at rate_hz
    (False: as fast as the reader takes the bytes); loop: restart the clip at its end;
    corrupt_prob / drop_prob: per-record probability of one flipped byte / a dropped byte span;
    xbus_addressing: "bid" (BID = sensor id) or "device_id" (BID 0xFF + DeviceId item);
    orientation / precision / coord: initial MTData2 output (changeable by
    SetOutputConfiguration); extras: extra outputs among "acc", "gyro", "mag"; line_format:
    "csv" | "json"; line_checksum: append ``*HH`` to lines; paused: start silent until
    ``resume()`` (pyserial flushes what arrived before it opened the port, so a test that wants
    every record resumes once its reader is connected).
    """

    def __init__(self, motion, protocol: str = "xbus", rate_hz: float = 100.0, *,
                 layout: str | Path | dict[int, int] | None = None, mounting_seed: int | None = 0,
                 noise: ImuNoise = ImuNoise(), corrupt_prob: float = 0.0, drop_prob: float = 0.0,
                 seed: int = 0, realtime: bool = True, loop: bool = True,
                 xbus_addressing: str = "bid", orientation: str = "quat",
                 precision: str = "float32", coord: str = "enu", extras: tuple[str, ...] = (),
                 line_format: str = "csv", line_checksum: bool = True, paused: bool = False,
                 max_truth: int = 1_000_000):
        if protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
        if xbus_addressing not in ("bid", "device_id"):
            raise ValueError("xbus_addressing is 'bid' or 'device_id'")
        layout_map = layout if isinstance(layout, dict) else load_suit_layout(layout).as_dict()
        mounting = random_mounting(len(layout_map), mounting_seed)
        self.track: ImuTrack = simulate_imus(motion, layout_map, mounting=mounting, noise=noise, seed=seed)
        self.protocol = protocol
        self.rate_hz = float(rate_hz)
        self.realtime = realtime
        self.loop = loop
        self.corrupt_prob = corrupt_prob
        self.drop_prob = drop_prob
        self.xbus_addressing = xbus_addressing
        self.orientation, self.precision, self.coord = orientation, precision, coord
        self.extras = tuple(extras)
        self.line_format, self.line_checksum = line_format, line_checksum
        self._rng = np.random.default_rng(seed + 1)
        self._truth: deque = deque(maxlen=max_truth)
        self._truth_lock = threading.Lock()
        self._step = 0
        self._config_mode = False
        self._paused = paused
        self.counters: dict[str, int] = {"steps": 0, "records": 0, "bytes": 0, "commands": 0,
                                          "late_resets": 0}
        self.finished = threading.Event()
        self._dir = tempfile.mkdtemp(prefix="livecap-suit-")
        self.port = os.path.join(self._dir, "ttyIMU")
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._fds: tuple[int, int] | None = None
        self.reopen()

    # ------------------------------------------------------------------ lifecycle
    def reopen(self) -> None:
        """Plug the suit in: a fresh pty behind ``port`` and a streaming thread."""
        if self._thread is not None:
            return
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation: a byte pipe like a real UART
        os.set_blocking(master, False)
        self._fds = (master, slave)
        tmp = self.port + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="sim-imu-suit", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Unplug: stop streaming, close the pty (readers get an I/O error), remove ``port``."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        if os.path.lexists(self.port):
            os.unlink(self.port)
        for fd in self._fds or ():
            os.close(fd)
        self._fds = None

    def shutdown(self) -> None:
        """Close for good and remove the temporary directory."""
        self.close()
        if os.path.isdir(self._dir):
            os.rmdir(self._dir)

    def __enter__(self) -> SimulatedSuit:
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()

    def pause(self) -> None:
        """Stop sending samples (commands are still answered)."""
        self._paused = True

    def resume(self) -> None:
        self._paused = False

    @property
    def connected(self) -> bool:
        return self._thread is not None

    def truth(self) -> SentTruth:
        with self._truth_lock:
            rows = list(self._truth)
        if not rows:
            return SentTruth(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                             np.zeros((0, 4)), np.zeros(0, bool))
        step, sensor, counter, quat, intact = zip(*rows)
        return SentTruth(np.array(step), np.array(sensor), np.array(counter), np.array(quat),
                         np.array(intact, dtype=bool))

    @property
    def total_steps(self) -> int:
        """Samples in one pass of the clip at rate_hz."""
        upper = int(np.ceil(self.track.frames * self.rate_hz / self.track.fps)) + 2
        return int(np.count_nonzero(self.frame_of_step(np.arange(upper)) < self.track.frames))

    def frame_of_step(self, step):
        """Motion frame sent at sample ``step`` (nearest frame; works on arrays too)."""
        return np.rint(np.asarray(step) * self.track.fps / self.rate_hz).astype(np.int64)

    # ------------------------------------------------------------------ streaming thread
    def _serve(self) -> None:
        master = self._fds[0]
        parser = xbus_stream.XbusParser()
        out = bytearray()
        next_due = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            streaming = not (self._config_mode or self._paused or self.finished.is_set())
            if not out and streaming and (not self.realtime or now >= next_due):
                out += self._make_step()
                if self.realtime:
                    next_due += 1.0 / self.rate_hz
                    if now - next_due > 0.5:  # the reader stalled us: do not burst to catch up
                        next_due = now
                        self.counters["late_resets"] += 1
            wait = 0.05
            if not out and streaming and self.realtime:
                wait = min(wait, max(0.0, next_due - time.monotonic()))
            readable, writable, _ = select.select([master], [master] if out else [], [], wait)
            if readable:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:  # no reader on the slave side yet; nothing to answer
                    data = b""
                if data and self.protocol == "xbus":
                    parser.feed(data)
                    while parser.messages:
                        out += self._answer(parser.messages.popleft())
            if writable and out:
                try:
                    n = os.write(master, out)
                except BlockingIOError:
                    n = 0
                del out[:n]
                self.counters["bytes"] += n

    def _make_step(self) -> bytes:
        track = self.track
        step = self._step
        frame = int(self.frame_of_step(step))
        if frame >= track.frames:
            if not self.loop:
                self.finished.set()
                return b""
            frame %= track.frames
        t_s = step / self.rate_hz
        chunks = []
        rows = []
        for s, sensor in enumerate(track.sensors):
            sensor = int(sensor)
            q = track.quats[frame, s]
            extra = {k: getattr(track, k)[frame, s] for k in self.extras}
            if self.protocol == "xbus":
                dev_id = DEVICE_ID_BASE + sensor if self.xbus_addressing == "device_id" else None
                payload = xbus.encode_mtdata2(
                    quat=q, counter=step, sample_time_fine=int(t_s * 10000), device_id=dev_id,
                    orientation=self.orientation, precision=self.precision, coord=self.coord, **extra)
                bid = sensor if dev_id is None else xbus.BID_MASTER
                msg = xbus.encode_message(bid, xbus.MID_MTDATA2, payload)
                key_sensor, counter = (dev_id if dev_id is not None else sensor), step & 0xFFFF
            else:
                t_us = int(round(t_s * 1e6))
                fmt_extra = extra if self.line_format == "json" else {
                    k: v for k, v in extra.items() if k in ("acc", "gyro") and "acc" in extra}
                msg = encode_line(sensor, t_us, q, fmt=self.line_format, checksum=self.line_checksum,
                                  **fmt_extra)
                key_sensor, counter = sensor, t_us
            msg, intact = self._damage(msg)
            chunks.append(msg)
            rows.append((step, key_sensor, counter, tuple(q), intact))
        with self._truth_lock:
            self._truth.extend(rows)
        self._step += 1
        self.counters["steps"] += 1
        self.counters["records"] += len(rows)
        return b"".join(chunks)

    def _damage(self, msg: bytes) -> tuple[bytes, bool]:
        """Flip one byte and/or drop a span, as a noisy cable would. Text lines keep their final
        newline so that damage stays within one record."""
        rng = self._rng
        intact = True
        body_len = len(msg) - 1 if self.protocol == "lines" else len(msg)
        if self.corrupt_prob > 0 and rng.random() < self.corrupt_prob:
            b = bytearray(msg)
            i = int(rng.integers(body_len))
            flip = int(rng.integers(1, 256))
            if self.protocol == "lines" and (b[i] ^ flip) == 0x0A:
                flip ^= 0x01
            b[i] ^= flip
            msg, intact = bytes(b), False
        if self.drop_prob > 0 and rng.random() < self.drop_prob:
            i = int(rng.integers(body_len))
            j = int(rng.integers(i + 1, body_len + 1))
            msg, intact = msg[:i] + msg[j:], False
        return msg, intact

    def _answer(self, msg: xbus.XbusMessage) -> bytes:
        """The reply of an MTi to one command."""
        self.counters["commands"] += 1
        bid = xbus.BID_MASTER

        def error(code: int) -> bytes:
            return xbus.encode_message(bid, xbus.MID_ERROR, bytes((code,)))

        if msg.mid == xbus.MID_GOTO_CONFIG:
            self._config_mode = True
            return xbus.encode_message(bid, xbus.MID_GOTO_CONFIG_ACK)
        if msg.mid == xbus.MID_GOTO_MEASUREMENT:
            self._config_mode = False
            return xbus.encode_message(bid, xbus.MID_GOTO_MEASUREMENT_ACK)
        if msg.mid == xbus.MID_REQ_DID:
            return xbus.encode_message(bid, xbus.MID_DEVICE_ID, struct.pack(">I", DEVICE_ID_BASE))
        if msg.mid == xbus.MID_SET_OUTPUT_CONFIGURATION:
            if not self._config_mode:
                return error(xbus.ERR_INVALID_MESSAGE)
            try:
                self._apply_output_configuration(xbus.parse_output_configuration(msg.data))
            except ValueError:
                return error(xbus.ERR_INVALID_PARAMETER)
            return xbus.encode_message(bid, xbus.MID_SET_OUTPUT_CONFIGURATION_ACK, msg.data)
        return error(xbus.ERR_INVALID_MESSAGE)

    def _apply_output_configuration(self, items: list[tuple[int, int]]) -> None:
        kinds = {v: k for k, v in xbus.ORIENTATIONS.items()}
        precs = {v: k for k, v in xbus.PRECISIONS.items()}
        coords = {v: k for k, v in xbus.COORDS.items()}
        extras_xdi = {xbus.XDI_ACCELERATION: "acc", xbus.XDI_RATE_OF_TURN: "gyro",
                      xbus.XDI_MAGNETIC_FIELD: "mag"}
        orient = None
        extras = []
        for xdi, freq in items:
            kind = xdi & xbus.XDI_TYPE_MASK
            if kind in kinds:
                if not 0 < freq <= 1000:
                    raise ValueError(f"unsupported output rate {freq}")
                orient = (kinds[kind], precs[xdi & 0x3], coords.get(xdi & 0xC), freq)
            elif kind in extras_xdi:
                extras.append(extras_xdi[kind])
        if orient is None or orient[2] is None:
            raise ValueError("the configuration has no orientation output")
        self.orientation, self.precision, self.coord, rate = orient
        self.rate_hz = float(rate)
        self.extras = tuple(extras)
