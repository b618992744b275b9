"""The skeleton stage on real depth it did not make: every frame of the shared real-depth folders
(an Asus Xtion in a room with the floor only in the bottom rows, a Kinect v2 with three people, a
Kinect v1 head-and-shoulders close-up; no extrinsics) gets a skeleton whose upper-body joints lie
on the body: the depth image at each joint's pixel is the body's surface just in front of it."""

from __future__ import annotations

import threading

import pytest

from live.core import assets
from models.skeleton.runtime import SkeletonStage
from research.real_depth_figure import UPPER_BODY, on_the_body
from sim.depth_folder import DepthFolderSource

REAL = assets.shared_data_dir() / "real_depth"
FOLDERS = sorted(p for p in REAL.iterdir() if p.is_dir()) if REAL.is_dir() else []


def _frames(folder):
    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    return frames


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
