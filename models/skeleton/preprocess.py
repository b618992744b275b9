"""Find the person in a depth frame and turn them into a fixed-size, normalised point sample.

Steps (all numpy / OpenCV, a few ms for a 640x400 frame):
1. depth image -> camera points on a pixel stride (the person keeps thousands of points);
2. camera -> world with the frame's camera_to_world (floor at y = 0); when the floor is not
   known (identity extrinsics) it is found once by RANSAC (``estimate_floor``);
3. range limits, optional learned static background, floor removal (y < floor_margin);
4. the largest plausible human-sized cluster: connected components of an occupancy grid on the
   floor plane (walls and furniture fail the size tests);
5. a fixed-size point sample, deterministic per frame, in the *person frame*: origin on the floor
   under the person, rotated about y so the camera is toward +z. ``PersonCloud.to_world`` maps
   person-frame joints back to world coordinates exactly.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from live.frames import DepthFrame


@dataclass(frozen=True)
class PreprocessConfig:
    num_points: int = 512
    pixel_stride: int = 2
    # Depth images: find the person on a coarser stride, then draw the sample from the person's
    # pixels at pixel_stride (the same points, ~4x less work). None: one pass at pixel_stride.
    coarse_stride: int | None = 4
    min_range_m: float = 0.3
    max_range_m: float = 6.0
    floor_margin_m: float = 0.03
    seed_height_m: float = 0.2
    cell_m: float = 0.05
    grid_half_extent_m: float = 6.0
    min_points: int = 120
    min_height_m: float = 0.35
    max_height_m: float = 2.4
    min_narrow_top: float = 0.4
    max_footprint_m: float = 1.8
    background_margin_m: float = 0.10
    # Motion cue: a cluster whose depth has not changed since a frame motion_lag_s ago (or the
    # oldest frame kept, early on) scores static_weight times a moving one: furniture never
    # moves, a performer does. A point moved when its depth changed by more than
    # motion_change_m + 1 cm x z^2 (stereo noise grows with the square of the range); a cluster
    # moves in proportion to its share of moved points above motion_noise_share (what noise and
    # flickering edges give a still surface), fully at motion_full_share. A still performer
    # next to still furniture gets no cue either way.
    motion_lag_s: float = 0.3
    motion_change_m: float = 0.05
    motion_noise_share: float = 0.15
    motion_full_share: float = 0.5
    static_weight: float = 0.1


@dataclass(frozen=True)
class PersonCloud:
    """points: (N, 3) float32 in the person frame; to_world: (4, 4) person frame -> world;
    count: person points found before sampling; floor_visible: whether the feet region is seen."""

    points: np.ndarray
    to_world: np.ndarray
    count: int
    height_m: float


def _person_frame(center_xz: np.ndarray, camera_pos: np.ndarray) -> np.ndarray:
    """(4,4) person frame -> world: origin on the floor at center, +z toward the camera."""
    d = camera_pos[[0, 2]] - center_xz
    yaw = np.arctan2(d[0], d[1])  # rotation about +y taking +z to the camera direction
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    m[0, 3], m[2, 3] = center_xz
    return m


def estimate_floor(points_cam: np.ndarray, distance_m: float = 0.02, iterations: int = 200,
                   seed: int = 0) -> np.ndarray | None:
    """RANSAC floor plane of a camera-frame cloud -> camera_to_world (floor y = 0, +y up,
    camera above the floor), or None when no plausible floor is seen. The floor is the largest
    plane whose normal is within 35 degrees of the camera's down direction (image +y)."""
    import open3d as o3d

    pts = np.asarray(points_cam, np.float64)
    if len(pts) < 500:
        return None
    rng = np.random.default_rng(seed)
    # Only points in the lower half of the view can be floor for any sane camera pitch.
    cand = pts[pts[:, 1] > np.percentile(pts[:, 1], 40)]
    if len(cand) > 20000:
        cand = cand[rng.choice(len(cand), 20000, replace=False)]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cand))
    o3d.utility.random.seed(seed)
    plane, inliers = cloud.segment_plane(distance_m, 3, iterations)
    n = np.asarray(plane[:3], np.float64)
    d = float(plane[3])
    norm = np.linalg.norm(n)
    n, d = n / norm, d / norm
    if n[1] > 0:  # the up normal points against image +y (OpenCV y is down)
        n, d = -n, -d
    if len(inliers) < 0.1 * len(cand) or -n[1] < np.cos(np.radians(35)):
        return None
    up = n  # world +y in camera coordinates
    forward = np.array([0.0, 0.0, 1.0]) - up * up[2]
    forward /= np.linalg.norm(forward)
    # World axes in camera coordinates: +y = up; the camera looks along world -z.
    z_axis = -forward
    x_axis = np.cross(up, z_axis)
    r_wc = np.stack([x_axis, up, z_axis])  # rows: world axes -> maps camera vectors to world
    m = np.eye(4)
    m[:3, :3] = r_wc
    m[:3, 3] = (0.0, d, 0.0)  # camera height = signed distance of the origin to the plane
    return m


def _quantiles(x: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """Nearest-rank quantiles of a 1-D array: one partition, ~10x cheaper than np.percentile on
    the few thousand points of a cluster (the person finder evaluates several per frame)."""
    ks = np.round(np.asarray(qs) * (len(x) - 1)).astype(np.intp)
    return np.partition(x, ks)[ks]


def _median(x: np.ndarray) -> float:
    """np.median of a 1-D float32 array, to the bit (the mean of the two middle values for an
    even count, in float32), from one partition instead of np.median's several passes."""
    n = len(x)
    if n % 2:
        return float(np.partition(x, n // 2)[n // 2])
    lo, hi = np.partition(x, (n // 2 - 1, n // 2))[n // 2 - 1:n // 2 + 1]
    return float((lo + hi) / x.dtype.type(2))


_EYE4 = np.eye(4)


def _is_identity(m: np.ndarray) -> bool:
    """np.allclose(m, eye(4)) with its default tolerances, without its ~0.2 ms of overhead."""
    return bool(np.all(np.abs(m - _EYE4) <= 1e-8 + 1e-5 * _EYE4))


def _narrow_top(pts: np.ndarray, ys: np.ndarray, y_top: float, c: np.ndarray, eye_xz: np.ndarray,
                band_m: float = 0.12) -> float:
    """Person-likeness in (0.1, 1] of a cluster's points (3, M): 1.2 minus the width of the cluster's top band over its whole
    width, both measured across the line of sight from ``eye_xz`` to the cluster's centre ``c``.
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


class BackgroundModel:
    """A static background depth learned from person-free frames (per-pixel median)."""

    def __init__(self) -> None:
        self._frames: list[np.ndarray] = []
        self.depth_mm: np.ndarray | None = None

    def learn(self, depth_mm: np.ndarray) -> None:
        self._frames.append(np.asarray(depth_mm, np.uint16))
        stack = np.stack(self._frames[-30:]).astype(np.float32)
        stack[stack == 0] = np.nan
        with warnings.catch_warnings():  # pixels never seen are all-NaN: no background there
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(stack, axis=0)
        self.depth_mm = np.nan_to_num(med, nan=0.0).astype(np.uint16)

    def foreground(self, depth_mm: np.ndarray, margin_m: float) -> np.ndarray:
        """Bool mask of pixels clearly in front of the background (or where none was seen)."""
        if self.depth_mm is None:
            return depth_mm > 0
        bg = self.depth_mm.astype(np.int32)
        d = depth_mm.astype(np.int32)
        return (d > 0) & ((bg == 0) | (d < bg - int(margin_m * 1000)))


@dataclass
class FinderCounters:
    frames: int = 0
    found: int = 0
    nobody: int = 0
    no_floor: int = 0


@dataclass
class PersonFinder:
    config: PreprocessConfig = field(default_factory=PreprocessConfig)
    background: BackgroundModel | None = None
    counters: FinderCounters = field(default_factory=FinderCounters)
    _floor_c2w: np.ndarray | None = None
    _last_center: np.ndarray | None = None
    _past_depth: deque = field(default_factory=lambda: deque(maxlen=64), repr=False)
    _rays: np.ndarray | None = field(default=None, repr=False)
    _rays_key: tuple | None = field(default=None, repr=False)

    def world_points(self, frame: DepthFrame, stride: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Valid, in-range world points (M, 3) float32 of a frame and the camera_to_world used
        (depth images read on ``stride``, default pixel_stride)."""
        got = self._world(frame, stride or self.config.pixel_stride)
        return None if got is None else (np.ascontiguousarray(got[0].T), got[2])

    def _world(self, frame: DepthFrame, s: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray] | None:
        """(world points (3, M) float32, their flat pixel indices in the strided image or None
        for a cloud frame, camera_to_world). Points are columns: the finder works on x, y and z
        rows, where numpy's ops on (M, 3) rows pay an inner loop of three per point."""
        cfg = self.config
        c2w = np.asarray(frame.camera_to_world, np.float64)
        if _is_identity(c2w):
            # Unknown extrinsics: find the floor once and keep it (the camera is static).
            if self._floor_c2w is None:
                self._floor_c2w = estimate_floor(self._camera_points(frame, s))
            if self._floor_c2w is None:
                self.counters.no_floor += 1
                return None
            c2w = self._floor_c2w
        if frame.depth_mm is None:
            r = c2w[:3, :3].astype(np.float32)
            world = self._camera_points(frame, s) @ r.T + c2w[:3, 3].astype(np.float32)
            return np.ascontiguousarray(world.T), None, c2w
        # Dense path: world = z * (R K^-1 (u, v, 1)) + t with the rotated rays cached per camera,
        # so a frame costs a few vector ops over the strided image.
        depth = frame.depth_mm[::s, ::s]
        z = depth.astype(np.float32) * np.float32(0.001)
        valid = (z > cfg.min_range_m) & (z < cfg.max_range_m)
        if self.background is not None:
            valid &= self.background.foreground(frame.depth_mm, cfg.background_margin_m)[::s, ::s]
        idx = np.flatnonzero(valid)
        rays = self._world_rays(frame.intrinsics, depth.shape, c2w, s)
        world = np.take(rays, idx, axis=1)
        world *= np.take(z.reshape(-1), idx)
        world += c2w[:3, 3].astype(np.float32)[:, None]
        return world, idx, c2w

    def _camera_points(self, frame: DepthFrame, s: int) -> np.ndarray:
        """In-range camera-frame points (M, 3) float32 (strided depth image, or the frame's cloud)."""
        cfg = self.config
        if frame.depth_mm is not None:
            depth = frame.depth_mm[::s, ::s]
            mask = depth > 0
            if self.background is not None:
                mask &= self.background.foreground(frame.depth_mm, cfg.background_margin_m)[::s, ::s]
            k = frame.intrinsics
            v, u = np.nonzero(mask)
            z = depth[v, u].astype(np.float32) * np.float32(0.001)
            x = (u.astype(np.float32) * s - np.float32(k[0, 2])) * z / np.float32(k[0, 0])
            y = (v.astype(np.float32) * s - np.float32(k[1, 2])) * z / np.float32(k[1, 1])
            cam = np.stack([x, y, z], axis=1)
        else:
            cam = np.asarray(frame.points, np.float32)
        dist = cam[:, 2]
        return cam[(dist > cfg.min_range_m) & (dist < cfg.max_range_m)]

    def _world_rays(self, k: np.ndarray, shape: tuple[int, int], c2w: np.ndarray, s: int) -> np.ndarray:
        """(3, h*w) float32 world directions (camera z = 1) of the strided pixels, cached."""
        key = (np.asarray(k, np.float64).tobytes(), shape, s, c2w.tobytes())
        if self._rays_key != key:
            v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64) * s
            d = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)])
            self._rays = np.ascontiguousarray(c2w[:3, :3] @ d.reshape(3, -1), np.float32)
            self._rays_key = key
        return self._rays

    def find(self, frame: DepthFrame) -> PersonCloud | None:
        """The person in ``frame`` as a normalised sample, or None when nobody is in view."""
        cfg = self.config
        self.counters.frames += 1
        coarse = (cfg.coarse_stride is not None and frame.depth_mm is not None
                  and cfg.coarse_stride > cfg.pixel_stride)
        got = self._world(frame, cfg.coarse_stride if coarse else cfg.pixel_stride)
        if got is None:
            return None
        world, pixels, c2w = got
        above = np.flatnonzero(world[1] > cfg.floor_margin_m)
        scale = (cfg.coarse_stride / cfg.pixel_stride) ** 2 if coarse else 1.0
        moving = self._moving_pixels(frame, cfg.coarse_stride if coarse else cfg.pixel_stride,
                                     None if pixels is None else pixels[above])
        found = self._cluster(np.take(world, above, axis=1), c2w[[0, 2], 3], min_points=max(int(cfg.min_points / scale), 10),
                              moving=moving)
        if found is None:
            self.counters.nobody += 1
            return None
        sel, labels, lab, origin = found
        person = np.take(world, above[sel], axis=1)
        center = np.array([_median(person[0]), _median(person[2])], np.float64)
        self._last_center = center
        to_world = _person_frame(center, c2w[:3, 3])
        rng = np.random.default_rng(frame.t_ns & 0xFFFFFFFF)
        n = cfg.num_points
        if coarse:
            pts = self._fine_sample(frame, c2w, pixels[above[sel]], labels, lab, origin, rng)
        else:
            pts = np.take(person, rng.choice(person.shape[1], n, replace=person.shape[1] < n), axis=1).T
        local = (pts - to_world[:3, 3].astype(np.float32)) @ to_world[:3, :3].astype(np.float32)
        self.counters.found += 1
        return PersonCloud(points=np.ascontiguousarray(local, np.float32), to_world=to_world,
                           count=int(person.shape[1] * scale), height_m=float(person[1].max()))

    def _moving_pixels(self, frame: DepthFrame, s: int, at: np.ndarray | None) -> np.ndarray | None:
        """Bool per flat index ``at`` of the strided depth image: depth changed since the newest
        stored frame at least motion_lag_s older (None without a depth image or such a frame)."""
        if frame.depth_mm is None or at is None:
            return None
        cfg = self.config
        depth = frame.depth_mm[::s, ::s]
        past = self._past_depth
        if past and (past[-1][1].shape != depth.shape or past[-1][0] >= frame.t_ns):
            past.clear()  # another camera, or time went backwards (a new replay)
        lag = int(cfg.motion_lag_s * 1e9)
        while len(past) > 1 and past[1][0] <= frame.t_ns - lag:
            past.popleft()  # keep one frame at least motion_lag_s old, and the newer ones
        ref = past[0][1] if past else None
        depth = depth.copy()  # contiguous: kept for later frames, and flat-indexed below
        past.append((frame.t_ns, depth))
        if ref is None:
            return None
        # Only at the points asked about (those above the floor): a third of the image or less.
        z = depth.reshape(-1)[at].astype(np.float32) * np.float32(0.001)
        z_ref = ref.reshape(-1)[at].astype(np.float32) * np.float32(0.001)
        return (z > 0) & (z_ref > 0) & (np.abs(z - z_ref) > cfg.motion_change_m + 0.01 * z * z)

    def _fine_sample(self, frame: DepthFrame, c2w: np.ndarray, person_idx: np.ndarray, labels: np.ndarray,
                     lab: int, origin: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """num_points world points (N, 3) drawn uniformly without replacement from the person's
        pixels at pixel_stride: the pixels of the coarse person's image box are visited in random
        order and kept when their point falls in the person's cells (above the floor)."""
        cfg = self.config
        cs, s = cfg.coarse_stride, cfg.pixel_stride
        h, w = frame.depth_mm.shape
        wc = -(-w // cs)
        rows, cols = (person_idx // wc) * cs, (person_idx % wc) * cs
        r0, r1 = max(rows.min() - cs, 0) // s * s, min(rows.max() + cs + 1, h)
        c0, c1 = max(cols.min() - cs, 0) // s * s, min(cols.max() + cs + 1, w)
        crop = frame.depth_mm[r0:r1:s, c0:c1:s]
        z = crop.astype(np.float32) * np.float32(0.001)
        valid = (z > cfg.min_range_m) & (z < cfg.max_range_m)
        if self.background is not None:
            valid &= self.background.foreground(frame.depth_mm, cfg.background_margin_m)[r0:r1:s, c0:c1:s]
        cand = np.flatnonzero(valid)
        rng.shuffle(cand)
        n, cells = cfg.num_points, labels.shape[0]
        kept: list[np.ndarray] = []
        total, start, chunk = 0, 0, 3 * n
        k = frame.intrinsics
        r = c2w[:3, :3].astype(np.float32)
        while total < n and start < len(cand):
            idx = cand[start:start + chunk]
            start += chunk
            chunk *= 2
            v = (idx // crop.shape[1]) * s + r0
            u = (idx % crop.shape[1]) * s + c0
            zi = z.reshape(-1)[idx]
            cam = np.stack([(u - k[0, 2]) / k[0, 0] * zi, (v - k[1, 2]) / k[1, 1] * zi, zi], 1).astype(np.float32)
            pts = cam @ r.T + c2w[:3, 3].astype(np.float32)
            i = np.floor((pts[:, 0] - origin[0]) / cfg.cell_m).astype(np.int64)
            j = np.floor((pts[:, 2] - origin[1]) / cfg.cell_m).astype(np.int64)
            ok = (i >= 0) & (i < cells) & (j >= 0) & (j < cells) & (pts[:, 1] > cfg.floor_margin_m)
            ok[ok] = labels[j[ok], i[ok]] == lab
            kept.append(pts[ok])
            total += int(ok.sum())
        pts = np.concatenate(kept) if kept else np.zeros((0, 3), np.float32)
        if len(pts) >= n:
            return pts[:n]
        if len(pts) == 0:  # cannot happen for a found person; keep the contract anyway
            pts = np.zeros((1, 3), np.float32)
        return pts[rng.choice(len(pts), n, replace=True)]

    def _cluster(self, pts: np.ndarray, eye_xz: np.ndarray, min_points: int, moving: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray] | None:
        """The person among world points (3, M) above the floor: (bool mask (M,) of its points,
        the cell label grid, its label, the grid origin (x, z)), or None. moving: (M,) bool,
        points whose depth changed lately (``_moving_pixels``), or None when not known."""
        cfg = self.config
        if pts.shape[1] < min_points:
            return None
        cells = int(2 * cfg.grid_half_extent_m / cfg.cell_m)
        origin = np.array([-cfg.grid_half_extent_m, -cfg.grid_half_extent_m], np.float32)
        if self._last_center is not None:
            origin = origin + self._last_center.astype(np.float32)
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
        if self._last_center is not None:
            # The previous person's label first (the grid is centred on them): their score then
            # prunes the others by their distance to it, from their boxes alone.
            ci, cj = (np.floor((self._last_center - origin) / cfg.cell_m)).astype(int)
            tracked = labels_flat[cj * cells + ci] if 0 <= ci < cells and 0 <= cj < cells else 0
            if tracked:
                order = np.concatenate([[tracked], order[order != tracked]])
        best, best_score = None, 0.0
        for k, lab in enumerate(order):
            if bound[lab] <= best_score:
                if k:
                    break  # candidates come by decreasing bound: none of the rest can score higher
                continue
            if lab == 0 or counts[lab] < min_points:
                continue
            # The component's box: its seed cells' box grown by the dilation, within the crop.
            si, sj = it[seed_label == lab], jt[seed_label == lab]
            b_i0, b_i1 = max(int(si.min()) - 1, 0), min(int(si.max()) + 1, crop.shape[1] - 1)
            b_j0, b_j1 = max(int(sj.min()) - 1, 0), min(int(sj.max()) + 1, crop.shape[0] - 1)
            footprint = np.hypot(b_i1 - b_i0 + 1, b_j1 - b_j0 + 1) * cfg.cell_m
            if footprint > cfg.max_footprint_m + 2 * cfg.cell_m:
                continue  # a wall or a large piece of furniture
            if self._last_center is not None and best is not None:
                # Its median lies in its box: the box's distance to the previous person bounds
                # the score's distance divisor (less 1 mm for float32 cell rounding).
                lo = origin + np.array([i0 + b_i0, j0 + b_j0]) * cfg.cell_m
                hi = origin + np.array([i0 + b_i1 + 1, j0 + b_j1 + 1]) * cfg.cell_m
                gap = np.maximum(np.maximum(lo - self._last_center, self._last_center - hi), 0.0)
                if bound[lab] / (1.0 + max(float(np.hypot(*gap)) - 1e-3, 0.0)) <= best_score:
                    continue
            sel = point_label == lab
            cluster = pts[:, sel]
            ys = cluster[1]
            y_lo, y_hi = _quantiles(ys, (0.01, 0.99))
            height = float(y_hi - y_lo)
            if height < cfg.min_height_m or y_hi > cfg.max_height_m:
                continue  # too flat to be a person, or a wall / door frame seen edge-on
            # Prefer many points, tall clusters (furniture is rarely taller than 1.2 m), shapes
            # narrower at the top than overall (a head, not the edge of a box or a table top),
            # and the previous person's position.
            c = np.array([_quantiles(cluster[0], (0.5,))[0], _quantiles(cluster[2], (0.5,))[0]])
            narrow = _narrow_top(cluster, ys, y_hi, c, eye_xz)
            if narrow < cfg.min_narrow_top:
                continue  # flat-topped: furniture (this also rejects a person lying down)
            score = counts[lab] * min(height, 1.8) ** 2 * narrow
            if moving is not None:
                score *= weight[lab]
            if self._last_center is not None:
                score /= 1.0 + np.linalg.norm(c - self._last_center)
            if score > best_score:
                best, best_score = (sel, labels_flat[:-1].reshape(cells, cells), int(lab), origin), score
        return best
