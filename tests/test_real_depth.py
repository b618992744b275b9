"""The skeleton stage on real depth it did not make: every frame of the shared real-depth folders
(an Asus Xtion in a room with the floor only in the bottom rows, a Kinect v2 with three people, a
Kinect v1 head-and-shoulders close-up; no extrinsics) gets a skeleton whose upper-body joints lie
on the body: the depth image at each joint's pixel is the body's surface just in front of it."""

from __future__ import annotations

import threading
from dataclasses import replace

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


ITOP = REAL / "itop_xtion_2frames"


@pytest.mark.skipif(not ITOP.is_dir(), reason="no ../shared/data/real_depth/itop_xtion_2frames")
def test_real_xtion_frames_with_a_level_pose_given_are_solved_in_the_room(tmp_path):
    """As a replay with the camera's pose given by hand (a level camera about 1.2 m above the
    floor, as the folder's README describes it). The room disagrees (the wall behind the performer
    leans 10 degrees in that world, or the floor in view lies off it): the stage turns the pose to
    the room's up, solves the body there and reports it in the given world. The skeleton is the
    one solved with no pose given at all, on the body, standing a standing adult's height tall."""
    import json
    import shutil

    import numpy as np

    for png in ITOP.glob("*.png"):
        shutil.copy(png, tmp_path / png.name)
    given = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera, level: x right, y up, looking along -z
    given[1, 3] = 1.2
    intrinsics = json.loads((ITOP / "intrinsics.json").read_text())
    (tmp_path / "intrinsics.json").write_text(json.dumps({**intrinsics, "camera_to_world": given.tolist()}))
    for frame in _frames(tmp_path):
        stage, unposed = SkeletonStage(), SkeletonStage()
        skeleton = stage.estimate(frame)
        assert skeleton is not None and stage.finder.up_source in ("given+wall", "given+floor")
        np.testing.assert_allclose(skeleton.camera_to_world, given, atol=1e-9)
        assert on_the_body(skeleton.joints[UPPER_BODY], skeleton.camera_to_world, frame).mean() >= 0.9
        y = skeleton.joints[:, 1] - skeleton.joints[:, 1].min()
        assert 1.3 < y.max() < 2.0, f"highest joint {y.max():.2f} m above the lowest"
        # The same body as with no pose given, seen from the camera (root-aligned).
        bare = replace(frame, camera_to_world=np.eye(4))
        other = unposed.estimate(bare)
        seen = [(s.joints - s.camera_to_world[:3, 3]) @ s.camera_to_world[:3, :3] for s in (skeleton, other)]
        gap = np.linalg.norm((seen[0] - seen[0][:1]) - (seen[1] - seen[1][:1]), axis=1)
        assert gap.mean() < 0.03, f"{1000 * gap.mean():.0f} mm from the skeleton solved without a pose"
