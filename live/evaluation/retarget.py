"""Retargeting evaluation with the reference metrics: ``evaluate_retarget``.

Ground truth: the motion's local rotations on the target's T-pose, the root scaled by the
leg-length ratio (CONVENTIONS.md), skinned with the target's true weights. Prediction: the motion
put on the source body (same convention), then either its exact joints (``from_="skeleton"``) or
the whole chain from a virtual depth camera (``from_="depth"``: SyntheticScene -> SkeletonStage
-> retargeter), retargeted online frame by frame (analytic or learned), skinned by LBS with the
target's weights. Metrics (live/core/metrics.py): MPJPE, PA-MPJPE, Acc, PA-Acc (mm/frame^2 at
the evaluation rate, keys ``acc_mm_per_frame2``, ``pa_acc_mm_per_frame2``) on joints; MPVD,
PA-MPVD, MDEL (edges to each vertex's 6 nearest T-pose neighbours, lengths compared with the
ground truth's per frame) on vertices; lengths in metres.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from live.core import assets
from live.core.errors import UserInputError
from live.core.kinematics import forward_kinematics
from live.core.skeleton import pelvis_height
from live.core.timing import frame_offset_ns

#: The reference method's figures (SMPL test set, naked targets), for the report.
REFERENCE = {"mpjpe": 0.158, "pa_mpjpe": 0.043, "acc_mm_per_frame2": 21.0, "pa_acc_mm_per_frame2": 8.0,
             "mpvd": 0.134, "pa_mpvd": 0.040, "mdel": 0.000524}
#: Acceleration errors, in mm/frame^2 (the other metrics are lengths in metres).
ACC_METRICS = ("acc_mm_per_frame2", "pa_acc_mm_per_frame2")
METRICS = ("mpjpe", "pa_mpjpe", *ACC_METRICS, "mpvd", "pa_mpvd", "mdel")


def grounded(motion):
    """The motion shifted vertically so its typical lowest joint (5th percentile over frames of the
    per-frame minimum) sits where its T-pose's lowest joint does: some converted CMU clips float or
    sink by up to a metre, and a performer must stand on the floor."""
    lowest = np.percentile(np.asarray(motion.joints)[:, :, 1].min(axis=1), 5)
    dy = np.float32(np.asarray(motion.rest_joints)[:, 1].min() - lowest)
    shift = np.array([0.0, dy, 0.0], np.float32)
    return replace(motion, root=(motion.root + shift).astype(np.float32),
                   joints=(motion.joints + shift).astype(np.float32))


def _on_body(motion, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(root T x 3, joints T x 22 x 3) of the motion on a body with T-pose ``rest``."""
    root = np.asarray(motion.root, np.float64) * (pelvis_height(rest) / pelvis_height(motion.rest_joints))
    return root, forward_kinematics(motion.rotations, root, rest)[0]


def make_retargeter(kind: str, source_rest: np.ndarray, target_rest: np.ndarray, fps: float,
                    model: str | Path | None = None, feet: bool = True):
    """An AnalyticRetargeter or a LearnedRetargeter, both as the pipeline's retarget stage runs
    them: foot lock + floor clearance on (``feet=False``: both without, the bare solvers)."""
    if kind == "analytic":
        from live.retarget.retargeter import AnalyticRetargeter

        return AnalyticRetargeter(source_rest, target_rest, fps=fps, foot_lock=feet, floor=feet)
    if kind == "learned":
        from live.retarget.learned import LearnedRetargeter

        return LearnedRetargeter(model, source_rest, target_rest, fps=fps, foot_lock=feet, floor=feet)
    raise UserInputError(f"unknown retargeter {kind!r}; choose analytic or learned")


def depth_skeletons(motion, source_body, *, camera: str = "oak-d", seed: int = 0,
                    skeleton_model: str | Path | None = None, lag: int = 0,
                    placement=None) -> tuple[np.ndarray, np.ndarray]:
    """Run the virtual camera and the skeleton stage over the motion on the source body.
    ``placement``: a sim.synth.CameraPlacement (default: 3 m in front, 1.2 m high).

    Returns (joints T x 22 x 3 world, found (T,) bool); frames where nobody was found repeat the
    last skeleton (the first found one before any), as a live avatar would hold its pose. With a
    lagging temporal model (``lag`` frames) each skeleton is put at the frame it estimates; the
    last ``lag`` come from the stage's flush at the clip's end, as a replay drains them."""
    from models.skeleton.runtime import SkeletonStage
    from sim.synth import SyntheticScene

    scene = SyntheticScene.build(motion, source_body, camera=camera, fps=motion.fps, seed=seed,
                                  placement=placement)
    stage = SkeletonStage(skeleton_model, lag=lag)
    out = np.full((scene.num_frames, 22, 3), np.nan)
    frame_at: dict[int, int] = {}
    for i in range(scene.num_frames):
        t_ns = 1_000_000_000 + frame_offset_ns(i, motion.fps)
        frame_at[t_ns] = i
        sk = stage.estimate(scene.depth(i, t_ns))
        if sk is not None:
            out[frame_at[sk.t_ns]] = sk.joints + scene.shift  # back to the motion's own coordinates
    for sk in stage.flush():
        out[frame_at[sk.t_ns]] = sk.joints + scene.shift
    found = ~np.isnan(out[:, 0, 0])
    if not found.any():
        raise UserInputError("the skeleton stage found nobody in any frame")
    last = out[np.argmax(found)]
    for i in range(len(out)):
        if found[i]:
            last = out[i]
        else:
            out[i] = last
    return out, found


def check_options(from_: str, retarget: str) -> None:
    """The evaluation's source (``--from``) and retargeter names, or a one-line user error."""
    if from_ not in ("skeleton", "depth"):
        raise UserInputError(f"unknown --from {from_!r}; choose skeleton or depth")
    if retarget not in ("analytic", "learned"):
        raise UserInputError(f"unknown retargeter {retarget!r}; choose analytic or learned")


def prepare_motion(motion, fps: float = 30.0, max_frames: int | None = None):
    """A Motion (or BVH path) without a leading bind pose (``cleaning.trim_bind_pose``: 76 of
    the 119 shared clips, three of the four held-out ones, start with a T-pose frame the take then
    leaves at 15-160 m/s), grounded, resampled to ``fps``, cut to its first ``max_frames``."""
    from live.motion.cleaning import trim_bind_pose
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion

    if isinstance(motion, (str, Path)):
        motion = load_motion(motion)
    motion = grounded(resample(trim_bind_pose(motion), fps))
    if max_frames is not None:
        n = int(max_frames)
        motion = replace(motion, joints=motion.joints[:n], rotations=motion.rotations[:n], root=motion.root[:n])
    if motion.num_frames < 3:
        raise UserInputError("the motion needs at least 3 frames")
    return motion


def evaluate_retarget(motion, source_body, target_body, from_: str = "skeleton", retarget: str = "analytic",
                      *, fps: float = 30.0, max_frames: int | None = None, model: str | Path | None = None,
                      camera: str = "oak-d", seed: int = 0, skeleton_model: str | Path | None = None,
                      lag: int = 0) -> dict[str, Any]:
    """Evaluate one retargeter on one motion from a source body to a target body.

    motion: a Motion or a BVH path (grounded, resampled to ``fps``, first ``max_frames`` kept);
    source_body / target_body: Body or a spec for live.body.library.load_body. from_: "skeleton" (exact
    source joints) or "depth" (virtual camera + skeleton regressor). retarget: "analytic" or
    "learned" (``model``: .onnx path, default the committed one). Returns a dict with the metrics
    in metres (Acc, PA-Acc in mm/frame^2), frames, fps, names and settings, and how many leading
    bind-pose frames of the clip (at its own rate) were cut."""
    from live.body.library import load_body
    from live.motion.cleaning import trim_bind_pose
    from live.motion.rig_mapping import load_motion

    check_options(from_, retarget)
    if isinstance(motion, (str, Path)):
        motion = load_motion(motion)
    cut = motion.num_frames - trim_bind_pose(motion).num_frames  # reported: the clip is shorter
    motion = prepare_motion(motion, fps, max_frames)
    src = source_body if hasattr(source_body, "rest_joints") else load_body(source_body)
    tgt = target_body if hasattr(target_body, "rest_joints") else load_body(target_body)
    src_joints, src_rest, found = source_skeletons(motion, src, from_, camera=camera, seed=seed,
                                                   skeleton_model=skeleton_model, lag=lag)
    result = score(motion, tgt, src_joints, src_rest, retarget, fps=fps, model=model)
    result.update(found=float(found.mean()), source_body=getattr(src, "name", str(source_body)), lag=lag,
                  bind_pose_frames_cut=int(cut), **{"from": from_})
    return result


def source_skeletons(motion, source_body, from_: str, **depth_options) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the retargeter sees: (joints T x 22 x 3, source T-pose 22 x 3, found (T,) bool).

    "skeleton": the motion's exact joints on the source body and its true T-pose; "depth": the
    virtual camera + skeleton stage, the T-pose estimated from the observed bone lengths (live,
    the performer's T-pose is unknown)."""
    if from_ == "skeleton":
        _, joints = _on_body(motion, source_body.rest_joints)
        return joints, np.asarray(source_body.rest_joints, np.float64), np.ones(len(joints), bool)
    joints, found = depth_skeletons(motion, source_body, **depth_options)
    return joints, estimated_rest(joints, found), found


def estimated_rest(joints: np.ndarray, found: np.ndarray) -> np.ndarray:
    """The performer's T-pose (22 x 3) as the chain estimates it from the observed joints
    (T x 22 x 3, ``found`` (T,) the frames really observed): bone lengths from them, bone
    directions from the training bodies' mean T-pose (the held-out ones are what is evaluated)."""
    from live.body.library import list_presets, mean_rest_template
    from live.retarget.analytic import estimate_rest_joints
    from sim.skeleton_data import split_bodies

    template = mean_rest_template(tuple(split_bodies(list_presets(), "train")))
    return estimate_rest_joints(np.asarray(joints)[np.asarray(found, bool)], template)


def score(motion, target_body, src_joints: np.ndarray, src_rest: np.ndarray, retarget: str, *, fps: float = 30.0,
          model: str | Path | None = None, feet: bool = True) -> dict[str, Any]:
    """Retarget source joints (T x 22 x 3) online onto the target body, skin, compare with the
    ground truth of the motion on the target: the metrics dict (see ``evaluate_retarget``)."""
    from live.body.skinning import lbs
    from live.core.metrics import acceleration_error, knn_edges, mpjpe, mpvd, pa_acceleration_error, pa_mpjpe, pa_mpvd

    tgt = target_body
    gt_root, gt_joints = _on_body(motion, tgt.rest_joints)
    rt = make_retargeter(retarget, src_rest, tgt.rest_joints, fps, model, feet)
    root, rot, joints = (np.stack(x) for x in zip(*(rt.step(j) for j in src_joints)))
    verts = lbs(tgt.vertices, tgt.weights, tgt.rest_joints, rot, root)
    gt_verts = lbs(tgt.vertices, tgt.weights, tgt.rest_joints, motion.rotations, gt_root)
    edges = knn_edges(np.asarray(tgt.vertices, np.float64), 6)
    return {
        "mpjpe": mpjpe(joints, gt_joints), "pa_mpjpe": pa_mpjpe(joints, gt_joints),
        "acc_mm_per_frame2": 1000 * acceleration_error(joints, gt_joints),
        "pa_acc_mm_per_frame2": 1000 * pa_acceleration_error(joints, gt_joints),
        "mpvd": mpvd(verts, gt_verts), "pa_mpvd": pa_mpvd(verts, gt_verts),
        "mdel": _mdel(verts, gt_verts, edges),
        "frames": int(motion.num_frames), "fps": float(fps), "motion": motion.name,
        "target_body": getattr(tgt, "name", "target"), "retarget": retarget, "vertices": int(len(tgt.vertices)),
    }


def _mdel(verts: np.ndarray, gt_verts: np.ndarray, edges: np.ndarray) -> float:
    """Mean |edge length - ground-truth edge length| (m), T-pose k-NN edges, per frame."""
    from live.core.metrics import mdel

    return float(np.mean([mdel(v[None], g[None], edges=edges) for v, g in zip(verts, gt_verts)]))


def format_report(results: dict[str, Any] | list[dict[str, Any]], reference: bool = True) -> str:
    """A Markdown table of one or several results (metrics in mm, Acc in mm/frame^2), with the
    reference method's figures as the last row."""
    rows = [results] if isinstance(results, dict) else list(results)
    head = "| retarget | from | motion | source -> target | MPJPE | PA-MPJPE | Acc | PA-Acc | MPVD | PA-MPVD | MDEL |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]

    def fmt(r: dict) -> str:
        return " | ".join(f"{r[m]:.1f}" if m in ACC_METRICS else f"{1000 * r[m]:.3f}" if m == "mdel"
                          else f"{1000 * r[m]:.1f}" for m in METRICS)

    for r in rows:
        name = r["retarget"] + ("" if r.get("feet", True) else ", no foot lock / floor")
        lines.append(f"| {name} | {r['from']} | {r['motion']} | {r['source_body']} -> {r['target_body']} "
                     f"| {fmt(r)} |")
    if reference:
        lines.append(f"| reference | - | SMPL test | - | {fmt(REFERENCE)} |")
    lines.append("")
    lines.append("Lengths in mm; Acc and PA-Acc in mm/frame^2 (at the evaluation frame rate).")
    return "\n".join(lines)


#: One held-out clip per held-out CMU subject (7, 8, 12, 16), for the side-by-side table.
HELD_OUT_CLIPS = ("cc_007_01.bvh", "mb_08_01.bvh", "mb_12_01.bvh", "mb_16_15.bvh")


def all_held_out_clips(bvh_dir: str | Path | None = None) -> tuple[str, ...]:
    """Every clip of the held-out CMU subjects (23 in ../shared/data/bvh): the four clips of the
    default table are 2.3-4.4 s long, so a take's first half second weighs much in them."""
    from sim.skeleton_data import BVH_DIR, list_clips, split_clips

    return tuple(c.file for c in split_clips(list_clips(Path(bvh_dir) if bvh_dir else BVH_DIR), "val"))


@dataclass(frozen=True)
class HeldOutRun:
    """One run of the held-out tables: a clip (prepared as ``prepare_motion`` does) from a held-out
    preset onto the next one; ``seed`` draws the virtual camera's noise and samples."""

    clip: str
    motion: Any
    source: Any
    target: Any
    seed: int

    @property
    def name(self) -> str:
        return f"{self.clip} {self.source.name} -> {self.target.name}"


def held_out_runs(clips=HELD_OUT_CLIPS, *, max_frames: int = 300, bvh_dir: str | Path | None = None,
                  seed: int = 0) -> Iterator[HeldOutRun]:
    """Every clip x every held-out preset as source, the next preset as target (the pairs of
    ``held_out_table``; seeds seed + 17 k + i for clip k and source i)."""
    from live.body.library import list_presets, load_body
    from sim.skeleton_data import split_bodies

    bvh = Path(bvh_dir) if bvh_dir is not None else assets.bvh_dir()
    bodies = [load_body(n) for n in split_bodies(list_presets(), "val")]
    for k, clip in enumerate(clips):
        motion = prepare_motion(bvh / clip, 30.0, max_frames)
        for i, src in enumerate(bodies):
            yield HeldOutRun(clip, motion, src, bodies[(i + 1) % len(bodies)], seed + 17 * k + i)


def held_out_table(from_: str = "skeleton", *, max_frames: int = 300, clips=HELD_OUT_CLIPS,
                   bvh_dir: str | Path | None = None, model: str | Path | None = None, seed: int = 0,
                   lag: int = 0, feet: bool = True, skeleton_model: str | Path | None = None,
                   progress=None) -> list[dict[str, Any]]:
    """Analytic and learned side by side on held-out clips x held-out body pairs (each held-out
    preset to the next), the same source skeletons fed to both. Returns one averaged result per
    retargeter (metrics are means over the runs; ``runs`` says how many). skeleton_model: the
    skeleton regressor (default the shipped one; its temporal models are the ones beside it)."""
    runs: dict[str, list[dict]] = {"analytic": [], "learned": []}
    sources: set[str] = set()
    for run in held_out_runs(clips, max_frames=max_frames, bvh_dir=bvh_dir, seed=seed):
        joints, rest, found = source_skeletons(run.motion, run.source, from_, seed=run.seed, lag=lag,
                                               skeleton_model=skeleton_model) \
            if from_ == "depth" else source_skeletons(run.motion, run.source, from_)
        for kind in runs:
            r = score(run.motion, run.target, joints, rest, kind, model=model, feet=feet)
            r["found"] = float(found.mean())
            runs[kind].append(r)
        sources.add(run.source.name)
        if progress is not None:
            progress(run.name)
    out = []
    for kind, rows in runs.items():
        mean = {m: float(np.mean([r[m] for r in rows])) for m in METRICS + ("found",)}
        mean.update(retarget=kind, feet=feet, motion=f"{len(clips)} held-out clips x {max_frames} frames",
                    source_body=f"{len(sources)} held-out bodies", target_body="the next one", runs=len(rows), lag=lag,
                    frames=int(sum(r["frames"] for r in rows)), fps=30.0, **{"from": from_})
        out.append(mean)
    return out


if __name__ == "__main__":  # python -m live.evaluation.retarget [skeleton|depth] [max_frames] [--lag N] [--card]
    import argparse
    import json
    import sys

    cli = argparse.ArgumentParser(prog="python -m live.evaluation.retarget",
                                  description="analytic and learned retargeters side by side on held-out data")
    cli.add_argument("which", nargs="?", default="skeleton", choices=["skeleton", "depth"])
    cli.add_argument("frames", nargs="?", type=int, default=300)
    cli.add_argument("--lag", type=int, default=0, help="skeleton stage lag in frames (with depth)")
    cli.add_argument("--no-feet", action="store_true", help="both retargeters without foot lock and floor clearance")
    cli.add_argument("--all-clips", action="store_true",
                     help="every clip of the held-out subjects instead of one per subject")
    cli.add_argument("--skeleton-model", type=Path, default=None,
                     help="skeleton regressor .onnx (with depth; its temporal models beside it)")
    cli.add_argument("--card", action="store_true", help="record the table in the retargeter's model card")
    a = cli.parse_args()
    if a.card and a.skeleton_model is not None:
        cli.error("--card records the shipped skeleton stage's figures: drop --skeleton-model")
    table = held_out_table(a.which, max_frames=a.frames, lag=a.lag, feet=not a.no_feet,
                           skeleton_model=a.skeleton_model,
                           clips=all_held_out_clips() if a.all_clips else HELD_OUT_CLIPS,
                           progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(format_report(table))
    print(json.dumps(table, indent=1))
    if a.card:
        from live.retarget.learned import DEFAULT_MODEL

        card_path = DEFAULT_MODEL.with_suffix(".json")
        card = json.loads(card_path.read_text())
        key = (f"from_{a.which}" + (f"_lag{a.lag}" if a.lag else "") + ("_no_feet" if a.no_feet else "")
               + ("_all_clips" if a.all_clips else ""))
        flags = (f" --lag {a.lag}" if a.lag else "") + (" --no-feet" if a.no_feet else "") \
            + (" --all-clips" if a.all_clips else "")
        card.setdefault("evaluation", {})[key] = {
            "command": f"python -m live.evaluation.retarget {a.which} {a.frames}{flags} --card", "rows": table}
        card_path.write_text(json.dumps(card, indent=2) + "\n")
