"""Is a limb seen where the suit puts it? Depth evidence around a bone, from the depth image.

The skeleton regressor always reports every joint, and its confidence (the sample points near a
joint) stays high when it guesses a hidden arm against the torso or the other arm. The depth
image itself says more: where the suit puts a bone, either the camera shows a surface there
(pixels whose points lie within ``radius`` of the bone) or it does not (no data, something in
front, or the camera sees past it). A limb the camera does not show where the suit has it is a
limb the depth skeleton can only guess.

Pure numpy: points along each bone projected into the image, each tested against the pixels of
a small window around it (the window's half-width is ``radius`` at the point's depth), all
points' windows in one gather.
"""

from __future__ import annotations

import numpy as np

from live.core.frames import DepthFrame

#: Where along a bone (parent 0 -> child 1) its points are tested: not at the parent, whose
#: surroundings belong to the segment above (a shoulder's, the torso's).
SAMPLE_FRACTIONS = np.array([0.35, 0.5, 0.65, 0.8, 0.95])


def seen_fraction(depth: DepthFrame, camera_to_world: np.ndarray, starts: np.ndarray, ends: np.ndarray, *,
                  radius: float = 0.04, max_window_px: int = 12) -> np.ndarray:
    """(K,) share of each bone's test points (``SAMPLE_FRACTIONS`` of the way from starts (K, 3) to
    ends (K, 3), world metres) with a depth pixel within ``radius`` of them (in 3D: the pixels of a
    window of half-width ``radius`` around their projection, unprojected). Points behind the camera or outside the image
    are not seen. ``camera_to_world``: the one the world points were solved in."""
    starts, ends = np.asarray(starts, np.float64), np.asarray(ends, np.float64)
    if depth.depth_mm is None or depth.intrinsics is None or not len(starts):
        return np.zeros(len(starts))
    pts = starts[:, None, :] + SAMPLE_FRACTIONS[None, :, None] * (ends - starts)[:, None, :]  # (K, n, 3)
    c2w = np.asarray(camera_to_world, np.float64)
    cam = (pts.reshape(-1, 3) - c2w[:3, 3]) @ c2w[:3, :3]
    k = np.asarray(depth.intrinsics, np.float64)
    img = depth.depth_mm
    h, w = img.shape
    z = cam[:, 2]
    front = z > 0.1
    zs = np.where(front, z, 1.0)
    u = np.rint(cam[:, 0] / zs * k[0, 0] + k[0, 2]).astype(np.int64)
    v = np.rint(cam[:, 1] / zs * k[1, 1] + k[1, 2]).astype(np.int64)
    half = np.clip(np.rint(radius * k[0, 0] / zs), 1, max_window_px).astype(np.int64)
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    seen = np.zeros(len(cam), bool)
    idx = np.flatnonzero(inside)
    if len(idx):
        # Every point's window at once: offsets up to the largest half-width, masked per point
        # to its own half-width and to the image (a few dozen points x at most 25 x 25 pixels).
        r = int(half[idx].max())
        off = np.arange(-r, r + 1)
        du, dv = np.meshgrid(off, off)
        uu, vv = u[idx, None] + du.ravel(), v[idx, None] + dv.ravel()  # (N, W)
        within = ((np.abs(du.ravel()) <= half[idx, None]) & (np.abs(dv.ravel()) <= half[idx, None])
                  & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h))
        zz = img[np.clip(vv, 0, h - 1), np.clip(uu, 0, w - 1)] * 1e-3
        dx = (uu - k[0, 2]) * zz / k[0, 0] - cam[idx, 0, None]
        dy = (vv - k[1, 2]) * zz / k[1, 1] - cam[idx, 1, None]
        near = dx * dx + dy * dy + (zz - z[idx, None]) ** 2 < radius * radius
        seen[idx] = np.any(within & (zz > 0) & near, axis=1)
    return seen.reshape(len(starts), len(SAMPLE_FRACTIONS)).mean(axis=1)


__all__ = ["seen_fraction", "SAMPLE_FRACTIONS"]
