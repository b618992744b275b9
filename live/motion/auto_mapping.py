"""Map a BVH rig never seen before onto the canonical 22 joints (``auto_mapping``): anchors from
joint names (sides and body-part words, whatever the naming style), the rest from the shape of
the hierarchy."""

from __future__ import annotations

import re

import numpy as np

from live.core.errors import FormatError
from live.core.skeleton import JOINT_NAMES, ancestors_of, joint_depths
from live.io.bvh_clip import BvhSkeleton
from live.io.bvh_kinematics import rest_positions, skeleton_span
from live.motion.rig_tables import RigTable, Spec

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
    depth = joint_depths(parents)
    classes = [joint_class(n) for n in names]
    missing: list[str] = []

    def find(side: str | None, cls: str) -> int | None:
        hits = [j for j, (s, c) in enumerate(classes) if c == cls and s == side]
        return min(hits, key=lambda j: depth[j]) if hits else None

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
    head = min(heads, key=lambda j: depth[j])
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


def _ancestors(parents: np.ndarray, j: int) -> list[int]:
    """j and the joints above it, up to the root."""
    return [j, *ancestors_of(parents, j)]


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
