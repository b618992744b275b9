"""Find the person in a depth frame and turn them into a fixed-size, normalised point sample.

Steps (all numpy / OpenCV, a few ms for a 640x400 frame):
1. depth image -> camera points on a pixel stride (the person keeps thousands of points);
2. camera -> world with the frame's camera_to_world (floor at y = 0); when it is not known
   (identity extrinsics) from the camera's IMU, a floor plane anywhere in view, or a level
   camera refined by the performer's vertical axis with the floor placed under them
   (``ground.GroundEstimator``);
3. range limits, optional learned static background (``background.BackgroundModel``), floor
   removal (y < floor_margin);
4. the largest plausible human-sized cluster: connected components of an occupancy grid on the
   floor plane (walls and furniture fail the size tests; ``person_clusters``);
5. a fixed-size point sample, deterministic per frame (``point_sample``), in the *person frame*:
   origin on the floor under the person, rotated about y so the camera is toward +z.
   ``PersonCloud.to_world`` maps person-frame joints back to world coordinates exactly.
Settings: ``preprocess_config.PreprocessConfig``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from live.core.frames import DepthFrame
from live.core.heading import direction_yaw, yaw_matrix
from models.skeleton.background import BackgroundModel
from models.skeleton.ground import GroundEstimator, body_up, floor_under_person
from models.skeleton.person_clusters import find_person_cluster
from models.skeleton.point_sample import fine_sample
from models.skeleton.preprocess_config import PreprocessConfig


@dataclass(frozen=True)
class PersonCloud:
    """points: (N, 3) float32 in the person frame; to_world: (4, 4) person frame -> world;
    count: person points found before sampling; height_m: the top of the person above the floor;
    camera_to_world: (4, 4) the camera -> world the frame was solved in (the frame's own, or the
    one the finder estimated)."""

    points: np.ndarray
    to_world: np.ndarray
    count: int
    height_m: float
    camera_to_world: np.ndarray | None = None


def _person_frame(center_xz: np.ndarray, camera_pos: np.ndarray) -> np.ndarray:
    """(4,4) person frame -> world: origin on the floor at center, +z toward the camera."""
    to_camera = camera_pos - np.array([center_xz[0], 0.0, center_xz[1]])
    m = np.eye(4)
    m[:3, :3] = yaw_matrix(direction_yaw(to_camera))  # the yaw turning +z toward the camera
    m[0, 3], m[2, 3] = center_xz
    return m


def _median(x: np.ndarray) -> float:
    """np.median of a 1-D float32 array, to the bit (the mean of the two middle values for an
    even count, in float32), from one partition instead of np.median's several passes."""
    n = len(x)
    if n % 2:
        return float(np.partition(x, n // 2)[n // 2])
    lo, hi = np.partition(x, (n // 2 - 1, n // 2))[n // 2 - 1:n // 2 + 1]
    return float((lo + hi) / x.dtype.type(2))


_EYE4 = np.eye(4)
#: A small image with no floor on the search stride is searched again on a stride that reads at
#: least this many pixels (a 640 x 400 image reads 16,000 on a stride of 4).
FLOOR_SEARCH_PIXELS = 12_000


def _is_identity(m: np.ndarray) -> bool:
    """np.allclose(m, eye(4)) with its default tolerances, without its ~0.2 ms of overhead."""
    return bool(np.all(np.abs(m - _EYE4) <= 1e-8 + 1e-5 * _EYE4))


@dataclass
class FinderCounters:
    frames: int = 0
    found: int = 0
    nobody: int = 0
    no_floor: int = 0  # frames solved without a floor in view (a level camera or the IMU's up)
    floor_searches: int = 0
    up_source_changes: int = 0
    tracked: int = 0  # frames searched only around the previous person
    full_searches: int = 0  # frames searched over the whole image (first, periodic, lost or cut)
    body_checks: int = 0  # picks that fit a skeleton badly, weighed against the rest of the image
    body_switches: int = 0  # ... where another cluster fitted better and was taken


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
    (``find_person_cluster``'s mask, label grid, label, grid origin and the person's points (3, P))."""

    world: np.ndarray
    pixels: np.ndarray | None
    width: int
    above: np.ndarray
    sel: np.ndarray
    labels: np.ndarray
    lab: int
    origin: np.ndarray
    person: np.ndarray
    c2w: np.ndarray
    cut_below: bool = False  # the person reaches the image's bottom edge
    moved_share: float | None = None  # the person's share of points that moved (None: no cue)

    @cached_property
    def person_pixels(self) -> np.ndarray:
        """The person's flat pixels in the strided image."""
        return self.pixels[self.above[self.sel]]

    @cached_property
    def box(self) -> tuple[int, int, int, int]:
        """The person's rows r0..r1 and cols c0..c1 (inclusive) in the strided image."""
        rows, cols = self.person_pixels // self.width, self.person_pixels % self.width
        return int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())


@dataclass(frozen=True)
class _Pick:
    """A candidate person of one frame: its cloud, its world points (3, P) at the floor it was
    placed on, their median (x, z), and without a floor in view the camera height it was placed
    at (else None)."""

    cloud: PersonCloud
    person: np.ndarray
    center: np.ndarray
    height_est: float | None


@dataclass
class PersonFinder:
    config: PreprocessConfig = field(default_factory=PreprocessConfig)
    background: BackgroundModel | None = None
    counters: FinderCounters = field(default_factory=FinderCounters)
    ground: GroundEstimator = field(default_factory=GroundEstimator)
    _height_est: float | None = field(default=None, repr=False)  # camera height, no floor in view
    _last_center: np.ndarray | None = None
    _past_depth: deque = field(default_factory=lambda: deque(maxlen=64), repr=False)
    _rays: dict = field(default_factory=dict, repr=False)  # stride -> (camera key, rays)
    _track: _Track | None = field(default=None, repr=False)
    _full_search_ns: int | None = field(default=None, repr=False)
    _confirmed: bool = field(default=False, repr=False)
    _cue_ready: bool = field(default=False, repr=False)  # the motion cue compares motion_lag_s apart
    # The tracked person has been seen moving (since they were first found within track_margin_m
    # of each frame before): only such a track holds back moving candidates and gets a window,
    # so a first pick of still clutter (a shelf, a figure) gives way to the performer who moves.
    _track_moved: bool = field(default=False, repr=False)

    def world_points(self, frame: DepthFrame, stride: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """Valid, in-range world points (M, 3) float32 of a frame and the camera_to_world used
        (depth images read on ``stride``, default pixel_stride)."""
        s = stride or self.config.pixel_stride
        c2w = self._camera_to_world(frame, s)
        return None if c2w is None else (np.ascontiguousarray(self._world(frame, s, c2w)[0].T), c2w)

    @property
    def gravity_up(self) -> np.ndarray | None:
        """World up in camera axes from the camera's IMU (set by the skeleton stage), or None."""
        return self.ground.gravity_up

    @gravity_up.setter
    def gravity_up(self, up: np.ndarray | None) -> None:
        self.ground.gravity_up = None if up is None else np.asarray(up, np.float64)

    @property
    def up_source(self) -> str | None:
        """Where up and the floor came from: given, imu, imu+floor, floor, level, level+body."""
        return self.ground.source

    def _camera_to_world(self, frame: DepthFrame, s: int) -> np.ndarray | None:
        """The frame's camera_to_world, or when it is not known (identity extrinsics) the
        ground estimator's (re-searched every few seconds); with no floor in view its height is
        provisional until the performer is found (``_no_floor``)."""
        c2w = np.asarray(frame.camera_to_world, np.float64)
        ground = self.ground
        fs = self._floor_stride(frame, s)
        finer = None if fs == s else (lambda: self._camera_points(frame, fs))
        points = self._camera_points(frame, s) if ground.due(frame.t_ns) else None
        given = not _is_identity(c2w)
        if given:
            ground.check_given(frame.t_ns, c2w, points, finer)
        else:
            ground.update(frame.t_ns, points, finer)
            if not ground.floor_seen:
                self.counters.no_floor += 1
        self.counters.floor_searches = ground.searches
        self.counters.up_source_changes = len(ground.changes)
        return ground.room_from_given(c2w) if given else ground.camera_to_world(0.0)

    def _floor_stride(self, frame: DepthFrame, s: int) -> int:
        """The stride the floor is searched on again when ``s`` shows none: ``s``, or a finer one
        that reads at least FLOOR_SEARCH_PIXELS of a small image (a floor seen at a grazing angle
        holds a few hundred of them; ``find_floor``'s minimum support is counted in points)."""
        if frame.depth_mm is None:
            return s
        h, w = frame.depth_mm.shape
        while s > 1 and -(-h // s) * -(-w // s) < FLOOR_SEARCH_PIXELS:
            s -= 1
        return s

    @property
    def _no_floor(self) -> bool:
        """No floor to stand on (``GroundEstimator.floor_unknown``). The search then lifts the
        lowest points to the floor whatever up is (a given camera height with a wrong up would
        sink the performer into it: lost or found on clutter), and the floor is placed once they
        are found."""
        return self.ground.floor_unknown

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
        key = (np.asarray(k, np.float64).tobytes(), shape, c2w[:3, :3].tobytes())
        cached = self._rays.get(s)
        if cached is None or cached[0] != key:
            v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64) * s
            d = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)])
            cached = self._rays[s] = key, np.ascontiguousarray(c2w[:3, :3] @ d.reshape(3, -1), np.float32)
        return cached[1]

    def find(self, frame: DepthFrame, judge: Callable[[PersonCloud], float] | None = None) -> PersonCloud | None:
        """The person in ``frame`` as a normalised sample, or None when nobody is in view.

        judge: how badly a cloud fits a skeleton (metres, lower is better: the skeleton stage's
        regressor and ``body_fit``), or None. Until the tracked person has been seen moving, a
        pick that fits worse than ``body_check_m`` is weighed against the best cluster of the rest
        of the image, which is taken when it fits within ``body_fit_m``, better by
        ``body_fit_margin_m``, stands at least ``body_min_height_m`` tall and has at least
        ``body_min_share`` of the pick's points: a still figure, shelf or sofa picked before the
        performer has moved is not a body."""
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
            self._track_moved = False
            return None
        pick = self._candidate(frame, found, s, coarse, scale)
        if (judge is not None and cfg.body_check_m is not None and not self._track_moved
                and found.pixels is not None):
            found, pick = self._body_check(frame, found, pick, judge, s, c2w, depths, min_points, coarse, scale)
        self._commit(frame, found, pick, whole_image, s)
        self.counters.found += 1
        return self._in_given_world(frame, pick.cloud)

    def _in_given_world(self, frame: DepthFrame, cloud: PersonCloud) -> PersonCloud:
        """A cloud solved in the room's world (given extrinsics turned to the room's up), its
        frame expressed in the given world through the camera: the skeleton comes out in the
        user's own world."""
        if self.ground.given_fix is None or _is_identity(np.asarray(frame.camera_to_world, np.float64)):
            return cloud
        given = np.asarray(frame.camera_to_world, np.float64)
        return replace(cloud, to_world=given @ np.linalg.solve(cloud.camera_to_world, cloud.to_world),
                       camera_to_world=given)

    def _body_check(self, frame: DepthFrame, found: _Search, pick: _Pick, judge: Callable[[PersonCloud], float],
                    s: int, c2w: np.ndarray, depths: tuple[np.ndarray, np.ndarray] | None, min_points: int,
                    coarse: bool, scale: float) -> tuple[_Search, _Pick]:
        """The pick, or the best cluster of the rest of the image where the pick fits no skeleton
        and that one does (``find``'s judge)."""
        cfg = self.config
        fit = judge(pick.cloud)
        if fit <= cfg.body_check_m:
            return found, pick
        self.counters.body_checks += 1
        other = self._search(frame, s, c2w, None, depths, min_points, leave_out=found.person_pixels)
        if other is None:
            return found, pick
        other_pick = self._candidate(frame, other, s, coarse, scale)
        other_fit = judge(other_pick.cloud)
        if (other_fit <= cfg.body_fit_m and other_fit < fit - cfg.body_fit_margin_m
                and other_pick.cloud.height_m >= cfg.body_min_height_m
                and other_pick.cloud.count >= cfg.body_min_share * pick.cloud.count):
            self.counters.body_switches += 1
            return other, other_pick
        return found, pick

    def _candidate(self, frame: DepthFrame, found: _Search, s: int, coarse: bool, scale: float) -> _Pick:
        """The cloud of a search's person; the finder's state is left as it was."""
        cfg = self.config
        c2w, person, height_est = found.c2w, found.person, None
        if self._no_floor:
            c2w, person, height_est = self._floor_placed(found)
        center = np.array([_median(person[0]), _median(person[2])], np.float64)
        to_world = _person_frame(center, c2w[:3, 3])
        rng = np.random.default_rng(frame.t_ns & 0xFFFFFFFF)
        n = cfg.num_points
        if coarse:
            fs = cfg.pixel_stride
            rays = self._world_rays(frame.intrinsics, frame.depth_mm[::fs, ::fs].shape, c2w, fs)
            pts = fine_sample(frame, c2w, found.box, found.labels, found.lab, found.origin, rng, rays, cfg,
                              self.background)
        else:
            pts = np.take(person, rng.choice(person.shape[1], n, replace=person.shape[1] < n), axis=1).T
        local = (pts - to_world[:3, 3].astype(np.float32)) @ to_world[:3, :3].astype(np.float32)
        cloud = PersonCloud(points=np.ascontiguousarray(local, np.float32), to_world=to_world,
                            count=int(person.shape[1] * scale), height_m=float(person[1].max()),
                            camera_to_world=c2w)
        return _Pick(cloud, person, center, height_est)

    def _commit(self, frame: DepthFrame, found: _Search, pick: _Pick, whole_image: bool, s: int) -> None:
        """Track the person taken: their position, whether they moved, their window, and without a
        floor in view the camera height and the body's up."""
        cfg = self.config
        if pick.height_est is not None:
            self._height_est = pick.height_est
            if self.ground.gravity_up is None:
                axis = body_up(pick.person.T, np.array([0.0, 1.0, 0.0]))
                if axis is not None:
                    self.ground.refine_with_body(frame.t_ns, pick.cloud.camera_to_world[:3, :3].T @ axis)
        center = pick.center
        same = (self._last_center is not None and cfg.track_margin_m is not None
                and float(np.hypot(*(center - self._last_center))) < cfg.track_margin_m)
        moved = found.moved_share is not None and found.moved_share > cfg.motion_noise_share
        self._track_moved = moved or (same and self._track_moved)
        if whole_image:  # a window only once a whole-image search agrees with the frame before
            self._confirmed = same and self._track_moved
        self._last_center = center
        if found.pixels is not None:
            self._remember(found, s)

    def _floor_placed(self, found: _Search) -> tuple[np.ndarray, np.ndarray, float]:
        """No floor in view: the floor at the given camera height (with the IMU's up), else under
        the performer (``floor_under_person``, smoothed over frames). Returns the frame's
        camera_to_world, the person's points (3, P) at that floor and the camera height."""
        person = found.person
        given = self.ground.known_height
        if given is not None:
            height_est = float(given)
        else:
            y_low, y_top = (float(v) for v in np.quantile(person[1], (0.01, 0.99)))
            height = float(found.c2w[1, 3]) - floor_under_person(y_low, y_top, found.cut_below)
            height_est = height if self._height_est is None else 0.9 * self._height_est + 0.1 * height
        c2w = found.c2w.copy()
        c2w[1, 3] = height_est
        person = person.copy()
        person[1] += np.float32(height_est - found.c2w[1, 3])
        return c2w, person, height_est

    def _search(self, frame: DepthFrame, s: int, c2w: np.ndarray, roi: tuple[int, int, int, int] | None,
                depths: tuple[np.ndarray, np.ndarray] | None, min_points: int,
                leave_out: np.ndarray | None = None) -> _Search | None:
        """The person among the points of ``roi`` (or of the whole image), or None; leave_out:
        flat pixels of the strided image not to search (another candidate's)."""
        world, pixels = self._world(frame, s, c2w, roi)
        if self._no_floor and world.shape[1]:
            # No floor: lift the lowest points to it, so that everything in view is above it;
            # the floor under the performer is placed once they are found.
            lift = -float(np.partition(world[1], len(world[1]) // 50)[len(world[1]) // 50]) + self.config.floor_margin_m
            world[1] += np.float32(lift)
            c2w = c2w.copy()
            c2w[1, 3] += lift
        above = np.flatnonzero(world[1] > self.config.floor_margin_m)
        if leave_out is not None:
            above = above[~np.isin(pixels[above], leave_out)]
        moving = None
        if depths is not None and pixels is not None:
            moving = self._moved(depths, pixels[above])
        width = -(-frame.depth_mm.shape[1] // s) if frame.depth_mm is not None else 0
        cut_below = cut_above = None
        if pixels is not None:  # the two bottom and the two top rows of the strided image
            rows = -(-frame.depth_mm.shape[0] // s)
            cut_below = pixels[above] >= (rows - 2) * width
            cut_above = pixels[above] < 2 * width
        # The previous person holds back every other candidate once seen moving (and always
        # without a motion cue: no depth image); until then only candidates moving no more than
        # it (``find_person_cluster``'s pull).
        pull = self._track_moved or pixels is None
        got = find_person_cluster(np.take(world, above, axis=1), c2w[[0, 2], 3], min_points, self.config,
                                  self._last_center, moving=moving, cut_below=cut_below, cut_above=cut_above,
                                  floor_known=not self._no_floor, pull=pull)
        if got is None:
            return None
        cut = cut_below is not None and int(np.count_nonzero(cut_below[got[0]])) >= 3
        share = None if moving is None else float(np.count_nonzero(moving[got[0]])) / got[4].shape[1]
        return _Search(world, pixels, width, above, *got, c2w, cut, share)

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
        """Bool per flat index ``at`` of the strided depth image: something came nearer since
        the reference of ``_motion_reference`` (only at the points asked about, those above the
        floor: a third of the image or less). Only nearer: where a performer moved away the
        surface behind them shows again, farther, and that wall or shelf did not move."""
        cfg = self.config
        depth, ref = depths
        z = np.take(depth.reshape(-1), at).astype(np.float32) * np.float32(0.001)
        z_ref = np.take(ref.reshape(-1), at).astype(np.float32) * np.float32(0.001)
        noise = cfg.motion_change_m + 0.01 * z * z
        moved = z_ref - z > noise  # came nearer
        if cfg.motion_recede_m is not None:
            farther = z - z_ref
            moved |= (farther > noise) & (farther < noise + cfg.motion_recede_m)
        return (z > 0) & (z_ref > 0) & moved
