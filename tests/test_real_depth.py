"""The skeleton stage on real depth it did not make: every frame of the shared real-depth folders
(an Asus Xtion in a room with the floor only in the bottom rows, a Kinect v2 with three people, a
Kinect v1 head-and-shoulders close-up; no extrinsics) gets a skeleton whose upper-body joints lie
on the body: the depth image at each joint's pixel is the body's surface just in front of it."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from live.core import assets
from live.core.skeleton import JOINT_INDEX
from models.skeleton.runtime import SkeletonStage
from sim.depth_folder import DepthFolderSource

REAL = assets.shared_data_dir() / "real_depth"
FOLDERS = sorted(p for p in REAL.iterdir() if p.is_dir()) if REAL.is_dir() else []
UPPER_BODY = [JOINT_INDEX[n] for n in ("spine3", "neck", "head", "left_collar", "right_collar",
                                       "left_shoulder", "right_shoulder")]


def _frames(folder):
    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    return frames


def on_the_body(joints: np.ndarray, c2w: np.ndarray, frame, reach_m: float = 0.04) -> np.ndarray:
    """(J,) bool: within ``reach_m`` of each joint's pixel the image sees a surface 0-45 cm in
    front of the joint (a joint lies inside the body, behind its surface: up to a shoulder width
    behind it in a profile view) or up to 10 cm behind it (depth noise)."""
    cam = (joints.astype(np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    k = frame.intrinsics
    h, w = frame.depth_mm.shape
    ok = np.zeros(len(joints), bool)
    for j, (x, y, z) in enumerate(cam):
        if z <= 0:
            continue
        u, v = x / z * k[0, 0] + k[0, 2], y / z * k[1, 1] + k[1, 2]
        r = int(np.ceil(reach_m * k[0, 0] / z))
        u0, u1, v0, v1 = int(round(u)) - r, int(round(u)) + r + 1, int(round(v)) - r, int(round(v)) + r + 1
        if u1 <= 0 or v1 <= 0 or u0 >= w or v0 >= h:
            continue
        patch = frame.depth_mm[max(v0, 0):v1, max(u0, 0):u1] * 1e-3
        gap = z - patch[patch > 0]
        ok[j] = bool(np.any((gap > -0.10) & (gap < 0.45)))
    return ok


@pytest.mark.skipif(not FOLDERS, reason="no ../shared/data/real_depth")
def test_every_real_frame_gets_a_skeleton_with_its_upper_body_on_the_body():
    checked, on_body, report = 0, 0, []
    for folder in FOLDERS:
        stage = SkeletonStage()
        for frame in _frames(folder):
            skeleton = stage.estimate(frame)
            assert skeleton is not None, f"{folder.name}: nobody found at t={frame.t_ns}"
            assert skeleton.camera_to_world is not None
            ok = on_the_body(skeleton.joints[UPPER_BODY], skeleton.camera_to_world, frame)
            checked += len(ok)
            on_body += int(ok.sum())
            report.append(f"{folder.name}: {int(ok.sum())}/{len(ok)}")
    # The goal, over every real frame: >= 95 % of the upper-body joints on the body.
    assert on_body >= 0.95 * checked, f"{on_body} of {checked} upper-body joints on the body ({', '.join(report)})"
