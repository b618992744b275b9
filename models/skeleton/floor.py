"""The floor plane of a camera-frame cloud by RANSAC: camera_to_world when a frame's extrinsics
are not known."""

from __future__ import annotations

import numpy as np


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
