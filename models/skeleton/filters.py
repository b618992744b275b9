"""Temporal filtering and consistency of regressed skeletons (pure numpy, per frame).

- ``OneEuroFilter``: Casiez et al.'s 1-euro filter on (22, 3) joints: smooth when still,
  responsive when moving; ``min_cutoff`` (Hz) trades jitter for lag, ``beta`` trades lag at speed.
- ``BoneLengthKeeper``: learns the performer's bone lengths (running median of confident frames)
  and re-lays each bone at that length along its observed direction, root outward.
- ``FlipGuard``: a left/right (or front/back) flip of the whole body between two frames shows
  up as the mirrored labelling being much closer to the previous frame; it is undone.
- ``joint_confidence``: [0, 1] per joint from the depth support around the joint.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from live.core.skeleton import BONES, LEFT_RIGHT_SWAP, NUM_JOINTS


@dataclass
class OneEuroFilter:
    min_cutoff: float = 1.5
    beta: float = 0.5
    d_cutoff: float = 1.0
    _x: np.ndarray | None = None
    _dx: np.ndarray | None = None
    _t: float | None = None

    @staticmethod
    def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
        tau = 1.0 / (2.0 * np.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def reset(self) -> None:
        self._x = self._dx = self._t = None

    def __call__(self, x: np.ndarray, t_s: float) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if self._x is None or self._t is None or t_s <= self._t:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), t_s
            return x.copy()
        dt = t_s - self._t
        dx = (x - self._x) / dt
        a_d = self._alpha(self.d_cutoff, dt)
        self._dx = a_d * dx + (1.0 - a_d) * self._dx
        speed = np.linalg.norm(self._dx, axis=-1, keepdims=True)
        a = self._alpha(self.min_cutoff + self.beta * speed, dt)
        self._x = a * x + (1.0 - a) * self._x
        self._t = t_s
        return self._x.copy()


_PARENT = np.array([p for p, _ in BONES])
_CHILD = np.array([c for _, c in BONES])


@dataclass
class BoneLengthKeeper:
    """Keeps bone lengths constant per performer once enough confident frames were seen."""

    warmup_frames: int = 15
    history: int = 300
    update_every: int = 10
    _lengths: list[np.ndarray] = field(default_factory=list)
    _seen: int = 0
    lengths: np.ndarray | None = None

    def __call__(self, joints: np.ndarray, confidence: np.ndarray) -> np.ndarray:
        joints = np.asarray(joints, np.float64)
        obs = np.linalg.norm(joints[_CHILD] - joints[_PARENT], axis=1)
        confident = (confidence[_CHILD] > 0.5) & (confidence[_PARENT] > 0.5)
        sample = np.where(confident, obs, np.nan)
        self._lengths.append(sample)
        if len(self._lengths) > self.history:
            self._lengths.pop(0)
        self._seen += 1
        # The median of a few hundred frames moves slowly: refresh it every few frames only.
        due = self.lengths is None or self._seen % self.update_every == 0
        if len(self._lengths) >= self.warmup_frames and due:
            with warnings.catch_warnings():  # bones never confidently seen are all-NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(np.stack(self._lengths), axis=0)
            self.lengths = np.where(np.isfinite(med), med, obs)
        if self.lengths is None:
            return joints
        out = joints.copy()
        for b, (p, c) in enumerate(BONES):
            d = joints[c] - joints[p]
            n = np.linalg.norm(d)
            if n > 1e-6:
                out[c] = out[p] + d * (self.lengths[b] / n)
            else:
                out[c] = out[p] + d
        return out


@dataclass
class FlipGuard:
    """Undo whole-body left/right label flips relative to the previous frame.

    A flip is a glitch of a frame or two; when the estimates disagree with the guard's history
    for ``max_run`` frames in a row, the history was the flip (a first frame estimated mirrored,
    often at the far end of the range), and the guard follows the estimates again
    (``recoveries``). Without that, one mirrored first frame would mirror the whole take."""

    margin: float = 0.5
    max_run: int = 3
    flips: int = 0
    recoveries: int = 0
    _prev: np.ndarray | None = None
    _run: int = 0

    def __call__(self, joints: np.ndarray) -> np.ndarray:
        joints = np.asarray(joints, np.float64)
        if self._prev is not None:
            keep = np.linalg.norm(joints - self._prev, axis=1).mean()
            swapped = joints[LEFT_RIGHT_SWAP]
            swap = np.linalg.norm(swapped - self._prev, axis=1).mean()
            if swap < self.margin * keep:
                self._run += 1
                if self._run < self.max_run:
                    joints = swapped
                    self.flips += 1
                else:
                    self._run = 0
                    self.recoveries += 1
            else:
                self._run = 0
        self._prev = joints
        return joints

    def reset(self) -> None:
        self._prev = None
        self._run = 0


def joint_confidence(joints: np.ndarray, points: np.ndarray, radius_m: float = 0.12,
                     full_support: int = 6) -> np.ndarray:
    """(22,) confidence in [0, 1]: the share of ``full_support`` sample points within
    ``radius_m`` of each joint (joints of body parts the camera does not see get ~0)."""
    p = np.asarray(points, np.float64)
    j = np.asarray(joints, np.float64)
    # |p - j|^2 = |p|^2 - 2 p.j + |j|^2: one (22, N) matmul instead of a (22, N, 3) difference.
    d2 = (p * p).sum(1)[None, :] - 2.0 * (j @ p.T) + (j * j).sum(1)[:, None]
    support = (d2 < radius_m * radius_m).sum(axis=1)
    return np.minimum(support / float(full_support), 1.0).astype(np.float32)  # support >= 0


__all__ = ["OneEuroFilter", "BoneLengthKeeper", "FlipGuard", "joint_confidence", "NUM_JOINTS"]
