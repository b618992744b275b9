"""BVH parse + FK + rig-mapping speed (median of 5 runs).

Usage: python benchmarks/bench_bvh.py [--data ../shared/data/bvh] [--repeat 5]
Clips: the largest file in the data folder, the CC_Base clip with the most frames (101 joints),
and a 10,000-frame CMU-MotionBuilder clip made by tiling a real one (written to a temp dir).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from live.io.bvh_kinematics import bvh_forward_kinematics
from live.io.bvh_reader import read_bvh
from live.io.bvh_writer import write_bvh
from live.motion.rig_mapping import map_clip

ROOT = Path(__file__).resolve().parents[1]


def _median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def bench(path: Path, repeat: int) -> dict:
    clip = read_bvh(path, scale="auto")
    return {
        "clip": path.name,
        "frames": clip.num_frames,
        "joints": clip.skeleton.num_joints,
        "MB": path.stat().st_size / 1e6,
        "parse_ms": _median_ms(lambda: read_bvh(path, scale="auto"), repeat),
        "fk_ms": _median_ms(lambda: bvh_forward_kinematics(clip), repeat),
        "map_ms": _median_ms(lambda: map_clip(clip), repeat),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "bvh")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    files = sorted(args.data.glob("*.bvh"))
    largest = max(files, key=lambda p: p.stat().st_size)
    longest_cc = max((p for p in files if p.name.startswith("cc_")),
                     key=lambda p: read_bvh(p).num_frames)
    src = read_bvh(next(p for p in files if p.name.startswith("mb_")))
    with tempfile.TemporaryDirectory() as tmp:
        long_path = Path(tmp) / "tiled_10k_mb.bvh"
        reps = -(-10_000 // src.num_frames)
        write_bvh(long_path, replace(src, channels=np.tile(src.channels, (reps, 1))[:10_000]))
        rows = [bench(p, args.repeat) for p in dict.fromkeys([largest, longest_cc, long_path])]
    print(f"{'clip':24s} {'frames':>7s} {'joints':>6s} {'MB':>5s} {'parse ms':>9s} {'FK ms':>7s} "
          f"{'map ms':>7s}")
    for r in rows:
        print(f"{r['clip']:24s} {r['frames']:7d} {r['joints']:6d} {r['MB']:5.1f} "
              f"{r['parse_ms']:9.1f} {r['fk_ms']:7.1f} {r['map_ms']:7.1f}")


if __name__ == "__main__":
    main()
