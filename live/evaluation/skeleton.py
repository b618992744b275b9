"""Evaluate the skeleton stage on recorded sessions with ground truth (synthetic sessions).

``evaluate_sessions(paths)`` replays each session's depth frames through a fresh
``SkeletonStage`` (frame by frame, as live) and compares every produced skeleton with the
ground truth of that frame (the gt channel): MPJPE and PA-MPJPE (mm), per-joint MPJPE,
PCK@10cm, the share of frames whose body is turned more than 45 degrees from the truth's (read
facing elsewhere), acceleration error (mm/frame^2, over runs of consecutive frames), stage latency
p50/p95/p99 (ms), and how many frames had no skeleton. ``compare_baseline=True`` runs the
reference PointNet (models/weights/skeleton_baseline.onnx) beside the shipped model.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from live.core.depth import between_worlds
from live.core.errors import UserInputError
from live.core.frames import DepthFrame, GroundTruth
from live.core.metrics import acceleration_error, mpjpe, pa_mpjpe, pck, per_joint_mpjpe, turned_share
from live.core.report import percentiles
from live.core.skeleton import JOINT_NAMES
from models.skeleton.runtime import BASELINE_MODEL, DEFAULT_MODEL, SkeletonStage


@dataclass
class EvalSession:
    """A session read for evaluation: (depth frame, ground truth at the same t_ns) pairs and the
    side frames (the camera's IMU, a suit) in time order; true_camera_to_world: the camera's
    real extrinsics when the depth stream withholds them (a session made with hidden
    extrinsics keeps them in its gt stream's metadata), else None."""

    pairs: list[tuple[DepthFrame, GroundTruth]]
    side: list[tuple[int, object]] = field(default_factory=list)
    true_camera_to_world: np.ndarray | None = None


def read_eval_session(path: str | Path) -> EvalSession:
    """A session's depth / ground-truth pairs, side frames and true extrinsics (see EvalSession)."""
    from live.io.session import SessionReader

    reader = SessionReader(path)
    truth: dict[int, GroundTruth] = {}
    depth: list[DepthFrame] = []
    side: list[tuple[int, object]] = []
    true_c2w = None
    for stream, frame in reader.frames():
        if isinstance(frame, GroundTruth):
            truth[frame.t_ns] = frame
            if true_c2w is None and "camera_to_world" in stream.meta:
                true_c2w = np.asarray(stream.meta["camera_to_world"], np.float64)
        elif isinstance(frame, DepthFrame):
            depth.append(frame)
        else:
            side.append((int(getattr(frame, "t_ns", 0)), frame))
    pairs = [(d, truth[d.t_ns]) for d in depth if d.t_ns in truth]
    if not pairs:
        raise UserInputError(f"{Path(path).name}: no depth frames with ground truth (not a synthetic session?)")
    return EvalSession(pairs, side, true_c2w)


def session_frames(path: str | Path) -> list[tuple[DepthFrame, GroundTruth]]:
    """(depth frame, ground truth at the same t_ns) pairs of a session, in time order."""
    return read_eval_session(path).pairs


def truth_in_solved_frame(truth_joints: np.ndarray, solved_c2w: np.ndarray | None,
                          true_c2w: np.ndarray | None) -> np.ndarray:
    """The true joints (J, 3) in the world frame a skeleton was solved in: moved through the camera
    (solved_c2w @ inverse(true_c2w)) when the stage estimated its own extrinsics, else as they are."""
    if solved_c2w is None or true_c2w is None:
        return truth_joints
    return between_worlds(truth_joints, true_c2w, solved_c2w)


def _acc_error(pred: np.ndarray, gt: np.ndarray, t_ns: np.ndarray) -> float | None:
    """Acceleration error (m/frame^2) over the longest-possible runs of consecutive produced frames."""
    if len(t_ns) < 3:
        return None
    dt = np.diff(t_ns)
    step = np.median(dt)
    breaks = np.flatnonzero(dt > 1.5 * step) + 1
    errs, weights = [], []
    for s, e in zip(np.r_[0, breaks], np.r_[breaks, len(t_ns)]):
        if e - s >= 3:
            errs.append(acceleration_error(pred[s:e], gt[s:e]))
            weights.append(e - s - 2)
    return float(np.average(errs, weights=weights)) if errs else None


def evaluate_model(sessions: list[EvalSession], model_path: Path, threads: int = 1, **stage_options) -> dict:
    """Metrics of one model over already-read sessions (a fresh stage per session; side frames
    such as the camera's IMU observed in time order; the truth moved into the frame each
    skeleton was solved in when the session withholds its extrinsics)."""
    preds, gts, latency = [], [], []
    acc, acc_w, missing, frames = [], [], 0, 0
    for session in sessions:
        pairs = session.pairs
        stage = SkeletonStage(model_path, threads, **stage_options)
        truth_at = {depth.t_ns: truth for depth, truth in pairs}
        p_s, g_s, t_s = [], [], []
        side = iter(session.side)
        pending = next(side, None)
        for depth, _ in pairs:
            while pending is not None and pending[0] <= depth.t_ns:
                stage.observe(pending[1])
                pending = next(side, None)
            t0 = time.perf_counter()
            skel = stage.estimate(depth)
            latency.append((time.perf_counter() - t0) * 1e3)
            frames += 1
            if skel is None:
                missing += 1
                continue
            # A lagging temporal model estimates an earlier frame: score it against that one.
            p_s.append(skel.joints)
            g_s.append(truth_in_solved_frame(truth_at[skel.t_ns].joints, skel.camera_to_world,
                                             session.true_camera_to_world))
            t_s.append(skel.t_ns)
        if p_s:
            p, g = np.asarray(p_s, np.float64), np.asarray(g_s, np.float64)
            preds.append(p)
            gts.append(g)
            a = _acc_error(p, g, np.asarray(t_s))
            if a is not None:
                acc.append(a)
                acc_w.append(len(p))
    out = {"model": str(model_path), "frames": frames, "no_skeleton": missing,
           "latency_ms": percentiles(latency, digits=3)}
    if not preds:
        return out
    pred, gt = np.concatenate(preds), np.concatenate(gts)
    out.update({
        "mpjpe_mm": round(1000 * mpjpe(pred, gt), 1),
        "pa_mpjpe_mm": round(1000 * pa_mpjpe(pred, gt), 1),
        "pck_10cm": round(pck(pred, gt, 0.1), 4),
        "turned_45_share": round(turned_share(pred, gt, 45.0), 4),
        "acc_mm_per_frame2": round(1000 * float(np.average(acc, weights=acc_w)), 2) if acc else None,
        "per_joint_mm": {n: round(1000 * float(e), 1) for n, e in zip(JOINT_NAMES, per_joint_mpjpe(pred, gt))},
    })
    return out


def evaluate_sessions(paths: list[str | Path], model_path: str | Path | None = None,
                      compare_baseline: bool = False, threads: int = 1, **stage_options) -> dict:
    """Replay sessions through the stage; {"sessions": [...], "models": {"ours": metrics,
    ["baseline": metrics]}}. stage_options go to SkeletonStage (min_cutoff, beta, filter, ...)."""
    if not paths:
        raise UserInputError("no session to evaluate")
    sessions = [read_eval_session(p) for p in paths]
    models = {"ours": Path(model_path) if model_path is not None else DEFAULT_MODEL}
    if compare_baseline:
        models["baseline"] = BASELINE_MODEL
    return {"sessions": [str(p) for p in paths],
            # The temporal model learnt our regressor's errors: the baseline runs without it.
            "models": {name: evaluate_model(sessions, path, threads,
                                            **({**stage_options, "temporal": False, "lag": 0} if name == "baseline"
                                               else stage_options))
                       for name, path in models.items()}}


def format_report(report: dict) -> str:
    """A plain-text table: one column per model, then per-joint MPJPE."""
    models = report["models"]
    names = list(models)
    rows = [("frames", "frames"), ("no skeleton", "no_skeleton"), ("MPJPE (mm)", "mpjpe_mm"),
            ("PA-MPJPE (mm)", "pa_mpjpe_mm"), ("PCK@10cm", "pck_10cm"), ("turned > 45 deg", "turned_45_share"),
            ("Acc (mm/frame^2)", "acc_mm_per_frame2")]
    width = max(12, *(len(n) + 2 for n in names))
    lines = [f"{len(report['sessions'])} session(s)", f"{'':<18}" + "".join(f"{n:>{width}}" for n in names)]
    for label, key in rows:
        lines.append(f"{label:<18}" + "".join(f"{_fmt(models[n].get(key)):>{width}}" for n in names))
    for q in ("p50", "p95", "p99"):
        lines.append(f"{'latency ' + q + ' (ms)':<18}"
                     + "".join(f"{_fmt(models[n]['latency_ms'].get(q)):>{width}}" for n in names))
    if all("per_joint_mm" in models[n] for n in names):
        lines.append("per-joint MPJPE (mm)")
        for j in JOINT_NAMES:
            lines.append(f"  {j:<16}" + "".join(f"{_fmt(models[n]['per_joint_mm'][j]):>{width}}" for n in names))
    return "\n".join(lines)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 1 else f"{v:.1f}"
    return str(v)
