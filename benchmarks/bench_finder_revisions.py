"""The person finder's cost per frame against the finder of another git revision, in one process.

Run: .venv/bin/python benchmarks/bench_finder_revisions.py [--rev HEAD~1] [--frames 120] [--rounds 3]

The finder modules of ``--rev`` (models/skeleton/*.py as they were there) are loaded from git
into a private package beside the working tree's, and both find the performer in the same frames, rounds
alternating: the frames of benchmarks/bench_skeleton.py (virtual OAK-D, cluttered room) with
their extrinsics, and the same frames with the extrinsics withheld (identity camera_to_world,
as a depth folder has them: the working tree's finder estimates up and the floor). Prints per-frame median
and p95 (ms) of each and the ratio working tree / revision.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_skeleton import render_frames  # noqa: E402

from live.core.report import percentiles  # noqa: E402
from models.skeleton.preprocess import PersonFinder  # noqa: E402

MODULES = ("preprocess", "preprocess_config", "person_clusters", "point_sample", "background", "floor", "ground")


def finder_at(rev: str, into: Path):
    """PersonFinder class of revision ``rev`` (its models/skeleton modules copied into a private
    package whose imports point at each other)."""
    pkg = into / "finder_at_rev"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name in MODULES:
        shown = subprocess.run(["git", "show", f"{rev}:models/skeleton/{name}.py"], cwd=ROOT,
                               capture_output=True, text=True)
        if shown.returncode == 0:
            (pkg / f"{name}.py").write_text(shown.stdout.replace("models.skeleton.", "finder_at_rev."))
    sys.path.insert(0, str(into))
    return importlib.import_module("finder_at_rev.preprocess").PersonFinder


def time_finder(make, frames) -> list[float]:
    finder = make()
    out = []
    for f in frames:
        t0 = time.perf_counter()
        finder.find(f)
        out.append((time.perf_counter() - t0) * 1e3)
    return out[5:]  # the first frames pay one-off set-up (rays, the first floor search)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", default="HEAD~1")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    frames = render_frames(args.frames)
    hidden = [dataclasses.replace(f, camera_to_world=np.eye(4)) for f in frames]
    with tempfile.TemporaryDirectory() as tmp:
        before = finder_at(args.rev, Path(tmp))
        times: dict[str, list[float]] = {k: [] for k in ("given/rev", "given/now", "hidden/rev", "hidden/now")}
        for _ in range(args.rounds):
            for label, frames_of in (("given", frames), ("hidden", hidden)):
                times[f"{label}/rev"] += time_finder(before, frames_of)
                times[f"{label}/now"] += time_finder(PersonFinder, frames_of)
    print(f"person finder, {args.frames} OAK-D frames x {args.rounds} rounds, alternating; ms per frame")
    print(f"{'':10s} {args.rev + ' p50':>14s} {'p95':>7s} {'now p50':>9s} {'p95':>7s} {'ratio p50':>10s} {'p95':>6s}")
    for label in ("given", "hidden"):
        r50, r95 = percentiles(times[f"{label}/rev"], (50, 95)).values()
        n50, n95 = percentiles(times[f"{label}/now"], (50, 95)).values()
        print(f"{label:10s} {r50:14.2f} {r95:7.2f} {n50:9.2f} {n95:7.2f} {n50 / r50:10.2f} {n95 / r95:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
