"""What the realism training scenes look like (docs/img/realism_scenes.png).

    python -m research.realism_figure [--out docs/img/realism_scenes.png] [--seed 1]

Eight held-out "val_real" jobs (sim.sensor_realism: five sensors, clothes, desks and chair backs,
bystanders, postures, any camera height and pitch), the middle frame of each, depth in turbo
(black = no depth), captioned with the sensor, the posture, what stands around and whether the frame carries
its extrinsics. Deterministic per seed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "realism_scenes.png"
TILE = (320, 240)


def scene_tile(job) -> np.ndarray:
    """The depth image of a realism job's middle frame, as run_job renders it, with a caption."""
    from sim.sensor_realism import random_extras, realism_motion
    from sim.skeleton_data import body_by_name, clip_motion, grounded_joints, random_view
    from sim.synth import SyntheticScene

    rng = np.random.default_rng(job.seed)
    motion, posture = realism_motion(clip_motion(job.clip), job.seed)
    body = body_by_name(job.body)
    root, joints = grounded_joints(motion, body)
    i = len(root) // 2
    shift = np.array([joints[i, 0, 0], 0.0, joints[i, 0, 2]])
    root, joints = root - shift, joints - shift
    camera, room = random_view(job, rng)
    extras = random_extras(rng, body, joints, np.array([i]), camera.camera_to_world, job.closeup, posture)
    room = extras.room(room)
    scene = SyntheticScene(motion=motion, body=body, camera=camera, root=root, joints=joints)
    depth = camera.render(*extras.mesh(scene.vertices(i), body, joints[i], i), room=room)
    img = cv2.applyColorMap(np.clip(depth / 5000.0 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[depth == 0] = 0
    img = cv2.resize(img, TILE, interpolation=cv2.INTER_NEAREST)
    notes = [job.camera, posture if posture != "clip" else "", "clothes" if extras.outfit else "",
             "desk/chair" if extras.boxes else "", "bystander" if extras.bystander is not None else "",
             "no extrinsics" if extras.hide_extrinsics else ""]
    cv2.putText(img, " ".join(n for n in notes if n), (5, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1,
                cv2.LINE_AA)
    return img


def main(argv: list[str] | None = None) -> int:
    from sim.skeleton_data import plan_jobs

    ap = argparse.ArgumentParser(prog="python -m research.realism_figure", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    tiles = [scene_tile(job) for job in plan_jobs("val_real", 80, args.seed)[:8]]
    grid = np.vstack([np.hstack(tiles[r * 4:(r + 1) * 4]) for r in range(2)])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), grid)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
