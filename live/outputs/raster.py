"""A small z-buffer triangle rasteriser and Lambert shader in numpy (for the video sink).

Vectorised over triangles: triangles are grouped by the power-of-two size of their pixel
bounding box, and each group tests every pixel centre of its (bw x bh) window at once with edge
functions. Depth is interpolated perspective-correctly (1/z is linear in screen space), and the
nearest fragment per pixel wins. Pixel centres are at integer coordinates, as OpenCV intrinsics
assume. Shapes: vertices (V, 3) camera frame (OpenCV axes, metres), faces (F, 3) int.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Raster:
    """depth (H, W) float32 camera z in metres, inf where empty; face (H, W) int32 index of the
    visible face, -1 where empty; bary (H, W, 3) float32 perspective-correct barycentric weights
    of that face's three vertices (0 where empty)."""

    depth: np.ndarray
    face: np.ndarray
    bary: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.face >= 0


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 1.0, 0.0)) -> np.ndarray:
    """(4, 4) camera_to_world of an OpenCV camera at eye looking at target (+Y down in image)."""
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, dtype=np.float64))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, fwd, eye
    return m


def world_to_camera(points: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> (..., 3) camera-frame points."""
    m = np.asarray(camera_to_world, dtype=np.float64)
    r, t = m[:3, :3], m[:3, 3]
    return (np.asarray(points, dtype=np.float64) - t) @ r


def project(points_cam: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(..., 3) camera-frame points -> (..., 2) pixel coordinates (u, v); z must be > 0."""
    k = np.asarray(intrinsics, dtype=np.float64)
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[..., 2]
    return np.stack([k[0, 0] * p[..., 0] / z + k[0, 2], k[1, 1] * p[..., 1] / z + k[1, 2]], axis=-1)


def rasterize(
    vertices_cam: np.ndarray,
    faces: np.ndarray,
    intrinsics: np.ndarray,
    size: tuple[int, int],
    near: float = 0.05,
) -> Raster:
    """Z-buffer rasterisation of a triangle mesh seen by a pinhole camera.

    vertices_cam (V, 3) camera frame; faces (F, 3); intrinsics (3, 3); size (W, H).
    Triangles with a vertex closer than ``near`` are skipped (no clipping: the virtual cameras
    that use this frame their subject). Both windings are drawn (no back-face culling), so a
    mesh of either orientation renders correctly. Returns a Raster.
    """
    w, h = int(size[0]), int(size[1])
    depth = np.full(h * w, np.inf, dtype=np.float32)
    face_buf = np.full(h * w, -1, dtype=np.int32)
    bary_buf = np.zeros((h * w, 3), dtype=np.float32)
    v = np.asarray(vertices_cam, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or len(v) == 0:
        return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))

    z_all = v[:, 2]
    front = np.all(z_all[f] > near, axis=1)
    face_ids = np.flatnonzero(front)
    f = f[front]
    uv = np.zeros((len(v), 2))
    ok = z_all > near
    uv[ok] = project(v[ok], intrinsics)
    x, y, zt = uv[f, 0], uv[f, 1], z_all[f]  # (F, 3) each
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    x0 = np.maximum(np.ceil(x.min(axis=1)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(x.max(axis=1)), w - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(y.min(axis=1)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(y.max(axis=1)), h - 1).astype(np.int64)
    keep = (np.abs(area) > 1e-12) & (x1 >= x0) & (y1 >= y0)
    if not np.any(keep):
        return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))
    x, y, zt, area = x[keep], y[keep], zt[keep], area[keep]
    x0, x1, y0, y1, face_ids = x0[keep], x1[keep], y0[keep], y1[keep], face_ids[keep]

    # Bucket by the power-of-two bounding-box size so each bucket is one dense array op.
    bw = _next_pow2(x1 - x0 + 1)
    bh = _next_pow2(y1 - y0 + 1)
    frags = []
    for sw, sh in {(int(a), int(b)) for a, b in zip(bw, bh)}:
        sel = np.flatnonzero((bw == sw) & (bh == sh))
        frags.append(_bucket_fragments(sel, sw, sh, x, y, zt, area, x0, x1, y0, y1, w))
    pix = np.concatenate([fr[0] for fr in frags])
    z = np.concatenate([fr[1] for fr in frags])
    tri = np.concatenate([fr[2] for fr in frags])
    bary = np.concatenate([fr[3] for fr in frags])
    if len(pix) == 0:
        return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))

    # Nearest fragment per pixel: order near to far, keep each pixel's first occurrence
    # (np.unique documents return_index as the first one; fancy assignment with repeated
    # indices has no documented order).
    order = np.argsort(z, kind="stable")
    _, first = np.unique(pix[order], return_index=True)
    win = order[first]
    depth[pix[win]] = z[win]
    face_buf[pix[win]] = face_ids[tri[win]]
    bary_buf[pix[win]] = bary[win]
    return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))


def _next_pow2(n: np.ndarray) -> np.ndarray:
    return (1 << np.ceil(np.log2(np.maximum(n, 1))).astype(np.int64)).astype(np.int64)


def _bucket_fragments(sel, sw, sh, x, y, zt, area, x0, x1, y0, y1, w):
    """Fragments of the triangles ``sel`` whose boxes fit an (sw x sh) window:
    (pixel index, depth, triangle row, perspective-correct barycentrics)."""
    dy, dx = np.divmod(np.arange(sw * sh), sw)
    px = x0[sel, None] + dx  # (n, sw*sh)
    py = y0[sel, None] + dy
    inside = (px <= x1[sel, None]) & (py <= y1[sel, None])
    xs, ys = x[sel], y[sel]
    # Edge functions: e_i is the signed area opposite vertex i, normalised by the full area.
    e0 = (xs[:, 1, None] - px) * (ys[:, 2, None] - py) - (xs[:, 2, None] - px) * (ys[:, 1, None] - py)
    e1 = (xs[:, 2, None] - px) * (ys[:, 0, None] - py) - (xs[:, 0, None] - px) * (ys[:, 2, None] - py)
    inv_a = 1.0 / area[sel, None]
    l0, l1 = e0 * inv_a, e1 * inv_a
    l2 = 1.0 - l0 - l1
    eps = -1e-9  # pixel centres exactly on a shared edge belong to both; the z-test decides
    inside &= (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    r, c = np.nonzero(inside)
    l = np.stack([l0[r, c], l1[r, c], l2[r, c]], axis=-1)
    tri = sel[r]
    inv_z = l / zt[tri]  # screen-space weights / z, linear in screen space
    s = inv_z.sum(axis=-1)
    pix = py[r, c] * w + px[r, c]
    return pix, (1.0 / s).astype(np.float32), tri, (inv_z / s[:, None]).astype(np.float32)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of a mesh (V, 3), (F, 3)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):  # bincount is much faster than np.add.at for scatter-adds
        for c in range(3):
            n[:, c] += np.bincount(f[:, k], weights=fn[:, c], minlength=len(v))
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def shade_lambert(
    raster: Raster,
    normals_cam: np.ndarray,
    faces: np.ndarray,
    color: tuple[float, float, float] = (0.85, 0.72, 0.62),
    light_dir: tuple[float, float, float] = (-0.4, -0.6, -1.0),
    ambient: float = 0.25,
    background: tuple[int, int, int] = (40, 40, 40),
) -> np.ndarray:
    """(H, W, 3) uint8 image (RGB order of ``color``) of a rasterised mesh with Lambert shading.

    normals_cam (V, 3) vertex normals in the camera frame, interpolated per pixel; light_dir
    points from the surface towards the light, camera frame. Two-sided (|n . l|), so the
    mesh's winding does not matter.
    """
    h, w = raster.face.shape
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[:] = background
    m = raster.mask
    if not np.any(m):
        return img
    fidx = np.asarray(faces)[raster.face[m]]  # (P, 3)
    n = np.einsum("pk,pkc->pc", raster.bary[m], np.asarray(normals_cam, dtype=np.float32)[fidx])
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    light = np.asarray(light_dir, dtype=np.float32)
    light /= np.linalg.norm(light)
    k = ambient + (1.0 - ambient) * np.abs(n @ light)
    img[m] = np.clip(k[:, None] * np.asarray(color, dtype=np.float32) * 255.0, 0, 255).astype(np.uint8)
    return img
