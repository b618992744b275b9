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
    cull_backfaces: bool = False,
) -> Raster:
    """Z-buffer rasterisation of a triangle mesh seen by a pinhole camera.

    vertices_cam (V, 3) camera frame; faces (F, 3); intrinsics (3, 3); size (W, H).
    Triangles with a vertex closer than ``near`` are skipped (no clipping: the virtual cameras
    that use this frame their subject). Both windings are drawn (no back-face culling), so a
    mesh of either orientation renders correctly, unless ``cull_backfaces``: then only faces whose
    (v1 - v0) x (v2 - v0) normal points towards the camera are drawn (a closed mesh with
    outward-facing winding, see ``orient_outward``), which halves the work. Returns a Raster.
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
    zf = z_all[f]
    # Column-wise ops: numpy's reductions over a length-3 axis are several times slower.
    front = (zf[:, 0] > near) & (zf[:, 1] > near) & (zf[:, 2] > near)
    if cull_backfaces:
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        front &= np.einsum("fc,fc->f", np.cross(b - a, c - a), a) < 0.0
    face_ids = np.flatnonzero(front)
    f = f[front]
    uv = np.zeros((len(v), 2))
    ok = z_all > near
    uv[ok] = project(v[ok], intrinsics)
    x, y, zt = uv[f, 0], uv[f, 1], z_all[f]  # (F, 3) each
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    x0 = np.maximum(np.ceil(_min3(x)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(_max3(x)), w - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(_min3(y)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(_max3(y)), h - 1).astype(np.int64)
    keep = (np.abs(area) > 1e-12) & (x1 >= x0) & (y1 >= y0)
    if not np.any(keep):
        return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))
    x, y, zt, area = x[keep], y[keep], zt[keep], area[keep]
    x0, x1, y0, y1, face_ids = x0[keep], x1[keep], y0[keep], y1[keep], face_ids[keep]

    # Bucket by the power-of-two bounding-box size so each bucket is one dense array op.
    bw = _next_pow2(x1 - x0 + 1)
    bh = _next_pow2(y1 - y0 + 1)
    key = bw * (4 * max(w, h)) + bh
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.diff(key[order], prepend=-1))
    frags = []
    for a, b in zip(starts, np.append(starts[1:], len(order))):
        sel = order[a:b]
        sw, sh = int(bw[sel[0]]), int(bh[sel[0]])
        frags.append(_bucket_fragments(sel, sw, sh, x, y, zt, area, x0, x1, y0, y1, w))
    pix = np.concatenate([fr[0] for fr in frags])
    z = np.concatenate([fr[1] for fr in frags])
    tri = np.concatenate([fr[2] for fr in frags])
    bary = np.concatenate([fr[3] for fr in frags])
    if len(pix) == 0:
        return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))

    # Z-test: the per-pixel minimum depth, then the fragments that reach it (fancy assignment
    # with repeated indices has no documented order, so equal-depth ties may pick either).
    np.minimum.at(depth, pix, z)
    win = np.flatnonzero(z <= depth[pix])
    face_buf[pix[win]] = face_ids[tri[win]]
    bary_buf[pix[win]] = bary[win]
    return Raster(depth.reshape(h, w), face_buf.reshape(h, w), bary_buf.reshape(h, w, 3))


def _min3(a: np.ndarray) -> np.ndarray:
    return np.minimum(np.minimum(a[:, 0], a[:, 1]), a[:, 2])


def _max3(a: np.ndarray) -> np.ndarray:
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])


def _next_pow2(n: np.ndarray) -> np.ndarray:
    return (1 << np.ceil(np.log2(np.maximum(n, 1))).astype(np.int64)).astype(np.int64)


def _bucket_fragments(sel, sw, sh, x, y, zt, area, x0, x1, y0, y1, w):
    """Fragments of the triangles ``sel`` whose boxes fit an (sw x sh) window:
    (pixel index, depth, triangle row, perspective-correct barycentrics)."""
    dy, dx = np.divmod(np.arange(sw * sh), sw)
    bx0, by0 = x0[sel], y0[sel]
    inside = (dx <= (x1[sel] - bx0)[:, None]) & (dy <= (y1[sel] - by0)[:, None])  # (n, sw*sh)
    xs, ys = x[sel], y[sel]
    inv_a = 1.0 / area[sel]
    # Edge function of the edge opposite vertex i, normalised by the signed area, is linear in
    # the pixel: l_i = c_i + a_i * dx + b_i * dy, measured from the box corner (bx0, by0).
    ls = []
    for _i, j, k in ((0, 1, 2), (1, 2, 0)):
        a = (ys[:, j] - ys[:, k]) * inv_a
        b = (xs[:, k] - xs[:, j]) * inv_a
        c = (xs[:, j] * ys[:, k] - xs[:, k] * ys[:, j]) * inv_a + a * bx0 + b * by0
        ls.append(c[:, None] + a[:, None] * dx + b[:, None] * dy)
    l0, l1 = ls
    l2 = 1.0 - l0 - l1
    eps = -1e-9  # pixel centres exactly on a shared edge belong to both; the z-test decides
    inside &= (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    r, c = np.nonzero(inside)
    tri = sel[r]
    zs = zt[tri]
    # Screen-space weights / z are linear in screen space: perspective-correct interpolation.
    q0, q1, q2 = l0[r, c] / zs[:, 0], l1[r, c] / zs[:, 1], l2[r, c] / zs[:, 2]
    s = q0 + q1 + q2
    pix = (by0[r] + dy[c]) * w + bx0[r] + dx[c]
    bary = (np.stack([q0, q1, q2], axis=-1) / s[:, None]).astype(np.float32)
    return pix, (1.0 / s).astype(np.float32), tri, bary


def orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) faces of a closed mesh, reordered if needed so that (v1 - v0) x (v2 - v0) points
    outwards (positive signed volume)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volume = np.einsum("fc,fc->f", a, np.cross(b, c)).sum() / 6.0
    return f if volume >= 0 else f[:, [0, 2, 1]]


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
    albedo: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W, 3) uint8 image (RGB order of ``color``) of a rasterised mesh with Lambert shading.

    normals_cam (V, 3) vertex normals in the camera frame, interpolated per pixel; light_dir
    points from the surface towards the light, camera frame. Two-sided (|n . l|), so the
    mesh's winding does not matter. albedo: (P, 3) colours in 0..1 of the covered pixels (in
    ``np.flatnonzero(raster.face >= 0)`` order, e.g. textures), used instead of ``color``.
    """
    h, w = raster.face.shape
    img = np.empty((h * w, 3), dtype=np.uint8)
    img[:] = background
    idx = np.flatnonzero(raster.face.ravel() >= 0)
    if len(idx) == 0:
        return img.reshape(h, w, 3)
    fidx = np.asarray(faces)[raster.face.ravel()[idx]]  # (P, 3)
    bary = raster.bary.reshape(-1, 3)[idx]
    nv = np.asarray(normals_cam, dtype=np.float32)
    n = bary[:, 0:1] * nv[fidx[:, 0]] + bary[:, 1:2] * nv[fidx[:, 1]] + bary[:, 2:3] * nv[fidx[:, 2]]
    light = np.asarray(light_dir, dtype=np.float32)
    light /= np.linalg.norm(light)
    cos = np.abs(n @ light) / np.sqrt(np.maximum(np.einsum("pc,pc->p", n, n), 1e-12))
    k = ambient + (1.0 - ambient) * cos
    base = np.asarray(color, dtype=np.float32) if albedo is None else np.asarray(albedo, dtype=np.float32)
    img[idx] = np.clip(k[:, None] * (base * 255.0), 0, 255).astype(np.uint8)
    return img.reshape(h, w, 3)
