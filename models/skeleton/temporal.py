"""Temporal refinement of the per-frame skeleton: the last half second of estimates in, the
current frame's joints out (numpy + onnxruntime; trained by models/train/train_skeleton_temporal.py).

The per-frame regressor sees one depth frame, so an occluded foot or a self-occluded wrist is a
guess that jumps from frame to frame. The temporal model reads a window of ``window`` past
estimates sampled every 1/fps s (fps of its training data, 30), each expressed in the *current*
person frame, with their depth-support confidences and a flag per sample telling whether a real
observation was there, and regresses a correction of the current estimate. It is causal (no
look-ahead, no added latency) and stateless apart from the window, so replay is deterministic.

The window is sampled in time, not in frames: at 60 fps or with dropped frames the history is
interpolated to the training rate; before the first observation it repeats the first one (its
flag says so).

A model trained with a *lag* of L samples (card ``"lag"``, default 0) trades latency for
smoothness: it sees L samples after the frame it estimates, so each skeleton comes out L / fps
later (at 30 fps, lag 2 = 67 ms) with much less jitter. Its output is stamped with the time of
the frame it estimates, the newest frame at least (L - 1/2) / fps old, so outputs keep the input
frames' timestamps; the first frames of a take get no skeleton, and the last L of a stream come
from ``flush()`` once it has ended (the pipeline drains them).

A folder of unrelated stills is no take: when most recent frames break from the one before
(``STILLS_BREAKS``), each frame is given as the regressor read it.
"""

from __future__ import annotations

import hashlib
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import ModelError
from live.core.skeleton import NUM_JOINTS

WEIGHTS_DIR = assets.weights_dir()
DEFAULT_TEMPORAL_MODEL = WEIGHTS_DIR / "skeleton_temporal.onnx"
#: When the online model's estimate lies farther than RESTART_DEVIATION_M (m, mean over joints)
#: from the frame's own per-frame estimate on RESTART_FRAMES frames in a row, that frame's estimate
#: is given and the history restarts from it. Chosen on the other renderer's tuning cases (seed 1),
#: our own validation sequences and the retarget chain (docs/skeleton.md, "Temporal model"): the
#: PCK threshold, beyond which neither counts as right; one frame is a fast move the model is
#: still catching up with (restarting there made the avatar's jitter 40 % worse).
RESTART_DEVIATION_M = 0.10
RESTART_FRAMES = 2
#: A frame whose joints lie farther than this (m, mean over joints) from the last frame's is of
#: something else (the finder moved from clutter to the performer, or back; the finder's own
#: "same person" distance): no one moves half a metre in a frame, and the other thing's history
#: pulled the estimates toward it for several frames. The history starts again at that frame (a
#: lagging model still estimates the frames before it as before, its look-ahead reaching past the
#: jump: the performer's frames pull the last ones on the clutter toward the truth).
RESTART_JUMP_M = 0.5
#: Frames that do not continue the one before: a jump (RESTART_JUMP_M), or a pose (joints less
#: the pelvis) farther than BREAK_POSE_M (m, mean over joints, per elapsed sample period) from the
#: last frame's. A moving body's per-frame estimates change by 2-3 cm a frame (median over
#: held-out takes), unrelated stills by 14 cm. When STILLS_BREAKS of the last STILLS_WINDOW frames
#: break so, the stream is a folder of stills, not a take (a dataset's test frames from many
#: recordings, replayed as one 30 fps sequence): each frame is given as read, with nothing before
#: or after it to smooth with, until fewer than STILLS_KEEP of them break (similar stills in a
#: row do not end it). On held-out takes of depth as users' sensors give it, 0.7 % of the frames
#: are given so (runs of a body read turned and back), on clean takes none; on stills all but
#: the first dozen or so (research.unrelated_frames).
BREAK_POSE_M = 0.10
STILLS_WINDOW = 12
STILLS_BREAKS = 8
STILLS_KEEP = 4


def temporal_model_path(lag: int = 0, regressor_path: Path | None = None) -> Path:
    """The temporal model of a lag: skeleton_temporal.onnx (online), or skeleton_temporal_lag<L>.onnx;
    the one beside ``regressor_path`` when there is one there (a regressor trained or wrapped
    elsewhere comes with its own temporal models), else the shipped one."""
    name = "skeleton_temporal.onnx" if lag == 0 else f"skeleton_temporal_lag{int(lag)}.onnx"
    if regressor_path is not None and (Path(regressor_path).parent / name).is_file():
        return Path(regressor_path).parent / name
    return WEIGHTS_DIR / name


@dataclass(frozen=True)
class TemporalWindow:
    """One input of the temporal model. joints (W, 22, 3) person frame of the newest sample,
    newest first; confidence (W, 22); observed (W,) 1 where a real estimate lies within half a
    sample period of the sample time, else 0 (interpolated or repeated)."""

    joints: np.ndarray
    confidence: np.ndarray
    observed: np.ndarray

    def features(self) -> np.ndarray:
        """The flat float32 input vector of the network: joints, then confidences, then flags."""
        return np.concatenate([self.joints.reshape(-1), self.confidence.reshape(-1),
                               self.observed.reshape(-1)]).astype(np.float32)


def feature_size(window: int) -> int:
    return window * (NUM_JOINTS * 4 + 1)


def to_person_frame(joints_world: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """World joints (..., 22, 3) -> coordinates of the person frame ``to_world`` (4, 4)."""
    return (np.asarray(joints_world, np.float64) - to_world[:3, 3]) @ to_world[:3, :3]


def sample_history(times_s: np.ndarray, joints_world: np.ndarray, confidence: np.ndarray, t_now_s: float,
                   to_world: np.ndarray, window: int, fps: float) -> TemporalWindow:
    """The window at sample times t_now - k / fps (k = 0..window-1) from past observations
    (times_s (H,) increasing, the last one at t_now; joints_world (H, 22, 3); confidence (H, 22)),
    linearly interpolated between observations, clamped to the first one before it."""
    t = np.asarray(times_s, np.float64)
    q = t_now_s - np.arange(window) / fps
    hi = np.searchsorted(t, q, side="left")
    np.minimum(hi, len(t) - 1, out=hi)  # (np.minimum, not np.clip: a fifth of the overhead)
    before = q <= t[0]
    lo = np.where(before, 0, np.maximum(hi - 1, 0))
    t_lo, t_hi = t[lo], t[hi]
    span = t_hi - t_lo
    # Interpolation weight of the later observation (0 before the first one: repeat it).
    w = np.minimum(np.maximum((q - t_lo) / np.where(span > 0, span, 1.0), 0.0), 1.0)
    w[(span <= 0) & ~before] = 1.0
    w[before] = 0.0
    j = (1.0 - w)[:, None, None] * joints_world[lo] + w[:, None, None] * joints_world[hi]
    c = (1.0 - w)[:, None] * confidence[lo] + w[:, None] * confidence[hi]
    observed = (np.minimum(np.abs(t_lo - q), np.abs(t_hi - q)) < 0.5 / fps).astype(np.float32)
    return TemporalWindow(joints=to_person_frame(j, to_world), confidence=c, observed=observed)


@dataclass(frozen=True)
class RefinedSkeleton:
    """The temporal model's estimate of one frame: t_ns of that frame (``lag`` frames before
    the newest one), world joints (22, 3) and that frame's confidences (22,)."""

    t_ns: int
    joints: np.ndarray
    confidence: np.ndarray


class TemporalRefiner:
    """The exported temporal model in an onnxruntime session, with its own history.

    ``refiner(t_ns, joints_world, confidence, to_world)`` -> RefinedSkeleton of the current frame
    (lag 0) or of the frame ``lag`` samples back, or None while a lagging model waits for its
    first frames; ``flush()`` gives the frames still owed at the end of a stream; ``reset()``
    forgets the performer. ``window``, ``fps`` and ``lag`` come from
    the card."""

    def __init__(self, model_path: str | Path | None = None, threads: int = 1):
        from live.core.onnx import open_session

        self.path = Path(model_path) if model_path is not None else DEFAULT_TEMPORAL_MODEL
        self.session, self.card = open_session(self.path, threads=threads, what="temporal skeleton model",
                                               retrain="python -m models.train.train_skeleton_temporal")
        self.window = int(self.card.get("window", 16))
        self.fps = float(self.card.get("fps", 30.0))
        self.lag = int(self.card.get("lag", 0))
        if not 0 <= self.lag < self.window:
            raise ModelError(f"{self.path.name}: lag {self.lag} must be in [0, window {self.window})")
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or inputs[0].shape[-1] != feature_size(self.window):
            raise ModelError(f"{self.path.name}: expected one (B, {feature_size(self.window)}) input, "
                             f"got {[i.shape for i in inputs]}")
        self._input = inputs[0].name
        self.restarts = 0  # histories dropped because the model strayed from the frame (RESTART_DEVIATION_M)
        self.jumps = 0  # histories dropped because the frame jumped to something else (RESTART_JUMP_M)
        self.stills = 0  # frames given as read in a stream of stills (STILLS_BREAKS)
        self.reset()

    @property
    def lag_s(self) -> float:
        """The latency the model adds (s): how much older than the newest frame its output is."""
        return self.lag / self.fps

    def reset(self) -> None:
        # History as preallocated arrays, oldest first, in [_start, _end): enough for the window,
        # plus slack for faster cameras and dropped frames. Dropping moves _start; the live part
        # is moved to the front only when the end is reached (not on every frame).
        size = 8 * (self.window + self.lag)
        self._times = np.zeros(size, np.int64)
        self._joints = np.zeros((size, NUM_JOINTS, 3))
        self._conf = np.zeros((size, NUM_JOINTS))
        self._start = self._end = 0
        self._cut: int | None = None  # index of the first frame after a jump, while frames before it are owed
        self._emitted: int | None = None
        self._to_world: np.ndarray | None = None
        self._straying = 0
        self._breaks: deque[bool] = deque(maxlen=STILLS_WINDOW)  # per frame: did it break from the last?
        self._stills = False  # the stream is stills (STILLS_BREAKS)

    def _append(self, t_ns: int, joints_world: np.ndarray, confidence: np.ndarray) -> None:
        """Add an observation; drop what the window can no longer reach (all but one entry older
        than that, at least two kept) and, when full, the oldest."""
        if self._end == len(self._times):
            a, b = self._start, self._end
            if a == 0:  # full: the oldest goes
                a = 1
            for arr in (self._times, self._joints, self._conf):
                arr[:b - a] = arr[a:b]
            self._start, self._end = 0, b - a
            if self._cut is not None:
                self._cut -= a
        e = self._end
        self._times[e], self._joints[e], self._conf[e] = t_ns, joints_world, confidence
        self._end = e = e + 1
        n = e - self._start
        if n > 2:
            reach_ns = (self.window + self.lag + 1) * 1e9 / self.fps
            stale = int(np.searchsorted(self._times[self._start + 1:e], t_ns - reach_ns, side="left"))
            self._start += min(stale, n - 2)
        if self._cut is not None and self._cut <= self._start:
            self._cut = None

    def matches(self, regressor_path: Path) -> bool:
        """Whether this model was trained on the outputs of that regressor file, or measured behind
        it on held-out data and found to help (the card's ``validated_behind``: a regressor
        fine-tuned from the one it was trained behind makes errors of the same kind)."""
        want = self.card.get("regressor_sha256")
        if want is None:
            return True
        have = file_sha256(regressor_path)
        return want == have or any(v.get("sha256") == have for v in self.card.get("validated_behind", []))

    def __call__(self, t_ns: int, joints_world: np.ndarray, confidence: np.ndarray,
                 to_world: np.ndarray) -> RefinedSkeleton | None:
        t_ns = int(t_ns)
        if self._end > self._start and t_ns <= self._times[self._end - 1]:
            self.reset()  # time went backwards (a new replay): start over
        jump = False
        if self._end > self._start:
            last = self._joints[self._end - 1]
            jump = np.linalg.norm(joints_world - last, axis=1).mean() > RESTART_JUMP_M
            periods = max(1.0, (t_ns - int(self._times[self._end - 1])) * 1e-9 * self.fps)
            self._breaks.append(jump or pose_change(joints_world, last) > BREAK_POSE_M * periods)
            self._stills = sum(self._breaks) >= (STILLS_KEEP if self._stills else STILLS_BREAKS)
        self._append(t_ns, joints_world, confidence)
        if jump:
            self.jumps += 1
            self._cut = self._end - 1
        self._to_world = to_world
        times = self._times[self._start:self._end]
        # The frame to estimate: the oldest one not yet estimated, once it is at least (lag - 1/2)
        # samples old (lag 0: this one). Where the finder missed a frame, the frames owed are
        # given one a call, a frame later each, until the missed frame's turn comes: none is skipped.
        due = int(np.searchsorted(times, t_ns - (self.lag - 0.5) * 1e9 / self.fps, side="right")) - 1
        k = self._first_owed(times)
        if due < 0 or k > due:
            return None
        at = self._start + k
        if self._stills:
            return self._as_read(at)
        out = self._estimate(at)
        raw = self._joints[at]
        strays = self.lag == 0 and np.linalg.norm(out.joints - raw, axis=1).mean() > RESTART_DEVIATION_M
        self._straying = self._straying + 1 if strays else 0
        if self._straying >= RESTART_FRAMES:
            self._straying = 0
            # The online model keeps straying from what the frames show: its history no longer
            # explains the present (depth unlike its training data). The frame's own estimate is
            # given, and the history starts again from this frame. (A lagging model sees the
            # frames after it too, and strays for good reason: restarting it only costs.)
            self.restarts += 1
            self._start = at
            out = RefinedSkeleton(t_ns=out.t_ns, joints=raw.copy(), confidence=out.confidence)
        return out

    def flush(self) -> list[RefinedSkeleton]:
        """At the end of a stream, the frames a lagging model still owes (the last ``lag``; none
        at lag 0), oldest first. Each window is anchored lag samples after its frame as usual; the
        samples past the newest observation repeat it, flagged as not observed, as those before a
        take's first frame repeat the first one. The model then owes nothing more until new frames
        come."""
        if self._to_world is None or self._end == self._start:
            return []
        give = self._as_read if self._stills else self._estimate
        first = self._first_owed(self._times[self._start:self._end])
        return [give(at) for at in range(self._start + first, self._end)]

    def _first_owed(self, times: np.ndarray) -> int:
        """Index in the live history ``times`` of the oldest frame not yet estimated."""
        return 0 if self._emitted is None else int(np.searchsorted(times, self._emitted, side="right"))

    def _as_read(self, at: int) -> RefinedSkeleton:
        """The observation at index ``at`` as the regressor read it (its history holds other
        people and poses)."""
        self.stills += 1
        self._emitted = int(self._times[at])
        return RefinedSkeleton(t_ns=self._emitted, joints=self._joints[at].copy(), confidence=self._conf[at].copy())

    def _estimate(self, at: int) -> RefinedSkeleton:
        """The model's estimate of the observation at index ``at``, in the newest frame's person
        frame: from the whole history for a frame before a jump (a lagging model's look-ahead
        reaches past it), from the history that starts at the jump for the frames from it on."""
        if self._cut is not None and at >= self._cut:
            self._start, self._cut = self._cut, None
        live = slice(self._start, self._end)
        times, to_world = self._times[live], self._to_world
        t_at = int(self._times[at])
        self._emitted = t_at
        anchor_s = t_at * 1e-9 + self.lag_s  # the window's newest sample, lag samples after it
        win = sample_history(times * 1e-9, self._joints[live], self._conf[live], anchor_s, to_world, self.window,
                             self.fps)
        local = self.session.run(None, {self._input: win.features()[None]})[0][0].astype(np.float64)
        return RefinedSkeleton(t_ns=t_at, joints=local @ to_world[:3, :3].T + to_world[:3, 3],
                               confidence=self._conf[at].copy())


def pose_change(joints: np.ndarray, before: np.ndarray) -> float:
    """Mean distance (m) between two skeletons (22, 3) with their pelvises put together: how far
    the pose changed, wherever the body went."""
    return float(np.linalg.norm((joints - joints[0]) - (before - before[0]), axis=1).mean())


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


__all__ = ["TemporalRefiner", "RefinedSkeleton", "TemporalWindow", "sample_history", "to_person_frame", "feature_size",
           "file_sha256", "pose_change", "temporal_model_path", "DEFAULT_TEMPORAL_MODEL"]
