"""Replay of the bundled demo session at max speed: the source inline against a source thread.

Run: .venv/bin/python benchmarks/bench_replay.py [--runs 4]
The pipeline of `livecap demo` without its sinks (skeleton stage, analytic retargeting onto the
default avatar with LBS), over sim/data/demo.mcap, alternating in one process between the
every-frame runner's default (the lone replay source runs in the caller's thread) and a source
thread that reads ahead (``Pipeline(..., inline=False)``, the runner before). Prints, per mode,
the medians over the runs of fps and of the stages' and end-to-end p50 / p95 latencies (ms).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as the CLI runs

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from live.app.running import DEMO_SESSION  # noqa: E402
from live.body.library import load_body  # noqa: E402
from live.pipeline.runner import Pipeline  # noqa: E402
from live.pipeline.stages import RetargetStage  # noqa: E402
from models.skeleton.runtime import SkeletonStage  # noqa: E402
from sim.replay import ReplaySource  # noqa: E402


def one_run(skeleton: SkeletonStage, avatar, inline: bool) -> dict:
    skeleton.reset()
    stages = [skeleton, RetargetStage(avatar, skin=True)]
    stats = Pipeline([ReplaySource(DEMO_SESSION)], stages, mode="every", inline=inline).run()
    row = {"fps": stats["fps"]}
    for name, st in stats["stages"].items():
        row[f"{name} p50"], row[f"{name} p95"] = st["latency_ms"]["p50"], st["latency_ms"]["p95"]
    row["end to end p50"] = stats["end_to_end"]["latency_ms"]["p50"]
    row["end to end p95"] = stats["end_to_end"]["latency_ms"]["p95"]
    return row


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=4)
    args = p.parse_args(argv)
    avatar = load_body("default")
    skeleton = SkeletonStage()
    one_run(skeleton, avatar, True)  # warm-up: model sessions, ray tables, the body library
    rows: dict[str, list[dict]] = {"inline (default)": [], "source thread": []}
    for _ in range(args.runs):
        rows["inline (default)"].append(one_run(skeleton, avatar, True))
        rows["source thread"].append(one_run(skeleton, avatar, False))
    keys = list(rows["inline (default)"][0])
    print(f"{DEMO_SESSION.name}, {args.runs} runs per mode, alternating; medians over the runs")
    print(f"{'':<20}" + "".join(f"{k:>17}" for k in keys))
    for mode, runs in rows.items():
        print(f"{mode:<20}" + "".join(f"{np.median([r[k] for r in runs]):>17.2f}" for k in keys))


if __name__ == "__main__":
    main()
