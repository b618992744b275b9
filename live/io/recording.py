"""What a recording went through: per-stream tallies, gaps in the data, the sources' state.

The session writer keeps a ``StreamTally`` per stream on its own clock (when each message
reached it), so a gap is measured the same way whatever clock the stream's timestamps use. A
gap is a silence longer than ``gap_threshold_s`` (1 s, or 4 of the stream's mean intervals for a
slow stream). Gaps and the sources' state are stored in the session as metadata records (see
live/io/session.py); at the end ``summarise`` says what went wrong, for ``livecap record``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

GAP_S = 1.0
GAP_INTERVALS = 4.0


@dataclass(frozen=True)
class Gap:
    """No message on ``stream`` for ``seconds`` (recorder clock) after the message stamped
    ``after_t_ns``; ``until_t_ns`` is the first message after it, None when none came."""

    stream: str
    after_t_ns: int
    seconds: float
    until_t_ns: int | None = None

    def as_meta(self) -> dict[str, str]:
        return {"stream": self.stream, "after_t_ns": str(self.after_t_ns), "seconds": f"{self.seconds:.3f}",
                "until_t_ns": "" if self.until_t_ns is None else str(self.until_t_ns)}

    @classmethod
    def from_meta(cls, meta: dict[str, str]) -> Gap:
        """ValueError / KeyError on a record that does not hold a gap."""
        until = meta["until_t_ns"]
        return cls(str(meta["stream"]), int(meta["after_t_ns"]), float(meta["seconds"]),
                   int(until) if until else None)

    def __str__(self) -> str:
        end = "never came back" if self.until_t_ns is None else "then resumed"
        return f"{self.stream}: no data for {self.seconds:.1f} s, {end}"


@dataclass
class StreamTally:
    """Counts of one stream as the recorder wrote it (``*_arrival_ns``: the recorder's monotonic clock)."""

    name: str
    kind: str
    messages: int = 0
    bytes: int = 0
    refused: int = 0  # frames over the codec's size limits, not written
    first_t_ns: int | None = None
    last_t_ns: int | None = None
    first_arrival_ns: int | None = None
    last_arrival_ns: int | None = None
    gaps: list[Gap] = field(default_factory=list)
    open_gap: Gap | None = None  # a silence already stored as an open gap record

    def gap_threshold_s(self) -> float:
        if self.messages < 2 or self.first_arrival_ns is None or self.last_arrival_ns is None:
            return GAP_S
        mean_s = (self.last_arrival_ns - self.first_arrival_ns) / 1e9 / (self.messages - 1)
        return max(GAP_S, GAP_INTERVALS * mean_s)

    def silence_s(self, now_ns: int) -> float:
        return 0.0 if self.last_arrival_ns is None else (now_ns - self.last_arrival_ns) / 1e9

    def arrived(self, t_ns: int, size: int, now_ns: int) -> Gap | None:
        """Count a message; returns the gap it ends, if it ends one."""
        gap = None
        if self.last_t_ns is not None and self.silence_s(now_ns) >= self.gap_threshold_s():
            gap = Gap(self.name, self.last_t_ns, self.silence_s(now_ns), t_ns)
            self.gaps.append(gap)
        self.open_gap = None
        if self.first_t_ns is None:
            self.first_t_ns, self.first_arrival_ns = t_ns, now_ns
        self.messages += 1
        self.bytes += size
        self.last_t_ns, self.last_arrival_ns = t_ns, now_ns
        return gap

    def open_gap_at(self, now_ns: int) -> Gap | None:
        """The silence so far as an open gap, when it is one and not stored yet."""
        if self.open_gap is not None or self.last_t_ns is None or self.silence_s(now_ns) < self.gap_threshold_s():
            return None
        self.open_gap = Gap(self.name, self.last_t_ns, self.silence_s(now_ns))
        return self.open_gap

    def as_dict(self) -> dict:
        seconds = 0.0 if self.first_t_ns is None or self.last_t_ns is None else (self.last_t_ns - self.first_t_ns) / 1e9
        return {"name": self.name, "kind": self.kind, "messages": self.messages, "bytes": self.bytes,
                "refused": self.refused, "seconds": round(seconds, 3),
                "gaps": [asdict(g) for g in self.gaps]}


@dataclass
class RecordingSummary:
    """The end of a recording: what each stream got, the sources' last state, and what went
    wrong. ``problems``: a source died or a stream ended silent (``record`` exits non-zero);
    ``warnings``: gaps it recovered from, frames refused."""

    path: str
    messages: int
    streams: list[dict]
    sources: dict[str, dict]
    problems: list[str]
    warnings: list[str]

    def as_dict(self) -> dict:
        return asdict(self)


def summarise(path: str, tallies: list[StreamTally], sources: dict[str, dict], end_ns: int) -> RecordingSummary:
    """Close the open gaps at ``end_ns`` and name what went wrong. ``sources``: per source its
    ``streams``, ``error`` (None), ``ended`` (its run returned), ``connected`` (None: unknown)
    and ``disconnects``."""
    problems: list[str] = []
    warnings: list[str] = []
    owner = {s: name for name, src in sources.items() for s in src.get("streams", [])}
    for name, src in sources.items():
        if src.get("error"):
            problems.append(f"source {name} stopped: {src['error']}")
        elif src.get("connected") is False:
            problems.append(f"source {name} was disconnected at the end ({src.get('disconnects', 0)} disconnects)")
        elif src.get("disconnects"):
            warnings.append(f"source {name} was disconnected {src['disconnects']} times and came back")
    for tally in tallies:
        src = sources.get(owner.get(tally.name, ""), {})
        finished = bool(src.get("ended")) and not src.get("error")
        if tally.messages == 0:
            if not finished:
                problems.append(f"{tally.name}: no data at all")
            continue
        silence = tally.silence_s(end_ns)
        if silence >= tally.gap_threshold_s():
            gap = Gap(tally.name, int(tally.last_t_ns or 0), silence)
            tally.gaps.append(gap)
            if not finished:  # a replay that ended is not a dead source
                problems.append(f"{gap} (of {tally.messages} messages)")
        for gap in tally.gaps:
            if gap.until_t_ns is not None:
                warnings.append(str(gap))
        if tally.refused:
            warnings.append(f"{tally.name}: {tally.refused} frames over the size limits were not recorded")
    return RecordingSummary(path, sum(t.messages for t in tallies), [t.as_dict() for t in tallies], sources,
                            problems, warnings)
