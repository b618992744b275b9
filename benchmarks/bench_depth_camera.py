"""Frames per second of the virtual depth camera: 640x400 (oak-d), a ~7k-vertex body in a room.

Run from the repository root:  .venv/bin/python benchmarks/bench_depth_camera.py [--frames 60]
Prints the median over 5 runs (the machine is shared, so medians, not best cases) of the mean
frame time of each run, with noise off and on; the body moves every frame so that nothing can
be cached across frames that a live stream could not cache.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from live.core.skeleton import default_rest_joints  # noqa: E402
from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera  # noqa: E402
from sim.room import Box, Room, capsule_body  # noqa: E402


def body_mesh() -> tuple[np.ndarray, np.ndarray, str]:
    """The library's default body if it exists, else the capsule stand-in (~7k vertices)."""
    try:
        from live.body.library import load_body

        b = load_body("default")
        return np.asarray(b.vertices, np.float32), np.asarray(b.faces, np.int32), f"body:{b.name}"
    except (ImportError, OSError, ValueError):
        v, f = capsule_body(default_rest_joints())
        return v, f, "capsule stand-in"


def run(noise: NoiseModel, frames: int, repeats: int, preset: str) -> list[float]:
    v, f, _ = body_mesh()
    room = Room(boxes=(Box((1.8, 0.4, -1.5), (0.8, 0.8, 0.8)), Box((-2.0, 0.5, -2.5), (1.0, 1.0, 0.6))))
    cam = VirtualDepthCamera(preset, look_at_camera(2.5, 1.3, 0.3), noise=noise, seed=0)
    cam.render(v, f, room=room)  # warm-up: builds the cached room view
    fps = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(frames):
            # Sway the body a little per frame: new geometry each frame, as in a live stream.
            shift = np.array([0.05 * np.sin(0.3 * i), 0.0, 0.05 * np.cos(0.2 * i)], np.float32)
            cam.render(v + shift, f, room=room)
        fps.append(frames / (time.perf_counter() - t0))
    return fps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--preset", default="oak-d")
    args = ap.parse_args()
    v, f, name = body_mesh()
    print(f"{args.preset}, mesh: {name}, {len(v)} vertices, {len(f)} faces, room with 2 boxes")
    for label, noise in (("noise off", NoiseModel.none()), ("noise on ", NoiseModel())):
        fps = run(noise, args.frames, args.repeats, args.preset)
        print(f"{label}: median {np.median(fps):6.1f} frames/s  ({1000 / np.median(fps):.1f} ms/frame;"
              f" runs: {', '.join(f'{x:.0f}' for x in fps)})")


if __name__ == "__main__":
    main()
