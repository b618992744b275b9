"""IMU suit -> skeleton: latency on a live pty, and accuracy of depth-only / IMU-only / fused.

Latency: a SimulatedSuit (sim.imu_device, Xbus, 15 sensors, real time at 100 Hz) on a pty,
performing a T-pose hold and then a CMU clip, read by drivers.serial_source.SerialSource and
posed by live.imu.stage.ImuSkeletonStage in a live ("latest") Pipeline. Reported: skeletons/s
and latency from byte arrival (the read's host timestamp) to the skeleton frame, p50/p95
(goal >= 100 Hz, p95 <= 5 ms). Median over --runs runs.

Accuracy: synthetic sessions (sim.imu_stream.write_suit_session: the suit with 10 deg mounting
errors, heading drift and noise, plus ground truth) replayed through depth-only, IMU-only and
fused pipelines; the depth skeleton is sim.imu_stream.NoisySkeletonStage (ground truth + 2 cm
noise, 1.5 cm per-joint bias, occlusion spells) unless a trained skeleton model and the body
renderer are available. MPJPE in cm against ground truth, per clip.

Usage: python benchmarks/bench_imu.py [--seconds 15] [--runs 3] [--skip-latency] [--skip-accuracy]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.serial_source import SerialSource  # noqa: E402
from live.core.heading import yaw_of  # noqa: E402
from live.core.report import percentiles  # noqa: E402
from live.core.skeleton import default_rest_joints  # noqa: E402
from live.imu.stage import ImuSkeletonStage, build_stages  # noqa: E402
from live.io.session import SessionReader  # noqa: E402
from live.motion.clips import resample  # noqa: E402
from live.motion.rig_mapping import load_motion  # noqa: E402
from live.pipeline.runner import Pipeline  # noqa: E402
from sim.imu_device import SimulatedSuit  # noqa: E402
from sim.imu_model import SimpleMotion  # noqa: E402
from sim.imu_stream import MotionScene, NoisySkeletonStage, calibration_prelude, write_suit_session  # noqa: E402
from sim.replay import ReplaySource  # noqa: E402

BVH = ROOT.parent / "shared" / "data" / "bvh"
CLIPS = ("cc_002_05", "cc_007_01", "daz_10_01", "cc_005_02", "daz_martial_03")


def suit_motion(clip: str, rate: float = 100.0) -> SimpleMotion:
    """A clip at ``rate`` preceded by a 1.5 s T-pose hold (what the stage calibrates on)."""
    m = resample(load_motion(BVH / f"{clip}.bvh"), rate)
    pre = calibration_prelude(m.rotations[0], "tpose", m.rest_joints, 1.5, 0.25, rate)
    root = np.concatenate([np.broadcast_to(m.root[0], (len(pre), 3)), m.root])
    return SimpleMotion(fps=rate, rotations=np.concatenate([pre, m.rotations]), root=root, rest_joints=m.rest_joints)


def latency_run(seconds: float, motion: SimpleMotion) -> dict:
    lat: list[float] = []
    done: list[int] = []
    with SimulatedSuit(motion, "xbus", rate_hz=100.0, mounting_seed=None, paused=True, loop=True) as suit:
        source = SerialSource(suit.port, "xbus", name="suit")
        stage = ImuSkeletonStage(hold_s=1.0, height=1.75, device="suit")

        def on_result(result) -> None:
            if result.skeleton is not None and result.mocap is not None:
                now = time.monotonic_ns()
                lat.append((now - result.mocap.t_ns) / 1e6)
                done.append(now)

        pipe = Pipeline([source], [stage], mode="latest", on_result=on_result)
        stop = threading.Event()
        threading.Timer(0.3, suit.resume).start()
        timer = threading.Timer(seconds + 0.3, stop.set)
        timer.start()
        t0 = time.monotonic()
        stats = pipe.run(stop)
        timer.cancel()
        suit_rate = suit.counters["steps"] / (time.monotonic() - t0 - 0.3)
    # Rate over the calibrated part (the stage first needs the 1 s hold).
    return {"skeletons_per_s": (len(done) - 1) / ((done[-1] - done[0]) / 1e9),
            **{f"{k}_ms": v for k, v in percentiles(lat, (50, 95)).items()},
            "stage_p95_ms": stats["stages"]["imu"]["latency_ms"]["p95"],
            "skipped": stats["drops"]["skipped_for_latest"], "suit_samples_per_s": suit_rate}


def accuracy(clip: str, seconds: float, tmp: Path) -> dict[str, float]:
    rest = default_rest_joints(1.68)
    scene = MotionScene.of(resample(load_motion(BVH / f"{clip}.bvh"), 30.0), rest)
    path = tmp / f"{clip}.mcap"
    write_suit_session(path, scene, seed=3, frames=int(seconds * 30))
    meta = next(s.meta for s in SessionReader(path).info.streams if s.kind == "serial")
    out = {}
    for mode in ("depth", "imu", "fused"):
        stages = build_stages(mode, depth_stage=NoisySkeletonStage(seed=1), stream_meta=meta, height=1.75)
        if mode == "imu":  # the performer starts on a marked spot facing a marked direction
            stages[0].world_yaw = float(yaw_of(scene.motion.rotations[0, 0]))
            stages[0].start = scene.root[0]
        rows = []
        Pipeline([ReplaySource(path)], stages, mode="every",
                 on_result=lambda r: rows.append((r.skeleton.joints, r.truth.joints))
                 if r.depth is not None and r.skeleton is not None else None).run()
        pred = np.array([a for a, _ in rows], np.float64)
        gt = np.array([b for _, b in rows], np.float64)
        out[mode] = 100 * float(np.linalg.norm(pred - gt, axis=-1).mean())
        out[mode + "_rel"] = 100 * float(np.linalg.norm((pred - pred[:, :1]) - (gt - gt[:, :1]), axis=-1).mean())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-latency", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    args = ap.parse_args()
    if not args.skip_latency:
        motion = suit_motion("cc_002_05")
        runs = [latency_run(args.seconds, motion) for _ in range(args.runs)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"suit on a pty -> skeleton ({args.runs} runs of {args.seconds:g} s, medians):")
        print(f"  suit samples/s {med['suit_samples_per_s']:.1f}   skeletons/s {med['skeletons_per_s']:.1f}   byte arrival -> skeleton p50 {med['p50_ms']:.2f} ms, "
              f"p95 {med['p95_ms']:.2f} ms   (stage p95 {med['stage_p95_ms']:.2f} ms)")
    if not args.skip_accuracy:
        import tempfile

        print("\nMPJPE cm (root-relative in brackets), depth-only / IMU-only / fused:")
        with tempfile.TemporaryDirectory() as tmp:
            rows = []
            for clip in CLIPS:
                r = accuracy(clip, args.seconds, Path(tmp))
                rows.append(r)
                print(f"  {clip:<16} " + "  ".join(f"{m} {r[m]:5.2f} ({r[m + '_rel']:4.2f})"
                                                    for m in ("depth", "imu", "fused")))
            mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
            print(f"  {'mean':<16} " + "  ".join(f"{m} {mean[m]:5.2f} ({mean[m + '_rel']:4.2f})"
                                                for m in ("depth", "imu", "fused")))


if __name__ == "__main__":
    main()
