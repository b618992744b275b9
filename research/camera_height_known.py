"""What the skeleton stage gains on depth without a camera pose when the user tells it more.

    python -m research.camera_height_known [--model M.onnx] [--val 1200] [--roll DEG] [--only NAME ...] [--json FILE]

The held-out val_real scenes (research.compare_skeleton's, seed 3) whose extrinsics the set
hides (40 %; no floor in view in some), solved again with the finder told: nothing (as the set
draws them: up and the floor estimated), the camera's height above the floor
(``--camera-height``), up from the camera's IMU, both, and the whole camera pose (the upper
bound). Same scenes, same noise; per posture, MPJPE mm / PCK@10cm in the person frame and after
root alignment. ``--roll DEG`` turns every camera about its optical axis (training never rolls
one): what a camera set down a little crooked costs when nobody gives its pose. Runs in one
process (the finder is wrapped here): about a minute per variant.
"""

from __future__ import annotations

import argparse
import json
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from live.core import assets
from research.compare_skeleton import scores
from research.given_pose_error import error_transform

#: The variants: (name, the camera's height given, up from an IMU, the whole pose given).
VARIANTS = (("guessed", False, False, False), ("camera height", True, False, False),
            ("IMU up", False, True, False), ("IMU up + camera height", True, True, False),
            ("camera pose given", False, False, True))


@contextmanager
def told(height: bool, imu: bool, pose: bool, roll_deg: float = 0.0):
    """Run sim.skeleton_data.run_job with its finder told the true camera height and / or up,
    or with the extrinsics the job hides given after all; yields a dict whose "hidden" is the
    last job's hide flag as drawn."""
    import sim.sensor_realism as realism
    import sim.skeleton_data as data
    from models.skeleton import preprocess
    from sim.depth_camera import VirtualDepthCamera

    state: dict = {}
    view, extras, find = data.random_view, realism.random_extras, preprocess.PersonFinder.find
    turn = error_transform("roll", roll_deg)[0]  # about the camera's optical axis

    def random_view(job, rng):
        camera, room = view(job, rng)
        if roll_deg:
            rolled = VirtualDepthCamera(camera.preset, camera.camera_to_world @ turn, noise=camera.noise)
            rolled.rng = camera.rng  # the same noise draws
            camera = rolled
        state["c2w"] = np.asarray(camera.camera_to_world, np.float64)
        return camera, room

    def random_extras(*args, **kwargs):
        drawn = extras(*args, **kwargs)
        state["hidden"] = drawn.hide_extrinsics
        return replace(drawn, hide_extrinsics=False) if pose else drawn

    def finder_find(self, frame, **kwargs):
        if height:
            self.ground.camera_height_m = float(state["c2w"][1, 3])
        if imu:
            self.ground.gravity_up = state["c2w"][1, :3].copy()  # world up in camera axes
        return find(self, frame, **kwargs)

    data.random_view, realism.random_extras, preprocess.PersonFinder.find = random_view, random_extras, finder_find
    try:
        yield state
    finally:
        data.random_view, realism.random_extras, preprocess.PersonFinder.find = view, extras, find


def solve_variant(model: Path, n_val: int, height: bool, imu: bool, pose: bool, progress: bool = True,
                  roll_deg: float = 0.0) -> dict:
    """The val_real frames of the jobs whose extrinsics are hidden: points, truth, posture."""
    import sim.skeleton_data as data
    from models.skeleton.runtime import SkeletonRegressor

    reg = SkeletonRegressor(model)
    jobs = data.plan_jobs("val_real", n_val, 3, edge_jump_share=reg.edge_jump_share)
    kept: list[dict] = []
    it = jobs
    if progress:
        from tqdm import tqdm

        it = tqdm(jobs, desc="jobs", unit="job", leave=False)
    with told(height, imu, pose, roll_deg) as state:
        for job in it:
            result = data.run_job(job)
            if state.get("hidden") and len(result["frame"]):
                kept.append(result)
    points = np.concatenate([r["points"] for r in kept])
    pred = np.concatenate([reg(points[a:a + 256, :reg.num_points]) for a in range(0, len(points), 256)])
    return {"pred": pred.astype(np.float64), "gt": np.concatenate([r["joints"] for r in kept]).astype(np.float64),
            "posture": np.concatenate([r["posture"] for r in kept])}


def score(pred: np.ndarray, gt: np.ndarray) -> dict:
    """compare_skeleton's scores, root alignment moving each frame's pelvis onto the truth's."""
    return scores(pred, gt, gt[:, :1] - pred[:, :1])


def table(results: dict) -> str:
    groups = list(next(iter(results.values())))
    lines = ["| told the finder | " + " | ".join(groups) + " |", "|---|" + "---|" * len(groups)]
    for name, by_group in results.items():
        cells = [f"{r['frames']}: {r['mpjpe_mm']} / {r['pck_10cm']:.3f}; {r['root_aligned_mpjpe_mm']} / "
                 f"{r['root_aligned_pck_10cm']:.3f}" if r else "-" for r in (by_group.get(g) for g in groups)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.camera_height_known", description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=assets.weight("skeleton.onnx"))
    ap.add_argument("--val", type=int, default=1200, help="samples of val_real (the cards' 1200)")
    ap.add_argument("--roll", type=float, default=0.0, help="every camera rolled by this (degrees)")
    ap.add_argument("--only", nargs="+", choices=[v[0] for v in VARIANTS], default=None,
                    help="these variants only (default all)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if not args.model.is_file():
        ap.error(f"no model file {args.model}")
    results: dict = {}
    for name, height, imu, pose in VARIANTS:
        if args.only and name not in args.only:
            continue
        d = solve_variant(args.model, args.val, height, imu, pose, roll_deg=args.roll)
        rows = {"all": score(d["pred"], d["gt"])}
        for posture in ("clip", "seated", "crouching", "in-place"):
            m = d["posture"] == posture
            if m.any():
                rows[posture] = score(d["pred"][m], d["gt"][m])
        results[name] = rows
        print(f"{name}: {rows['all']}", flush=True)
    print("\nval_real frames whose extrinsics the set hides; frames: MPJPE mm / PCK@10cm; root-aligned the same\n")
    print(table(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
