"""Which cluster of the points above the floor is the person: connected components of an occupancy
grid on the floor plane, size and shape tests (walls and furniture fail them), scored by size,
height, a narrow top, motion and closeness to the previous person (``find_person_cluster``)."""

from __future__ import annotations

import cv2
import numpy as np

from models.skeleton.preprocess_config import PreprocessConfig


def _quantiles(x: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """Nearest-rank quantiles of a 1-D array: one partition, ~10x cheaper than np.percentile on
    the few thousand points of a cluster (the person finder evaluates several per frame)."""
    ks = np.round(np.asarray(qs) * (len(x) - 1)).astype(np.intp)
    return np.partition(x, ks)[ks]


def _narrow_top(pts: np.ndarray, ys: np.ndarray, y_top: float, c: np.ndarray, eye_xz: np.ndarray,
                band_m: float = 0.12) -> float:
    """Person-likeness in (0.1, 1] of a cluster's points (3, M): 1.2 minus the width of its top
    band over its whole width, both measured across the line of sight from ``eye_xz`` to the
    cluster's centre ``c``.
    A box, a table or a wall edge is as wide at the top as overall (~0.1); a person is topped
    by a head, or by hands (~0.2-0.8)."""
    d = c - np.asarray(eye_xz, np.float32)
    n = float(np.hypot(d[0], d[1]))
    if n < 1e-6:
        return 1.0
    lateral = (pts[0] - c[0]) * (d[1] / n) - (pts[2] - c[1]) * (d[0] / n)
    lo, hi = _quantiles(lateral, (0.02, 0.98))
    top = lateral[ys > y_top - band_m]
    if len(top) < 5 or hi - lo < 1e-3:
        return 1.0
    t_lo, t_hi = _quantiles(top, (0.05, 0.95))
    return float(np.clip(1.2 - (t_hi - t_lo) / (hi - lo), 0.1, 1.0))


def plane_share(pts: np.ndarray, tolerance_m: float, max_points: int = 400, hypotheses: int = 48) -> float:
    """The largest share of a cluster's points (3, M) within ``tolerance_m`` of one plane (a
    RANSAC count on at most ``max_points`` of them, every k-th, with a fixed seed: the same
    cluster always gets the same share). A box, shelves, a wall or a figure of boxes puts most
    of what the camera sees of it on one face (0.7-1.0); a person's limbs, head and the curve of
    the torso leave 0.4-0.6 on the best plane."""
    m = pts.shape[1]
    sub = np.ascontiguousarray(pts[:, ::max(1, -(-m // max_points))].T, np.float64)
    n = len(sub)
    if n < 10:
        return 0.0
    picks = np.random.default_rng(0).integers(0, n, size=(hypotheses, 3))
    a, b, c = sub[picks[:, 0]], sub[picks[:, 1]], sub[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not ok.any():
        return 0.0
    normals = normals[ok] / norms[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, a[ok])
    inliers = (np.abs(sub @ normals.T + offsets) <= tolerance_m).sum(axis=0)
    return float(inliers.max()) / n


def wall_inliers(pts: np.ndarray, eye_xz: np.ndarray, tolerance_m: float, min_width_m: float,
                 max_points: int = 400, hypotheses: int = 48) -> np.ndarray:
    """(M,) bool: the points (3, M) of the vertical plane holding most of them, within
    ``tolerance_m`` + 1 cm x range² of it (the range from ``eye_xz``: depth noise grows with
    its square), when they span at least ``min_width_m`` along it (a wall, not the face of a
    box a performer stands beside); else none. A vertical plane is a line on the floor, so each
    hypothesis is the line through two points at least 30 cm apart (RANSAC on at most
    ``max_points``, every k-th, fixed seed: the same cluster always gives the same plane)."""
    xz = np.stack([pts[0], pts[2]], axis=1).astype(np.float64)
    m = len(xz)
    if m < 10:
        return np.zeros(m, bool)
    eye = np.asarray(eye_xz, np.float64)
    tol = tolerance_m + 0.01 * ((xz - eye) ** 2).sum(1)
    step = max(1, -(-m // max_points))
    sub, sub_tol = xz[::step], tol[::step]
    picks = np.random.default_rng(0).integers(0, len(sub), size=(hypotheses, 2))
    a, d = sub[picks[:, 0]], sub[picks[:, 1]] - sub[picks[:, 0]]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 0.3
    if not ok.any():
        return np.zeros(m, bool)
    normals = np.stack([-d[ok, 1], d[ok, 0]], axis=1) / length[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, a[ok])
    best = int(np.argmax((np.abs(sub @ normals.T + offsets) <= sub_tol[:, None]).sum(0)))
    inliers = np.abs(xz @ normals[best] + offsets[best]) <= tol
    if inliers.sum() < 10:
        return np.zeros(m, bool)
    along = xz[inliers] @ np.array([normals[best, 1], -normals[best, 0]])
    lo, hi = _quantiles(along, (0.02, 0.98))
    return inliers if hi - lo >= min_width_m else np.zeros(m, bool)


def _score(base: float, flat: float, motion_weight: float | None, apart: float | None) -> float:
    """A candidate's score: its size, height and top term times its flatness factor and motion
    weight, over one plus its distance to the previous person (None: not applied)."""
    out = base * flat
    if motion_weight is not None:
        out *= motion_weight
    if apart is not None:
        out /= apart
    return out


def find_person_cluster(pts: np.ndarray, eye_xz: np.ndarray, min_points: int, cfg: PreprocessConfig,
                        last_center: np.ndarray | None, moving: np.ndarray | None = None,
                        cut_below: np.ndarray | None = None, cut_above: np.ndarray | None = None,
                        floor_known: bool = True, pull: bool = True, wall_cut: bool = False
                        ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray] | None:
    """The person among world points (3, M) above the floor: (bool mask (M,) of its points,
    the cell label grid, its label, the grid origin (x, z), its points (3, P)), or None.
    moving: (M,) bool, points whose depth changed lately (``PersonFinder._moved``), or None when not
    known; last_center: the previous person's (x, z), or None; cut_below: (M,) bool, points on the
    image's bottom edge, or None: a cluster holding some goes on below the view (a seated
    performer's close-up, legs out of frame), so its height counts from the floor; cut_above:
    (M,) bool, points on the image's top edge, or None: a cluster holding some has its top out of
    view (a low camera looking down), so its top's shape says nothing. The cluster of the
    previous person (tracked) passes the top test at half its threshold: a raised arm or a turn
    that widens the top for a frame does not lose them. floor_known: False when no floor is in view
(heights are then above the lowest points seen, not above a floor): the height limit applies
to a cluster's own extent. pull: whether the previous person's position holds back every other candidate
(score / (1 + distance)); False while that person has not been seen moving: it then holds back
only candidates moving no more than it, so that a first pick of still clutter gives way to a
performer who moves (the tracked cluster's half threshold applies either way). When no
candidate passes, each cluster too wide to be a person loses the points of its wall (a vertical
plane holding most of it, ``wall_inliers``) and what is left is searched again (``wall_cut``:
this second search, which cuts no further and takes only clusters that move, any before motion
is known): a performer close to a wall, joined to it by noise or flying pixels between them,
and not the clutter against it."""
    if pts.shape[1] < min_points:
        return None
    cells = int(2 * cfg.grid_half_extent_m / cfg.cell_m)
    origin = np.array([-cfg.grid_half_extent_m, -cfg.grid_half_extent_m], np.float32)
    if last_center is not None:
        origin = origin + last_center.astype(np.float32)
    i = np.floor((pts[0] - origin[0]) / cfg.cell_m).astype(np.int32)
    j = np.floor((pts[2] - origin[1]) / cfg.cell_m).astype(np.int32)
    inside = (i >= 0) & (i < cells) & (j >= 0) & (j < cells)
    if inside.sum() < min_points:
        return None
    # Only cells with points well above the floor seed the clusters: stereo noise lifts the
    # far floor by several cm, and low noisy floor cells would join the person to the floor.
    # Low points (feet) still join the cluster of the cell they fall in after the dilation.
    tall = inside & (pts[1] > cfg.seed_height_m)
    if not tall.any():
        return None
    # Label only the occupied part of the grid (a room fills a fraction of the 12 m square),
    # with a one-cell margin for the dilation: the components, their raster order and so
    # their labels are those of the whole grid.
    jt, it = j[tall], i[tall]
    j0, j1 = max(int(jt.min()) - 1, 0), min(int(jt.max()) + 2, cells)
    i0, i1 = max(int(it.min()) - 1, 0), min(int(it.max()) + 2, cells)
    crop = np.zeros((j1 - j0, i1 - i0), np.uint8)
    jt, it = jt - j0, it - i0
    crop[jt, it] = 1
    # Close one-cell gaps (stereo holes) so a person is one component. (Labels without
    # OpenCV's statistics, which cost 4x the labelling: the few candidates' boxes come from
    # their seed cells below.)
    crop = cv2.dilate(crop, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    n, crop_labels = cv2.connectedComponents(crop, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return None
    # Flat label lookup with a zero sentinel cell for the points outside the grid.
    labels_flat = np.zeros(cells * cells + 1, np.int32)
    labels_flat[:-1].reshape(cells, cells)[j0:j1, i0:i1] = crop_labels
    point_label = labels_flat[np.where(inside, j * cells + i, cells * cells)]
    seed_label = crop_labels[jt, it]
    counts = np.bincount(point_label, minlength=n)
    # Each label's exact motion weight, so that count x 1.8^2 x weight bounds its score:
    # candidates are visited by decreasing bound and the search stops when none can win
    # (still furniture is bounded by a tenth of its size once a moving performer is seen).
    weight = np.ones(n)
    if moving is not None:
        moved = np.bincount(point_label[moving], minlength=n)
        share = (moved / np.maximum(counts, 1) - cfg.motion_noise_share) / (
            cfg.motion_full_share - cfg.motion_noise_share)
        weight = cfg.static_weight + (1.0 - cfg.static_weight) * np.clip(share, 0.0, 1.0)
    bound = counts * 1.8 ** 2 * weight
    order = np.argsort(-bound, kind="stable")
    tracked = 0
    if last_center is not None:
        # The previous person's label first (the grid is centred on them): their score then
        # prunes the others by their distance to it, from their boxes alone.
        ci, cj = (np.floor((last_center - origin) / cfg.cell_m)).astype(int)
        tracked = labels_flat[cj * cells + ci] if 0 <= ci < cells and 0 <= cj < cells else 0
        if tracked:
            order = np.concatenate([[tracked], order[order != tracked]])
    # Which candidates the previous person's position holds back (score / (1 + distance)): all of
    # them, or with pull off only those moving no more than the previous person's cluster.
    pulled = np.full(n, last_center is not None)
    if not pull and moving is not None:
        pulled &= weight <= (weight[tracked] if tracked else cfg.static_weight)
    best, best_score = None, 0.0
    too_wide = []
    for k, lab in enumerate(order):
        if bound[lab] <= best_score:
            if k:
                break  # candidates come by decreasing bound: none of the rest can score higher
            continue
        if lab == 0 or counts[lab] < min_points or (wall_cut and weight[lab] <= cfg.static_weight):
            continue  # (split off a wall: only what moves, when motion is known)
        # The component's box: its seed cells' box grown by the dilation, within the crop.
        si, sj = it[seed_label == lab], jt[seed_label == lab]
        b_i0, b_i1 = max(int(si.min()) - 1, 0), min(int(si.max()) + 1, crop.shape[1] - 1)
        b_j0, b_j1 = max(int(sj.min()) - 1, 0), min(int(sj.max()) + 1, crop.shape[0] - 1)
        footprint = np.hypot(b_i1 - b_i0 + 1, b_j1 - b_j0 + 1) * cfg.cell_m
        if footprint > cfg.max_footprint_m + 2 * cfg.cell_m:
            too_wide.append(lab)
            continue  # a wall or a large piece of furniture
        if pulled[lab] and best is not None:
            # Its median lies in its box: the box's distance to the previous person bounds
            # the score's distance divisor (less 1 mm for float32 cell rounding).
            lo = origin + np.array([i0 + b_i0, j0 + b_j0]) * cfg.cell_m
            hi = origin + np.array([i0 + b_i1 + 1, j0 + b_j1 + 1]) * cfg.cell_m
            gap = np.maximum(np.maximum(lo - last_center, last_center - hi), 0.0)
            if bound[lab] / (1.0 + max(float(np.hypot(*gap)) - 1e-3, 0.0)) <= best_score:
                continue
        sel = point_label == lab
        cluster = pts[:, sel]
        ys = cluster[1]
        y_lo, y_hi = _quantiles(ys, (0.01, 0.99))
        seen = float(y_hi - y_lo)
        height = seen
        if cut_below is not None and int(np.count_nonzero(cut_below[sel])) >= 3:
            height = float(y_hi - min(y_lo, 0.0))  # it goes on below the view, down to the floor
        if height < cfg.min_height_m or (y_hi if floor_known else seen) > cfg.max_height_m:
            continue  # too flat to be a person, or a wall / door frame seen edge-on
        # Prefer many points, tall clusters (furniture is rarely taller than 1.2 m), shapes
        # narrower at the top than overall (a head, not the edge of a box or a table top),
        # and the previous person's position.
        c = np.array([_quantiles(cluster[0], (0.5,))[0], _quantiles(cluster[2], (0.5,))[0]])
        narrow = _narrow_top(cluster, ys, y_hi, c, eye_xz)
        if cut_above is not None and int(np.count_nonzero(cut_above[sel])) >= 3:
            narrow = max(narrow, cfg.min_narrow_top)  # the top is out of view
        if narrow < (cfg.min_narrow_top / 2 if lab == tracked else cfg.min_narrow_top):
            continue  # flat-topped: furniture (this also rejects a person lying down)
        base = counts[lab] * min(height, 1.8) ** 2 * narrow
        moved = weight[lab] if moving is not None else None
        apart = 1.0 + np.linalg.norm(c - last_center) if pulled[lab] else None
        if _score(base, 1.0, moved, apart) <= best_score:
            continue  # it cannot win whatever its flatness (the plane count costs ~0.1 ms)
        flat = 1.0
        if cfg.flat_share is not None:
            # Not a flat face: a cluster with more of its points on one plane than a person has
            # scores less, down to flat_weight for a cluster all on one plane.
            flat = (1.0 - plane_share(cluster, cfg.flat_tolerance_m)) / (1.0 - cfg.flat_share)
            flat = min(max(flat, cfg.flat_weight), 1.0)
        score = _score(base, flat, moved, apart)
        if score > best_score:
            best, best_score = (sel, labels_flat[:-1].reshape(cells, cells), int(lab), origin, cluster), score
    if best is None and not wall_cut and cfg.wall_tolerance_m is not None:
        for lab in too_wide:
            idx = np.flatnonzero(point_label == lab)
            rest = idx[~wall_inliers(pts[:, idx], eye_xz, cfg.wall_tolerance_m, cfg.max_footprint_m)]
            if len(rest) < min_points or len(rest) > len(idx) // 2:
                continue  # no wall holding most of it
            moving_r, below_r, above_r = (None if a is None else a[rest] for a in (moving, cut_below, cut_above))
            got = find_person_cluster(pts[:, rest], eye_xz, min_points, cfg, last_center, moving_r, below_r, above_r,
                                      floor_known, pull, wall_cut=True)
            if got is not None:
                sel = np.zeros(pts.shape[1], bool)
                sel[rest[got[0]]] = True
                return (sel, *got[1:])
    return best
