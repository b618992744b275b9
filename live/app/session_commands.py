"""``livecap export`` and ``livecap info``: what a recorded session holds.

Both read around damage (live.io.session.SessionReader) and then exit with EXIT_DATA_LOSS and a
one-line summary on stderr when anything was skipped.
"""

from __future__ import annotations

import json
import sys

from live.app.running import EXIT_DATA_LOSS
from live.core.errors import UserInputError
from live.core.timing import seconds_between

#: Damaged regions ``info`` lists one per line (the JSON holds up to the reader's own limit).
_DAMAGE_LINES = 20


def _damage_exit(command: str, error: str | None) -> int:
    if error:
        print(f"livecap {command}: {error}", file=sys.stderr)
        return EXIT_DATA_LOSS
    return 0


def cmd_export(args) -> int:
    if args.foxglove is not None:
        from live.io.foxglove import export_foxglove

        res = export_foxglove(args.session, args.foxglove, results_dir=args.results, max_points=args.max_points)
        print(f"livecap export: {sum(res.messages.values())} Foxglove messages -> {res.path}")
        if res.skipped:
            print(f"  not exported (no Foxglove schema): {res.skipped}")
        return _damage_exit("export", res.error)
    if args.out is None:
        raise UserInputError("export needs --out DIR (npz files) or --foxglove OUT.mcap")
    from live.io.export import export_session

    written, damage = export_session(args.session, args.out)
    for p in written:
        print(p)
    return _damage_exit("export", damage)


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
    recording = info.recording
    doc = {
        "path": str(args.session), "livecap_version": info.version, "start_wall_time_ns": info.start_wall_time_ns,
        "finished": reader.finished,
        "streams": [{"name": s.name, "kind": s.kind, "messages": counts.get(s.name, 0),
                     "duration_s": round(seconds_between(first.get(s.name, 0), last.get(s.name, 0)), 3), "meta": s.meta}
                    for s in info.streams],
        "extra": info.extra, "attachments": sorted(reader.attachments),
        "recording": {"gaps": [str(g) for g in recording.gaps], "sources": recording.status,
                      "end": recording.end},
        "damaged_regions": reader.damage_count, "damage": [str(d) for d in reader.damage], "error": reader.error,
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return _damage_exit("info", reader.error)  # the JSON on stdout, the one line on stderr
    state = "" if reader.finished else (" (unfinished: its recorder never closed it; read to its last "
                                        "complete record)")
    print(f"{args.session}: livecap {info.version or '?'} session{state}")
    for s in doc["streams"]:
        print(f"  {s['kind']:<6} {s['name']:<12} {s['messages']:>7} messages  {s['duration_s']:8.2f} s")
    if doc["attachments"]:
        print(f"  attachments: {', '.join(doc['attachments'])}")
    for gap in recording.gaps:
        print(f"  gap: {gap}")
    for problem in (recording.end or {}).get("problems", []):
        print(f"  recording problem: {problem}")
    for d in reader.damage[:_DAMAGE_LINES]:
        print(f"  damaged: {d}")
    if len(reader.damage) > _DAMAGE_LINES:
        print(f"  damaged: ... {len(reader.damage) - _DAMAGE_LINES} more (--json lists them)")
    return _damage_exit("info", reader.error)
