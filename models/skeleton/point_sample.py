"""The person's fixed-size point sample: their pixels visited along a randomly shifted R2
sequence (an evenly spread draw, ``r2_grid_order``), kept when they fall in the person's cells
(``fine_sample``)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from live.core.frames import DepthFrame
from models.skeleton.background import BackgroundModel
from models.skeleton.depth_edges import edge_pixels_at
from models.skeleton.preprocess_config import PreprocessConfig

#: Step of the R2 sequence (Roberts 2018: the additive recurrence on the plastic number), whose
#: every prefix covers the unit square evenly (low discrepancy).
_PLASTIC = 1.3247179572447460
R2_STEP = np.array([1.0 / _PLASTIC, 1.0 / _PLASTIC ** 2])
#: Box pixels the fine sample visits per point it needs, before it falls back to a shuffle.
R2_VISITS = 6


@lru_cache(maxsize=4)
def _r2_points(count: int) -> np.ndarray:
    """The first ``count`` points of the R2 sequence (count, 2), computed once per count."""
    k = np.arange(1, count + 1)[:, None] * R2_STEP
    k -= np.floor(k)
    k.flags.writeable = False
    return k


def r2_grid_order(rows: int, cols: int, count: int, offset: np.ndarray) -> np.ndarray:
    """Flat indices into a rows x cols grid along the first ``count`` points of the R2 sequence
    shifted by ``offset`` (2,) in [0, 1)^2: distinct, in order of first visit. Any prefix of the
    order is spread evenly over the grid, unlike a uniform random draw, which clumps and leaves
    holes; with a random offset each cell is still visited with equal probability."""
    k = _r2_points(count) + offset
    k -= np.floor(k)
    idx = (k[:, 0] * rows).astype(np.int64) * cols + (k[:, 1] * cols).astype(np.int64)
    # First visits without a sort (np.unique's was 60 % of this function): written in reverse
    # order, each cell keeps the position of its earliest visit.
    order = np.arange(len(idx))
    first = np.empty(rows * cols, np.int64)
    first[idx[::-1]] = order[::-1]
    return idx[first[idx] == order]


def fine_sample(frame: DepthFrame, c2w: np.ndarray, box: tuple[int, int, int, int], labels: np.ndarray, lab: int,
                origin: np.ndarray, rng: np.random.Generator, rays: np.ndarray, cfg: PreprocessConfig,
                background: BackgroundModel | None) -> np.ndarray:
    """num_points world points (N, 3), distinct, from the person's pixels at pixel_stride: the
    pixels of the coarse person's image box (``box``: rows r0..r1, cols c0..c1 at
    coarse_stride) are visited along a randomly shifted R2 sequence (``r2_grid_order``) and
    kept when their point falls in the person's cells (above the floor). rays: (3, h*w) world
    directions of the pixel_stride image (``PersonFinder._world_rays``).

    Why not a uniform random draw: which 256 of the person's thousands of pixels are drawn
    moves the regressor's joints from frame to frame (the spread of four draws of one frame:
    25 mm rms per joint), most at the hands and feet that only a few points cover. An evenly
    spread draw covers every part of the body in proportion to its area: on 16 held-out runs
    the stage (temporal model included) went 32.7 -> 31.7 mm MPJPE and Acc 11.3 -> 10.2
    mm/frame^2 with the same network (docs/skeleton.md, "Evenly spread point sample")."""
    cs, s = cfg.coarse_stride, cfg.pixel_stride
    h, w = frame.depth_mm.shape
    top, bottom, left, right = (v * cs for v in box)
    r0, r1 = max(top - cs, 0) // s * s, min(bottom + cs + 1, h)
    c0, c1 = max(left - cs, 0) // s * s, min(right + cs + 1, w)
    at = (slice(r0, r1, s), slice(c0, c1, s))
    z = frame.depth_mm[at].astype(np.float32) * np.float32(0.001)
    valid = (z > cfg.min_range_m) & (z < cfg.max_range_m)
    if background is not None:
        valid &= background.foreground(frame.depth_mm, cfg.background_margin_m, at)
    n = cfg.num_points
    share = cfg.edge_jump_share

    def usable(idx: np.ndarray) -> np.ndarray:
        """The candidate pixels (flat crop indices) with depth in range, off depth edges."""
        idx = idx[valid.reshape(-1)[idx]]
        return idx if share is None else idx[~edge_pixels_at(z, valid, idx, share)]

    crop = (r0 // s, c0 // s, z.shape[1], -(-w // s))
    # 6n visits of the box hold n of the person's pixels when they fill a sixth of it (0.29-0.48
    # on a CMU clip); when they do not, start over on a shuffle of all candidates (uniform).
    order = r2_grid_order(z.shape[0], z.shape[1], R2_VISITS * n, rng.random(2))
    pts = _person_points(usable(order), rays, z, c2w, origin, labels, lab, crop, cfg)
    if len(pts) < n:
        cand = usable(np.flatnonzero(valid))
        rng.shuffle(cand)
        pts = _person_points(cand, rays, z, c2w, origin, labels, lab, crop, cfg, n)
    if len(pts) >= n:
        return pts[:n]
    if len(pts) == 0:  # cannot happen for a found person; keep the contract anyway
        pts = np.zeros((1, 3), np.float32)
    return pts[rng.choice(len(pts), n, replace=True)]


def _person_points(idx: np.ndarray, rays: np.ndarray, z: np.ndarray, c2w: np.ndarray, origin: np.ndarray,
                   labels: np.ndarray, lab: int, crop: tuple[int, int, int, int], cfg: PreprocessConfig,
                   enough: int | None = None) -> np.ndarray:
    """World points (K, 3) of the candidate crop pixels ``idx`` (flat in the crop at rows r0,
    cols c0 of the strided image, ``crop`` = (r0, c0, crop width, image width)) that fall in
    the person's cells above the floor, in the order of ``idx``; with ``enough``, read in
    growing chunks until that many are found."""
    cells = labels.shape[0]
    r0, c0, crop_w, w_s = crop
    kept: list[np.ndarray] = []
    total, start, chunk = 0, 0, len(idx) if enough is None else 3 * enough
    while start < len(idx) and (enough is None or total < enough):
        part = idx[start:start + chunk]
        start += chunk
        chunk *= 2
        pts = np.take(rays, (part // crop_w + r0) * w_s + part % crop_w + c0, axis=1)
        pts *= np.take(z.reshape(-1), part)
        pts += c2w[:3, 3].astype(np.float32)[:, None]
        i = np.floor((pts[0] - origin[0]) / cfg.cell_m).astype(np.int64)
        j = np.floor((pts[2] - origin[1]) / cfg.cell_m).astype(np.int64)
        ok = (i >= 0) & (i < cells) & (j >= 0) & (j < cells) & (pts[1] > cfg.floor_margin_m)
        ok[ok] = labels[j[ok], i[ok]] == lab
        kept.append(pts[:, ok])
        total += int(ok.sum())
    return np.concatenate(kept, axis=1).T if kept else np.zeros((0, 3), np.float32)
