"""Surface colours of a rasterised avatar from its file's materials (``AvatarLook``): per covered
pixel, the base colour of its triangle's material times that material's base-colour texture,
sampled (nearest texel, glTF's REPEAT wrap) at the perspective-correct interpolated texture
coordinates. Lambert shading (live/outputs/raster.py ``shade_lambert``) then lights it."""

from __future__ import annotations

import numpy as np

from live.body.body import AvatarLook
from live.outputs.raster import Raster


def surface_albedo(raster: Raster, faces: np.ndarray, look: AvatarLook,
                   default: tuple[float, float, float]) -> np.ndarray:
    """(P, 3) float32 BGR colours in 0..1 of the P covered pixels, in ``np.flatnonzero(raster.face >= 0)``
    order; faces (F, 3) as rasterised (their rows are the look's triangles, vertex order may differ);
    default: the colour of triangles without a material."""
    face_of = raster.face.ravel()
    idx = np.flatnonzero(face_of >= 0)
    tri = face_of[idx]
    out = np.empty((len(idx), 3), np.float32)
    out[:] = default
    if len(idx) == 0:
        return out
    fidx = np.asarray(faces)[tri]
    bary = raster.bary.reshape(-1, 3)[idx]
    uv = np.asarray(look.uv, np.float32)
    uv_px = bary[:, 0:1] * uv[fidx[:, 0]] + bary[:, 1:2] * uv[fidx[:, 1]] + bary[:, 2:3] * uv[fidx[:, 2]]
    material = np.asarray(look.face_material)[tri]
    for m in np.unique(material):
        if m < 0:
            continue
        sel = material == m
        colour = look.colours[m]
        tex = look.textures[m]
        if tex is None:
            out[sel] = colour
            continue
        ox, oy, sx, sy = look.uv_transforms[m]
        h, w = tex.shape[:2]
        u = np.mod(uv_px[sel, 0] * sx + ox, 1.0)
        v = np.mod(uv_px[sel, 1] * sy + oy, 1.0)
        x = np.minimum((u * w).astype(np.int64), w - 1)
        y = np.minimum((v * h).astype(np.int64), h - 1)
        out[sel] = tex[y, x].astype(np.float32) * (colour / 255.0)
    return out
