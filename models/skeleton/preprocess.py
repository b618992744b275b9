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

from dataclasses import dataclass, field

import cv2
import numpy as np

from live.frames import DepthFrame


@dataclass(frozen=True)
class PreprocessConfig:
    num_points: int = 512
    pixel_stride: int = 2
    min_range_m: float = 0.3
    max_range_m: float = 6.0
    floor_margin_m: float = 0.03
    cell_m: float = 0.05
    grid_half_extent_m: float = 6.0
    min_points: int = 120
    min_height_m: float = 0.35
    max_footprint_m: float = 1.8
    background_margin_m: float = 0.10


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


class BackgroundModel:
    """A static background depth learned from person-free frames (per-pixel median)."""

    def __init__(self) -> None:
        self._frames: list[np.ndarray] = []
        self.depth_mm: np.ndarray | None = None

    def learn(self, depth_mm: np.ndarray) -> None:
        self._frames.append(np.asarray(depth_mm, np.uint16))
        stack = np.stack(self._frames[-30:]).astype(np.float32)
        stack[stack == 0] = np.nan
        with np.errstate(all="ignore"):
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

    def world_points(self, frame: DepthFrame) -> tuple[np.ndarray, np.ndarray] | None:
        """Valid, in-range world points of a frame and the camera_to_world used."""
        cfg = self.config
        if frame.depth_mm is not None:
            s = cfg.pixel_stride
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
        cam = cam[(dist > cfg.min_range_m) & (dist < cfg.max_range_m)]
        c2w = np.asarray(frame.camera_to_world, np.float64)
        if np.allclose(c2w, np.eye(4)):
            # Unknown extrinsics: find the floor once and keep it (the camera is static).
            if self._floor_c2w is None:
                self._floor_c2w = estimate_floor(cam)
            if self._floor_c2w is None:
                self.counters.no_floor += 1
                return None
            c2w = self._floor_c2w
        r = c2w[:3, :3].astype(np.float32)
        world = cam @ r.T + c2w[:3, 3].astype(np.float32)
        return world, c2w

    def find(self, frame: DepthFrame) -> PersonCloud | None:
        """The person in ``frame`` as a normalised sample, or None when nobody is in view."""
        cfg = self.config
        self.counters.frames += 1
        got = self.world_points(frame)
        if got is None:
            return None
        world, c2w = got
        person = self._cluster(world[world[:, 1] > cfg.floor_margin_m])
        if person is None:
            self.counters.nobody += 1
            return None
        center = np.median(person[:, [0, 2]], axis=0).astype(np.float64)
        self._last_center = center
        to_world = _person_frame(center, c2w[:3, 3])
        local = (person - to_world[:3, 3].astype(np.float32)) @ to_world[:3, :3].astype(np.float32)
        rng = np.random.default_rng(frame.t_ns & 0xFFFFFFFF)
        n = cfg.num_points
        idx = rng.choice(len(local), n, replace=len(local) < n)
        self.counters.found += 1
        return PersonCloud(points=np.ascontiguousarray(local[idx], np.float32), to_world=to_world,
                           count=len(person), height_m=float(person[:, 1].max()))

    def _cluster(self, pts: np.ndarray) -> np.ndarray | None:
        cfg = self.config
        if len(pts) < cfg.min_points:
            return None
        cells = int(2 * cfg.grid_half_extent_m / cfg.cell_m)
        origin = np.array([-cfg.grid_half_extent_m, -cfg.grid_half_extent_m], np.float32)
        if self._last_center is not None:
            origin = origin + self._last_center.astype(np.float32)
        ij = np.floor((pts[:, [0, 2]] - origin) / cfg.cell_m).astype(np.int32)
        inside = np.all((ij >= 0) & (ij < cells), axis=1)
        pts, ij = pts[inside], ij[inside]
        if len(pts) < cfg.min_points:
            return None
        grid = np.zeros((cells, cells), np.uint8)
        grid[ij[:, 1], ij[:, 0]] = 1
        # Close one-cell gaps (stereo holes) so a person is one component.
        grid = cv2.dilate(grid, np.ones((3, 3), np.uint8))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(grid, connectivity=8)
        if n <= 1:
            return None
        point_label = labels[ij[:, 1], ij[:, 0]]
        counts = np.bincount(point_label, minlength=n)
        best, best_score = None, 0.0
        for lab in np.argsort(-counts):
            if lab == 0 or counts[lab] < cfg.min_points:
                continue
            w, h = stats[lab, cv2.CC_STAT_WIDTH], stats[lab, cv2.CC_STAT_HEIGHT]
            footprint = np.hypot(w, h) * cfg.cell_m
            if footprint > cfg.max_footprint_m + 2 * cfg.cell_m:
                continue  # a wall or a large piece of furniture
            sel = point_label == lab
            ys = pts[sel, 1]
            height = float(np.percentile(ys, 99) - np.percentile(ys, 1))
            if height < cfg.min_height_m:
                continue
            # Prefer many points, tall clusters, and the previous person's position.
            score = counts[lab] * min(height, 1.8)
            if self._last_center is not None:
                c = np.median(pts[sel][:, [0, 2]], axis=0)
                score /= 1.0 + np.linalg.norm(c - self._last_center)
            if score > best_score:
                best, best_score = sel, score
        return None if best is None else pts[best]
