"""Pictures of the simulator for the docs: ``python -m research.figures [--out docs/img/virtual_depth.png]``.

virtual_depth_figure renders one frame of a real CMU clip (from the shared clips) with the
virtual depth camera, and writes ideal depth beside measured (noisy) depth with the ground-truth
skeleton projected over it. The body is the body library's default skinned with the clip when
live.body.library / live.body.skinning exist, else capsules around the clip's joints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.kinematics import forward_kinematics
from live.core.skeleton import BONES, pelvis_height
from live.motion.rig_mapping import load_motion
from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera
from sim.room import Box, Room, capsule_body

DEFAULT_CLIP = assets.bvh_dir() / "cc_002_01.bvh"
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "virtual_depth.png"  # from the checkout root


def posed_subject(clip: Path, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(vertices (V, 3), faces (F, 3), joints (22, 3) world, description) at one clip frame."""
    motion = load_motion(clip)
    frame = min(frame, motion.num_frames - 1)
    try:
        from live.body.library import load_body
        from live.body.skinning import lbs
    except ImportError:
        joints = motion.joints[frame]
        v, f = capsule_body(joints)
        return v, f, joints, "capsule stand-in"
    body = load_body("default")
    # Conventions: moving a motion onto another body scales the root by the leg-length ratio.
    root = motion.root[frame:frame + 1] * (pelvis_height(body.rest_joints) / pelvis_height(motion.rest_joints))
    rot = motion.rotations[frame:frame + 1]
    verts = lbs(body.vertices, body.weights, body.rest_joints, rot, root)[0]
    joints = forward_kinematics(rot, root, body.rest_joints)[0][0]
    return np.asarray(verts, np.float32), np.asarray(body.faces, np.int32), joints, f"body {body.name}"


def colorize(depth_mm: np.ndarray, near_m: float = 0.5, far_m: float = 7.0) -> np.ndarray:
    """(H, W) uint16 mm -> (H, W, 3) uint8 BGR, turbo colour map, black where there is no data."""
    t = (depth_mm.astype(np.float32) / 1000.0 - near_m) / (far_m - near_m)
    img = cv2.applyColorMap((np.clip(t, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[depth_mm == 0] = 0
    return img


def project(points: np.ndarray, camera: VirtualDepthCamera) -> np.ndarray:
    """(N, 3) world points -> (N, 2) pixel coordinates."""
    m = camera.camera_to_world
    p = (np.asarray(points, np.float64) - m[:3, 3]) @ m[:3, :3]
    k = camera.intrinsics
    return np.stack([p[:, 0] / p[:, 2] * k[0, 0] + k[0, 2], p[:, 1] / p[:, 2] * k[1, 1] + k[1, 2]], 1)


def virtual_depth_figure(out: Path = DEFAULT_OUT, clip: Path = DEFAULT_CLIP, frame: int = 60,
                         preset: str = "oak-d", seed: int = 0) -> Path:
    """Write the two-panel picture to ``out`` and return its path."""
    verts, faces, joints, what = posed_subject(clip, frame)
    pelvis = joints[0]
    pose = look_at_camera(2.6, 1.5, 0.5, target=(float(pelvis[0]), 1.0, float(pelvis[2])))
    room = Room(boxes=(Box((1.8, 0.4, -1.5), (0.8, 0.8, 0.8)), Box((-2.2, 0.6, -2.8), (1.2, 1.2, 0.6))))
    ideal = VirtualDepthCamera(preset, pose, noise=NoiseModel.none()).render(verts, faces, room)
    cam = VirtualDepthCamera(preset, pose, seed=seed)
    measured = cam.render(verts, faces, room)
    left, right = colorize(ideal), colorize(measured)
    uv = np.rint(project(joints, cam)).astype(int)
    for a, b in BONES:
        cv2.line(right, tuple(uv[a]), tuple(uv[b]), (255, 255, 255), 2, cv2.LINE_AA)
    for p in uv:
        cv2.circle(right, tuple(p), 4, (0, 0, 255), -1, cv2.LINE_AA)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(left, f"ideal depth ({preset}, {what})", (10, 24), font, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(right, "measured depth + ground-truth skeleton", (10, 24), font, 0.6, (255, 255, 255), 1,
                cv2.LINE_AA)
    cv2.putText(right, f"{clip.name} frame {frame}; colour 0.5-7 m, black = no data", (10, right.shape[0] - 12),
                font, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    gap = np.full((left.shape[0], 6, 3), 255, np.uint8)
    cv2.imwrite(str(out), np.concatenate([left, gap, right], axis=1))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m research.figures", description="Render the docs' virtual depth camera picture.")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--clip", type=Path, default=DEFAULT_CLIP)
    ap.add_argument("--frame", type=int, default=60)
    ap.add_argument("--preset", default="oak-d")
    args = ap.parse_args(argv)
    print(virtual_depth_figure(args.out, args.clip, args.frame, args.preset))


if __name__ == "__main__":
    main()
