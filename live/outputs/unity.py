"""Canonical skeleton <-> Unity humanoid: the one place mapping joints to HumanBodyBones and
converting between our right-handed world and Unity's left-handed one.

Frames. Ours: right-handed, +Y up, the T-pose faces +Z with the left arm along +X. Unity:
left-handed, +Y up, +Z forward, +X right; a humanoid avatar faces +Z, so its left arm points
along -X. Mirroring the x axis, M = diag(-1, 1, 1), takes one to the other (it maps the facing
direction, up and the left arm onto each other, and flips handedness):

    position   p_u = M p = (-x, y, z)
    rotation   R_u = M R M

For a unit quaternion q = (w, x, y, z), a rotation by angle a about axis n, M R M is the
rotation by a about det(M) * M n = (n_x, -n_y, -n_z) (an axis is a pseudovector: a mirror
flips it once as a vector and once more through the determinant). So

    q_u = (w, x, -y, -z), sent in Unity's component order (x, -y, -z, w).

Unity's Quaternion uses the same algebra (same product, same quaternion-to-matrix formula), so
``quat_to_matrix(q_u) == M @ quat_to_matrix(q) @ M`` holds exactly; the tests check it. The map
is its own inverse, and it distributes over products (M R1 R2 M = (M R1 M)(M R2 M)), so local
rotations convert joint by joint.

Bones. The canonical parents match Unity's humanoid hierarchy one to one, and a normalised
humanoid (VRM, VSeeFace, Warudo, VirtualMotionCapture) has identity local rotations in its
T-pose, as ours do, so a canonical local rotation is directly the bone's localRotation. A VRM /
glTF avatar whose bones have rest rotations of their own gets its bones' own values instead
(live/body/gltf_rig.py, live/outputs/vmc.py ``rig_bone_messages``).
"""

from __future__ import annotations

import numpy as np

from live.core.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS

#: canonical joint -> Unity HumanBodyBones name. Every one of the 22 joints drives one bone.
JOINT_TO_UNITY_BONE: dict[str, str] = {
    "pelvis": "Hips",
    "spine1": "Spine",
    "spine2": "Chest",
    "spine3": "UpperChest",
    "neck": "Neck",
    "head": "Head",
    "left_collar": "LeftShoulder",
    "right_collar": "RightShoulder",
    "left_shoulder": "LeftUpperArm",
    "right_shoulder": "RightUpperArm",
    "left_elbow": "LeftLowerArm",
    "right_elbow": "RightLowerArm",
    "left_wrist": "LeftHand",
    "right_wrist": "RightHand",
    "left_hip": "LeftUpperLeg",
    "right_hip": "RightUpperLeg",
    "left_knee": "LeftLowerLeg",
    "right_knee": "RightLowerLeg",
    "left_ankle": "LeftFoot",
    "right_ankle": "RightFoot",
    "left_foot": "LeftToes",
    "right_foot": "RightToes",
}

#: Unity bone names in canonical joint order (index i drives UNITY_BONES[i]).
UNITY_BONES: tuple[str, ...] = tuple(JOINT_TO_UNITY_BONE[n] for n in JOINT_NAMES)
#: Unity bone name -> canonical joint index.
UNITY_BONE_INDEX: dict[str, int] = {b: JOINT_INDEX[n] for n, b in JOINT_TO_UNITY_BONE.items()}

assert len(UNITY_BONES) == NUM_JOINTS and len(set(UNITY_BONES)) == NUM_JOINTS

#: The HumanBodyBones an avatar file may map beyond the 22 joints: eyes, jaw, fingers. They are
#: sent at rest (identity localRotation): their localPosition is the file's own rest offset.
UNITY_EXTRA_BONES: frozenset[str] = frozenset(
    ["LeftEye", "RightEye", "Jaw"]
    + [f"{side}{finger}{part}" for side in ("Left", "Right") for finger in ("Thumb", "Index", "Middle", "Ring", "Little")
       for part in ("Proximal", "Intermediate", "Distal")])

_MIRROR_X = np.array([-1.0, 1.0, 1.0])
_MIRROR_Q = np.array([1.0, 1.0, -1.0, -1.0])


def position_to_unity(p: np.ndarray) -> np.ndarray:
    """(..., 3) positions, our world -> Unity (x mirrored). Its own inverse."""
    return np.asarray(p) * _MIRROR_X


def position_from_unity(p: np.ndarray) -> np.ndarray:
    """(..., 3) Unity positions -> our world."""
    return np.asarray(p) * _MIRROR_X


def quat_to_unity(q: np.ndarray) -> np.ndarray:
    """(..., 4) (w, x, y, z) ours -> (..., 4) Unity quaternion in Unity order (x, y, z, w)."""
    m = np.asarray(q) * _MIRROR_Q
    return np.concatenate([m[..., 1:], m[..., :1]], axis=-1)


def quat_from_unity(q_xyzw: np.ndarray) -> np.ndarray:
    """(..., 4) Unity (x, y, z, w) -> (..., 4) ours (w, x, y, z)."""
    q = np.asarray(q_xyzw)
    wxyz = np.concatenate([q[..., 3:], q[..., :3]], axis=-1)
    return wxyz * _MIRROR_Q
