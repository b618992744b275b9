"""``livecap devices`` and ``livecap calibrate``: the hardware attached to this machine."""

from __future__ import annotations

import sys

from live.app.sources import open_source
from live.core.errors import UserInputError


def cmd_devices(args) -> int:
    from drivers.discovery import format_device_list, list_devices

    print(format_device_list(list_devices()))
    return 0


def cmd_calibrate(args) -> int:
    import threading

    from live.core.skeleton import default_rest_joints
    from live.imu.calibration import CalibrationCollector
    from live.imu.layout import load_suit_layout

    layout = load_suit_layout(args.layout)  # a bad layout file is reported before the port is opened
    source = open_source(args.source)
    collector = CalibrationCollector(layout, args.pose, default_rest_joints(args.height), hold_s=2.0)
    stop = threading.Event()
    found = []

    def emit(packet) -> None:
        if getattr(packet, "decoded", False) and not found:
            cal = collector.feed(packet)
            if cal is not None:
                found.append(cal)
                stop.set()

    print(f"livecap calibrate: hold a {args.pose} still for 2 s ...", file=sys.stderr)
    timer = threading.Timer(args.timeout, stop.set)
    timer.daemon = True
    timer.start()
    try:
        source.run(emit, stop)
    finally:
        timer.cancel()
    if not found:
        raise UserInputError(f"no still {args.pose} held for 2 s within {args.timeout:g} s")
    found[0].save(args.out)
    print(f"livecap calibrate: saved {args.out}")
    return 0
