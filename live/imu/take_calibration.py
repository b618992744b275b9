"""Calibration from a recorded take itself: its still calibration pose, and how each sensor faces.

A take starts with the performer holding the calibration pose (N-pose or T-pose). ``find_still``
finds it: the first stretch of at least ``min_s`` during which every sensor turns slower than
``max_deg_s``.

A static pose fixes each sensor's tilt on its segment, not its heading: for a sensor on segment
j, q_cal = A P_j M (A: the performer's facing in that sensor's world, P_j: the pose, M: the
mounting), and A and the mounting's turn about the vertical cannot be told apart. Leg segments
walk like hinges: the thigh, shank and foot turn mostly about the body's left-right axis, so the
dominant axis of a sensor's rotation during the take (the principal axis of its angular
velocity, in the sensor frame) is the segment's +x or -x. ``facing_from_motion`` takes that axis
into the world at the hold, which gives A; the sign comes from how legs move (the hip flexes
forward more than it extends, the knee only bends backward, the heel lifts at push-off).
Sensors without such evidence (pelvis, torso, arms) take the mean facing of those with it (one
shared world heading at the hold), or their own heading with identity mounting when no sensor
has any. ``take_mounting`` then gives each sensor the nominal mounting that makes its heading
vote in live.imu.calibration exactly its own A: every sensor's heading is aligned on its own
evidence (``per_sensor_heading``), so sensors whose magnetometer worlds disagree at the hold
still agree on the body.

Pure numpy on a common time grid: quats (N, S, 4) sensor-to-world, t (N,) seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.heading import direction_yaw, mean_angle, yaw_of, yaw_quat
from live.core.rotations import quat_conjugate, quat_multiply, quat_normalize, quat_rotate, quat_to_axis_angle
from live.core.skeleton import JOINT_INDEX
from live.imu.calibration import mean_quat, pose_globals

_THIGHS = {JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]}
_SHANKS = {JOINT_INDEX["left_knee"], JOINT_INDEX["right_knee"]}
_FEET = {JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]}
HINGE_SEGMENTS = _THIGHS | _SHANKS | _FEET


def body_rates(quats: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Angular velocity (N, S, 3) rad/s in each sensor's frame (backward differences; the first
    row repeats the second); NaN where a sample is missing."""
    dq = quat_multiply(quat_conjugate(quats[:-1]), quats[1:])
    dq = dq * np.where(dq[..., :1] < 0, -1.0, 1.0)
    w = quat_to_axis_angle(dq) / np.diff(t)[:, None, None]
    return np.concatenate([w[:1], w], axis=0)


def find_still(quats: np.ndarray, t: np.ndarray, *, max_deg_s: float = 15.0, min_s: float = 0.5,
               search_s: float = 30.0, trim_s: float = 0.15) -> tuple[int, int] | None:
    """(first, last) sample index of the first still stretch of at least ``min_s`` starting in the
    first ``search_s`` seconds: every sensor slower than ``max_deg_s`` (samples where one is
    missing break it). Its last ``trim_s`` (the motion starting) is left out. None if none."""
    speed = np.degrees(np.linalg.norm(body_rates(quats, t), axis=-1))
    # A little smoothing: one noisy sample does not end a hold.
    k = 3
    smooth = np.stack([np.convolve(np.nan_to_num(s, nan=1e9), np.ones(k) / k, mode="same") for s in speed.T], -1)
    still = np.all(smooth < max_deg_s, axis=1)
    start = None
    for i in range(len(t) + 1):
        if i < len(t) and still[i]:
            start = i if start is None else start
            continue
        if start is not None:
            end = i - 1
            while end > start and t[end] - t[i - 1] > -trim_s:
                end -= 1
            if t[end] - t[start] >= min_s:
                return start, end
            start = None
        if i < len(t) and t[i] - t[0] > search_s:
            break
    return None


@dataclass(frozen=True)
class Facing:
    """Per sensor (S,): yaw (radians) of the performer's facing at the hold, in the sensor's
    world; how it was found ("hinge": its own rotation axis, "shared": the others' mean,
    "own": its own heading, nothing better); hinge_share: how much of its rotation is about its
    main axis (1 = a perfect hinge)."""

    yaw: np.ndarray
    method: tuple[str, ...]
    hinge_share: np.ndarray


def _pitch(quats: np.ndarray, q_cal: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(N,) radians a segment turned about its own axis (sensor frame) since the hold, its turns
    about the vertical taken out first (walking back the other way is no pitch); 0 where missing."""
    change = quat_multiply(quats, quat_conjugate(q_cal)[None])  # in the world, since the hold
    tilt = quat_multiply(yaw_quat(-yaw_of(change)), change)
    rel = quat_multiply(quat_multiply(quat_conjugate(q_cal)[None], tilt), q_cal[None])
    return np.nan_to_num(_twist(rel, axis))


def _knee_score(knee: np.ndarray) -> float:
    """How knee-like an angle series is (radians): positive on average, hardly ever negative."""
    return float(np.mean(knee) - 3.0 * np.mean(np.maximum(-knee, 0.0)))


def _twist(rel: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle (N,) of rotations (N, 4) about a unit axis (3,) (their twist)."""
    return 2.0 * np.arctan2(rel[:, 1:] @ axis, rel[:, 0])


def facing_from_motion(quats: np.ndarray, t: np.ndarray, joints: np.ndarray, still: tuple[int, int], *,
                       min_share: float = 0.6, min_speed_deg_s: float = 30.0) -> Facing:
    """Each sensor's facing at the hold (see the module doc). joints (S,): each sensor's segment."""
    S = quats.shape[1]
    i0, i1 = still
    q_cal = np.stack([mean_quat(quats[i0:i1 + 1, s]) for s in range(S)])
    rates = body_rates(quats, t)
    after = np.arange(len(t)) > i1
    yaw = np.full(S, np.nan)
    share = np.zeros(S)
    axes = np.zeros((S, 3))
    pitch: dict[int, bool] = {}  # sensors with a rotation axis
    up = np.array([0.0, 1.0, 0.0])
    for s in range(S):
        # Turning on the spot (about the vertical) is not the hinge: only the rest of the turn rate.
        q = quats[after, s]
        ok = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(rates[after, s]), axis=1)
        w_world = quat_rotate(q[ok], rates[after, s][ok])
        w_world -= (w_world @ up)[:, None] * up
        w = quat_rotate(quat_conjugate(q[ok]), w_world)
        w = w[np.degrees(np.linalg.norm(w, axis=1)) > min_speed_deg_s]
        if len(w) < 10:
            continue
        vals, vecs = np.linalg.eigh(w.T @ w)
        share[s] = vals[-1] / max(vals.sum(), 1e-12)
        axes[s] = vecs[:, -1]
        pitch[s] = True
    # Signs, so that each axis is the body's +x (left): per leg, the pair (thigh, shank) that
    # makes the knee bend one way only, forward-positive (knee flexion about +x), then the foot
    # that keeps the ankle's range small (it turns far less than the shank and the foot do).
    theta = {s: _pitch(quats[after, s], q_cal[s], axes[s]) for s in pitch}
    row = {int(j): s for s, j in enumerate(joints)}
    for side in ("left", "right"):
        th, sh, ft = (row.get(JOINT_INDEX[f"{side}_{n}"]) for n in ("hip", "knee", "ankle"))
        th = th if th in theta else None
        sh = sh if sh in theta else None
        if th is not None and sh is not None:
            best = max(((a, b) for a in (1, -1) for b in (1, -1)),
                       key=lambda ab: _knee_score(ab[1] * theta[sh] - ab[0] * theta[th]))
            axes[th] *= best[0]
            axes[sh] *= best[1]
            theta[th] *= best[0]
            theta[sh] *= best[1]
        elif th is not None and np.mean(theta[th]) > 0:  # the hip flexes (about -x) more than it extends
            axes[th] *= -1
            theta[th] *= -1
        if ft in theta and sh is not None:
            if np.var(theta[ft] + theta[sh]) < np.var(theta[ft] - theta[sh]):
                axes[ft] *= -1
    method = []
    for s, j in enumerate(joints):
        if int(j) in HINGE_SEGMENTS and share[s] >= min_share:
            left = quat_rotate(q_cal[s], axes[s])  # the body's +x in the world at the hold
            yaw[s] = direction_yaw(left) - np.pi / 2
            method.append("hinge")
        else:
            method.append("")
    known = np.isfinite(yaw)
    if known.any():
        mean = mean_angle(yaw[known])
        method = [m or "shared" for m in method]
        yaw = np.where(known, yaw, mean)
    else:
        method = ["own"] * S
    return Facing(yaw=np.arctan2(np.sin(yaw), np.cos(yaw)), method=tuple(method), hinge_share=share)


def take_mounting(quats: np.ndarray, joints: np.ndarray, still: tuple[int, int], facing: Facing, pose: str,
                  rest_joints: np.ndarray | None = None) -> np.ndarray:
    """(S, 4) nominal mounting of each sensor (sensor in segment) that makes the hold's
    orientation mean exactly ``pose`` facing ``facing.yaw``: M = P_j^-1 A^-1 q_cal. For "own"
    sensors A is their own heading (identity mounting about the vertical)."""
    i0, i1 = still
    S = quats.shape[1]
    q_cal = np.stack([mean_quat(quats[i0:i1 + 1, s]) for s in range(S)])
    P = pose_globals(pose, rest_joints)[np.asarray(joints)]
    out = np.empty((S, 4))
    for s in range(S):
        if facing.method[s] == "own":
            out[s] = [1.0, 0.0, 0.0, 0.0]
            continue
        A = yaw_quat(facing.yaw[s])
        out[s] = quat_multiply(quat_multiply(quat_conjugate(P[s]), quat_conjugate(A)), q_cal[s])
    return quat_normalize(out)


__all__ = ["find_still", "facing_from_motion", "take_mounting", "Facing", "body_rates", "HINGE_SEGMENTS"]
