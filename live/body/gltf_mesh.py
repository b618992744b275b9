"""The meshes of a glTF / VRM avatar at rest: ``read_meshes`` (vertices, triangles, skin weights
folded onto the 22 joints, texture coordinates and each triangle's material) and ``read_look``
(each material's base colour factor and base-colour texture, for the video).

Every triangle primitive is posed by the node tree at rest: a skinned one through its skin (joint
world matrix x inverse bind matrix), any other one rigidly by its node. Primitives that share
their vertex accessors share their vertices. Textures are decoded by OpenCV (PNG, JPEG) and kept
at most ``MAX_TEXTURE_SIDE`` pixels a side: the avatar panel of the video is a few hundred pixels
tall. A texture that does not decode is logged and its material keeps its base colour factor.
"""

from __future__ import annotations

import base64
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.body.body import AvatarLook
from live.body.gltf_file import read_accessor
from live.core.errors import FormatError
from live.core.skeleton import NUM_JOINTS

log = logging.getLogger(__name__)

MAX_VERTICES = 2_000_000
MAX_FACES = 4_000_000
MAX_TEXTURE_SIDE = 1024


@dataclass(frozen=True)
class Meshes:
    """vertices (V, 3) in the file's scene frame; faces (F, 3); weights (V, 22) rows summing to 1;
    uv (V, 2) TEXCOORD_0 (0 where a primitive has none); face_material (F,) material index, -1 for none."""

    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    uv: np.ndarray
    face_material: np.ndarray


def read_meshes(doc, buffers, world: np.ndarray, fold: np.ndarray | None, where: str) -> Meshes:
    """Every triangle mesh of the file at rest (module docstring); fold: node -> canonical joint its
    skin weight goes to (None: every vertex on joint 0, for a mesh without a skeleton)."""
    verts, faces, weights, uvs, mats = [], [], [], [], []
    count = 0
    fold = np.zeros(len(doc.nodes), np.int64) if fold is None else fold
    for ni, node in enumerate(doc.nodes):
        if node.mesh is None:
            continue
        if not 0 <= node.mesh < len(doc.meshes or []):
            raise FormatError(f"node {ni} points at mesh {node.mesh}, which does not exist", path=where)
        skin = doc.skins[node.skin] if node.skin is not None and 0 <= node.skin < len(doc.skins or []) else None
        if skin is not None:
            sj = np.array([int(j) for j in skin.joints or []], np.int64)
            if len(sj) == 0 or sj.min() < 0 or sj.max() >= len(doc.nodes):
                raise FormatError(f"skin {node.skin} names joints that do not exist", path=where)
            ibm = read_accessor(doc, buffers, skin.inverseBindMatrices, where).reshape(-1, 4, 4).transpose(0, 2, 1) \
                if skin.inverseBindMatrices is not None else np.tile(np.eye(4), (len(sj), 1, 1))
            if len(ibm) < len(sj):
                raise FormatError(f"skin {node.skin} has {len(ibm)} inverse bind matrices for {len(sj)} joints",
                                  path=where)
            joint_mats = world[sj] @ ibm[:len(sj)]
        seen: dict[tuple, tuple[int, int]] = {}  # primitives sharing a vertex set share its vertices
        for prim in doc.meshes[node.mesh].primitives or []:
            if (prim.mode if prim.mode is not None else 4) != 4 or prim.attributes.POSITION is None:
                continue  # points and lines carry no surface
            a = prim.attributes
            key = (a.POSITION, a.JOINTS_0, a.WEIGHTS_0, a.TEXCOORD_0)
            if key not in seen:
                p = read_accessor(doc, buffers, a.POSITION, where)[:, :3]
                count += len(p)
                if count > MAX_VERTICES:
                    raise FormatError(f"more than the {MAX_VERTICES} vertices an avatar may have", path=where)
                ph = np.concatenate([p, np.ones((len(p), 1))], axis=1)
                if skin is not None and a.JOINTS_0 is not None and a.WEIGHTS_0 is not None:
                    ji = read_accessor(doc, buffers, a.JOINTS_0, where).astype(np.int64)
                    wi = read_accessor(doc, buffers, a.WEIGHTS_0, where)
                    if len(ji) != len(p) or len(wi) != len(p) or ji.min(initial=0) < 0 or ji.max(initial=0) >= len(sj):
                        raise FormatError("JOINTS_0 / WEIGHTS_0 do not match the positions or the skin", path=where)
                    wi = np.clip(wi, 0.0, None)
                    mats_v = np.einsum("vk,vkab->vab", wi / np.maximum(wi.sum(1, keepdims=True), 1e-12),
                                       joint_mats[ji])
                    v = np.einsum("vab,vb->va", mats_v, ph)[:, :3]
                    w = np.zeros((len(p), NUM_JOINTS))
                    np.add.at(w, (np.repeat(np.arange(len(p)), ji.shape[1]), fold[sj[ji]].ravel()), wi.ravel())
                else:
                    v = (ph @ world[ni].T)[:, :3]
                    w = np.zeros((len(p), NUM_JOINTS))
                    w[:, fold[ni]] = 1.0
                uv = np.zeros((len(p), 2))
                if a.TEXCOORD_0 is not None:
                    uv = read_accessor(doc, buffers, a.TEXCOORD_0, where)[:, :2]
                    if len(uv) != len(p):
                        raise FormatError("TEXCOORD_0 does not match the positions", path=where)
                seen[key] = (sum(len(x) for x in verts), len(p))
                verts.append(v)
                weights.append(w)
                uvs.append(uv)
            offset, n_here = seen[key]
            idx = read_accessor(doc, buffers, prim.indices, where)[:, 0].astype(np.int64) \
                if prim.indices is not None else np.arange(n_here)
            if len(idx) % 3 or (len(idx) and (idx.min() < 0 or idx.max() >= n_here)):
                raise FormatError("a triangle list that is not whole triangles of its own vertices", path=where)
            faces.append(idx.reshape(-1, 3) + offset)
            material = prim.material if isinstance(prim.material, int) and 0 <= prim.material < len(
                doc.materials or []) else -1
            mats.append(np.full(len(idx) // 3, material, np.int32))
    if not verts:
        raise FormatError("no triangle meshes", path=where)
    v, w = np.concatenate(verts), np.concatenate(weights)
    f = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    if len(f) > MAX_FACES:
        raise FormatError(f"more than the {MAX_FACES} faces an avatar may have", path=where)
    if len(f) and f.max() >= len(v):
        raise FormatError("triangles index vertices that do not exist", path=where)
    empty = w.sum(1) <= 0
    w[empty, 0] = 1.0  # vertices with no weight at all follow the pelvis
    return Meshes(vertices=v, faces=f, weights=w / w.sum(1, keepdims=True), uv=np.concatenate(uvs),
                  face_material=np.concatenate(mats) if mats else np.zeros(0, np.int32))


# ----------------------------------------------------------------------------- materials


def _image_bytes(doc, buffers, image, folder: Path) -> bytes | None:
    if image.bufferView is not None:
        if not 0 <= image.bufferView < len(doc.bufferViews or []):
            return None
        view = doc.bufferViews[image.bufferView]
        if not 0 <= view.buffer < len(buffers):
            return None
        start = view.byteOffset or 0
        return buffers[view.buffer][start:start + view.byteLength]
    uri = image.uri or ""
    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[-1], validate=False)
    target = (folder / uri).resolve()
    # A file beside the glTF only, as for buffers (names are not trusted).
    if uri and target.parent == folder.resolve() and target.is_file():
        return target.read_bytes()
    return None


def _decode(data: bytes | None) -> np.ndarray | None:
    """(H, W, 3) uint8 BGR of a PNG / JPEG, at most MAX_TEXTURE_SIDE a side, or None."""
    import cv2

    if not data:
        return None
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        return None
    side = max(img.shape[:2])
    if side > MAX_TEXTURE_SIDE:
        s = MAX_TEXTURE_SIDE / side
        img = cv2.resize(img, (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s))),
                         interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img)


def read_look(doc, buffers, path: Path, uv: np.ndarray, face_material: np.ndarray) -> AvatarLook:
    """The avatar's materials for the video: per material, the base colour factor as BGR in 0..1
    (sRGB; glTF's factor is linear and is raised to 1/2.2) and its base-colour texture (decoded
    once per image), with the texture transform (KHR_texture_transform offset and scale) folded
    into per-material uv offset and scale."""
    where = str(path)
    colours, textures, transforms = [], [], []
    decoded: dict[int, np.ndarray | None] = {}
    for mi, mat in enumerate(doc.materials or []):
        pbr = mat.pbrMetallicRoughness
        factor = np.asarray((pbr.baseColorFactor if pbr is not None and pbr.baseColorFactor else [1, 1, 1, 1])[:3],
                            np.float64)
        colours.append(np.clip(factor[::-1], 0.0, 1.0) ** (1 / 2.2))
        tex, transform = None, (0.0, 0.0, 1.0, 1.0)
        info = pbr.baseColorTexture if pbr is not None else None
        if info is not None and isinstance(info.index, int) and 0 <= info.index < len(doc.textures or []):
            src = doc.textures[info.index].source
            if isinstance(src, int) and 0 <= src < len(doc.images or []):
                if src not in decoded:
                    decoded[src] = _decode(_image_bytes(doc, buffers, doc.images[src], path.parent))
                    if decoded[src] is None:
                        log.warning("%s: image %d does not decode; material %d keeps its base colour", where, src, mi)
                tex = decoded[src]
            t = (info.extensions or {}).get("KHR_texture_transform") or {}
            off, scale = t.get("offset") or [0.0, 0.0], t.get("scale") or [1.0, 1.0]
            transform = (float(off[0]), float(off[1]), float(scale[0]), float(scale[1]))
        textures.append(tex)
        transforms.append(transform)
    return AvatarLook(uv=uv.astype(np.float32), face_material=face_material.astype(np.int32),
                      colours=np.array(colours, np.float32).reshape(-1, 3), textures=tuple(textures),
                      uv_transforms=np.array(transforms, np.float32).reshape(-1, 4))
