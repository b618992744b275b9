"""Depth + IMU fusion against its parts, on held-out sessions (docs/results.md, docs/imu.md).

Each case (research/imu_fusion_sessions.py: a CMU clip of a subject the skeleton model never saw,
on a held-out body, the virtual OAK-D, the simulated suit with pocket errors, an imperfect
calibration pose, jitter and heading drift) is scored three ways against its ground truth:

- depth only: the shipped skeleton stage (regressor + temporal model);
- IMU only: the suit alone (live.imu.stage.ImuSkeletonStage, told a 1.75 m performer), starting
  on a marked spot facing a marked direction (the true root and heading of the first frame);
- fused: the skeleton stage, then live.imu.stage.FusionStage.

MPJPE over the frames where the depth stage found the performer (all three have a skeleton
there); the fused skeleton also exists where it did not (the suit carries on): scored apart.
Cases that lose a limb for 2 s (both legs out of frame, or one arm blanked) are also scored on
that limb during the loss.

Splits: ``--tune`` runs the cases the fusion's settings were chosen on (subject 7 clips on two
held-out bodies, ``TUNE``) and prints the depth stage's per-joint noise that
live.imu.fusion.DEPTH_STD holds; the default runs the report cases (subjects 8, 12 and 16 on the
two other held-out bodies, ``REPORT``), never used for tuning.

    python -m research.imu_fusion_eval [--tune] [--json FILE] [--cases N]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass

import numpy as np

from live.body.library import list_presets, mean_rest_template
from live.core.frames import FrameResult, SkeletonFrame
from live.core.skeleton import JOINT_NAMES, NUM_JOINTS, default_rest_joints, pelvis_height
from live.imu.stage import FusionStage, ImuSkeletonStage, suit_options_from_stream
from research.imu_fusion_sessions import LOST_JOINTS, Case, CaseData, load_case
from sim.skeleton_data import split_bodies

TUNE_CLIPS = ("cc_007_02.bvh", "cc_007_04.bvh", "cc_007_06.bvh", "cc_007_08.bvh")
TUNE_LOSS_CLIPS = ("cc_007_04.bvh", "cc_007_05.bvh")
TUNE_BODIES = ("adult_male_average", "short_male")
REPORT_CLIPS = ("mb_08_04.bvh", "mb_08_11.bvh", "mb_12_01.bvh", "mb_12_03.bvh", "mb_16_15.bvh", "mb_16_31.bvh",
                "mb_16_47.bvh", "mb_16_58.bvh")
REPORT_LOSS_CLIPS = ("mb_08_04.bvh", "mb_12_01.bvh", "mb_12_03.bvh", "mb_16_15.bvh")
REPORT_BODIES = ("elderly_female_heavy", "teen_girl_14y")
#: A limb "fails" in depth when its error over the loss exceeds this (m), or has no skeleton.
LIMB_GOAL_M = 0.060


def cases(split: str) -> list[Case]:
    clips, loss_clips, bodies = ((TUNE_CLIPS, TUNE_LOSS_CLIPS, TUNE_BODIES) if split == "tune"
                                 else (REPORT_CLIPS, REPORT_LOSS_CLIPS, REPORT_BODIES))
    out = [Case(c, b, seed=11 * k + i) for k, c in enumerate(clips) for i, b in enumerate(bodies)]
    out += [Case(c, b, seed=11 * k + i + 5, loss=loss) for k, c in enumerate(loss_clips)
            for i, b in enumerate(bodies) for loss in ("legs", "left_arm", "right_arm")]
    return out


def training_template(height: float = 1.75) -> np.ndarray:
    """The training bodies' mean T-pose at a performer's height's pelvis (the held-out bodies
    stay unseen)."""
    tpl = mean_rest_template(tuple(split_bodies(list_presets(), "train")))
    return tpl * pelvis_height(default_rest_joints(height))


def _feed(data: CaseData, stage, with_depth: bool) -> np.ndarray:
    """Every packet observed, every frame processed in time order -> (F, 22, 3) NaN where none."""
    packets = data.packets()
    out = np.full((len(data.t), NUM_JOINTS, 3), np.nan)
    k = 0
    for f, t in enumerate(data.t):
        while k < len(packets) and packets[k].t_ns <= t:
            stage.observe(packets[k])
            k += 1
        result = FrameResult(t_ns=int(t))
        if with_depth and np.isfinite(data.depth[f]).all():
            result.depth = data.depth_frame(f)
            result.skeleton = SkeletonFrame(int(t), data.depth[f].astype(np.float32), data.conf[f].astype(np.float32),
                                            camera_to_world=data.camera_to_world[f])
        if stage.process(result) and result.skeleton is not None:
            out[f] = result.skeleton.joints
    return out


def run_modes(data: CaseData, fuser_options: dict | None = None) -> dict[str, np.ndarray]:
    opts = suit_options_from_stream(data.meta)
    imu = ImuSkeletonStage(height=1.75, world_yaw=data.start_yaw, start=data.start_root, **opts)
    fuser_options = {"template": training_template(), **(fuser_options or {})}
    fused = FusionStage(height=1.75, fuser_options=fuser_options, **opts)
    return {"depth": data.depth, "imu": _feed(data, imu, False), "fused": _feed(data, fused, True)}


@dataclass
class Score:
    name: str
    loss: str
    frames: int
    depth_found: int
    mpjpe: dict[str, float]
    carried_mm: float | None  # fused where depth found nobody
    limb: dict[str, float | None] | None  # during a loss: depth / fused error on the lost limb

    def as_dict(self) -> dict:
        return self.__dict__.copy()


def _err(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(pred - truth, axis=-1)


def score(data: CaseData, out: dict[str, np.ndarray]) -> Score:
    has_truth = np.isfinite(data.truth).all(axis=(1, 2))
    common = has_truth & np.all([np.isfinite(v).all(axis=(1, 2)) for v in out.values()], axis=0)
    mpjpe = {m: 1000 * float(_err(v[common], data.truth[common]).mean()) for m, v in out.items()}
    alone = has_truth & ~np.isfinite(out["depth"]).all(axis=(1, 2)) & np.isfinite(out["fused"]).all(axis=(1, 2))
    carried = 1000 * float(_err(out["fused"][alone], data.truth[alone]).mean()) if alone.any() else None
    limb = None
    if data.case.loss != "none":
        lost = data.lost & has_truth
        joints = list(LOST_JOINTS[data.case.loss])
        limb = {}
        for m in ("depth", "fused"):
            v = out[m][lost][:, joints]
            seen = np.isfinite(v).all(axis=(1, 2))
            limb[m] = 1000 * float(_err(v[seen], data.truth[lost][seen][:, joints]).mean()) if seen.any() else None
            limb[m + "_frames"] = int(seen.sum())
        limb["frames"] = int(lost.sum())
    return Score(data.case.name, data.case.loss, int(has_truth.sum()), int(common.sum()), mpjpe, carried, limb)


def depth_noise(datas: list[CaseData]) -> np.ndarray:
    """Per-joint, per-axis RMS error (m) of the depth stage where it supports the joint (conf > 0;
    all frames for joints it never supports), bias removed per case: what DEPTH_STD holds."""
    errs: list[list[np.ndarray]] = [[] for _ in range(NUM_JOINTS)]
    for d in datas:
        ok = np.isfinite(d.depth).all(axis=(1, 2)) & np.isfinite(d.truth).all(axis=(1, 2)) & ~d.lost
        e = d.depth[ok] - d.truth[ok]
        for j in range(NUM_JOINTS):
            errs[j].append(e[d.conf[ok][:, j] > 0, j])
    out = np.zeros(NUM_JOINTS)
    for j in range(NUM_JOINTS):
        e = np.concatenate(errs[j])
        if len(e) < 20:
            e = np.concatenate([d.depth[:, j] - d.truth[:, j] for d in datas])
            e = e[np.isfinite(e).all(axis=1)]
        out[j] = float(np.sqrt(np.mean((e - np.median(e, axis=0)) ** 2)))
    return out


def table(scores: list[Score]) -> str:
    lines = ["| case | frames (depth found) | depth only | IMU only | fused | fused where depth found nobody |",
             "|---|---|---|---|---|---|"]
    for s in scores:
        if s.loss != "none":
            continue
        best = min(s.mpjpe["depth"], s.mpjpe["imu"])
        f = s.mpjpe["fused"]
        lines.append(f"| {s.name} | {s.frames} ({s.depth_found}) | {s.mpjpe['depth']:.1f} | {s.mpjpe['imu']:.1f} | "
                     f"{'**' if f <= best else ''}{f:.1f}{'**' if f <= best else ''} | "
                     f"{'-' if s.carried_mm is None else f'{s.carried_mm:.0f}'} |")
    plain = [s for s in scores if s.loss == "none"]
    mean = {m: float(np.mean([s.mpjpe[m] for s in plain])) for m in ("depth", "imu", "fused")}
    lines.append(f"| mean of {len(plain)} | | {mean['depth']:.1f} | {mean['imu']:.1f} | **{mean['fused']:.1f}** | |")
    lost = [s for s in scores if s.loss != "none"]
    if lost:
        lines += ["", "| case | lost for 2 s | depth only: that limb | fused: that limb | whole body depth / fused |",
                  "|---|---|---|---|---|"]
        for s in lost:
            d, f = s.limb["depth"], s.limb["fused"]
            dtxt = "no skeleton" if d is None else f"{d:.0f} mm" + (
                f" ({s.limb['depth_frames']} of {s.limb['frames']} frames)" if s.limb["depth_frames"] < s.limb["frames"] else "")
            lines.append(f"| {s.name.rsplit('_', 1)[0]} | {s.loss} | {dtxt} | {f:.0f} mm | "
                         f"{s.mpjpe['depth']:.1f} / {s.mpjpe['fused']:.1f} |")
    return "\n".join(lines)


def summary(scores: list[Score]) -> dict:
    plain = [s for s in scores if s.loss == "none"]
    lost = [s for s in scores if s.loss != "none"]
    return {
        "cases": len(plain),
        "fused_never_worse": sum(s.mpjpe["fused"] <= min(s.mpjpe["depth"], s.mpjpe["imu"]) for s in plain),
        "mean_mm": {m: float(np.mean([s.mpjpe[m] for s in plain])) for m in ("depth", "imu", "fused")},
        "losses": len(lost),
        "limb_fused_within_goal": sum(s.limb["fused"] <= 1000 * LIMB_GOAL_M for s in lost),
        "limb_depth_failed": sum(s.limb["depth"] is None or s.limb["depth"] > 1000 * LIMB_GOAL_M for s in lost),
        "limb_mean_mm": {m: float(np.mean([s.limb[m] for s in lost if s.limb[m] is not None]))
                         for m in ("depth", "fused")} if lost else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tune", action="store_true", help="the tuning cases (and the depth noise table)")
    ap.add_argument("--cases", type=int, default=None, help="only the first N cases")
    ap.add_argument("--json", default=None, help="also write the scores here")
    args = ap.parse_args()
    todo = cases("tune" if args.tune else "report")[: args.cases]
    datas, scores = [], []
    for i, case in enumerate(todo):
        data = load_case(case)
        datas.append(data)
        scores.append(score(data, run_modes(data)))
        s = scores[-1]
        print(f"[{i + 1}/{len(todo)}] {s.name}: " + "  ".join(f"{m} {v:.1f}" for m, v in s.mpjpe.items())
              + ("" if s.limb is None else f"  limb depth {s.limb['depth']} fused {s.limb['fused']:.0f}"), flush=True)
    print()
    print(table(scores))
    print()
    print(json.dumps(summary(scores), indent=1))
    if args.tune:
        noise = depth_noise([d for d in datas if d.case.loss == "none"])
        print("\ndepth noise per joint (m, per axis):",
              ", ".join(f"{JOINT_NAMES[j]} {noise[j]:.3f}" for j in range(NUM_JOINTS)))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scores": [s.as_dict() for s in scores], "summary": summary(scores)}, f, indent=1)


if __name__ == "__main__":
    main()
