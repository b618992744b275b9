"""Depth image <-> point cloud, pure numpy (camera frame, OpenCV axes, metres)."""

from __future__ import annotations

import numpy as np


def depth_to_points(depth_mm: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(H, W) uint16 millimetres -> (N, 3) float32 points of the valid (non-zero) pixels,
    in row-major pixel order."""
    depth_mm = np.asarray(depth_mm)
    k = np.asarray(intrinsics, dtype=np.float64)
    v, u = np.nonzero(depth_mm)
    z = depth_mm[v, u].astype(np.float32) * np.float32(0.001)
    x = (u.astype(np.float32) - np.float32(k[0, 2])) * z / np.float32(k[0, 0])
    y = (v.astype(np.float32) - np.float32(k[1, 2])) * z / np.float32(k[1, 1])
    return np.stack([x, y, z], axis=-1)


def points_to_world(points: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame points -> (N, 3) world points (float32)."""
    m = np.asarray(camera_to_world, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return (p @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


def between_worlds(points: np.ndarray, from_camera_to_world: np.ndarray, to_camera_to_world: np.ndarray
                   ) -> np.ndarray:
    """(..., 3) world points of one world frame expressed in another that sees the same camera
    (e.g. the truth moved into the frame a skeleton stage estimated for a camera without
    extrinsics): through the camera, ``to @ inverse(from)``; float64."""
    m = np.asarray(to_camera_to_world, np.float64) @ np.linalg.inv(np.asarray(from_camera_to_world, np.float64))
    return np.asarray(points, np.float64) @ m[:3, :3].T + m[:3, 3]


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
