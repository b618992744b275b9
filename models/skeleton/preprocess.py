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
from functools import cached_property, lru_cache

import cv2
import numpy as np

from live.core.frames import DepthFrame


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
    # Tracking: a frame is searched only in a window around the previous person grown by
    # track_margin_m (at their depth) on each side; the whole image is searched when nobody was
    # tracked, when the window holds no person or cuts the one found, and every
    # track_full_search_s (another person or a missed performer is found within that time).
    # A window is used only once the motion cue compares frames motion_lag_s apart and after a
    # whole-image search agreed with the frame before it (the person within track_margin_m): a
    # first pick of clutter is not kept by its window.
    # None: every frame searches the whole image.
    track_margin_m: float | None = 0.5
    track_full_search_s: float = 1.0


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


def _is_identity(m: np.ndarray) -> bool:
    """np.allclose(m, eye(4)) with its default tolerances, without its ~0.2 ms of overhead."""
    return bool(np.all(np.abs(m - _EYE4) <= 1e-8 + 1e-5 * _EYE4))


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

    def foreground(self, depth_mm: np.ndarray, margin_m: float, at: tuple[slice, slice] = (slice(None), slice(None))
                   ) -> np.ndarray:
        """Bool mask of the pixels ``depth_mm[at]`` clearly in front of the background (or where
        none was seen); ``at`` picks a strided crop so that only the pixels used are compared."""
        d = depth_mm[at].astype(np.int32)
        if self.depth_mm is None:
            return d > 0
        bg = self.depth_mm[at].astype(np.int32)
        return (d > 0) & ((bg == 0) | (d < bg - int(margin_m * 1000)))


@dataclass
class FinderCounters:
    frames: int = 0
    found: int = 0
    nobody: int = 0
    no_floor: int = 0
    tracked: int = 0  # frames searched only around the previous person
    full_searches: int = 0  # frames searched over the whole image (first, periodic, lost or cut)


@dataclass(frozen=True)
class _Track:
    """The previous person in the strided image: box rows r0..r1, cols c0..c1 (inclusive),
    median depth (m), for the stride and image shape it was found at."""

    r0: int
    r1: int
    c0: int
    c1: int
    depth_m: float
    key: tuple


@dataclass
class _Search:
    """One search's result: world points (3, M), their flat pixels in the strided image (None
    for a cloud frame) of width ``width``, the above-floor indices, and the person among them
    (``_cluster``'s mask, label grid, label, grid origin and the person's points (3, P))."""

    world: np.ndarray
    pixels: np.ndarray | None
    width: int
    above: np.ndarray
    sel: np.ndarray
    labels: np.ndarray
    lab: int
    origin: np.ndarray
    person: np.ndarray

    @cached_property
    def person_pixels(self) -> np.ndarray:
        """The person's flat pixels in the strided image."""
        return self.pixels[self.above[self.sel]]

    @cached_property
    def box(self) -> tuple[int, int, int, int]:
        """The person's rows r0..r1 and cols c0..c1 (inclusive) in the strided image."""
        rows, cols = self.person_pixels // self.width, self.person_pixels % self.width
        return int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())


@dataclass
class PersonFinder:
    config: PreprocessConfig = field(default_factory=PreprocessConfig)
    background: BackgroundModel | None = None
    counters: FinderCounters = field(default_factory=FinderCounters)
    _floor_c2w: np.ndarray | None = None
    _last_center: np.ndarray | None = None
    _past_depth: deque = field(default_factory=lambda: deque(maxlen=64), repr=False)
    _rays: dict = field(default_factory=dict, repr=False)  # stride -> (camera key, rays)
    _track: _Track | None = field(default=None, repr=False)
    _full_search_ns: int | None = field(default=None, repr=False)
    _confirmed: bool = field(default=False, repr=False)
    _cue_ready: bool = field(default=False, repr=False)  # the motion cue compares motion_lag_s apart

    def world_points(self, frame: DepthFrame, stride: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Valid, in-range world points (M, 3) float32 of a frame and the camera_to_world used
        (depth images read on ``stride``, default pixel_stride)."""
        s = stride or self.config.pixel_stride
        c2w = self._camera_to_world(frame, s)
        return None if c2w is None else (np.ascontiguousarray(self._world(frame, s, c2w)[0].T), c2w)

    def _camera_to_world(self, frame: DepthFrame, s: int) -> np.ndarray | None:
        """The frame's camera_to_world, or when it is not known (identity extrinsics) the floor
        found once by RANSAC and kept (the camera is static); None when no floor is seen."""
        c2w = np.asarray(frame.camera_to_world, np.float64)
        if not _is_identity(c2w):
            return c2w
        if self._floor_c2w is None:
            self._floor_c2w = estimate_floor(self._camera_points(frame, s))
        if self._floor_c2w is None:
            self.counters.no_floor += 1
        return self._floor_c2w

    def _world(self, frame: DepthFrame, s: int, c2w: np.ndarray, roi: tuple[int, int, int, int] | None = None
               ) -> tuple[np.ndarray, np.ndarray | None]:
        """(world points (3, M) float32, their flat pixel indices in the strided image or None
        for a cloud frame), of the strided rows r0:r1 and cols c0:c1 of ``roi`` or of the whole
        image. Points are columns: the finder works on x, y and z rows, where numpy's ops on
        (M, 3) rows pay an inner loop of three per point."""
        cfg = self.config
        if frame.depth_mm is None:
            r = c2w[:3, :3].astype(np.float32)
            world = self._camera_points(frame, s) @ r.T + c2w[:3, 3].astype(np.float32)
            return np.ascontiguousarray(world.T), None
        # Dense path: world = z * (R K^-1 (u, v, 1)) + t with the rotated rays cached per camera,
        # so a frame costs a few vector ops over the strided image.
        depth = frame.depth_mm[::s, ::s]
        rays = self._world_rays(frame.intrinsics, depth.shape, c2w, s)
        r0, r1, c0, c1 = roi or (0, depth.shape[0], 0, depth.shape[1])
        at = (slice(r0 * s, r1 * s, s), slice(c0 * s, c1 * s, s))
        z = frame.depth_mm[at].astype(np.float32) * np.float32(0.001)
        valid = (z > cfg.min_range_m) & (z < cfg.max_range_m)
        if self.background is not None:
            valid &= self.background.foreground(frame.depth_mm, cfg.background_margin_m, at)
        idx = np.flatnonzero(valid)
        zi = np.take(z.reshape(-1), idx)
        if roi is not None:  # crop indices -> indices of the whole strided image
            idx = (idx // (c1 - c0) + r0) * depth.shape[1] + idx % (c1 - c0) + c0
        world = np.take(rays, idx, axis=1)
        world *= zi
        world += c2w[:3, 3].astype(np.float32)[:, None]
        return world, idx

    def _camera_points(self, frame: DepthFrame, s: int) -> np.ndarray:
        """In-range camera-frame points (M, 3) float32 (strided depth image, or the frame's cloud)."""
        cfg = self.config
        if frame.depth_mm is not None:
            depth = frame.depth_mm[::s, ::s]
            mask = depth > 0
            if self.background is not None:
                mask &= self.background.foreground(frame.depth_mm, cfg.background_margin_m, (slice(None, None, s),) * 2)
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
        """(3, h*w) float32 world directions (camera z = 1) of the strided pixels, cached per
        stride (the coarse search and the fine sample each read theirs)."""
        key = (np.asarray(k, np.float64).tobytes(), shape, c2w.tobytes())
        cached = self._rays.get(s)
        if cached is None or cached[0] != key:
            v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64) * s
            d = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)])
            cached = self._rays[s] = key, np.ascontiguousarray(c2w[:3, :3] @ d.reshape(3, -1), np.float32)
        return cached[1]

    def find(self, frame: DepthFrame) -> PersonCloud | None:
        """The person in ``frame`` as a normalised sample, or None when nobody is in view."""
        cfg = self.config
        self.counters.frames += 1
        coarse = (cfg.coarse_stride is not None and frame.depth_mm is not None
                  and cfg.coarse_stride > cfg.pixel_stride)
        s = cfg.coarse_stride if coarse else cfg.pixel_stride
        c2w = self._camera_to_world(frame, s)
        if c2w is None:
            return None
        depths = self._motion_reference(frame, s)
        scale = (cfg.coarse_stride / cfg.pixel_stride) ** 2 if coarse else 1.0
        min_points = max(int(cfg.min_points / scale), 10)
        roi = self._tracking_roi(frame, s)
        found = None if roi is None else self._search(frame, s, c2w, roi, depths, min_points)
        if found is not None and self._cut_by(found, roi, frame.depth_mm.shape, s):
            found = None  # the person reaches the window's edge: look at the whole image
        whole_image = found is None
        if whole_image:
            self.counters.full_searches += 1
            self._full_search_ns = frame.t_ns
            found = self._search(frame, s, c2w, None, depths, min_points)
        else:
            self.counters.tracked += 1
        if found is None:
            self.counters.nobody += 1
            self._track = None
            return None
        person = found.person
        center = np.array([_median(person[0]), _median(person[2])], np.float64)
        if whole_image:  # a window only once a whole-image search agrees with the frame before
            self._confirmed = (self._last_center is not None and cfg.track_margin_m is not None
                               and float(np.hypot(*(center - self._last_center))) < cfg.track_margin_m)
        self._last_center = center
        to_world = _person_frame(center, c2w[:3, 3])
        rng = np.random.default_rng(frame.t_ns & 0xFFFFFFFF)
        n = cfg.num_points
        if found.pixels is not None:
            self._remember(found, s)
        if coarse:
            pts = self._fine_sample(frame, c2w, found.box, found.labels, found.lab, found.origin, rng)
        else:
            pts = np.take(person, rng.choice(person.shape[1], n, replace=person.shape[1] < n), axis=1).T
        local = (pts - to_world[:3, 3].astype(np.float32)) @ to_world[:3, :3].astype(np.float32)
        self.counters.found += 1
        return PersonCloud(points=np.ascontiguousarray(local, np.float32), to_world=to_world,
                           count=int(person.shape[1] * scale), height_m=float(person[1].max()))

    def _search(self, frame: DepthFrame, s: int, c2w: np.ndarray, roi: tuple[int, int, int, int] | None,
                depths: tuple[np.ndarray, np.ndarray] | None, min_points: int) -> _Search | None:
        """The person among the points of ``roi`` (or of the whole image), or None."""
        world, pixels = self._world(frame, s, c2w, roi)
        above = np.flatnonzero(world[1] > self.config.floor_margin_m)
        moving = None
        if depths is not None and pixels is not None:
            moving = self._moved(depths, pixels[above])
        got = self._cluster(np.take(world, above, axis=1), c2w[[0, 2], 3], min_points=min_points, moving=moving)
        width = -(-frame.depth_mm.shape[1] // s) if frame.depth_mm is not None else 0
        return None if got is None else _Search(world, pixels, width, above, *got)

    def _tracking_roi(self, frame: DepthFrame, s: int) -> tuple[int, int, int, int] | None:
        """Strided rows r0:r1 and cols c0:c1 around the previous person, grown by
        track_margin_m at their depth; None for a whole-image search (no person tracked, or
        not confirmed, no full motion cue yet, a cloud frame, tracking off, or
        track_full_search_s since the last whole-image search)."""
        cfg, track = self.config, self._track
        if (cfg.track_margin_m is None or track is None or not self._confirmed or not self._cue_ready
                or frame.depth_mm is None):
            return None
        depth_shape = frame.depth_mm[::s, ::s].shape
        if track.key != (depth_shape, s) or self._full_search_ns is None:
            return None
        since = frame.t_ns - self._full_search_ns
        if since < 0 or since >= cfg.track_full_search_s * 1e9:
            return None
        k = frame.intrinsics
        grow_c = int(np.ceil(cfg.track_margin_m * k[0, 0] / (track.depth_m * s)))
        grow_r = int(np.ceil(cfg.track_margin_m * k[1, 1] / (track.depth_m * s)))
        return (max(track.r0 - grow_r, 0), min(track.r1 + 1 + grow_r, depth_shape[0]),
                max(track.c0 - grow_c, 0), min(track.c1 + 1 + grow_c, depth_shape[1]))

    def _remember(self, found: _Search, s: int) -> None:
        """Keep the person's strided-image box and median depth for the next frame's window."""
        depth = self._past_depth[-1][1]  # this frame's strided depth image, contiguous
        # The median depth of at most ~2,000 of their pixels (every k-th) is as good for a margin.
        px = found.person_pixels
        z = np.take(depth.reshape(-1), px[::-(-len(px) // 2048)]).astype(np.float32) * np.float32(0.001)
        self._track = _Track(*found.box, max(_median(z), self.config.min_range_m), (depth.shape, s))

    def _cut_by(self, found: _Search, roi: tuple[int, int, int, int], shape: tuple[int, int], s: int) -> bool:
        """Whether the person found in ``roi`` touches one of its edges inside the image (they
        may go on beyond it)."""
        h, w = -(-shape[0] // s), -(-shape[1] // s)
        top, bottom, left, right = found.box
        r0, r1, c0, c1 = roi
        return (r0 > 0 and top <= r0) or (r1 < h and bottom >= r1 - 1) or (c0 > 0 and left <= c0) or (
            c1 < w and right >= c1 - 1)

    def _motion_reference(self, frame: DepthFrame, s: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(this frame's strided depth image, contiguous; that of the newest stored frame at
        least motion_lag_s older), or None without a depth image or such a frame. Stores this
        frame's."""
        if frame.depth_mm is None:
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
        self._cue_ready = bool(past) and frame.t_ns - past[0][0] >= lag
        depth = depth.copy()  # contiguous: flat-indexed here and by later frames
        past.append((frame.t_ns, depth))
        return None if ref is None else (depth, ref)

    def _moved(self, depths: tuple[np.ndarray, np.ndarray], at: np.ndarray) -> np.ndarray:
        """Bool per flat index ``at`` of the strided depth image: depth changed since the
        reference of ``_motion_reference`` (only at the points asked about, those above the
        floor: a third of the image or less)."""
        cfg = self.config
        depth, ref = depths
        z = np.take(depth.reshape(-1), at).astype(np.float32) * np.float32(0.001)
        z_ref = np.take(ref.reshape(-1), at).astype(np.float32) * np.float32(0.001)
        return (z > 0) & (z_ref > 0) & (np.abs(z - z_ref) > cfg.motion_change_m + 0.01 * z * z)

    def _fine_sample(self, frame: DepthFrame, c2w: np.ndarray, box: tuple[int, int, int, int], labels: np.ndarray,
                     lab: int, origin: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """num_points world points (N, 3), distinct, from the person's pixels at pixel_stride: the
        pixels of the coarse person's image box (``box``: rows r0..r1, cols c0..c1 at
        coarse_stride) are visited along a randomly shifted R2 sequence (``r2_grid_order``) and
        kept when their point falls in the person's cells (above the floor).

        Why not a uniform random draw: which 256 of the person's thousands of pixels are drawn
        moves the regressor's joints from frame to frame (the spread of four draws of one frame:
        25 mm rms per joint), most at the hands and feet that only a few points cover. An evenly
        spread draw covers every part of the body in proportion to its area: on 16 held-out runs
        the stage (temporal model included) went 32.7 -> 31.7 mm MPJPE and Acc 11.3 -> 10.2
        mm/frame^2 with the same network (docs/skeleton.md, "Evenly spread point sample")."""
        cfg = self.config
        cs, s = cfg.coarse_stride, cfg.pixel_stride
        h, w = frame.depth_mm.shape
        top, bottom, left, right = (v * cs for v in box)
        r0, r1 = max(top - cs, 0) // s * s, min(bottom + cs + 1, h)
        c0, c1 = max(left - cs, 0) // s * s, min(right + cs + 1, w)
        at = (slice(r0, r1, s), slice(c0, c1, s))
        z = frame.depth_mm[at].astype(np.float32) * np.float32(0.001)
        valid = (z > cfg.min_range_m) & (z < cfg.max_range_m)
        if self.background is not None:
            valid &= self.background.foreground(frame.depth_mm, cfg.background_margin_m, at)
        n = cfg.num_points
        rays = self._world_rays(frame.intrinsics, frame.depth_mm[::s, ::s].shape, c2w, s)
        crop = (r0 // s, c0 // s, z.shape[1], -(-w // s))
        # 6n visits of the box hold n of the person's pixels when they fill a sixth of it (0.29-0.48
        # on a CMU clip); when they do not, start over on a shuffle of all candidates (uniform).
        order = r2_grid_order(z.shape[0], z.shape[1], R2_VISITS * n, rng.random(2))
        pts = self._person_points(order[valid.reshape(-1)[order]], rays, z, c2w, origin, labels, lab, crop)
        if len(pts) < n:
            cand = np.flatnonzero(valid)
            rng.shuffle(cand)
            pts = self._person_points(cand, rays, z, c2w, origin, labels, lab, crop, n)
        if len(pts) >= n:
            return pts[:n]
        if len(pts) == 0:  # cannot happen for a found person; keep the contract anyway
            pts = np.zeros((1, 3), np.float32)
        return pts[rng.choice(len(pts), n, replace=True)]

    def _person_points(self, idx: np.ndarray, rays: np.ndarray, z: np.ndarray, c2w: np.ndarray, origin: np.ndarray,
                       labels: np.ndarray, lab: int, crop: tuple[int, int, int, int], enough: int | None = None
                       ) -> np.ndarray:
        """World points (K, 3) of the candidate crop pixels ``idx`` (flat in the crop at rows r0,
        cols c0 of the strided image, ``crop`` = (r0, c0, crop width, image width)) that fall in
        the person's cells above the floor, in the order of ``idx``; with ``enough``, read in
        growing chunks until that many are found."""
        cfg, cells = self.config, labels.shape[0]
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

    def _cluster(self, pts: np.ndarray, eye_xz: np.ndarray, min_points: int, moving: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray] | None:
        """The person among world points (3, M) above the floor: (bool mask (M,) of its points,
        the cell label grid, its label, the grid origin (x, z), its points (3, P)), or None.
        moving: (M,) bool, points whose depth changed lately (``_moved``), or None when not known."""
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
                best, best_score = (sel, labels_flat[:-1].reshape(cells, cells), int(lab), origin, cluster), score
        return best
