"""Skeleton regressors on performers raising a leg toward the camera (``knee-up`` or ``kick``).

Held-out clips on the held-out bodies, performed in sim.postures' knee-up posture (the left and
then the right knee raised in turn) or its kick posture (front kicks in turn), seen from in front
(within 45 degrees of where the performer faces, 1.8-3.5 m away, 0.7-1.5 m high, level) by each
sensor model in turn. Every frame goes through the skeleton stage without its temporal model
(per-frame joints, as research.compare_skeleton scores them), extrinsics given:

    python -m research.knee_up_views [--models A.onnx B.onnx ...] [--posture knee-up|kick] [--scenes 12]
                                      [--frames 48] [--json FILE]

Prints MPJPE / PA-MPJPE mm and PCK@10cm per model, and the knees' and ankles' mean error. The
held-out realism set (val_real) holds no such pose; the training clips hold few.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.skeleton import JOINT_INDEX
from research.compare_skeleton import scores

CAMERAS = ("xtion", "kinect-v1", "oak-d", "oak-d-pro", "kinect-v2")
LEGS = {"knees": ("left_knee", "right_knee"), "ankles": ("left_ankle", "right_ankle")}


def scenes(n: int, frames: int, seed: int = 0, posture: str = "knee-up") -> list:
    """``n`` SyntheticScenes in ``posture`` of held-out clips and bodies, cameras in front (seeded)."""
    from live.body.library import list_presets, load_body
    from live.core.heading import mean_angle, yaw_of
    from sim.skeleton_data import clip_motion, list_clips, split_bodies, split_clips
    from sim.synth import CameraPlacement, SyntheticScene

    rng = np.random.default_rng(seed)
    clips = split_clips(list_clips(), "val")
    bodies = split_bodies(list_presets(), "val")
    out = []
    for k in range(n):
        motion = clip_motion(clips[int(rng.integers(len(clips)))].file)
        facing = mean_angle(yaw_of(np.asarray(motion.rotations[:, 0], np.float64)))
        placement = CameraPlacement(distance=float(rng.uniform(1.8, 3.5)), height=float(rng.uniform(0.7, 1.5)),
                                    yaw=facing + float(np.radians(rng.uniform(-45.0, 45.0))), pitch=0.0)
        scene = SyntheticScene.build(motion, load_body(bodies[k % len(bodies)]), camera=CAMERAS[k % len(CAMERAS)],
                                     fps=30.0, placement=placement, seed=k, posture=posture)
        out.append((scene, min(frames, scene.num_frames)))
    return out


def solve(models: list[Path], built: list) -> dict:
    """Per-frame joints of every scene by each model's stage without its temporal model, scored:
    {model: row}. Each frame is rendered once and read by every model (the camera's noise draws
    move on with every render)."""
    from live.core.metrics import per_joint_mpjpe
    from models.skeleton.runtime import SkeletonStage

    preds: dict = {m: [] for m in models}
    truths: dict = {m: [] for m in models}
    for scene, frames in built:
        stages = {m: SkeletonStage(m, temporal=False, filter=False) for m in models}
        for i in range(frames):
            frame = scene.depth(i, t_ns=i * 33_333_333)
            for m, stage in stages.items():
                skeleton = stage.estimate(frame)
                if skeleton is not None:
                    preds[m].append(skeleton.joints)
                    truths[m].append(scene.joints[i])
    out = {}
    for m in models:
        pred, gt = np.asarray(preds[m], np.float64), np.asarray(truths[m], np.float64)
        row = scores(pred, gt, gt[:, :1] - pred[:, :1])
        per_joint = per_joint_mpjpe(pred, gt)
        row["frames_missed"] = int(sum(f for _, f in built) - len(pred))
        row.update({f"{name}_mm": round(1000 * float(per_joint[[JOINT_INDEX[j] for j in joints]].mean()), 1)
                    for name, joints in LEGS.items()})
        out[str(m)] = row
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.knee_up_views", description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=Path, nargs="+", default=[assets.weight("skeleton.onnx")])
    ap.add_argument("--posture", choices=["knee-up", "kick"], default="knee-up")
    ap.add_argument("--scenes", type=int, default=12)
    ap.add_argument("--frames", type=int, default=48, help="frames per scene at 30 fps (48: both legs once)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    missing = [m for m in args.models if not m.is_file()]
    if missing:
        ap.error(f"no model file {missing[0]}")
    built = scenes(args.scenes, args.frames, posture=args.posture)
    results = solve(args.models, built)
    print("| model | frames | MPJPE / PA-MPJPE mm / PCK@10cm | knees / ankles mm |\n|---|---|---|---|")
    for m, r in results.items():
        print(f"| {m} | {r['frames']} | {r['mpjpe_mm']} / {r['pa_mpjpe_mm']} / {r['pck_10cm']:.3f} | "
              f"{r['knees_mm']} / {r['ankles_mm']} |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
