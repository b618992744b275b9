"""What a camera pose given wrong costs the skeleton stage, with and without its check.

    python -m research.given_pose_error [--val 1200] [--errors pitch:9 pitch:-9 ...] [--json FILE]

The held-out val_real scenes (research.compare_skeleton's, seed 3) whose extrinsics the set gives
(60 %), given instead with an error a user makes when they give the pose by hand: the pitch off by
a few degrees (about the camera's x axis: ``pitch:DEG``, positive looks further down than given),
the roll (``roll:DEG``), the height (``height:CM``). Solved with the given pose checked against
the room (the default: ``GroundEstimator.check_given``) and taken as given (``--trust-extrinsics``).
The truth is scored in the person frame the finder solved in, and after root alignment, as
compare_skeleton scores; also on the views like the real Xtion frames' (``like_real_xtion``).
Same scenes and noise for every row; about 45 s per row on 2 cores.
"""

from __future__ import annotations

import argparse
import json
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.rotations import axis_matrix
from research.compare_skeleton import like_real_xtion, scores

DEFAULT_ERRORS = ("none:0", "pitch:3", "pitch:-3", "pitch:5", "pitch:-5", "pitch:9", "pitch:-9", "roll:9",
                  "height:20", "height:-20")


def error_transform(kind: str, amount: float) -> tuple[np.ndarray, bool]:
    """(4, 4) and whether it acts on the camera's side (given = c2w @ it) or the world's
    (given = it @ c2w)."""
    m = np.eye(4)
    if kind == "pitch":
        m[:3, :3] = axis_matrix("X", np.radians(amount))
    elif kind == "roll":
        m[:3, :3] = axis_matrix("Z", np.radians(amount))
    elif kind == "height":
        m[1, 3] = amount / 100.0
        return m, False
    elif kind != "none":
        raise ValueError(f"unknown error {kind!r}: pitch, roll, height or none")
    return m, True


@contextmanager
def given_wrong(kind: str, amount: float, check: bool):
    """Run sim.skeleton_data.run_job with its given extrinsics off by the error, the finder's
    check on or off, and the person frame it returns expressed in the true world (so that the
    job's truth lands in the frame the finder solved in)."""
    import live.core.frames as frames
    from models.skeleton import preprocess

    err, camera_side = error_transform(kind, amount)
    state: dict = {}
    depth_frame, find = frames.DepthFrame, preprocess.PersonFinder.find

    def make_frame(*args, camera_to_world=None, **kwargs):
        c2w = np.asarray(camera_to_world, np.float64)
        state["given"] = not np.allclose(c2w, np.eye(4))
        if state["given"]:
            wrong = c2w @ err if camera_side else err @ c2w
            state["true_from_given"] = c2w @ np.linalg.inv(wrong)
            camera_to_world = wrong
        return depth_frame(*args, camera_to_world=camera_to_world, **kwargs)

    def finder_find(self, frame, **kwargs):
        self.ground.check_given_pose = check
        cloud = find(self, frame, **kwargs)
        if cloud is not None and state.get("given"):
            cloud = replace(cloud, to_world=state["true_from_given"] @ cloud.to_world)
        return cloud

    frames.DepthFrame, preprocess.PersonFinder.find = make_frame, finder_find
    try:
        yield
    finally:
        frames.DepthFrame, preprocess.PersonFinder.find = depth_frame, find


def solve(model: Path, n_val: int, kind: str, amount: float, check: bool, workers: int = 2) -> dict:
    """Scores of the given-extrinsics jobs of val_real under one error."""
    import sim.skeleton_data as data
    from models.skeleton.runtime import SkeletonRegressor

    reg = SkeletonRegressor(model)
    jobs = data.plan_jobs("val_real", n_val, 3, edge_jump_share=reg.edge_jump_share)
    with given_wrong(kind, amount, check):
        results = data.run_jobs(data.run_job, jobs, workers)
    kept = []
    for job, r in zip(jobs, results):
        if len(r["frame"]) and not r["hidden_extrinsics"][0]:
            kept.append({**{k: v for k, v in r.items() if k != "attempted"},
                         "closeup": np.repeat(job.closeup, len(r["frame"]))})
    d = {k: np.concatenate([r[k] for r in kept]) for k in kept[0]}
    pred = np.concatenate([reg(d["points"][a:a + 256, :reg.num_points])
                           for a in range(0, len(d["points"]), 256)]).astype(np.float64)
    gt = d["joints"].astype(np.float64)
    shift = gt[:, :1] - pred[:, :1]
    like = like_real_xtion(d)
    return {"all": scores(pred, gt, shift), "like the real Xtion frames": scores(pred[like], gt[like], shift[like])}


def table(rows: dict) -> str:
    lines = ["| given pose | frames found, checked / as given | all: checked | all: as given "
             "| like the Xtion frames: checked | as given |", "|---|---|---|---|---|---|"]
    for name, r in rows.items():
        def cell(x: dict) -> str:
            return f"{x['mpjpe_mm']} / {x['root_aligned_mpjpe_mm']} mm, {x['root_aligned_pck_10cm']:.3f}"
        c, t = r["checked"], r["as given"]
        lines.append(f"| {name} | {c['all']['frames']} / {t['all']['frames']} | {cell(c['all'])} | {cell(t['all'])} "
                     f"| {cell(c['like the real Xtion frames'])} | {cell(t['like the real Xtion frames'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.given_pose_error", description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=assets.weight("skeleton.onnx"))
    ap.add_argument("--val", type=int, default=1200, help="samples of val_real (the cards' 1200)")
    ap.add_argument("--errors", nargs="+", default=list(DEFAULT_ERRORS), metavar="KIND:AMOUNT",
                    help="pitch:DEG, roll:DEG, height:CM or none:0")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if not args.model.is_file():
        ap.error(f"no model file {args.model}")
    rows: dict = {}
    for spec in args.errors:
        kind, _, amount = spec.partition(":")
        try:
            error_transform(kind, float(amount or 0))
        except ValueError as e:
            ap.error(f"--errors {spec}: {e}")
        rows[spec] = {}
        for name, check in (("checked", True), ("as given", False)):
            rows[spec][name] = solve(args.model, args.val, kind, float(amount or 0), check)
            print(f"{spec} {name}: {rows[spec][name]['all']}", flush=True)
    print("\nval_real scenes with extrinsics given, the pose given wrong; MPJPE in the person frame / "
          "root-aligned MPJPE, root-aligned PCK@10cm\n")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
