"""The real Xtion frames given a level camera pose by hand, taken as given and checked
(docs/img/given_pose_check.png).

    python -m research.given_pose_figure [--out docs/img/given_pose_check.png] [--height 1.2]

The shared ``itop_xtion_2frames`` folder's README describes its camera as level, about 1.2 m above
the floor; given that pose, the stage solves each frame twice: with the pose taken as given
(``--trust-extrinsics``) and checked against the room (the default: ``GroundEstimator.check_given``).
Each panel is a side view in the given world (horizontal distance from the camera against height
above the given floor): the person's sample and the skeleton, with the given floor. A third
column solves the frame with no pose at all, for comparison. Prints how far each skeleton lies
from the no-pose one (root-aligned, seen from the camera) and the source of up.
"""

from __future__ import annotations

import argparse
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.skeleton import PARENTS

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "given_pose_check.png"
FOLDER = "itop_xtion_2frames"


def level_pose(height_m: float) -> np.ndarray:
    """camera_to_world of a level OpenCV camera ``height_m`` above the floor, looking along -z."""
    c2w = np.diag([1.0, -1.0, -1.0, 1.0])
    c2w[1, 3] = height_m
    return c2w


def solve(frame, check: bool | None) -> dict:
    """One frame through a fresh stage: check None solves it without a pose."""
    from models.skeleton.runtime import SkeletonStage

    stage = SkeletonStage(temporal=False, check_extrinsics=bool(check))
    if check is None:
        frame = replace(frame, camera_to_world=np.eye(4))
    skeleton = stage.estimate(frame)
    cloud = stage.last_cloud
    c2w = skeleton.camera_to_world
    sample = cloud.points @ cloud.to_world[:3, :3].T + cloud.to_world[:3, 3]
    to_camera = np.linalg.inv(c2w)
    return {"source": stage.finder.up_source,
            "joints_cam": skeleton.joints @ to_camera[:3, :3].T + to_camera[:3, 3],
            "sample_cam": sample @ to_camera[:3, :3].T + to_camera[:3, 3]}


PANEL = (330, 460)  # width, height in pixels
SPAN_M, LOW_M, HIGH_M = 1.4, -0.45, 2.0  # a panel's horizontal extent and its height range


def panel(sample: np.ndarray, joints: np.ndarray, caption: list[str]) -> np.ndarray:
    """A side view (BGR): given-world points (N, 3) and joints (22, 3) as distance ahead of the
    camera against height, the given floor dashed, the caption on top."""
    import cv2

    w, h = PANEL
    img = np.full((h, w, 3), 255, np.uint8)
    top = 44
    centre = float(-sample[:, 2].mean())
    scale = min(w / SPAN_M, (h - top) / (HIGH_M - LOW_M))

    def px(p: np.ndarray) -> tuple[int, int]:
        return int(round(w / 2 + (-p[2] - centre) * scale)), int(round(top + (HIGH_M - p[1]) * scale))

    floor_y = px(np.array([0.0, 0.0, -centre]))[1]
    for x in range(0, w, 12):
        cv2.line(img, (x, floor_y), (x + 6, floor_y), (200, 120, 40), 1, cv2.LINE_AA)
    for p in sample:
        cv2.circle(img, px(p), 1, (160, 160, 160), -1)
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            cv2.line(img, px(joints[j]), px(joints[parent]), (40, 40, 210), 2, cv2.LINE_AA)
    for i, line in enumerate(caption):
        cv2.putText(img, line, (6, 16 + 16 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def main(argv: list[str] | None = None) -> int:
    import cv2

    from sim.depth_folder import DepthFolderSource

    ap = argparse.ArgumentParser(prog="python -m research.given_pose_figure", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--height", type=float, default=1.2, help="the given camera height, m (the README's)")
    args = ap.parse_args(argv)
    folder = assets.shared_data_dir() / "real_depth" / FOLDER
    if not folder.is_dir():
        ap.error(f"no {folder}")
    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    given = level_pose(args.height)
    frames = [replace(f, camera_to_world=given) for f in frames]
    columns = (("pose taken as given", False), ("pose checked (default)", True), ("no pose given", None))
    rows = []
    for row, frame in enumerate(frames):
        solved = {name: solve(frame, check) for name, check in columns}
        bare = solved["no pose given"]["joints_cam"]
        panels = []
        for name, _ in columns:
            s = solved[name]
            gap = np.linalg.norm((s["joints_cam"] - s["joints_cam"][:1]) - (bare - bare[:1]), axis=1).mean()
            print(f"frame {row}: {name}: up from {s['source']}, {1000 * gap:.0f} mm from the no-pose skeleton")
            in_given = [a @ given[:3, :3].T + given[:3, 3] for a in (s["sample_cam"], s["joints_cam"])]
            panels.append(panel(*in_given, [f"frame {row + 1}: {name}", f"up: {s['source']}; {1000 * gap:.0f} mm "
                                            "from no pose"]))
        rows.append(np.hstack(panels))
    grid = np.vstack(rows)
    title = np.full((30, grid.shape[1], 3), 255, np.uint8)
    cv2.putText(title, f"Real Xtion frames given a level camera {args.height:g} m high: side views, the camera "
                "to the left (dashed: the given floor)", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack([title, grid]))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
