"""Per-frame cost of the learned retargeter beside the analytic one, alone and with LBS.

Run: .venv/bin/python benchmarks/bench_retarget_learned.py [--frames 600] [--model PATH]
Timing (median / p95 ms, 10 warm-up frames skipped), same process, same motion (a held-out CMU
clip at 30 fps, subject 12, on a preset body, retargeted onto another):
- the ONNX step alone (session.run with the GRU states), LearnedRetargeter.step as the network
  alone and with foot lock + floor clearance (as the pipeline's retarget stage runs it);
- AnalyticRetargeter.step (foot lock + floor), for comparison;
- each retargeter's step + LBS of the target avatar (~7k vertices: a body preset), the stage goal
  being <= 2 ms p95 per frame;
- the skinning field on all the avatar's vertices (once per avatar, not per frame).
BLAS runs single-threaded (OPENBLAS_NUM_THREADS=1 unless set): on the shared 2-core machine a
multi-threaded BLAS made one 7k-vertex LBS 10x slower (18 ms instead of 1.8 ms median).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from live.core.report import percentiles  # noqa: E402
from live.retarget.learned import LearnedRetargeter  # noqa: E402
from live.retarget.retargeter import AnalyticRetargeter  # noqa: E402

BVH = ROOT.parent / "shared" / "data" / "bvh"


def _times(fn, items) -> tuple[float, float]:
    ts = []
    for it in items:
        t0 = time.perf_counter()
        fn(it)
        ts.append(time.perf_counter() - t0)
    ms = np.array(ts[10:]) * 1e3
    p = percentiles(ms, (50, 95))
    return p["p50"], p["p95"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--model", default=None)
    ap.add_argument("--source", default=None, help="source body preset (default: the first)")
    ap.add_argument("--target", default=None, help="target body preset (default: the last)")
    args = ap.parse_args()
    from live.body.library import list_presets, load_body
    from live.body.skinning import lbs, pose_transforms, skin
    from live.body.skinning_field import SkinningFieldModel
    from live.evaluation.retarget import _on_body, grounded
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion

    names = sorted(list_presets())
    src = load_body(args.source or names[0])
    tgt = load_body(args.target or names[-1])
    motion = grounded(resample(load_motion(BVH / "mb_12_01.bvh"), 30.0))
    _, joints = _on_body(motion, src.rest_joints)
    joints = np.concatenate([joints] * (1 + args.frames // len(joints)))[:args.frames]
    print(f"{len(joints)} frames, {src.name} -> {tgt.name} ({len(tgt.vertices)} vertices); ms median / p95")

    # Both as the pipeline's retarget stage runs them: foot lock + floor clearance after the solve.
    learned = LearnedRetargeter(args.model, src.rest_joints, tgt.rest_joints, foot_lock=True, floor=True)
    network = LearnedRetargeter(args.model, src.rest_joints, tgt.rest_joints)
    analytic = AnalyticRetargeter(src.rest_joints, tgt.rest_joints)
    feed = {"source": np.zeros((1, learned.session.get_inputs()[0].shape[1]), np.float32),
            "target": learned._tgt_feat, "h_enc": learned.h_enc, "h_dec": learned.h_dec}
    rows = [("learned: ONNX session.run alone", _times(lambda _: learned.session.run(None, feed), joints))]
    rows.append(("learned: step(), network only", _times(network.step, joints)))
    rows.append(("learned: step() (foot lock + floor)", _times(learned.step, joints)))
    rows.append(("analytic: step() (foot lock + floor)", _times(analytic.step, joints)))
    for name, rt in (("learned", learned), ("analytic", analytic)):
        rt.reset()

        def stage(j, rt=rt):  # as live/pipeline/stages.py skins: the step's own global rotations
            _, _, posed = rt.step(j)
            skin(tgt.vertices, tgt.weights, pose_transforms(rt.last_globals, posed, tgt.rest_joints)[None])

        def stage_from_quats(j, rt=rt):
            r, q, _ = rt.step(j)
            lbs(tgt.vertices, tgt.weights, tgt.rest_joints, q[None], r[None])

        rows.append((f"{name}: step() + LBS", _times(stage, joints)))
        rt.reset()
        rows.append((f"{name}: step() + LBS from quaternions", _times(stage_from_quats, joints)))
    field = SkinningFieldModel()
    rows.append((f"skinning field, {len(tgt.vertices)} points (per avatar)",
                 _times(lambda _: field.weights(tgt.vertices, tgt.rest_joints), range(30))))
    for name, (med, p95) in rows:
        print(f"  {name:44s} {med:7.3f} / {p95:7.3f}")


if __name__ == "__main__":
    main()
