"""Frame timing helpers: the arithmetic every caller used before, bit for bit."""

from __future__ import annotations

import pytest

from live.core.timing import FrameClock, frame_interval_ns, frame_interval_s, frame_offset_ns, seconds_between

RATES = (30.0, 29.97, 25, 60.0, 100.0, 7.5, 1000 / 33)


@pytest.mark.parametrize("fps", RATES)
def test_same_arithmetic_as_written_out(fps):
    assert frame_interval_s(fps) == 1.0 / fps
    assert frame_interval_ns(fps) == int(round(1e9 / fps))
    for k in (0, 1, 2, 3, 299, 10_000, 123_457):
        assert frame_offset_ns(k, fps) == int(round(k * 1e9 / fps))
    t0 = 1_700_000_000_123_456_789
    for t in (t0, t0 + 33_333_333, t0 + frame_offset_ns(12345, fps), t0 - 7):
        assert seconds_between(t0, t) == (t - t0) / 1e9


def test_offsets_do_not_drift():
    """Rounded once per frame, so frame 30 000 at 30 fps is exactly 1000 s in."""
    assert frame_offset_ns(30_000, 30.0) == 1_000_000_000_000
    assert frame_interval_ns(30.0) == 33_333_333


def test_frame_clock():
    clock = FrameClock()
    assert clock.tick(100) is None  # the first frame
    assert clock.tick(100 + 33_333_333) == 33_333_333 / 1e9
    assert clock.tick(100 + 33_333_333) is None  # not after the previous one
    assert clock.tick(50) is None and clock.last_t_ns == 50
    clock.reset()
    assert clock.last_t_ns is None and clock.tick(10) is None
