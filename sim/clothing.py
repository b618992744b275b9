"""Clothes and hair on a posed body mesh, for training data that looks like people as sensors see
them: loose tops, sleeves, trousers, skirts and hair move the surface outward by region.

A region is the set of vertices a bone drives (the body's skin weights), so an outfit is one
outward offset per joint (metres, along the vertex normals, blended by the weights): the surface
stays smooth and closed, and the joints under it do not move. Hair and hoods grow the head mostly
at its top and back. numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.skeleton import JOINT_INDEX, NUM_JOINTS

_TORSO = ("pelvis", "spine1", "spine2", "spine3", "left_collar", "right_collar")
_UPPER_ARMS = ("left_shoulder", "right_shoulder")
_FOREARMS = ("left_elbow", "right_elbow")
_THIGHS = ("left_hip", "right_hip")
_SHINS = ("left_knee", "right_knee")


@dataclass(frozen=True)
class Outfit:
    """Outward offsets (metres) per region; ``offsets()`` gives them per joint (22,)."""

    top: float = 0.0
    sleeves: float = 0.0
    forearms: float = 0.0
    trousers: float = 0.0
    shins: float = 0.0
    skirt: float = 0.0
    hair: float = 0.0

    def offsets(self) -> np.ndarray:
        off = np.zeros(NUM_JOINTS, np.float32)
        for names, value in ((_TORSO, self.top), (_UPPER_ARMS, self.sleeves), (_FOREARMS, self.forearms),
                             (_THIGHS, self.trousers + self.skirt), (_SHINS, self.shins)):
            for name in names:
                off[JOINT_INDEX[name]] = value
        off[JOINT_INDEX["pelvis"]] += self.skirt
        return off


def random_outfit(rng: np.random.Generator) -> Outfit:
    """A random outfit: most people in close-fitting to loose clothes, some in skirts, some with
    long hair or a hood (ranges in cm: top 0-5, sleeves 0-3, trousers 0-3.5, skirt 2-6, hair 1-6)."""
    def maybe(p: float, lo: float, hi: float) -> float:
        return float(rng.uniform(lo, hi)) if rng.random() < p else 0.0

    top = maybe(0.8, 0.0, 0.05)
    return Outfit(top=top, sleeves=maybe(0.7, 0.0, 0.03), forearms=maybe(0.4, 0.0, 0.015),
                  trousers=maybe(0.7, 0.0, 0.035), shins=maybe(0.5, 0.0, 0.02),
                  skirt=maybe(0.12, 0.02, 0.06), hair=maybe(0.5, 0.01, 0.06))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float32 unit normals: area-weighted sums of the adjacent faces' normals (outward for a
    mesh wound counter-clockwise seen from outside)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    # each face's normal added to its three corners: a weighted bincount per axis (faster than add.at)
    corners, weights = f.reshape(-1), np.repeat(fn, 3, axis=0)
    n = np.stack([np.bincount(corners, weights[:, k], minlength=len(v)) for k in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.maximum(length, 1e-12)).astype(np.float32)


def dress(vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray, joints: np.ndarray,
          outfit: Outfit, outward: float = 1.0) -> np.ndarray:
    """Posed vertices (V, 3) moved outward by the outfit: offset_v = weights_v . offsets along the
    vertex normal, plus hair on the head above the neck (growing toward the top and the back).
    ``outward`` is +1 for outward normals (-1 if the mesh is wound the other way). joints (22, 3)
    are the posed joints (for the head's frame)."""
    v = np.asarray(vertices, np.float32)
    normals = vertex_normals(v, faces) * np.float32(outward)
    amount = np.asarray(weights, np.float32) @ outfit.offsets()
    if outfit.hair > 0:
        head, neck = joints[JOINT_INDEX["head"]], joints[JOINT_INDEX["neck"]]
        up = (head - neck) / max(float(np.linalg.norm(head - neck)), 1e-6)
        w_head = np.asarray(weights, np.float32)[:, JOINT_INDEX["head"]]
        above = np.clip(((v - neck) @ up) / max(float(np.linalg.norm(head - neck)) * 2.0, 1e-6), 0.0, 1.0)
        amount = amount + np.float32(outfit.hair) * w_head * above.astype(np.float32)
    return v + normals * amount[:, None]


__all__ = ["Outfit", "random_outfit", "vertex_normals", "dress"]
