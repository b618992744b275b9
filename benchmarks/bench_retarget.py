"""Per-frame cost and accuracy of the analytic retargeter.

Run: .venv/bin/python benchmarks/bench_retarget.py [--frames 600] [--clips 3]
Timing: median and p95 of AnalyticRetargeter.step over a motion, per configuration, plus the
same with LBS of a ~7k-vertex mesh when live/body/skinning.py exists. Accuracy: MPJPE against the
ground truth (source rotations on the target rest skeleton, root scaled by the leg ratio) on
synthetic held-out bodies and on real CMU clips (when live/motion/rig_mapping.py exists).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from test_retarget_analytic import perturbed_body, synth_motion  # noqa: E402

from live.core.kinematics import forward_kinematics  # noqa: E402
from live.core.metrics import mpjpe  # noqa: E402
from live.core.report import percentiles  # noqa: E402
from live.retarget.analytic import leg_ratio  # noqa: E402
from live.retarget.retargeter import AnalyticRetargeter, retarget_motion  # noqa: E402

BVH_DIR = ROOT.parent / "shared" / "data" / "bvh"


def _time_steps(fn, items) -> tuple[float, float]:
    ts = []
    for it in items:
        t0 = time.perf_counter()
        fn(it)
        ts.append(time.perf_counter() - t0)
    ms = np.array(ts[10:]) * 1e3  # skip warm-up
    p = percentiles(ms, (50, 95))
    return p["p50"], p["p95"]


def bench_speed(frames: int) -> None:
    rng = np.random.default_rng(0)
    src, dst = perturbed_body(rng, 1.75), perturbed_body(rng, 1.55)
    rot, root = synth_motion(rng, src, t=frames)
    joints, _ = forward_kinematics(rot, root, src)
    print(f"per-frame step() over {frames} frames (ms, median / p95):")
    for name, kw in [
        ("joints, no lock/floor", dict(foot_lock=False, floor=False)),
        ("joints, foot lock + floor", dict()),
        ("joints, foot lock + hand IK", dict(hand_ik=True)),
    ]:
        rt = AnalyticRetargeter(src, dst, **kw)
        med, p95 = _time_steps(rt.step, joints)
        print(f"  {name:32s} {med:6.3f} / {p95:6.3f}")
    rt = AnalyticRetargeter(src, dst)
    med, p95 = _time_steps(lambda i: rt.step(rot[i], root[i]), range(frames))
    print(f"  {'rotations, foot lock + floor':32s} {med:6.3f} / {p95:6.3f}")
    try:
        from live.body.skinning import pose_transforms, skin
    except ImportError:
        print("  (live/body/skinning.py not available: LBS not timed)")
        return
    verts = 7000
    rest_v = (dst[rng.integers(0, 22, verts)] + rng.normal(scale=0.03, size=(verts, 3))).astype(np.float32)
    w = rng.random((verts, 22)).astype(np.float32) ** 8
    w /= w.sum(axis=1, keepdims=True)
    # Read-only, like a loaded avatar: the skinning layout is then prepared once, not per frame.
    rest_v.flags.writeable = False
    w.flags.writeable = False
    rt = AnalyticRetargeter(src, dst)

    def stage(j):  # as live/pipeline/stages.py skins: the step's own global rotations and joints
        _, _, posed = rt.step(j)
        skin(rest_v, w, pose_transforms(rt.last_globals, posed, dst)[None])

    med, p95 = _time_steps(stage, joints)
    print(f"  {'step + LBS (7k vertices)':32s} {med:6.3f} / {p95:6.3f}")


def _report(name: str, src, dst, joints, truth, fps) -> None:
    _, _, plain = retarget_motion(src, dst, joints=joints, fps=fps, foot_lock=False, floor=False)
    _, _, locked = retarget_motion(src, dst, joints=joints, fps=fps)
    print(f"  {name:34s} plain {mpjpe(plain, truth) * 1e3:6.2f} mm   lock+floor {mpjpe(locked, truth) * 1e3:6.2f} mm")


def bench_accuracy(clips: int) -> None:
    print("MPJPE against ground truth (rotations on target body, root x leg ratio):")
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        src = perturbed_body(rng, rng.uniform(1.5, 1.95))
        dst = perturbed_body(rng, rng.uniform(1.1, 2.0))
        rot, root = synth_motion(rng, src, t=300)
        joints, _ = forward_kinematics(rot, root, src)
        truth, _ = forward_kinematics(rot, root * leg_ratio(src, dst), dst)
        _report(f"synthetic #{seed} ({src[0, 1]:.2f} -> {dst[0, 1]:.2f} m pelvis)", src, dst, joints, truth, 30.0)
    try:
        from live.motion.rig_mapping import load_motion
    except ImportError:
        print("  (live/motion/rig_mapping.py not available: real clips skipped)")
        return
    rng = np.random.default_rng(7)
    for path in sorted(BVH_DIR.glob("*.bvh"))[1 : 1 + clips]:
        m = load_motion(path)
        n = min(len(m.joints), 600)
        dst = perturbed_body(rng, 1.4)
        truth, _ = forward_kinematics(m.rotations[:n], m.root[:n] * leg_ratio(m.rest_joints, dst), dst)
        _report(f"{path.name} ({n} frames)", m.rest_joints, dst, np.asarray(m.joints[:n], np.float64), truth, m.fps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--clips", type=int, default=3)
    args = ap.parse_args()
    bench_speed(args.frames)
    bench_accuracy(args.clips)


if __name__ == "__main__":
    main()
