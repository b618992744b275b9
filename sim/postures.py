"""Postures for synthetic sessions: a clip played as recorded, in place, seated or crouching.

The shared clips are mostly walks and runs that cross the room; a performer in front of a desk
or a monitor stays in one spot, often seated. ``apply_posture`` turns any clip into such a
performance on the canonical skeleton (``live.motion.clips.Motion``):

- ``clip``: as recorded;
- ``in-place``: the root's travel taken out (a centred one-second moving average of its
  horizontal position), its sway kept: the performer moves on the spot;
- ``seated``: in place, thighs horizontal and shins vertical, feet flat, the legs still (the
  clip's mean heading, the pelvis at its median height), the rest of the body as recorded;
  ``seat_boxes`` gives the chair under them;
- ``crouching``: in place, thighs 20 degrees above horizontal, shins 15 degrees from vertical
  (knees forward), the trunk leaning 20 degrees forward: a deep crouch;
- ``knee-up``: in place, the knees raised in turn (left, then right, KNEE_UP_PERIOD_S a pair),
  the thigh swung forward up to 100 degrees and the knee bent up to 110, the standing leg
  straight, the rest of the body as recorded: a knee held toward whoever the performer faces;
- ``kick``: in place, front kicks in turn with the same timing: the thigh swung forward up to
  KICK_HIP_DEG while the knee first bends (chambered, up to KICK_KNEE_DEG half way) and then
  straightens, so at the top the whole leg points ahead, the foot about a leg's length in front.

Leg angles are set in the world, about the pelvis's heading (clips tilt their pelvis by up to
20 degrees, which would tilt the thighs with it), so they mean the same on any clip and body;
``sim.synth.pose_motion_on_body`` then puts the feet on the floor.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from live.core.errors import UserInputError
from live.core.heading import direction_yaw, mean_angle, yaw_of, yaw_quat
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_conjugate, quat_from_axis_angle, quat_multiply
from live.core.skeleton import JOINT_INDEX
from live.motion.clips import Motion
from sim.room import Box

POSTURES = ("clip", "in-place", "seated", "crouching", "knee-up", "kick")
#: knee-up: seconds for the left and then the right knee to rise and fall; the raised thigh's
#: largest swing forward from hanging and the knee's largest bend, degrees.
KNEE_UP_PERIOD_S = 1.6
KNEE_UP_HIP_DEG = 100.0
KNEE_UP_KNEE_DEG = 110.0
#: kick: the thigh's largest swing forward (reached with the knee straight) and the knee's
#: largest bend (half way up), degrees.
KICK_HIP_DEG = 80.0
KICK_KNEE_DEG = 100.0

# Rotations about +x in the performer's heading frame, degrees (negative swings a leg bone
# forward): the hip's of the thigh from hanging straight down, the knee's and ankle's relative
# to the bone above; lean: the trunk's forward tilt added at spine1.
_LEGS = {
    "seated": {"hip": -90.0, "knee": 90.0, "ankle": 0.0, "lean": 0.0},
    "crouching": {"hip": -110.0, "knee": 125.0, "ankle": -15.0, "lean": 20.0},
}


def _x_rotation(deg: float | np.ndarray) -> np.ndarray:
    """Rotations (..., 4) about +x by ``deg`` (...,) degrees."""
    deg = np.asarray(deg, np.float64)
    return quat_from_axis_angle(np.stack([np.radians(deg), np.zeros_like(deg), np.zeros_like(deg)], axis=-1))


def remove_travel(root: np.ndarray, fps: float, window_s: float = 1.0) -> np.ndarray:
    """(T, 3) root with its horizontal travel taken out: x and z minus their centred moving
    average over ``window_s`` (the ends extended by point reflection, which continues a steady
    walk), plus their mean."""
    root = np.asarray(root, np.float64).copy()
    pad = min(int(round(window_s * fps)) // 2, len(root) - 1)
    k = 2 * pad + 1  # odd: centred
    for axis in (0, 2):
        x = root[:, axis]
        padded = np.concatenate([2 * x[0] - x[pad:0:-1], x, 2 * x[-1] - x[-2:-pad - 2:-1]])
        trend = np.convolve(padded, np.ones(k) / k, mode="valid")
        root[:, axis] = x - trend + x.mean()
    return root


def apply_posture(motion: Motion, posture: str) -> Motion:
    """The motion performed in ``posture`` (one of POSTURES); joints recomputed by FK."""
    if posture not in POSTURES:
        raise UserInputError(f"unknown posture {posture!r}; choose from {', '.join(POSTURES)}")
    if posture == "clip":
        return motion
    root = remove_travel(motion.root, motion.fps)
    rotations = np.asarray(motion.rotations, np.float64).copy()
    legs = _LEGS.get(posture)
    if legs is not None:
        # Still legs: one heading (the clip's mean), the pelvis at its median height.
        pelvis = rotations[:, 0]  # the root's local rotation is its global one
        yaw = yaw_of(pelvis)
        heading = mean_angle(yaw)
        root[:, 1] = np.median(root[:, 1])
        thigh = quat_multiply(yaw_quat(np.full(len(pelvis), heading)), _x_rotation(legs["hip"]))
        hip_local = quat_multiply(quat_conjugate(pelvis), thigh)
        for side in ("left", "right"):
            rotations[:, JOINT_INDEX[f"{side}_hip"]] = hip_local
            for part in ("knee", "ankle"):
                rotations[:, JOINT_INDEX[f"{side}_{part}"]] = _x_rotation(legs[part])
            rotations[:, JOINT_INDEX[f"{side}_foot"]] = _x_rotation(0.0)
        if legs["lean"]:
            spine = JOINT_INDEX["spine1"]
            rotations[:, spine] = quat_multiply(_x_rotation(legs["lean"]), rotations[:, spine])
    if posture in ("knee-up", "kick"):
        root[:, 1] = np.median(root[:, 1])
        _raise_legs(rotations, motion.fps, kick=posture == "kick")
    rotations = rotations.astype(np.float32)
    joints, _ = forward_kinematics(rotations, root, motion.rest_joints)
    return replace(motion, rotations=rotations, root=root.astype(np.float32),
                   joints=joints.astype(np.float32), name=f"{motion.name} ({posture})")


def knee_raise(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) share in [0, 1] of a full knee raise or kick at times ``t_s`` (T,) seconds: each
    leg rises and falls smoothly (sin²) in its half of KNEE_UP_PERIOD_S, the left first."""
    phase = (np.asarray(t_s, np.float64) % KNEE_UP_PERIOD_S) / (KNEE_UP_PERIOD_S / 2)
    up = np.sin(np.pi * (phase % 1.0)) ** 2
    return np.where(phase < 1.0, up, 0.0), np.where(phase >= 1.0, up, 0.0)


def _raise_legs(rotations: np.ndarray, fps: float, kick: bool) -> None:
    """Set the legs of local rotations (T, 22, 4) in place for ``knee-up`` or ``kick``: each thigh
    swung forward about the pelvis's own heading (so the leg rises where the body faces), the
    shin bent (a kick straightens it again at the top), the foot in line with the shin; the
    standing leg hangs straight."""
    pelvis = rotations[:, 0]  # the root's local rotation is its global one
    facing = yaw_quat(yaw_of(pelvis))
    shares = knee_raise(np.arange(len(rotations)) / fps)
    for side, share in zip(("left", "right"), shares):
        hip = KICK_HIP_DEG * share if kick else KNEE_UP_HIP_DEG * share
        knee = KICK_KNEE_DEG * np.sin(np.pi * share) if kick else KNEE_UP_KNEE_DEG * share
        thigh = quat_multiply(facing, _x_rotation(-hip))
        rotations[:, JOINT_INDEX[f"{side}_hip"]] = quat_multiply(quat_conjugate(pelvis), thigh)
        rotations[:, JOINT_INDEX[f"{side}_knee"]] = _x_rotation(knee)
        rotations[:, JOINT_INDEX[f"{side}_ankle"]] = _x_rotation(0.0)
        rotations[:, JOINT_INDEX[f"{side}_foot"]] = _x_rotation(0.0)


def seat_boxes(joints: np.ndarray) -> tuple[Box, ...]:
    """A chair (seat and backrest) under a seated performer's posed joints (T, 22, 3) world:
    the seat's top 10 cm below the hip joints (the thighs' flesh), from 10 cm behind the hips
    to 30 cm in front of them, the backrest behind the pelvis."""
    j = np.asarray(joints, np.float64)
    hips = j[:, [JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]]].mean(axis=(0, 1))
    knees = j[:, [JOINT_INDEX["left_knee"], JOINT_INDEX["right_knee"]]].mean(axis=(0, 1))
    forward = (knees - hips) * np.array([1.0, 0.0, 1.0])
    forward /= max(float(np.linalg.norm(forward)), 1e-9)
    yaw = float(direction_yaw(forward))
    top = max(float(hips[1]) - 0.10, 0.15)
    seat_c = hips + 0.10 * forward
    back_c = hips - 0.16 * forward
    seat = Box((float(seat_c[0]), top / 2, float(seat_c[2])), (0.46, top, 0.42), yaw)
    back = Box((float(back_c[0]), top + 0.25, float(back_c[2])), (0.44, 0.50, 0.05), yaw)
    return seat, back


__all__ = ["POSTURES", "KICK_HIP_DEG", "KICK_KNEE_DEG", "KNEE_UP_PERIOD_S", "apply_posture", "knee_raise", "remove_travel", "seat_boxes"]
