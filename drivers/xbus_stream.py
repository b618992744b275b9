"""The Xbus byte stream: ``XbusParser`` (bytes in, samples out, resynchronising on garbage, never
raising) and ``XbusConfigurator`` (a device put into measurement with the outputs we read). The
message and MTData2 codecs are in drivers/xbus.py."""

from __future__ import annotations

import struct
import time
from collections import deque
from collections.abc import Iterable
from typing import Any, Protocol

from drivers.plausibility import (
    XBUS_LIMITS,
    ContinuityFilter,
    ImplausibleSample,
    PlausibilityLimits,
    new_counters,
)
from drivers.xbus import (
    BID_MASTER,
    COORDS,
    FREQ_EVERY_PACKET,
    MAX_DATA_LEN,
    MID_DEVICE_ID,
    MID_ERROR,
    MID_GOTO_CONFIG,
    MID_GOTO_CONFIG_ACK,
    MID_GOTO_MEASUREMENT,
    MID_GOTO_MEASUREMENT_ACK,
    MID_MTDATA2,
    MID_REQ_DID,
    MID_RESET,
    MID_RESET_ACK,
    MID_SET_OUTPUT_CONFIGURATION,
    MID_SET_OUTPUT_CONFIGURATION_ACK,
    MID_WAKEUP,
    MID_WAKEUP_ACK,
    ORIENTATIONS,
    PRECISIONS,
    XDI_ACCELERATION,
    XDI_MAGNETIC_FIELD,
    XDI_PACKET_COUNTER,
    XDI_RATE_OF_TURN,
    XDI_SAMPLE_TIME_FINE,
    XbusMessage,
    XbusSample,
    decode_mtdata2,
    encode_message,
    output_configuration,
    parse_output_configuration,
)
from live.core.errors import DeviceError

# Non-data messages we accept, with their allowed payload lengths. A checksum-valid
# frame with another MID is most likely garbage that summed to zero, so the parser resyncs past
# its first byte instead of swallowing the bytes (which may hold real frames).
_KNOWN_MIDS: dict[int, Any] = {
    MID_REQ_DID: (0,), MID_DEVICE_ID: (4, 8), MID_GOTO_MEASUREMENT: (0,),
    MID_GOTO_MEASUREMENT_ACK: (0,), MID_GOTO_CONFIG: (0,), MID_GOTO_CONFIG_ACK: (0,),
    MID_WAKEUP: (0,), MID_WAKEUP_ACK: (0,), MID_RESET: (0,), MID_RESET_ACK: (0,),
    MID_ERROR: (1,), MID_SET_OUTPUT_CONFIGURATION: range(0, 257, 4),
    MID_SET_OUTPUT_CONFIGURATION_ACK: range(0, 257, 4),
}


class XbusParser:
    """Incremental Xbus decoder: ``feed(bytes) -> [XbusSample]``, never raises.

    Resynchronises on the 0xFA preamble after garbage; a frame that fails its checksum, length
    or content checks costs one byte of resync, so an intact frame right after garbage is still
    found. The internal buffer never holds more than one maximal frame between calls. Non-data
    messages go to ``messages`` (a bounded deque). Counts in ``counters``.

    plausibility: the checks of drivers/plausibility.py on every MTData2 sample (a NaN / inf
    value or a non-unit orientation costs one byte of resync like a bad payload; a counter,
    SampleTimeFine or turn rate that does not follow the sensor's previous sample drops the
    frame), counted by reason. None decodes whatever passes the checksum and the content checks.
    """

    def __init__(self, max_messages: int = 64, *,
                 plausibility: PlausibilityLimits | None = XBUS_LIMITS):
        self._buf = bytearray()
        self.messages: deque[XbusMessage] = deque(maxlen=max_messages)
        self.counters: dict[str, int] = {
            "frames": 0, "samples": 0, "bad_checksum": 0, "bad_length": 0, "bad_payload": 0,
            "unknown_mid": 0, "skipped_bytes": 0, "unknown_xdi": 0,
        }
        self.limits = plausibility
        self._continuity: ContinuityFilter | None = None
        if plausibility is not None:
            self.counters.update(new_counters())
            # Packet counter: u16; SampleTimeFine: u32 ticks of 100 us.
            self._continuity = ContinuityFilter(plausibility, self.counters, clock_hz=10_000.0,
                                                counter_modulus=1 << 16, clock_modulus=1 << 32)

    def feed(self, data: bytes) -> list[XbusSample]:
        buf = self._buf
        buf += data
        n = len(buf)
        c = self.counters
        continuity = self._continuity
        out: list[XbusSample] = []
        pos = 0
        while True:
            start = buf.find(0xFA, pos)
            if start < 0:
                c["skipped_bytes"] += n - pos
                pos = n
                break
            c["skipped_bytes"] += start - pos
            pos = start
            if n - start < 5:
                break
            length = buf[start + 3]
            head = 4
            if length == 0xFF:
                if n - start < 7:
                    break
                length = (buf[start + 4] << 8) | buf[start + 5]
                head = 6
                if length > MAX_DATA_LEN:
                    c["bad_length"] += 1
                    c["skipped_bytes"] += 1
                    pos = start + 1
                    continue
            end = start + head + length + 1
            if end > n:
                break
            if sum(buf[start + 1:end]) & 0xFF:
                c["bad_checksum"] += 1
                c["skipped_bytes"] += 1
                pos = start + 1
                continue
            mid = buf[start + 2]
            if mid == MID_MTDATA2:
                try:
                    sample = decode_mtdata2(bytes(buf[start + head:end - 1]), buf[start + 1], c,
                                            limits=self.limits)
                except ImplausibleSample as e:
                    c[e.reason] += 1
                    c["skipped_bytes"] += 1
                    pos = start + 1
                    continue
                except (ValueError, struct.error, OverflowError):
                    c["bad_payload"] += 1
                    c["skipped_bytes"] += 1
                    pos = start + 1
                    continue
                if continuity is None or continuity.accept(
                        sample.sensor, sample.counter, sample.sample_time_fine,
                        None if sample.quat is None else sample.quat.tolist()):
                    out.append(sample)
            else:
                allowed = _KNOWN_MIDS.get(mid)
                if allowed is None or length not in allowed:
                    c["unknown_mid"] += 1
                    c["skipped_bytes"] += 1
                    pos = start + 1
                    continue
                self.messages.append(XbusMessage(buf[start + 1], mid, bytes(buf[start + head:end - 1])))
            c["frames"] += 1
            pos = end
        del buf[:pos]
        c["samples"] += len(out)
        return out

    @property
    def buffered(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)


# ----------------------------------------------------------------------------- configuration


class SerialLike(Protocol):
    def write(self, data: bytes) -> int | None: ...
    def read(self, size: int = 1) -> bytes: ...


class XbusConfigurator:
    """Sends configuration commands to an Xsens device and waits for their acknowledgements.

    ``port`` is anything with ``write(bytes)`` and ``read(n)`` that returns after its own short
    timeout (a pyserial port opened with ``timeout=0.05``, say). Every command waits at most
    ``timeout`` seconds for MID + 1; an Error message (0x42) or the timeout raise DeviceError.
    """

    def __init__(self, port: SerialLike, *, timeout: float = 1.0, bid: int = BID_MASTER):
        self.port = port
        self.timeout = timeout
        self.bid = bid
        self.parser = XbusParser()

    def request(self, mid: int, data: bytes = b"") -> XbusMessage:
        """Send one command and return its acknowledgement."""
        self.parser.messages.clear()
        self.port.write(encode_message(self.bid, mid, data))
        deadline = time.monotonic() + self.timeout
        while True:
            while self.parser.messages:
                msg = self.parser.messages.popleft()
                if msg.mid == mid + 1:
                    return msg
                if msg.mid == MID_ERROR:
                    code = msg.data[0] if msg.data else -1
                    raise DeviceError(f"Xsens device refused message 0x{mid:02X} (error code {code})")
            if time.monotonic() > deadline:
                raise DeviceError(f"no acknowledgement for Xsens message 0x{mid:02X} "
                                  f"within {self.timeout:.2f} s")
            chunk = self.port.read(256)
            if chunk:
                self.parser.feed(chunk)  # data samples still streaming in are dropped here

    def go_to_config(self) -> None:
        self.request(MID_GOTO_CONFIG)

    def go_to_measurement(self) -> None:
        self.request(MID_GOTO_MEASUREMENT)

    def set_output_configuration(self, items: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
        """Send (XDI, frequency) pairs; returns the configuration the device acknowledged."""
        ack = self.request(MID_SET_OUTPUT_CONFIGURATION, output_configuration(items))
        return parse_output_configuration(ack.data)

    def configure(self, rate_hz: int = 100, *, orientation: str = "quat", precision: str = "float32",
                  coord: str = "enu", extras: Iterable[str] = ()) -> list[tuple[int, int]]:
        """GoToConfig, output orientation + packet counter + SampleTimeFine (+ extras among
        "acc", "gyro", "mag") at ``rate_hz``, then GoToMeasurement. Returns the acked config."""
        prec = PRECISIONS[precision]
        items = [(XDI_PACKET_COUNTER, FREQ_EVERY_PACKET), (XDI_SAMPLE_TIME_FINE, FREQ_EVERY_PACKET),
                 (ORIENTATIONS[orientation] | COORDS[coord] | prec, rate_hz)]
        extra_xdi = {"acc": XDI_ACCELERATION, "gyro": XDI_RATE_OF_TURN, "mag": XDI_MAGNETIC_FIELD}
        items += [(extra_xdi[name] | prec, rate_hz) for name in extras]
        self.go_to_config()
        acked = self.set_output_configuration(items)
        self.go_to_measurement()
        return acked
