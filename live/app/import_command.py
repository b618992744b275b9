"""``livecap import FORMAT PATH --out S.mcap``: a recorded suit into a session (live.imu.importing)."""

from __future__ import annotations


def cmd_import(args) -> int:
    from live.imu.importing import import_session

    report = import_session(args.format, list(args.path), args.out, layout=args.layout, pose=args.pose,
                            rate_hz=args.rate, stream=args.stream, height=args.height)
    print(f"livecap import: {report.format} {report.source}")
    for line in report.lines():
        print(f"  {line}")
    print(f"  replay it: livecap replay {args.out} --out DIR")
    return 0
