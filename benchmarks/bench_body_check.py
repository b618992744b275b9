"""What the skeleton stage's body check costs, on the sessions where it runs most.

Run: .venv/bin/python benchmarks/bench_body_check.py [--quick]

The body check (docs/skeleton.md, "Body check") runs until the tracked person has been seen
moving: every frame of the finder bench's held-out sessions (``benchmarks/bench_finder.py``, whose
cache it reads: performers on the spot, seated and crouching, many never moving enough to be
seen moving, from hard heights and pitches) goes through two stages in turn, frame by frame in
one process, one with the check and one without (``SkeletonStage(body_check=False)``).
Prints the share of frames checked and each stage's median and p95 per frame (each session's
first frame left out, as bench_finder does) with their ratios.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv: list[str] | None = None) -> int:
    import bench_finder

    from live.evaluation.skeleton import session_frames
    from models.skeleton.runtime import SkeletonStage

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a few sessions")
    args = ap.parse_args(argv)
    specs, _ = bench_finder.plan(args.quick)
    bench_finder.generate(specs, workers=1)
    variants = {"without the check": False, "with the check": True}
    times: dict[str, list[float]] = {k: [] for k in variants}
    checks = frames = 0
    for n, spec in enumerate(specs):
        stages = {name: SkeletonStage(body_check=on) for name, on in variants.items()}
        for i, (depth, _) in enumerate(session_frames(spec.path)):
            frames += 1
            for name, stage in stages.items():
                t0 = time.perf_counter()
                stage.estimate(depth)
                if i:
                    times[name].append((time.perf_counter() - t0) * 1e3)
        checks += stages["with the check"].finder.counters.body_checks
        print(f"\rsessions {n + 1}/{len(specs)}", end="", file=sys.stderr)
    print(file=sys.stderr)
    off = np.array(times["without the check"])
    print(f"{len(specs)} sessions, {frames} frames, {checks} checked ({checks / max(frames, 1):.1%})")
    print(f"{'':20s} {'median ms':>10s} {'p95 ms':>8s}")
    for name in variants:
        t = np.array(times[name])
        print(f"{name:20s} {np.median(t):10.2f} {np.quantile(t, 0.95):8.2f}")
    on = np.array(times["with the check"])
    print(f"with / without (same process): median {np.median(on) / np.median(off):.2f}x, "
          f"p95 {np.quantile(on, 0.95) / np.quantile(off, 0.95):.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
