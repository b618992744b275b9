"""Plausibility checks on decoded IMU samples: the damage a checksum lets through.

Xbus frames carry an 8-bit sum and text lines an optional 8-bit XOR, so a few flipped bits
pass them now and then (two flips that cancel in the sum: a sign bit of a quaternion component
is a rotation up to 180 degrees away). These checks drop such samples and count them by reason:

* ``non_finite``: a NaN or infinite value (orientation, acc, gyro, mag);
* ``implausible_norm``: the orientation quaternion is further than ``norm_tolerance`` from unit
  length (devices send unit quaternions; a damaged mantissa or exponent moves the norm). Xbus
  devices send them to float precision (XBUS_LIMITS: 1e-3); text lines may be printed with a
  few decimals (LINE_LIMITS: 1e-2, what ``%.2f`` can still meet);
* ``counter_jump``: the packet counter of a sensor did not advance by 1..``max_counter_step``,
  or its device clock (Xbus SampleTimeFine, the text line's t_us) did not advance by a positive
  amount of at most ``max_clock_gap`` seconds (a damaged counter or clock, a duplicate, a reset),
  or a counter or clock the sensor sent before is missing (its item id was damaged);
* ``implausible_rate``: the orientation turned faster than ``max_rate`` rad/s since the
  sensor's previous sample, by its device clock (no body segment turns at 50 rad/s; a damaged
  sign bit does). Needs the device clock; samples without one skip this check.

The stateful checks (counter, clock, rate) compare a sample with the last accepted sample of the
same sensor. A real discontinuity (the device was reset, unplugged for long, or the clip of a
simulated suit looped) would otherwise lock a sensor out, so a rejected sample is kept as a
candidate: when the next sample is plausible against the candidate, though not against the last
accepted one, the sensor continues from the candidate (counted as ``reanchored``). Damage is
random, so two damaged samples in a row that agree with each other are vanishingly rare. The
first sample of a sensor has nothing to compare with and is accepted (a damaged sensor id shows
up as an id outside the suit layout, which the IMU stage ignores).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from live.core.errors import FormatError

REASONS = ("non_finite", "implausible_norm", "implausible_rate", "counter_jump")
#: Sensors whose state is kept; damaged ids beyond it evict the oldest entries (memory stays flat).
MAX_SENSORS = 4096


@dataclass(frozen=True)
class PlausibilityLimits:
    """What a plausible sample may do. norm_tolerance: |‖q‖ − 1|; max_rate: rad/s between two
    samples of a sensor; max_counter_step: packet counter increments; max_clock_gap: seconds."""

    norm_tolerance: float = 0.01
    max_rate: float = 50.0
    max_counter_step: int = 1000
    max_clock_gap: float = 5.0


#: Defaults of the two protocols.
XBUS_LIMITS = PlausibilityLimits(norm_tolerance=1e-3)
LINE_LIMITS = PlausibilityLimits(norm_tolerance=1e-2)


class ImplausibleSample(FormatError):
    """Raised by decoders for a sample that fails a stateless check; ``reason`` is in REASONS."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def all_finite(values) -> bool:
    """True when every float of ``values`` is finite (a few plain floats: cheaper than numpy)."""
    return all(map(math.isfinite, values))


def check_norm(norm: float, limits: PlausibilityLimits) -> None:
    """Raise ImplausibleSample unless a quaternion norm is within the tolerance of 1."""
    if not abs(norm - 1.0) <= limits.norm_tolerance:  # also true for NaN
        raise ImplausibleSample("implausible_norm", f"quaternion norm {norm:.6g} is not 1")


class _Track:
    """Last accepted state of one sensor (and the candidate rejected after it)."""

    __slots__ = ("counter", "clock", "quat", "quat_clock", "candidate")

    def __init__(self, counter, clock, quat):
        self.counter = counter
        self.clock = clock
        self.quat = quat
        self.quat_clock = clock if quat is not None else None
        self.candidate: _Track | None = None

    def advance(self, counter, clock, quat) -> None:
        self.counter = counter
        self.clock = clock
        if quat is not None:
            self.quat, self.quat_clock = quat, clock
        self.candidate = None


class ContinuityFilter:
    """Per-sensor counter, clock and angular-rate checks (see the module docstring).

    counter_modulus: the packet counter wraps there (Xbus: 2^16); clock_hz: device clock ticks
    per second; clock_modulus: the clock wraps there (Xbus SampleTimeFine: 2^32), or None for a
    clock that may be either 32-bit (Arduino ``micros()``, wrapping every 71.6 min) or 64-bit.
    """

    def __init__(self, limits: PlausibilityLimits, counters: dict[str, int], *, clock_hz: float,
                 counter_modulus: int = 1 << 16, clock_modulus: int | None = None):
        self.limits = limits
        self.counters = counters
        self.clock_hz = clock_hz
        self.counter_modulus = counter_modulus
        self.clock_modulus = clock_modulus
        self.max_clock_ticks = limits.max_clock_gap * clock_hz
        self._tracks: dict[int, _Track] = {}

    def accept(self, sensor: int, counter: int | None, clock: int | None, quat) -> bool:
        """True to keep the sample; False drops it (counted by reason). quat: unit (w, x, y, z)
        sequence or None."""
        track = self._tracks.get(sensor)
        if track is None:
            if len(self._tracks) >= MAX_SENSORS:
                del self._tracks[next(iter(self._tracks))]
            self._tracks[sensor] = _Track(counter, clock, quat)
            return True
        reason = self._judge(track, counter, clock, quat)
        if reason is None:
            track.advance(counter, clock, quat)
            return True
        candidate = track.candidate
        if candidate is not None and self._judge(candidate, counter, clock, quat) is None:
            candidate.advance(counter, clock, quat)
            self._tracks[sensor] = candidate
            self.counters["reanchored"] += 1
            return True
        self.counters[reason] += 1
        track.candidate = _Track(counter, clock, quat)
        return False

    def _clock_step(self, now: int, before: int) -> int:
        if self.clock_modulus is not None:
            return (now - before) % self.clock_modulus
        step = now - before
        if step < 0 and now < (1 << 32) and before < (1 << 32):
            step += 1 << 32  # a 32-bit microsecond clock wrapped
        return step

    def _judge(self, ref: _Track, counter, clock, quat) -> str | None:
        # A counter or clock the sensor sent before and not now: its item id was damaged (the
        # checks below would be skipped); a device reconfigured without it reanchors.
        if (counter is None and ref.counter is not None) or (clock is None and ref.clock is not None):
            return "counter_jump"
        if counter is not None and ref.counter is not None:
            if not 1 <= (counter - ref.counter) % self.counter_modulus <= self.limits.max_counter_step:
                return "counter_jump"
        if clock is None or ref.clock is None:
            return None
        if not 0 < self._clock_step(clock, ref.clock) <= self.max_clock_ticks:
            return "counter_jump"
        if quat is not None and ref.quat is not None and ref.quat_clock is not None:
            # Angle between the two orientations <= max_rate * dt, compared as cos(angle / 2).
            half = 0.5 * self.limits.max_rate * self._clock_step(clock, ref.quat_clock) / self.clock_hz
            if half < 0.5 * math.pi:
                r = ref.quat
                dot = abs(quat[0] * r[0] + quat[1] * r[1] + quat[2] * r[2] + quat[3] * r[3])
                if dot < math.cos(half):
                    return "implausible_rate"
        return None


def new_counters() -> dict[str, int]:
    """The counters the checks add to a parser's: one per reason, and ``reanchored``."""
    return dict.fromkeys((*REASONS, "reanchored"), 0)
