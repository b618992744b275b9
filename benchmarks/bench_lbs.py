"""LBS speed: frames/s for a ~7k-vertex body, one frame per call (the live case) and batched.

    python benchmarks/bench_lbs.py                          # BLAS threads as numpy defaults them
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_lbs.py   # as the livecap CLI runs
Prints medians of 5 repetitions and a one-line JSON summary (with the BLAS thread setting: the
batched path is a BLAS matmul, the single-frame path avoids BLAS).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from live.body.library import load_body  # noqa: E402
from live.body.skinning import lbs  # noqa: E402
from live.core.rotations import quat_normalize  # noqa: E402


def main() -> None:
    body = load_body("default")
    rng = np.random.default_rng(0)
    q = quat_normalize(np.concatenate([np.full((200, 22, 1), 3.0), rng.normal(size=(200, 22, 3))], -1))
    root = rng.normal(size=(200, 3))
    single, batched = [], []
    for _ in range(5):
        t = time.perf_counter()
        for i in range(200):
            lbs(body.vertices, body.weights, body.rest_joints, q[i], root[i])
        single.append(200 / (time.perf_counter() - t))
        t = time.perf_counter()
        for i in range(0, 200, 50):
            lbs(body.vertices, body.weights, body.rest_joints, q[i:i + 50], root[i:i + 50])
        batched.append(200 / (time.perf_counter() - t))
    out = {"vertices": len(body.vertices), "single_frame_fps": round(float(np.median(single)), 1),
           "batched_fps": round(float(np.median(batched)), 1),
           "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default")}
    print(f"LBS {out['vertices']} vertices: {out['single_frame_fps']} frames/s one at a time, "
          f"{out['batched_fps']} frames/s in batches of 50 (medians of 5; OpenBLAS threads: {out['openblas_threads']})")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
