"""What is plugged in: OAK devices, RealSense cameras and serial ports (``livecap devices``).

Every probe is bounded by a timeout and never raises: a failing or hanging backend leaves its
list empty and a note in DeviceList.notes. Each entry carries the source string that opens it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)

#: USB vendor ids of known motion-capture hardware -> kind.
VENDOR_KINDS = {0x2639: "xsens"}


@dataclass(frozen=True)
class OakDevice:
    name: str  # USB path ("1.3") or IP address
    mxid: str
    state: str  # "unbooted", "bootloader", "booted" (in use by a process), ...
    protocol: str
    platform: str
    usb_speed: str | None = None  # only known once a device is opened

    @property
    def source(self) -> str:
        return f"oak:{self.mxid}"


@dataclass(frozen=True)
class RealSenseDevice:
    name: str
    serial: str

    @property
    def source(self) -> str:
        return f"realsense:{self.serial}"


@dataclass(frozen=True)
class SerialPort:
    device: str
    description: str
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    manufacturer: str | None = None
    kind: str = "serial"  # "xsens" for Xsens' USB vendor id, else "usb" or "serial"

    @property
    def source(self) -> str:
        protocol = "xbus" if self.kind == "xsens" else "lines"
        return f"serial:{self.device}:{protocol}"


@dataclass(frozen=True)
class DeviceList:
    oak: tuple[OakDevice, ...] = ()
    realsense: tuple[RealSenseDevice, ...] = ()
    serial: tuple[SerialPort, ...] = ()
    notes: tuple[str, ...] = field(default=())

    @property
    def empty(self) -> bool:
        return not (self.oak or self.realsense or self.serial)


def _enum_name(value: Any) -> str:
    name = getattr(value, "name", str(value))
    return name.removeprefix("X_LINK_").lower()


def oak_device_from_info(info: Any) -> OakDevice:
    """A dai.DeviceInfo -> OakDevice."""
    return OakDevice(name=str(info.name), mxid=str(info.getDeviceId()), state=_enum_name(info.state),
                     protocol=_enum_name(info.protocol), platform=_enum_name(info.platform))


def serial_port_from_info(port: Any) -> SerialPort:
    """A serial.tools.list_ports ListPortInfo -> SerialPort (Xsens flagged by vendor id)."""
    vid, pid = getattr(port, "vid", None), getattr(port, "pid", None)
    kind = VENDOR_KINDS.get(vid, "usb") if vid is not None else "serial"
    return SerialPort(device=str(port.device), description=str(port.description or ""), vid=vid, pid=pid,
                      serial_number=port.serial_number, manufacturer=port.manufacturer, kind=kind)


def _bounded(what: str, fn: Callable[[], list], timeout_s: float, notes: list[str]) -> list:
    """fn() run in a daemon thread; [] plus a note when it fails or outlasts timeout_s."""
    result: list = []
    error: list[BaseException] = []

    def target() -> None:
        try:
            result.extend(fn())
        except Exception as exc:  # a broken backend must not break the listing
            error.append(exc)

    t = threading.Thread(target=target, name=f"discover-{what}", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        notes.append(f"{what}: no answer within {timeout_s:g} s")
        return []
    if error:
        notes.append(f"{what}: {type(error[0]).__name__}: {error[0]}")
        return []
    return result


def _probe_oak() -> list[OakDevice]:
    import depthai as dai

    return [oak_device_from_info(i) for i in dai.Device.getAllConnectedDevices()]


def _probe_realsense() -> list[RealSenseDevice]:
    from drivers.realsense import list_realsense_devices

    return [RealSenseDevice(d["name"], d["serial"]) for d in list_realsense_devices()]


def _probe_serial() -> list[SerialPort]:
    from serial.tools import list_ports

    return [serial_port_from_info(p) for p in sorted(list_ports.comports(), key=lambda p: p.device)]


def list_devices(timeout_s: float = 3.0, *, oak: bool = True, realsense: bool = True, serial: bool = True) -> DeviceList:
    """Probe every enabled backend in parallel, each bounded by timeout_s."""
    probes = [("oak", oak, _probe_oak), ("realsense", realsense, _probe_realsense), ("serial", serial, _probe_serial)]
    found: dict[str, list] = {}
    notes: dict[str, list[str]] = {}
    threads = []
    for what, enabled, fn in probes:
        if not enabled:
            continue
        notes[what] = []

        def job(what=what, fn=fn) -> None:
            found[what] = _bounded(what, fn, timeout_s, notes[what])

        t = threading.Thread(target=job, name=f"discover-{what}-outer", daemon=True)
        t.start()
        threads.append(t)
    for t in threads:
        t.join(timeout_s + 1.0)
    return DeviceList(
        oak=tuple(found.get("oak", [])), realsense=tuple(found.get("realsense", [])),
        serial=tuple(found.get("serial", [])), notes=tuple(n for what in notes for n in notes[what]),
    )


def _usb_id(vid: int | None, pid: int | None) -> str:
    return "" if vid is None else f" [{vid:04x}:{pid or 0:04x}]"


def format_device_list(devices: DeviceList) -> str:
    """A human-readable listing, one device per line with the --source string that opens it."""
    lines = [f"OAK devices ({len(devices.oak)}):"]
    for d in devices.oak:
        speed = f", usb {d.usb_speed}" if d.usb_speed else ""
        lines.append(f"  {d.source:<28} {d.name} ({d.state}, {d.protocol}{speed})")
    lines.append(f"RealSense devices ({len(devices.realsense)}):")
    for r in devices.realsense:
        lines.append(f"  {r.source:<28} {r.name}")
    lines.append(f"Serial ports ({len(devices.serial)}):")
    for s in devices.serial:
        tag = " XSENS" if s.kind == "xsens" else ""
        lines.append(f"  {s.source:<28} {s.description}{_usb_id(s.vid, s.pid)}{tag}")
    for note in devices.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines)
