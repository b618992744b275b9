"""Bodies built from an Anny phenotype (training code: needs the ``train`` extra, torch and anny).

Build the Anny body (rig ``cmu_mb``, topology ``notoes``), pose it from Anny's A-pose into the
canonical T-pose with its own bones (legs straight down, arms and forearms along +-x, everything
else as Anny rests it), convert Anny's frame (z up, facing -y) to ours (y up, facing +z, feet on
y = 0), decimate to about 7k vertices with open3d's quadric decimation (weights: inverse-distance
blend of the 4 nearest full-resolution vertices) and fold Anny's 31 bone weights onto the 22
canonical joints. Deterministic: the same anny and open3d versions give the same body byte for
byte, so ``anny:<a preset's phenotype>`` is that preset.

The runtime never builds: ``ensure_built`` writes each ``anny:`` body once into the body cache
(``live.body.library.anny_body_path``), where ``load_body`` reads it with numpy alone
(``livecap train bodies --anny SPEC``; the training commands build their phenotypes first).
torch and anny are imported only when a body is built.
"""

from __future__ import annotations

import numpy as np

from live.body.body import Body
from live.body.library import ANNY_KEYS, anny_body_path, format_anny_spec, parse_anny_spec, save_body
from live.core import assets
from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX, PARENTS

#: Anny frame -> ours: x stays (subject's left), z up -> y up, -y forward -> +z forward.
ANNY_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

#: Which canonical joint moves each Anny cmu_mb bone's vertices (bones fold into their joint).
BONE_TO_JOINT = {
    "Hips": "pelvis", "LHipJoint": "pelvis", "RHipJoint": "pelvis",
    "LeftUpLeg": "left_hip", "LeftLeg": "left_knee", "LeftFoot": "left_ankle", "LeftToeBase": "left_foot",
    "RightUpLeg": "right_hip", "RightLeg": "right_knee", "RightFoot": "right_ankle", "RightToeBase": "right_foot",
    "LowerBack": "spine1", "Spine": "spine2", "Spine1": "spine3", "Neck": "neck", "Neck1": "neck", "Head": "head",
    "LeftShoulder": "left_collar", "LeftArm": "left_shoulder", "LeftForeArm": "left_elbow",
    "LeftHand": "left_wrist", "LThumb": "left_wrist", "LeftFingerBase": "left_wrist", "LeftHandFinger1": "left_wrist",
    "RightShoulder": "right_collar", "RightArm": "right_shoulder", "RightForeArm": "right_elbow",
    "RightHand": "right_wrist", "RThumb": "right_wrist", "RightFingerBase": "right_wrist", "RightHandFinger1": "right_wrist",
}
#: Where each canonical joint sits: the head of this Anny bone.
JOINT_AT_BONE_HEAD = {
    "pelvis": "Hips", "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg", "spine1": "LowerBack",
    "left_knee": "LeftLeg", "right_knee": "RightLeg", "spine2": "Spine", "left_ankle": "LeftFoot",
    "right_ankle": "RightFoot", "spine3": "Spine1", "left_foot": "LeftToeBase", "right_foot": "RightToeBase",
    "neck": "Neck", "left_collar": "LeftShoulder", "right_collar": "RightShoulder", "head": "Head",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm", "left_elbow": "LeftForeArm",
    "right_elbow": "RightForeArm", "left_wrist": "LeftHand", "right_wrist": "RightHand",
}
#: T-pose bone directions (our frame) for the bones that Anny's A-pose holds differently.
TPOSE_DIRECTIONS = {
    "LeftUpLeg": (0.0, -1.0, 0.0), "LeftLeg": (0.0, -1.0, 0.0),
    "RightUpLeg": (0.0, -1.0, 0.0), "RightLeg": (0.0, -1.0, 0.0),
    "LeftArm": (1.0, 0.0, 0.0), "LeftForeArm": (1.0, 0.0, 0.0),
    "RightArm": (-1.0, 0.0, 0.0), "RightForeArm": (-1.0, 0.0, 0.0),
}

TARGET_VERTICES = 7000

TRAIN_EXTRA_MISSING = "building an anny: body needs the train extra: pip install 'livecap[train]'"

_MODEL = None


def _train_modules():
    """(anny, torch), or UserInputError when the train extra is not installed."""
    try:
        import anny  # first: it imports torch itself, and a missing anny should fail fast
        import torch
    except ImportError:
        raise UserInputError(TRAIN_EXTRA_MISSING) from None
    return anny, torch


def _anny_model():
    global _MODEL
    if _MODEL is None:
        anny, _ = _train_modules()
        from anny.paths import set_anny_cache_path

        cache = assets.cache_dir("anny")
        cache.mkdir(parents=True, exist_ok=True)
        set_anny_cache_path(str(cache))
        _MODEL = anny.Anny(rig="cmu_mb", topology="notoes", skinning_method="lbs")
    return _MODEL


def _rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    from live.core.rotations import quat_between, quat_to_matrix

    return quat_to_matrix(quat_between(u, v))


def _tpose(vertices, heads, tails, parents, names, weights_dense):
    """Pose Anny's rest mesh (our frame) into the T-pose by LBS over its own bones."""
    n = len(names)
    glob = np.zeros((n, 3, 3))
    new_heads = heads.copy()
    for b in range(n):
        p = parents[b]
        parent_rot = np.eye(3) if p < 0 else glob[p]
        if p >= 0:
            new_heads[b] = new_heads[p] + parent_rot @ (heads[b] - heads[p])
        target = TPOSE_DIRECTIONS.get(names[b])
        if target is None:
            glob[b] = parent_rot
        else:
            current = parent_rot @ (tails[b] - heads[b])
            glob[b] = _rotation_between(current, np.asarray(target)) @ parent_rot
    # Rigid transform of each bone: x -> R (x - head) + new_head.
    trans = new_heads - np.einsum("bij,bj->bi", glob, heads)
    posed = np.einsum("vb,bij,vj->vi", weights_dense, glob, vertices) + weights_dense @ trans
    return posed, new_heads


def build_body(phenotype: dict[str, float], name: str, target_vertices: int = TARGET_VERTICES) -> Body:
    """Build one body from an Anny phenotype (all of ANNY_KEYS, values in [0, 1])."""
    _, torch = _train_modules()
    import open3d as o3d
    from scipy.spatial import cKDTree

    model = _anny_model()
    with torch.no_grad():
        out = model(phenotype_kwargs={k: float(phenotype[k]) for k in ANNY_KEYS})
    verts = out["rest_vertices"][0].double().numpy() @ ANNY_TO_WORLD.T
    heads = out["rest_bone_heads"][0].double().numpy() @ ANNY_TO_WORLD.T
    tails = out["rest_bone_tails"][0].double().numpy() @ ANNY_TO_WORLD.T
    names = list(model.bone_labels)
    parents = [int(p) for p in model.bone_parents]
    faces = model.get_triangular_faces().numpy() if hasattr(model, "get_triangular_faces") else model.faces.numpy()
    idx = model.vertex_bone_indices.numpy()
    w = model.vertex_bone_weights.double().numpy()
    dense = np.zeros((len(verts), len(names)))
    np.add.at(dense, (np.repeat(np.arange(len(verts)), idx.shape[1]), idx.ravel()), w.ravel())
    dense /= dense.sum(axis=1, keepdims=True)

    posed, new_heads = _tpose(verts, heads, tails, parents, names, dense)
    floor = posed[:, 1].min()
    posed[:, 1] -= floor
    new_heads[:, 1] -= floor

    # Fold bone weights onto the 22 canonical joints.
    fold = np.zeros((len(names), len(PARENTS)))
    for b, bone in enumerate(names):
        fold[b, JOINT_INDEX[BONE_TO_JOINT[bone]]] = 1.0
    weights22 = dense @ fold
    rest_joints = np.stack([new_heads[names.index(JOINT_AT_BONE_HEAD[j])] for j in sorted(JOINT_INDEX, key=JOINT_INDEX.get)])

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(posed), o3d.utility.Vector3iVector(faces.astype(np.int32)))
    mesh.remove_unreferenced_vertices()
    if len(posed) > target_vertices:
        mesh = mesh.simplify_quadric_decimation(target_number_of_triangles=2 * target_vertices)
        mesh.remove_degenerate_triangles()
        mesh.remove_unreferenced_vertices()
    v_small = np.asarray(mesh.vertices)
    f_small = np.asarray(mesh.triangles, dtype=np.int32)
    # Weights of the decimated mesh: inverse-distance blend of the 4 nearest full-resolution vertices.
    dist, nn = cKDTree(posed).query(v_small, k=4)
    inv = 1.0 / np.maximum(dist, 1e-6)
    w_small = np.einsum("vk,vkj->vj", inv, weights22[nn]) / inv.sum(axis=1, keepdims=True)
    w_small /= w_small.sum(axis=1, keepdims=True)
    return Body(vertices=v_small.astype(np.float32), faces=f_small, rest_joints=rest_joints.astype(np.float32),
                weights=w_small.astype(np.float32), parents=PARENTS.copy(), name=name,
                phenotype={k: float(phenotype[k]) for k in ANNY_KEYS})


def ensure_built(specs: list[str], progress: bool = False) -> list[str]:
    """Build every ``anny:`` spec not yet in the body cache and save it there; returns the specs
    built (the others were cached)."""
    todo = [s for s in dict.fromkeys(specs) if not anny_body_path(s).is_file()]
    it = todo
    if progress and todo:
        from tqdm import tqdm

        it = tqdm(todo, desc="anny bodies", unit="body")
    for spec in it:
        phenotype = parse_anny_spec(spec)
        path = anny_body_path(spec)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_body(path, build_body(phenotype, format_anny_spec(phenotype)))
    return todo
