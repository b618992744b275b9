"""Gravity from a camera's own accelerometer: which way is up, in the camera's axes.

An accelerometer measures specific force: at rest it reads +g along the axis that points up
(the push of whatever holds it against gravity), so world up is the direction of the mean
reading while the sensor is still. ``GravityEstimator`` is fed samples in the camera's axes
(OpenCV: +x right, +y down, +z forward), finds still periods and averages over them:

- a sliding window (``window_s``) is still when the mean reading's magnitude is within
  ``norm_tolerance`` of g, the readings hardly vary (``acc_std``: root of the summed per-axis
  variances) and no sample in it moved: none turned faster than ``gyro_rate`` (when a gyroscope
  is given) or read a magnitude more than twice ``norm_tolerance`` away from g;
- the samples of a still period are averaged; a period whose up differs from the one in use by
  more than ``change_deg`` replaces it (the camera was moved: ``moves`` counts it), one that
  agrees refines it (the average goes on over both);
- a slow turn that keeps every window still is still a move: when the window's up drifts more
  than ``drift_deg`` from the period's, a new period begins there (and nothing of the turning
  one is merged into it).

``up_in_camera()`` is None until a still period was seen. Pure numpy, no I/O; the same samples
give the same estimate.

A camera's own IMU streams as ``<camera stream>_imu`` (the OAK driver, the virtual camera of
``livecap synth --camera-imu``): decoded samples of one sensor, acc in the camera's axes, no raw
bytes (an IMU suit's packets always carry the bytes they were parsed from).
``camera_imu_sample(frame)`` recognises such a packet.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from live.core.frames import MocapPacket
from live.core.rotations import angle_deg

STANDARD_GRAVITY = 9.80665
#: The stream name of a camera's own IMU is the camera stream's name plus this.
CAMERA_IMU_SUFFIX = "_imu"


@dataclass(frozen=True)
class GravityConfig:
    """Stillness tests and the change threshold (m/s^2, rad/s, seconds, degrees)."""

    g: float = STANDARD_GRAVITY
    norm_tolerance: float = 0.3
    acc_std: float = 0.25
    gyro_rate: float = 0.06
    window_s: float = 0.5
    change_deg: float = 3.0
    # A still period whose latest window turned this far from its mean is a slow turn: it restarts.
    drift_deg: float = 1.0
    # A gap longer than this in the samples ends a still period: the camera may have moved unseen.
    max_gap_s: float = 0.25


def camera_imu_sample(frame: object) -> tuple[int, np.ndarray, np.ndarray | None] | None:
    """(t_ns, acc (3,), gyro (3,) or None) when ``frame`` is a sample of a camera's own IMU
    (module docstring), else None."""
    if (not isinstance(frame, MocapPacket) or frame.raw or frame.acc is None
            or not frame.device.endswith(CAMERA_IMU_SUFFIX) or np.shape(frame.acc) != (1, 3)):
        return None
    gyro = None if frame.gyro is None or np.shape(frame.gyro) != (1, 3) else frame.gyro[0]
    return int(frame.t_ns), frame.acc[0], gyro


class GravityEstimator:
    """World up in the camera's axes from accelerometer (and gyroscope) samples; see the module
    docstring. Counters: ``samples`` fed, ``rejected`` (non-finite or malformed), ``still_samples``
    (averaged into an up), ``updates`` (an up adopted: the first one and every move), ``moves``."""

    def __init__(self, config: GravityConfig | None = None):
        self.config = config or GravityConfig()
        self._window_ns = int(round(self.config.window_s * 1e9))
        self._gap_ns = int(round(self.config.max_gap_s * 1e9))
        self.samples = 0
        self.rejected = 0
        self.still_samples = 0
        self.updates = 0
        self.moves = 0
        self._up: np.ndarray | None = None  # unit, in use
        self._up_sum = np.zeros(3)  # sum of the readings behind the up in use
        self._reset_window()
        self._period_sum: np.ndarray | None = None  # sum of the readings of the still period under way
        self._period_n = 0
        self._base_sum = np.zeros(3)  # what the period adds to: the agreeing up before it, or nothing
        self._period_counted = False  # the period already decided whether it moves the up
        self._anchor: np.ndarray | None = None  # the up as of the last update (moves are counted from it)
        self._drifted = False  # the last period ended turning: nothing of it is merged into the next
        self._last_t: int | None = None

    # -- the sliding window ----------------------------------------------------------------
    def _reset_window(self) -> None:
        self._win: deque[tuple[int, np.ndarray]] = deque()
        self._acc_sum = np.zeros(3)
        self._acc_sq = np.zeros(3)
        self._win_start: int | None = None  # first sample since the window was last reset
        self._last_loud: int | None = None  # the last sample that moved (turning, or a jolt)

    def _push(self, t_ns: int, acc: np.ndarray) -> None:
        self._win.append((t_ns, acc))
        self._acc_sum += acc
        self._acc_sq += acc * acc
        if self._win_start is None:
            self._win_start = t_ns
        while self._win[0][0] < t_ns - self._window_ns:
            _, a = self._win.popleft()
            self._acc_sum -= a
            self._acc_sq -= a * a

    def _window_still(self, t_ns: int) -> np.ndarray | None:
        """The window's mean reading when the window spans window_s and is still, else None."""
        c = self.config
        if self._win_start is None or t_ns - self._win_start < self._window_ns:
            return None
        if self._last_loud is not None and self._last_loud >= t_ns - self._window_ns:
            return None
        n = len(self._win)
        mean = self._acc_sum / n
        var = np.maximum(self._acc_sq / n - mean * mean, 0.0)
        if abs(math.sqrt(float(mean @ mean)) - c.g) > c.norm_tolerance:
            return None
        if math.sqrt(float(var.sum())) > c.acc_std:
            return None
        return mean

    # -- feeding -----------------------------------------------------------------------------
    def add(self, t_ns: int, acc: np.ndarray, gyro: np.ndarray | None = None) -> None:
        """One sample: t_ns (int ns), acc (3,) m/s^2 and gyro (3,) rad/s or None, camera axes.
        Samples must come in time order; one earlier than the last starts the window anew."""
        self.samples += 1
        a = np.asarray(acc, np.float64).reshape(-1)
        g = None if gyro is None else np.asarray(gyro, np.float64).reshape(-1)
        if a.shape != (3,) or not np.isfinite(a).all() or (g is not None and (g.shape != (3,) or
                                                                             not np.isfinite(g).all())):
            self.rejected += 1
            return
        t = int(t_ns)
        if self._last_t is not None and (t < self._last_t or t - self._last_t > self._gap_ns):
            self._reset_window()
            self._end_period()
        self._last_t = t
        # One sample that turns or jolts ends a still period at once (window means react slowly).
        c = self.config
        turning = g is not None and float(g @ g) > c.gyro_rate * c.gyro_rate
        if turning or abs(math.sqrt(float(a @ a)) - c.g) > 2 * c.norm_tolerance:
            self._last_loud = t
        self._push(t, a)
        mean = self._window_still(t)
        if mean is None:
            self._end_period()
            return
        if self._period_sum is not None and angle_deg(mean, self._period_sum) > self.config.drift_deg:
            # Still by every test, yet turned: a slow move. A new period starts from this window.
            self._end_period(drifted=True)
        if self._period_sum is None:
            # A still period begins: the whole window is still, so all of it counts.
            self._period_sum = self._acc_sum.copy()
            self._period_n = len(self._win)
        else:
            self._period_sum += a
            self._period_n += 1
        self._adopt(self._period_sum)

    def _end_period(self, drifted: bool = False) -> None:
        if self._period_sum is not None:
            self._drifted = drifted
        self.still_samples += self._period_n
        self._period_sum = None
        self._period_n = 0
        self._period_counted = False

    def _adopt(self, period_sum: np.ndarray) -> None:
        """Use the period under way: merged into the up in use when they agree (and the last
        period did not end turning), else replacing it; a move when it left the last update's up."""
        if not self._period_counted:
            change = self.config.change_deg
            agrees = self._up is not None and angle_deg(period_sum, self._up) <= change
            self._base_sum = self._up_sum.copy() if agrees and not self._drifted else np.zeros(3)
            if self._anchor is None or angle_deg(period_sum, self._anchor) > change:
                if self._anchor is not None:
                    self.moves += 1
                self.updates += 1
                self._anchor = period_sum / np.linalg.norm(period_sum)
            self._period_counted = True
        self._up_sum = self._base_sum + period_sum
        self._up = self._up_sum / np.linalg.norm(self._up_sum)

    # -- results -----------------------------------------------------------------------------
    def up_in_camera(self) -> np.ndarray | None:
        """(3,) unit vector of world up in camera axes, or None before the first still period."""
        return None if self._up is None else self._up.copy()

    @property
    def still(self) -> bool:
        """True while a still period is under way."""
        return self._period_sum is not None


__all__ = ["CAMERA_IMU_SUFFIX", "GravityConfig", "GravityEstimator", "STANDARD_GRAVITY",
           "camera_imu_sample"]
