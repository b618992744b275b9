"""The Body: a rigged, skinned human mesh in the canonical T-pose (the body-file contract of
CONVENTIONS.md in memory). Loaded and saved by live.body.library, built from an Anny phenotype by
models.train.anny_bodies."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from live.body.gltf_rig import AvatarRig


@dataclass(frozen=True)
class ExtraBone:
    """A humanoid bone of an avatar file beyond the 22 joints (a finger, an eye, the jaw), kept at
    rest: name in Unity's HumanBodyBones spelling (``LeftIndexProximal``; VRM's humanoid names are
    the same in lowerCamelCase); parent: the canonical joint (``left_wrist``) or the extra bone
    (``LeftIndexProximal``) it hangs from; offset: its rest position minus its parent's, metres,
    in the body's frame."""

    name: str
    parent: str
    offset: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class AvatarLook:
    """How an avatar file colours its mesh (the video draws it): uv (V, 2) texture coordinates of the
    Body's vertices (glTF's: u right, v down the image); face_material (F,) material of each
    triangle, -1 for none; colours (M, 3) each material's base colour, BGR in 0..1; textures (M,)
    each material's base-colour image (H, W, 3) uint8 BGR or None; uv_transforms (M, 4) the uv
    offset (2) and scale (2) of each material's texture."""

    uv: np.ndarray
    face_material: np.ndarray
    colours: np.ndarray
    textures: tuple[np.ndarray | None, ...]
    uv_transforms: np.ndarray


@dataclass(frozen=True, eq=False)
class Body:
    """vertices (V,3) float32 T-pose mesh, y up, feet on y=0, facing +z; faces (F,3) int32;
    rest_joints (22,3) float32; weights (V,22) float32 rows summing to 1; parents (22,) int32;
    phenotype: the Anny parameters it was made from, or None; joint_names: the avatar file's own
    name for each of the 22 joints (a VRM's humanoid bone nodes), or None (canonical names);
    extra_bones: the file's humanoid bones beyond the 22, parents first (VMC sends them at rest);
    rig: a VRM / glTF avatar's own bones, their rest frames and the joints it has no bone for
    (live/body/gltf_rig.py: the retarget stage fits poses to it, VMC drives its bones), or None;
    look: a glTF avatar's materials and textures (the video), or None (one flat colour).
    Arrays of a loaded body are read-only (load_body shares them between callers)."""

    vertices: np.ndarray
    faces: np.ndarray
    rest_joints: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    name: str
    phenotype: dict | None = None
    joint_names: tuple[str, ...] | None = None
    extra_bones: tuple[ExtraBone, ...] = ()
    rig: AvatarRig | None = None
    look: AvatarLook | None = None

    @property
    def height(self) -> float:
        return float(self.vertices[:, 1].max() - self.vertices[:, 1].min())
