"""Clips with self-contacts made from walks: hands on the hips, and clapping.

The CMU clips in ../shared/data/bvh have hands on the belly, washing, hands together in a dance,
but no clapping and no hands-on-hips take, and the held-out subjects (7, 8, 12, 16) only walk.
``contact_clip`` turns a held-out subject's walk into one: the legs, the trunk and the head keep
the take; the arms are posed by two-bone IK so that, on the performer's own body, the hands rest
on the sides of the hips (elbows out and back) or clap in front of the lower chest (1.5 claps a
second, the hands together a third of each cycle; higher, hands that follow their forearms put
the fingers into the performer's own chin and face). The hands are then moved, frame by frame,
until the skinned hand touches the hip or the other hand (signed distance on the posed mesh
within 2 mm), so the performer's contacts are real ones. Hands follow their forearms, as in any 22-joint
skeleton.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX

KINDS = ("hands-on-hips", "clapping")
_J = JOINT_INDEX
_ARMS = ((_J["left_shoulder"], _J["left_elbow"], _J["left_wrist"], 1.0),
         (_J["right_shoulder"], _J["right_elbow"], _J["right_wrist"], -1.0))
CLAP_HZ = 1.5
CLAP_OPEN = 0.32  # m between the hands at the widest
CLAP_HEIGHT = 0.7  # of the pelvis-to-upper-chest (spine3) height: where the wrists meet


def _arm_ik(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray, target: np.ndarray, pole: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """(elbow, wrist) of an arm of the same bone lengths reaching ``target`` (stretched toward it
    when out of reach), the elbow bent toward ``pole`` (a direction)."""
    upper, lower = np.linalg.norm(elbow - shoulder), np.linalg.norm(wrist - elbow)
    to = target - shoulder
    dist = float(np.clip(np.linalg.norm(to), abs(upper - lower) + 1e-4, upper + lower - 1e-4))
    u = to / max(np.linalg.norm(to), 1e-9)
    v = pole - u * (pole @ u)
    v /= max(np.linalg.norm(v), 1e-9)
    cos_a = (upper ** 2 + dist ** 2 - lower ** 2) / (2 * upper * dist)
    new_elbow = shoulder + upper * (cos_a * u + np.sqrt(max(1.0 - cos_a ** 2, 0.0)) * v)
    return new_elbow, shoulder + dist * u


def _pelvis_frames(joints: np.ndarray) -> np.ndarray:
    """(T, 3, 3) the pelvis's axes per frame: x to the left hip, y up the spine, z forward."""
    x = joints[:, _J["left_hip"]] - joints[:, _J["right_hip"]]
    y0 = joints[:, _J["spine1"]] - joints[:, _J["pelvis"]]
    z = np.cross(x, y0)
    y = np.cross(z, x)
    axes = [a / np.linalg.norm(a, axis=1, keepdims=True) for a in (x, y, z)]
    return np.stack(axes, axis=2)


def _hip_points(body) -> np.ndarray:
    """(2, 3) the outermost skin points of the hips (left, right) at the waist, relative to the
    rest pelvis."""
    rest = np.asarray(body.rest_joints, np.float64)
    v = np.asarray(body.vertices, np.float64)
    dominant = np.asarray(body.weights).argmax(1)
    torso = np.isin(dominant, [_J["pelvis"], _J["spine1"]])
    waist = 0.5 * (rest[_J["pelvis"], 1] + rest[_J["spine1"], 1])
    band = torso & (np.abs(v[:, 1] - waist) < 0.02)
    left = v[band][np.argmax(v[band, 0])]
    right = v[band][np.argmin(v[band, 0])]
    return np.stack([left, right]) - rest[_J["pelvis"]]


def _clap_gap(t: np.ndarray) -> np.ndarray:
    """The hands' extra opening (m) at times t (s): zero a third of each clap, smooth."""
    phase = 0.5 - 0.5 * np.cos(2 * np.pi * CLAP_HZ * t)  # 0..1
    return CLAP_OPEN * np.clip((phase - 1.0 / 3.0) * 1.5, 0.0, 1.0) ** 2


def _targets(kind: str, body, joints: np.ndarray, axes: np.ndarray, fps: float, push: np.ndarray) -> np.ndarray:
    """(T, 2, 3) wrist targets; push (T, 2): how far each is moved out along its direction."""
    pelvis = joints[:, _J["pelvis"]]
    rest = np.asarray(body.rest_joints, np.float64)
    out = np.zeros((len(joints), 2, 3))
    if kind == "hands-on-hips":
        hips = _hip_points(body)
        for a, sign in enumerate((1.0, -1.0)):
            local = hips[a] + np.array([sign * 0.03, 0.03, 0.0])
            local = local[None] + push[:, a, None] * np.array([sign, 0.0, 0.0])
            out[:, a] = pelvis + np.einsum("tij,tj->ti", axes, local)
    else:
        chest = CLAP_HEIGHT * (rest[_J["spine3"], 1] - rest[_J["pelvis"], 1])
        opening = _clap_gap(np.arange(len(joints)) / fps)
        for a, sign in enumerate((1.0, -1.0)):
            local = np.zeros((len(joints), 3))
            local[:, 0] = sign * (0.5 * opening + push[:, a])
            local[:, 1] = chest
            local[:, 2] = 0.36 * rest[_J["pelvis"], 1] / 0.95
            out[:, a] = pelvis + np.einsum("tij,tj->ti", axes, local)
    return out


def _pose_arms(kind: str, joints: np.ndarray, axes: np.ndarray, targets: np.ndarray) -> np.ndarray:
    out = joints.copy()
    for t in range(len(joints)):
        for a, (s, e, w, sign) in enumerate(_ARMS):
            pole_local = np.array([sign, -0.2, -0.7]) if kind == "hands-on-hips" else np.array([sign, -0.6, 0.0])
            out[t, e], out[t, w] = _arm_ik(joints[t, s], joints[t, e], joints[t, w], targets[t, a], axes[t] @ pole_local)
    return out


def _gaps(kind: str, body, joints: np.ndarray) -> np.ndarray:
    """(T, 2) each hand's exact gap to what it should touch (the hips' skin or the other hand's)."""
    from live.body.skinning import lbs
    from live.retarget.analytic import local_rotations_from_joints
    from live.retarget.contacts_surface import border_vertices, signed_distances, skin_faces, vertex_normals

    faces = np.asarray(body.faces, np.int64)
    dominant = np.asarray(body.weights).argmax(1)
    hands = [np.flatnonzero(dominant == _J[f"{side}_wrist"]) for side in ("left", "right")]
    torso = np.isin(dominant, [_J[n] for n in ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar")])
    masks = [torso, torso] if kind == "hands-on-hips" else [dominant == _J["right_wrist"], dominant == _J["left_wrist"]]
    skins = [faces[skin_faces(faces, m)] for m in masks]
    borders = [border_vertices(f, len(dominant)) for f in skins]
    rot = local_rotations_from_joints(joints, body.rest_joints)
    verts = lbs(body.vertices, body.weights, body.rest_joints, rot, joints[:, 0])
    out = np.zeros((len(joints), 2))
    for t, v in enumerate(np.asarray(verts, np.float64)):
        normals = vertex_normals(v, faces)
        for a in range(2):
            out[t, a] = signed_distances(v, normals, skins[a], v[hands[a]], borders[a])[0].min()
    return out


def contact_clip(kind: str, motion, body, passes: int = 6):
    """A Motion like ``motion`` (30 fps, prepared as the evaluations prepare clips) on ``body``
    with its arms replaced: ``hands-on-hips`` or ``clapping`` (see the module's docstring).
    Its rest skeleton is the body's: put back on that body it reproduces the contacts."""
    from live.evaluation.retarget import _on_body
    from live.retarget.analytic import local_rotations_from_joints

    if kind not in KINDS:
        raise UserInputError(f"unknown contact clip {kind!r}; choose {', '.join(KINDS)}")
    rest = np.asarray(body.rest_joints, np.float64)
    root, joints = _on_body(motion, rest)
    axes = _pelvis_frames(joints)
    # Clapping starts with the wrists a hand's length apart each side (the hands, along the
    # forearms, pointing at each other).
    push = np.full((len(joints), 2), 0.0 if kind == "hands-on-hips" else 0.09)
    touching = np.ones((len(joints), 2), bool) if kind == "hands-on-hips" else \
        np.repeat((_clap_gap(np.arange(len(joints)) / motion.fps) == 0.0)[:, None], 2, axis=1)
    edited = joints
    for _ in range(passes):
        edited = _pose_arms(kind, joints, axes, _targets(kind, body, joints, axes, motion.fps, push))
        gaps = _gaps(kind, body, edited)
        # Each hand moved in by what it misses, where it should touch (between the hands each by all
        # of it: the hands point along the forearms, toward each other, and open slowly).
        share = 1.0
        push = push - np.where(touching, share * gaps, 0.0)
        if kind == "clapping":  # one opening for every clap: the hands' shape does not change
            push[:] = np.median(push[touching[:, 0], 0]) if touching.any() else 0.0
    rot = local_rotations_from_joints(edited, rest).astype(np.float32)
    name = f"{motion.name}-{kind}"
    return replace(motion, name=name, rotations=rot, joints=edited.astype(np.float32), root=root.astype(np.float32),
                   rest_joints=rest.astype(np.float32))


#: Held-out takes with self-contacts (clip, first frame and frames at 30 fps, arms made into a
#: contact clip or as they are): none was used to choose the settings. Two held-out subjects'
#: walks made into hands-on-hips and clapping clips; a held-out subject's walk, hands passing the
#: thighs; hands on belly and hip, curled in (another take of subject 49); hands together and on
#: the torso (salsa); hands on the head and torso (martial arts).
CONTACT_TAKES = (("cc_007_04.bvh", 0, 150, "hands-on-hips"), ("mb_08_04.bvh", 0, 150, "clapping"),
                 ("mb_12_01.bvh", 0, 150, None), ("mb_49_10.bvh", 100, 200, None),
                 ("daz_salsa_10.bvh", 0, 200, None), ("daz_martial_05.bvh", 150, 200, None))


#: Takes the correction's settings were chosen on (training subjects, none of them in
#: CONTACT_TAKES): hands on hips and clapping made from subject 35's walks, hands on the belly
#: curled in (subject 49), washing (subject 2), another salsa and another martial-arts take.
TUNING_TAKES = (("mb_35_01.bvh", 0, 150, "hands-on-hips"), ("mb_35_09.bvh", 0, 150, "clapping"),
                ("mb_49_11.bvh", 120, 180, None), ("cc_002_10.bvh", 0, 240, None),
                ("daz_salsa_16.bvh", 0, 200, None), ("daz_martial_08.bvh", 0, 200, None))


def take_motion(clip: str, start: int, frames: int, kind: str | None, body, bvh_dir=None):
    """A take of CONTACT_TAKES prepared at 30 fps on the performer's body (its arms made into a
    contact clip when ``kind`` says so), grounded as a motion of its own: as the evaluation
    prepares it again (live/evaluation/retarget.py ``prepare_motion``), so that skeletons made
    from the take and the reference made from the prepared motion stand on the same floor (the
    clip grounded whole put a take's window up to 12 mm off it)."""
    from pathlib import Path

    from live.core import assets
    from live.evaluation.retarget import grounded, prepare_motion

    motion = prepare_motion((Path(bvh_dir) if bvh_dir else assets.bvh_dir()) / clip, 30.0)
    motion = replace(motion, joints=motion.joints[start:start + frames],
                     rotations=motion.rotations[start:start + frames], root=motion.root[start:start + frames])
    return grounded(contact_clip(kind, motion, body) if kind else motion)
