"""Frame timing: intervals and timestamps from a frame rate, seconds between nanosecond stamps.

One place for the arithmetic so that every caller rounds the same way (timestamps of a
synthetic session, the interval a retargeter assumes, a replay's pacing). Timestamps are int
nanoseconds; intervals in seconds are floats.
"""

from __future__ import annotations


def frame_interval_s(fps: float) -> float:
    """Seconds between two frames at ``fps``."""
    return 1.0 / fps


def frame_interval_ns(fps: float) -> int:
    """Nanoseconds between two frames at ``fps``, rounded to the nearest one."""
    return int(round(1e9 / fps))


def frame_offset_ns(k: int, fps: float) -> int:
    """Nanoseconds from frame 0 to frame ``k`` at ``fps`` (rounded once, so no drift over a clip)."""
    return int(round(k * 1e9 / fps))


def seconds_between(t0_ns: int, t1_ns: int) -> float:
    """Seconds from timestamp ``t0_ns`` to ``t1_ns`` (negative when t1 is earlier)."""
    return (t1_ns - t0_ns) / 1e9


class FrameClock:
    """The interval since the previous frame, from frame timestamps: None for the first frame and
    for a frame not after the previous one (then the caller assumes its nominal frame rate)."""

    def __init__(self) -> None:
        self.last_t_ns: int | None = None

    def reset(self) -> None:
        self.last_t_ns = None

    def tick(self, t_ns: int) -> float | None:
        """Seconds since the previous frame's ``t_ns`` (or None); ``t_ns`` becomes the previous."""
        dt = None
        if self.last_t_ns is not None and t_ns > self.last_t_ns:
            dt = seconds_between(self.last_t_ns, t_ns)
        self.last_t_ns = t_ns
        return dt
