"""Device discovery: conversions from the backends' own records, formatting, and a real probe
on this machine that must return (possibly empty lists) without raising or hanging."""

import threading

import pytest
from serial.tools.list_ports_common import ListPortInfo

from drivers.discovery import (
    DeviceList,
    OakDevice,
    RealSenseDevice,
    SerialPort,
    _bounded,
    format_device_list,
    list_devices,
    oak_device_from_info,
    serial_port_from_info,
)
from drivers.source_url import parse_source


def _port(device, vid=None, pid=None, description="n/a"):
    p = ListPortInfo(device, skip_link_detection=True)
    p.vid, p.pid, p.description = vid, pid, description
    p.serial_number = "D30A1B2C" if vid else None
    p.manufacturer = "Xsens" if vid == 0x2639 else None
    return p


def test_serial_ports_flag_xsens():
    xsens = serial_port_from_info(_port("/dev/ttyUSB0", 0x2639, 0x0301, "MTw2 Awinda Station"))
    ftdi = serial_port_from_info(_port("/dev/ttyUSB1", 0x0403, 0x6001, "FT232R USB UART"))
    uart = serial_port_from_info(_port("/dev/ttyS0"))
    assert (xsens.kind, ftdi.kind, uart.kind) == ("xsens", "usb", "serial")
    assert (xsens.vid, xsens.pid, xsens.manufacturer) == (0x2639, 0x0301, "Xsens")
    assert xsens.source == "serial:/dev/ttyUSB0:xbus" and ftdi.source == "serial:/dev/ttyUSB1:lines"
    assert parse_source(xsens.source).options == {"protocol": "xbus"}


def test_oak_device_from_depthai_info():
    dai = pytest.importorskip("depthai")
    info = dai.DeviceInfo("1.3", "18443010C1B2D41200", dai.XLinkDeviceState.X_LINK_UNBOOTED,
                          dai.XLinkProtocol.X_LINK_USB_VSC, dai.XLinkPlatform.X_LINK_MYRIAD_X,
                          dai.XLinkError_t.X_LINK_SUCCESS)
    d = oak_device_from_info(info)
    assert d == OakDevice(name="1.3", mxid="18443010C1B2D41200", state="unbooted", protocol="usb_vsc",
                          platform="myriad_x")
    assert parse_source(d.source).target == "18443010C1B2D41200"


def test_format_lists_every_device_with_its_source_string():
    devices = DeviceList(
        oak=(OakDevice("1.3", "18443010C1B2D41200", "unbooted", "usb_vsc", "myriad_x", usb_speed="SUPER"),),
        realsense=(RealSenseDevice("Intel RealSense D435", "213622078112"),),
        serial=(serial_port_from_info(_port("/dev/ttyUSB0", 0x2639, 0x0301, "MTw2 Awinda Station")),),
        notes=("oak: no answer within 3 s",),
    )
    text = format_device_list(devices)
    lines = text.splitlines()
    assert lines[0] == "OAK devices (1):"
    assert "oak:18443010C1B2D41200" in lines[1] and "usb SUPER" in lines[1]
    assert "realsense:213622078112" in text and "Intel RealSense D435" in text
    assert "serial:/dev/ttyUSB0:xbus" in text and "[2639:0301] XSENS" in text
    assert lines[-1] == "note: oak: no answer within 3 s"


def test_format_empty_list():
    text = format_device_list(DeviceList())
    assert text.splitlines() == ["OAK devices (0):", "RealSense devices (0):", "Serial ports (0):"]
    assert DeviceList().empty


def test_bounded_probe_reports_failures_and_hangs():
    notes = []
    assert _bounded("broken", lambda: 1 / 0, 1.0, notes) == []
    assert notes == ["broken: ZeroDivisionError: division by zero"]
    release = threading.Event()
    try:
        assert _bounded("stuck", lambda: [release.wait(30.0)], 0.05, notes) == []
    finally:
        release.set()
    assert notes[-1] == "stuck: no answer within 0.05 s"


def test_list_devices_on_this_machine():
    devices = list_devices(timeout_s=5.0)
    assert isinstance(devices, DeviceList)
    assert all(isinstance(d, OakDevice) for d in devices.oak)
    assert all(isinstance(d, RealSenseDevice) for d in devices.realsense)
    assert all(isinstance(p, SerialPort) for p in devices.serial)
    assert format_device_list(devices).startswith("OAK devices (")


def test_list_devices_can_skip_backends():
    devices = list_devices(timeout_s=5.0, oak=False, realsense=False)
    assert devices.oak == () and devices.realsense == ()
