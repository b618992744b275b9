"""Avatars from VRM and glTF humanoids: ``load_gltf_avatar(path) -> Body`` for ``.vrm``, ``.glb``, ``.gltf``.

The file is read by live/body/gltf_file.py (pygltflib for the container, numpy for the accessors,
every one checked against the bytes its buffer holds). What is read:

- the humanoid bone map: VRM 0.x ``extensions.VRM.humanoid.humanBones`` ([{bone, node}]), VRM 1.0
  ``extensions.VRMC_vrm.humanoid.humanBones`` ({bone: {node}}), or, for a plain glTF skin, the bone
  names matched as BVH rigs are (live/motion/auto_mapping.py);
- the node tree at rest (each node's TRS or matrix), giving the world position of every bone;
- every mesh primitive (triangles), posed by the nodes at rest: a skinned one through its skin
  (joint world matrix x inverse bind matrix), any other one rigidly by its node.

The humanoid bones become the 22 canonical joints (``joint_sources``: which bone each joint is, or
that it is a point between two); the file's skin weights are folded onto them, each file joint to
its nearest ancestor that is a canonical joint. The result is turned into our frame: +y up, metres,
facing +z with the left side at +x (VRM 0.x faces -z and is turned 180 degrees about y; the turn is
decided by the humanoid's own left and right, so a file whose metadata lies still comes out right),
feet on y = 0. The rest pose must be a T-pose: when the arms are more than 25 degrees from
horizontal (an A-pose), each upper arm and then each forearm is turned about its joint to point
straight out sideways, and the mesh follows through the file's own skin.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.body.body import Body, ExtraBone
from live.body.gltf_file import open_gltf, world_matrices
from live.body.gltf_mesh import read_look, read_meshes
from live.body.gltf_rig import build_rig
from live.core.errors import FormatError, LivecapError
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES, PARENTS, default_rest_joints

log = logging.getLogger(__name__)

GLTF_SUFFIXES = (".vrm", ".glb", ".gltf")
#: Arms further than this from horizontal in the rest pose are not a T-pose.
TPOSE_TOLERANCE_DEG = 25.0

#: VRM humanoid bone -> canonical joint, for the bones that are one (VRM 0.x and 1.0 share the names).
#: The torso is settled in ``_torso`` (which bone is spine2 / spine3 depends on the bones present).
VRM_BONE_TO_JOINT: dict[str, str] = {
    "hips": "pelvis", "spine": "spine1", "neck": "neck", "head": "head",
    **{f"{side}{bone}": f"{side}_{joint}" for side in ("left", "right") for bone, joint in (
        ("Shoulder", "collar"), ("UpperArm", "shoulder"), ("LowerArm", "elbow"), ("Hand", "wrist"),
        ("UpperLeg", "hip"), ("LowerLeg", "knee"), ("Foot", "ankle"), ("Toes", "foot"))},
}
#: Humanoid bones beyond the 22 joints, kept at rest (VMC sends them): VRM 0.x name -> Unity
#: HumanBodyBones name. VRM 1.0 names its thumb bones one step earlier (Metacarpal, Proximal, Distal
#: for Unity's Proximal, Intermediate, Distal): see ``_extra_bone_names``.
EXTRA_BONE_NAMES: dict[str, str] = {
    "leftEye": "LeftEye", "rightEye": "RightEye", "jaw": "Jaw",
    **{f"{side}{finger}{part}": f"{side.capitalize()}{finger}{part}" for side in ("left", "right")
       for finger in ("Thumb", "Index", "Middle", "Ring", "Little") for part in ("Proximal", "Intermediate", "Distal")},
}
REQUIRED_BONES = ("hips", "spine", "head", "leftUpperArm", "leftLowerArm", "leftHand", "rightUpperArm",
                  "rightLowerArm", "rightHand", "leftUpperLeg", "leftLowerLeg", "leftFoot", "rightUpperLeg",
                  "rightLowerLeg", "rightFoot")



@dataclass(frozen=True)
class GltfHumanoid:
    """What ``read_gltf_humanoid`` found: the Body, and where it came from.

    kind: "vrm0", "vrm1" or "skin"; bones: humanoid bone name -> node index (for "skin", the
    canonical joint names of the matched nodes); node_names: every node's name;
    joint_sources: per canonical joint, the node it is (its position and its weights), or None
    for a point placed between two bones (a bone the file does not have); turned: whether the
    file was turned 180 degrees about y (it faced -z); to_ours: (4, 4) file scene -> our frame.
    """

    body: Body
    kind: str
    bones: dict[str, int]
    node_names: tuple[str, ...]
    joint_sources: tuple[int | None, ...]
    turned: bool
    to_ours: np.ndarray


def is_gltf_file(spec: str | Path) -> bool:
    return Path(str(spec)).suffix.lower() in GLTF_SUFFIXES


# ----------------------------------------------------------------------------- the humanoid


def _humanoid_bones(doc, where: str) -> tuple[str, dict[str, int]]:
    """("vrm0" / "vrm1", {bone: node}), or ("skin", {}) when the file has no VRM humanoid."""
    ext = doc.extensions or {}
    n = len(doc.nodes)
    bones: dict[str, int] = {}
    if isinstance(ext.get("VRMC_vrm"), dict):
        kind, raw = "vrm1", (ext["VRMC_vrm"].get("humanoid") or {}).get("humanBones")
        items = [(b, v.get("node") if isinstance(v, dict) else None) for b, v in raw.items()] \
            if isinstance(raw, dict) else None
    elif isinstance(ext.get("VRM"), dict):
        kind, raw = "vrm0", (ext["VRM"].get("humanoid") or {}).get("humanBones")
        items = [(b.get("bone"), b.get("node")) for b in raw if isinstance(b, dict)] if isinstance(raw, list) else None
    else:
        return "skin", {}
    if items is None:
        raise FormatError(f"its {'VRMC_vrm' if kind == 'vrm1' else 'VRM'} extension has no humanoid.humanBones",
                          path=where)
    for bone, node in items:
        if isinstance(bone, str) and isinstance(node, int) and 0 <= node < n:
            bones[bone] = node
        elif isinstance(bone, str) and node not in (None, -1):
            raise FormatError(f"humanoid bone {bone!r} points at node {node!r}, which does not exist", path=where)
    missing = [b for b in REQUIRED_BONES if b not in bones]
    if missing:
        raise FormatError(f"the VRM humanoid lacks required bones: {', '.join(missing)}", path=where)
    return kind, bones


def _vrm_sources(bones: dict[str, int]) -> dict[str, int | tuple[int, int, float]]:
    """Canonical joint -> node, or (node a, node b, t) = the point lerp(a, b, t) for a joint the file
    has no bone for. The joint where the neck and the shoulders branch off is spine3, so that the
    chest's skin turns with it (with no upperChest that is the chest, and spine2 lies between)."""
    src: dict[str, int | tuple[int, int, float]] = {}
    for bone, joint in VRM_BONE_TO_JOINT.items():
        if bone in bones:
            src[joint] = bones[bone]
    spine, head = bones["spine"], bones["head"]
    chest, upper = bones.get("chest"), bones.get("upperChest")
    if upper is not None and chest is not None:
        src["spine2"], src["spine3"] = chest, upper
    elif upper is not None or chest is not None:
        src["spine3"] = upper if upper is not None else chest  # type: ignore[assignment]
        src["spine2"] = (spine, src["spine3"], 0.5)  # type: ignore[assignment]
    if "neck" not in src:
        top = src.get("spine3")
        src["neck"] = (top, head, 0.5) if isinstance(top, int) else (spine, head, 0.8)
    if "spine3" not in src:
        neck = src["neck"] if isinstance(src["neck"], int) else head
        src["spine2"], src["spine3"] = (spine, neck, 1 / 3), (spine, neck, 2 / 3)
    for side in ("left", "right"):
        if f"{side}_collar" not in src:
            top = src["spine3"]
            src[f"{side}_collar"] = (top, bones[f"{side}UpperArm"], 0.5) if isinstance(top, int) \
                else (spine, bones[f"{side}UpperArm"], 0.8)
    return src


def _skin_sources(doc, world: np.ndarray, parents: np.ndarray, where: str) -> dict[str, int | tuple[int, int, float]]:
    """Canonical joint -> node for a plain glTF skin, through the BVH auto-mapping of its bone names."""
    from live.io.bvh_clip import BvhSkeleton
    from live.motion.auto_mapping import auto_mapping

    joints = sorted({int(j) for skin in doc.skins or [] for j in skin.joints or [] if 0 <= j < len(doc.nodes)})
    if not joints:
        raise FormatError("no VRM humanoid and no skin: not a rigged avatar", path=where)
    # The skin's joints and their ancestors as a BVH-like tree (parents before children).
    keep = set(joints)
    for j in joints:
        p = int(parents[j])
        while p >= 0:
            keep.add(p)
            p = int(parents[p])
    order: list[int] = []
    roots = [j for j in keep if parents[j] < 0 or int(parents[j]) not in keep]
    stack = sorted(roots, reverse=True)
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(sorted((c for c in (doc.nodes[j].children or []) if c in keep), reverse=True))
    pos = {j: i for i, j in enumerate(order)}
    names = []
    for j in order:
        name = doc.nodes[j].name or f"node{j}"
        names.append(name if name not in names else f"{name}#{j}")
    par = np.array([pos.get(int(parents[j]), -1) for j in order], np.int64)
    xyz = world[order, :3, 3]
    offsets = np.array([xyz[i] - (xyz[par[i]] if par[i] >= 0 else 0.0) for i in range(len(order))])
    skeleton = BvhSkeleton(names=tuple(names), parents=par, offsets=offsets,
                           channels=tuple(() for _ in order))
    try:
        table = auto_mapping(skeleton)
    except FormatError as e:
        raise FormatError(f"no VRM humanoid, and its skin is not a recognisable skeleton: {e.message}",
                          path=where) from None
    by_name = {n: order[i] for i, n in enumerate(names)}
    src: dict[str, int | tuple[int, int, float]] = {}
    for joint, spec in table.joints.items():
        if isinstance(spec, str):
            if spec not in by_name:  # an end site: nothing of ours to place it on
                raise FormatError(f"its skin has no bone for {joint}", path=where)
            src[joint] = by_name[spec]
        else:
            src[joint] = (by_name[spec[0]], by_name[spec[1]], float(spec[2]))
    return src


# ----------------------------------------------------------------------------- the avatar


#: Canonical joint -> Unity HumanBodyBones name for a plain glTF skin (VRM files name their bones);
#: spine2 / spine3 are settled in ``_real_bones``.
_SKIN_BONE_NAMES = {joint: bone[0].upper() + bone[1:] for bone, joint in VRM_BONE_TO_JOINT.items()}


def _real_bones(kind: str, bones: dict[str, int], src: dict, owners: dict[int, int]) -> dict[int, tuple[int, str]]:
    """Canonical joint -> (node, HumanBodyBones name) for the joints that are a bone of the file (a
    joint placed between two bones is none). A VRM names its bones; for a plain skin the torso
    bones above the spine are Chest, then UpperChest, in order (one chest bone is the Chest)."""
    real = {j: int(src[name]) for name, j in JOINT_INDEX.items()
            if isinstance(src.get(name), int) and owners.get(int(src[name])) == j}
    if kind != "skin":
        node_bone = {node: bone for bone, node in bones.items() if bone in VRM_BONE_TO_JOINT or bone in
                     ("chest", "upperChest")}
        return {j: (n, node_bone[n][0].upper() + node_bone[n][1:]) for j, n in real.items() if n in node_bone}
    chest = iter(("Chest", "UpperChest"))
    return {j: (n, next(chest) if JOINT_NAMES[j] in ("spine2", "spine3") else _SKIN_BONE_NAMES[JOINT_NAMES[j]])
            for j, n in sorted(real.items())}


def _extra_bone_names(kind: str, bones: dict[str, int]) -> dict[int, str]:
    """Node -> Unity HumanBodyBones name, for the humanoid bones beyond the 22 joints. A VRM 1.0 side
    with a ``ThumbMetacarpal`` uses 1.0's thumb names; one without uses 0.x's (as some converters write)."""
    out: dict[int, str] = {}
    for bone, node in bones.items():
        name = bone
        if kind == "vrm1" and "Thumb" in bone and f"{bone.partition('Thumb')[0]}ThumbMetacarpal" in bones:
            side, _, part = bone.partition("Thumb")
            name = {"Metacarpal": f"{side}ThumbProximal", "Proximal": f"{side}ThumbIntermediate"}.get(
                part, f"{side}Thumb{part}" if part == "Distal" else "")
        if name in EXTRA_BONE_NAMES:
            out[node] = EXTRA_BONE_NAMES[name]
    return out


def _extra_bones(kind: str, bones: dict[str, int], world: np.ndarray, parents: np.ndarray,
                 to_ours: np.ndarray, joints: np.ndarray, owners: dict[int, int]) -> tuple[ExtraBone, ...]:
    """The file's humanoid bones beyond the 22 joints at rest, in our frame, each hung from its
    nearest ancestor that is a humanoid bone we send (a canonical joint or another extra bone),
    parents first. A bone with no such ancestor is left out."""
    named = {n: u for n, u in _extra_bone_names(kind, bones).items() if n not in owners}

    def position(n: int) -> np.ndarray:
        return to_ours[:3, :3] @ world[n, :3, 3] + to_ours[:3, 3]

    def depth(n: int) -> int:
        d = 0
        while parents[n] >= 0:
            n, d = int(parents[n]), d + 1
        return d

    out = []
    for n in sorted(named, key=lambda n: (depth(n), n)):
        k = int(parents[n])
        while k >= 0 and k not in named and k not in owners:
            k = int(parents[k])
        if k < 0:
            continue
        parent, at = (named[k], position(k)) if k in named else (JOINT_NAMES[owners[k]], joints[owners[k]])
        offset = position(n) - at
        out.append(ExtraBone(name=named[n], parent=parent, offset=(float(offset[0]), float(offset[1]), float(offset[2]))))
    return tuple(out)


def _point(world: np.ndarray, spec: int | tuple[int, int, float]) -> np.ndarray:
    if isinstance(spec, int):
        return world[spec, :3, 3]
    a, b, t = spec
    return (1.0 - t) * world[a, :3, 3] + t * world[b, :3, 3]


def _subtree(parents: np.ndarray, top: int) -> np.ndarray:
    inside = np.zeros(len(parents), bool)
    for j in range(len(parents)):
        k = j
        while k >= 0 and k != top:
            k = int(parents[k])
        inside[j] = k == top
    return np.flatnonzero(inside)


def _arm_angles(world: np.ndarray, src: dict, left_sign: float) -> tuple[float, float]:
    """Degrees between each arm (shoulder -> wrist) and its T-pose direction (left arm to the left)."""
    out = []
    for side, sign in (("left", left_sign), ("right", -left_sign)):
        d = _point(world, src[f"{side}_wrist"]) - _point(world, src[f"{side}_shoulder"])
        out.append(float(np.degrees(np.arccos(np.clip(sign * d[0] / max(np.linalg.norm(d), 1e-12), -1, 1)))))
    return out[0], out[1]


def _pose_arms_to_t(world: np.ndarray, parents: np.ndarray, src: dict, left_sign: float) -> np.ndarray:
    """World matrices with each upper arm, then each forearm, turned (shortest arc, about its joint)
    to point straight out sideways: an A-pose file posed into the T-pose by its own skeleton."""
    world = world.copy()
    for side, sign in (("left", left_sign), ("right", -left_sign)):
        for a, b in (("shoulder", "elbow"), ("elbow", "wrist")):
            ja, jb = src[f"{side}_{a}"], src[f"{side}_{b}"]
            if not isinstance(ja, int):
                continue
            p = world[ja, :3, 3].copy()
            d = _point(world, jb) - p
            d /= max(np.linalg.norm(d), 1e-12)
            target = np.array([sign, 0.0, 0.0])
            axis = np.cross(d, target)
            s, c = np.linalg.norm(axis), float(np.dot(d, target))
            if s < 1e-9:
                continue
            k = axis / s
            kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            r = np.eye(4)
            r[:3, :3] = np.eye(3) + s * kx + (1 - c) * kx @ kx
            move = np.eye(4)
            move[:3, 3] = p
            back = np.eye(4)
            back[:3, 3] = -p
            turn = move @ r @ back
            for n in _subtree(parents, ja):
                world[n] = turn @ world[n]
    return world


def _place_missing(joints: np.ndarray, src: dict) -> None:
    """A toe the file has no toes bone for, placed at the default skeleton's toe offset from the
    ankle scaled by the leg's length (ahead, +z). Every joint that is a file bone stays on its bone,
    even a spine bone on the hips (VRoid and Blender exports): the output rig turns the file's own
    bones (live/body/gltf_rig.py), so its joints must be where the file has them."""
    ref = default_rest_joints()
    for side in ("left", "right"):
        hip, ankle, foot = (JOINT_INDEX[f"{side}_{n}"] for n in ("hip", "ankle", "foot"))
        if f"{side}_foot" not in src:
            scale = np.linalg.norm(joints[ankle] - joints[hip]) / np.linalg.norm(ref[ankle] - ref[hip])
            joints[foot] = joints[ankle] + scale * (ref[foot] - ref[ankle])


#: What a field of the wrong JSON type (a string for a count, a list for an index) raises deep in the
#: reading; every one is a malformed file, reported in one line.
_MALFORMED = (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError)


def read_gltf_humanoid(path: str | Path) -> GltfHumanoid:
    """The avatar of a VRM 0.x / 1.0 file or a glTF with a recognisable skin (module docstring)."""
    path = Path(path)
    try:
        with np.errstate(all="ignore"):  # values are checked (finite, in range) where they are read
            return _read(path, str(path))
    except LivecapError:
        raise
    except _MALFORMED as e:
        raise FormatError(f"a malformed glTF ({type(e).__name__}: {e})", path=str(path)) from None


def _read(path: Path, where: str) -> GltfHumanoid:
    doc, buffers = open_gltf(path)
    world, parents = world_matrices(doc, where)
    kind, bones = _humanoid_bones(doc, where)
    src = _vrm_sources(bones) if kind != "skin" else _skin_sources(doc, world, parents, where)
    # Which way the file faces: its humanoid's left hand is on its +x side when it faces +z.
    left_sign = 1.0 if _point(world, src["left_wrist"])[0] >= _point(world, src["right_wrist"])[0] else -1.0
    left_deg, right_deg = _arm_angles(world, src, left_sign)
    if max(left_deg, right_deg) > TPOSE_TOLERANCE_DEG:
        world = _pose_arms_to_t(world, parents, src, left_sign)
        log.info("%s: arms %.0f / %.0f degrees from the T-pose (an A-pose), posed into the T-pose by its own skin",
                 where, left_deg, right_deg)
    owners = {spec: JOINT_INDEX[j] for j, spec in src.items() if isinstance(spec, int)}
    fold = np.zeros(len(doc.nodes), np.int64)  # node -> canonical joint: itself or its nearest owner above
    for n in range(len(doc.nodes)):
        k = n
        while k >= 0 and k not in owners:
            k = int(parents[k])
        fold[n] = owners[k] if k >= 0 else 0
    meshes = read_meshes(doc, buffers, world, fold, where)
    verts, faces, weights = meshes.vertices, meshes.faces, meshes.weights
    joints = np.stack([_point(world, src[n]) if n in src else np.zeros(3) for n in JOINT_NAMES])
    # Into our frame: turned about y so that the left side is +x (facing +z), feet on y = 0.
    to_ours = np.diag([left_sign, 1.0, left_sign, 1.0])
    verts = verts @ to_ours[:3, :3].T
    joints = joints @ to_ours[:3, :3].T
    floor = float(verts[:, 1].min())
    to_ours[1, 3] = -floor
    verts[:, 1] -= floor
    joints[:, 1] -= floor
    height = float(np.ptp(verts[:, 1]))
    if not (np.isfinite(verts).all() and np.isfinite(joints).all()):
        raise FormatError("its skin poses vertices at NaN or infinity (bad inverse bind matrices?)", path=where)
    if not 0.1 < height < 10.0:
        raise FormatError(f"the avatar is {height:.3g} m tall: not a humanoid in metres", path=where)
    if joints[JOINT_INDEX["pelvis"], 1] <= 0:
        raise FormatError("its hips are not above its lowest vertex", path=where)
    _place_missing(joints, src)
    sources = tuple(src[n] if isinstance(src.get(n), int) else None for n in JOINT_NAMES)  # type: ignore[misc]
    names = tuple(node.name or f"node{i}" for i, node in enumerate(doc.nodes))
    body = Body(vertices=verts.astype(np.float32), faces=faces.astype(np.int32), rest_joints=joints.astype(np.float32),
                weights=weights.astype(np.float32), parents=PARENTS.copy(), name=path.stem, phenotype=None,
                joint_names=bvh_joint_names(sources, names),
                extra_bones=_extra_bones(kind, bones, world, parents, to_ours, joints, owners),
                rig=build_rig(kind, world, parents, to_ours, _real_bones(kind, bones, src, owners),
                              _extra_bone_names(kind, bones)),
                look=read_look(doc, buffers, path, meshes.uv, meshes.face_material))
    return GltfHumanoid(body=body, kind=kind, bones=bones, node_names=names, joint_sources=sources,
                        turned=left_sign < 0, to_ours=to_ours)


def bvh_joint_names(sources: tuple[int | None, ...], node_names: tuple[str, ...]) -> tuple[str, ...]:
    """Per canonical joint, the name of the file's node it is, usable as a BVH joint name
    (whitespace becomes "_"); the canonical name for a joint placed between two bones, and for a
    node name that is empty or already taken (BVH importers key joints by name)."""
    out: list[str] = []
    for canonical, node in zip(JOINT_NAMES, sources, strict=True):
        name = "_".join(node_names[node].split()) if node is not None else ""
        out.append(name if name and name not in out and name not in JOINT_NAMES else canonical)
    return tuple(out)


def load_gltf_avatar(path: str | Path) -> Body:
    """The Body of a VRM / glTF humanoid (``read_gltf_humanoid``)."""
    return read_gltf_humanoid(path).body


def read_gltf_mesh(path: str | Path):
    """(vertices (V, 3) in the file's scene frame, faces (F, 3), AvatarLook) of a glTF without a
    skeleton: every triangle primitive placed by its node at rest (live/body/avatar.py fits a
    skeleton to it)."""
    path = Path(path)
    try:
        with np.errstate(all="ignore"):
            doc, buffers = open_gltf(path)
            world, _ = world_matrices(doc, str(path))
            meshes = read_meshes(doc, buffers, world, None, str(path))
            return meshes.vertices, meshes.faces, read_look(doc, buffers, path, meshes.uv, meshes.face_material)
    except LivecapError:
        raise
    except _MALFORMED as e:
        raise FormatError(f"a malformed glTF ({type(e).__name__}: {e})", path=str(path)) from None


def gltf_is_rigged(path: str | Path) -> bool:
    """True for a file read by ``load_gltf_avatar``: every ``.vrm``, and a ``.glb`` / ``.gltf`` with a
    VRM extension or a skin. A glTF mesh without either is a plain T-pose mesh (live/body/avatar.py
    fits a skeleton to it); one that cannot be read at all is a FormatError here."""
    path = Path(path)
    if path.suffix.lower() == ".vrm":
        return True
    try:
        doc, _ = open_gltf(path)
        ext = doc.extensions or {}
        return bool(doc.skins) or isinstance(ext.get("VRM"), dict) or isinstance(ext.get("VRMC_vrm"), dict)
    except LivecapError:
        raise
    except _MALFORMED as e:
        raise FormatError(f"a malformed glTF ({type(e).__name__}: {e})", path=str(path)) from None
