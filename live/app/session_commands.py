"""``livecap export`` and ``livecap info``: what a recorded session holds."""

from __future__ import annotations

import json
import sys

from live.core.errors import UserInputError
from live.core.timing import seconds_between


def cmd_export(args) -> int:
    if args.foxglove is not None:
        from live.io.foxglove import export_foxglove

        res = export_foxglove(args.session, args.foxglove, results_dir=args.results, max_points=args.max_points)
        print(f"livecap export: {sum(res.messages.values())} Foxglove messages -> {res.path}")
        if res.skipped:
            print(f"  not exported (no Foxglove schema): {res.skipped}")
        if res.error:
            print(f"livecap export: {res.error}", file=sys.stderr)
        return 0
    if args.out is None:
        raise UserInputError("export needs --out DIR (npz files) or --foxglove OUT.mcap")
    from live.io.export import export_session

    written, damage = export_session(args.session, args.out)
    for p in written:
        print(p)
    if damage:
        print(f"livecap export: {damage}", file=sys.stderr)
    return 0


def cmd_info(args) -> int:
    from live.io.session import SessionReader

    reader = SessionReader(args.session)
    counts: dict[str, int] = {}
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for stream, frame in reader.frames():
        counts[stream.name] = counts.get(stream.name, 0) + 1
        first.setdefault(stream.name, frame.t_ns)
        last[stream.name] = frame.t_ns
    info = reader.info
    doc = {
        "path": str(args.session), "livecap_version": info.version, "start_wall_time_ns": info.start_wall_time_ns,
        "streams": [{"name": s.name, "kind": s.kind, "messages": counts.get(s.name, 0),
                     "duration_s": round(seconds_between(first.get(s.name, 0), last.get(s.name, 0)), 3), "meta": s.meta}
                    for s in info.streams],
        "extra": info.extra, "attachments": sorted(reader.attachments), "damage": reader.error,
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{args.session}: livecap {info.version or '?'} session")
    for s in doc["streams"]:
        print(f"  {s['kind']:<6} {s['name']:<12} {s['messages']:>7} messages  {s['duration_s']:8.2f} s")
    if doc["attachments"]:
        print(f"  attachments: {', '.join(doc['attachments'])}")
    if reader.error:
        print(f"  damaged: {reader.error}")
    return 0
