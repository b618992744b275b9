"""Per-frame cost of the skeleton stage on 640x400 OAK-D frames.

Run: .venv/bin/python benchmarks/bench_skeleton.py [--frames 150] [--threads 1] [--against OLD.onnx]
Renders a real CMU clip on a body of the library (capsules when the library is missing) with the
virtual OAK-D in a room with clutter, then times, per frame: the person finder (preprocess), the
model alone (ours and the reference PointNet, same process, same input), and the whole stage
(preprocess + model + flip guard + temporal model + One Euro filter). Prints median and p95 (ms);
with a model whose card asks for the depth-edge test, the finder without it too, for the ratio.
With --against, another regressor (e.g. a previous shipped one, with its card beside it) is timed
in the same process, the two taking turns frame by frame, model alone and whole stage, for the
ratio of their medians. The given camera pose's check against the room (a floor search every 2 s)
is timed the same way: the stage as shipped and with ``check_extrinsics=False``, in turns.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from live.core.frames import DepthFrame  # noqa: E402
from live.core.report import percentiles  # noqa: E402
from models.skeleton.preprocess import PersonFinder  # noqa: E402
from models.skeleton.runtime import BASELINE_MODEL, DEFAULT_MODEL, SkeletonRegressor, SkeletonStage  # noqa: E402
from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera  # noqa: E402
from sim.room import Box, Room  # noqa: E402

CLIP = ROOT.parent / "shared" / "data" / "bvh" / "cc_002_05.bvh"


def render_frames(n: int, seed: int = 0) -> list[DepthFrame]:
    """n consecutive OAK-D frames of a performer 2.5 m from the camera, in a cluttered room."""
    from live.body.library import list_presets, load_body
    from sim.skeleton_data import clip_motion, grounded_joints
    from sim.synth import SyntheticScene

    body = load_body(sorted(list_presets())[0])
    motion = clip_motion(CLIP.name)
    root, joints = grounded_joints(motion, body)
    c = joints[: n, 0].mean(axis=0)
    shift = np.array([c[0], 0.0, c[2]])
    c2w = look_at_camera(2.5, 1.4, 0.5)
    cam = VirtualDepthCamera("oak-d", c2w, noise=NoiseModel(), seed=seed)
    scene = SyntheticScene(motion=motion, body=body, camera=cam, root=root - shift, joints=joints - shift)
    room = Room(boxes=(Box((1.8, 0.4, -1.0), (0.8, 0.8, 0.8)), Box((-2.0, 0.5, 0.8), (1.0, 1.0, 0.6))))
    frames = []
    for i in range(n):
        depth = cam.render(scene.vertices(i), body.faces, room=room)
        frames.append(DepthFrame(t_ns=1_000_000_000 + i * 33_333_333, sensor="oak", camera_to_world=c2w,
                                 depth_mm=depth, intrinsics=cam.intrinsics))
    return frames


def timed_alternating(fns, items, warmup: int = 10) -> list[tuple[float, float]]:
    """(median, p95) ms of each of ``fns`` on every item, the functions taking turns per item."""
    ts: list[list[float]] = [[] for _ in fns]
    for it in items:
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn(it)
            ts[k].append(time.perf_counter() - t0)
    out = []
    for t in ts:
        p = percentiles(np.array(t[warmup:]) * 1e3, (50, 95))
        out.append((p["p50"], p["p95"]))
    return out


def timed(fn, items, warmup: int = 10) -> tuple[float, float]:
    ts = []
    for it in items:
        t0 = time.perf_counter()
        fn(it)
        ts.append(time.perf_counter() - t0)
    ms = np.array(ts[warmup:]) * 1e3
    p = percentiles(ms, (50, 95))
    return p["p50"], p["p95"]


def against(other: Path, frames: list[DepthFrame], threads: int) -> list[tuple[str, float, float]]:
    """The shipped regressor and ``other`` in turns, frame by frame: model alone (each on a
    cloud sampled by its own finder settings) and whole stage."""
    regs = [SkeletonRegressor(p, threads=threads) for p in (DEFAULT_MODEL, other)]
    own_clouds = [[c for c in (PersonFinder(r.preprocess_config()).find(f) for f in frames) if c] for r in regs]
    pairs = list(zip(*own_clouds)) * 2
    model = timed_alternating([lambda pc, r=r, k=k: r(pc[k].points) for k, r in enumerate(regs)], pairs)
    stages = [SkeletonStage(p, threads=threads) for p in (DEFAULT_MODEL, other)]
    stage = timed_alternating([s.estimate for s in stages], frames)
    rows = []
    for what, res in (("model alone", model), ("whole stage", stage)):
        for name, (med, p95) in zip(("shipped", "other"), res):
            rows.append((f"{what}, in turns: {name}", med, p95))
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=150)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--against", type=Path, default=None, metavar="ONNX",
                   help="another regressor timed in turns with the shipped one (ratio of medians)")
    args = p.parse_args(argv)
    frames = render_frames(args.frames)
    print(f"{len(frames)} OAK-D 640x400 frames, onnxruntime threads={args.threads}")
    rows = []
    config = SkeletonRegressor(DEFAULT_MODEL).preprocess_config()  # the shipped model's finder settings
    finder = PersonFinder(config)
    if config.edge_jump_share is None:
        rows.append(("preprocess (PersonFinder)", *timed(finder.find, frames)))
    else:  # what the model's depth-edge test costs: both finders frame by frame, alternating
        bare = PersonFinder(dataclasses.replace(config, edge_jump_share=None))
        with_test, without = timed_alternating((finder.find, bare.find), frames)
        rows += [("preprocess (PersonFinder)", *with_test), ("preprocess without the edge test", *without)]
    clouds = [c for c in (PersonFinder(config).find(f) for f in frames) if c]
    for label, path in (("ours", DEFAULT_MODEL), ("baseline PointNet", BASELINE_MODEL)):
        if not path.is_file():
            print(f"(no {path.name}: skipped)")
            continue
        reg = SkeletonRegressor(path, threads=args.threads)
        rows.append((f"model alone: {label} ({reg.num_points} pts)", *timed(lambda c: reg(c.points), clouds * 2)))
        stage = SkeletonStage(path, threads=args.threads)
        temporal = " (+ temporal model)" if stage.temporal is not None else ""
        rows.append((f"whole stage: {label}{temporal}", *timed(stage.estimate, frames)))
        if stage.temporal is not None:
            plain = SkeletonStage(path, threads=args.threads, temporal=False)
            rows.append((f"whole stage: {label}, One Euro only", *timed(plain.estimate, frames)))
    checked, trusted = (SkeletonStage(threads=args.threads, check_extrinsics=c) for c in (True, False))
    both = timed_alternating([checked.estimate, trusted.estimate], frames)
    rows += [("whole stage, given pose checked", *both[0]), ("whole stage, given pose taken as is", *both[1])]
    if args.against is not None:
        rows += against(args.against, frames, args.threads)
    print(f"{'':<40}{'median ms':>10}{'p95 ms':>10}")
    for name, med, p95 in rows:
        print(f"{name:<40}{med:>10.2f}{p95:>10.2f}")
    by_name = {name: med for name, med, _ in rows}
    if "preprocess without the edge test" in by_name:
        print("preprocess: with / without the edge test (medians, same process) = "
              f"{by_name['preprocess (PersonFinder)'] / by_name['preprocess without the edge test']:.2f}")
    print("whole stage: given pose checked / taken as is (in turns, same process) = "
          f"{by_name['whole stage, given pose checked'] / by_name['whole stage, given pose taken as is']:.2f} median, "
          f"{both[0][1] / both[1][1]:.2f} p95")
    if args.against is not None:
        for what in ("model alone", "whole stage"):
            print(f"{what}: shipped / {args.against.name} (medians, in turns, same process) = "
                  f"{by_name[f'{what}, in turns: shipped'] / by_name[f'{what}, in turns: other']:.2f}")
    for what in ("model alone", "whole stage"):
        ours = [m for n, m in by_name.items() if n.startswith(f"{what}: ours") and "One Euro" not in n]
        ref = [m for n, m in by_name.items() if n.startswith(f"{what}: baseline")]
        if ours and ref:
            print(f"{what}: ours / reference PointNet (medians, same process) = {ours[0] / ref[0]:.2f}")


if __name__ == "__main__":
    main()
