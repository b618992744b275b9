"""The skeleton stage on unrelated stills against continuous takes: per frame, online, lag 2.

    python -m research.unrelated_frames [--cameras xtion kinect-v1 oak-d] [--stills 96] [--one-place | --in-place] [--sequences]

A folder of depth images need not be a take: a dataset's test frames are often stills drawn
from many recordings, and replayed as a folder they reach the temporal model as one 30 fps
sequence. For each camera model, eight synthetic sessions (held-out CMU clips and bodies, 4 s,
extrinsics hidden as in a folder; cached under .cache/unrelated_frames) are run through the stage
as takes, each on its own, and as stills: ``--stills`` frames drawn from them in turn, at random
times. Per mode, root-aligned MPJPE (mm) and PCK@10cm in the camera frame, frames with a
skeleton, the temporal model's jumps and the frames it gave as read, taking the stream for stills
(models/skeleton/temporal.py, ``STILLS_BREAKS``).

``--sequences`` also runs the temporal models frame by frame, as the stage runs them, on held-out
sequences behind the shipped regressor: the 150 clean validation sequences of the temporal
cards and the 200 realism sequences of ``research.facing_sequences`` (five sensors, clothes,
occluders, bodies read turned): how often a take is taken for stills, and what that costs.
"""

from __future__ import annotations

import argparse

import numpy as np

from live.core import assets
from live.core.metrics import mpjpe, pck

#: Held-out clips and bodies (sim.skeleton_data's split), one session each.
CLIPS = ("cc_007_03", "mb_08_01", "mb_12_03", "mb_16_15", "cc_007_09", "mb_08_07", "daz_16_36", "mb_16_47")
BODIES = ("adult_male_average", "elderly_female_heavy", "short_male", "teen_girl_14y")
MODES = ("per frame", "online", "lag 2")
PERIOD_NS = 33_333_333


def sessions(camera: str, one_place: bool = False, in_place: bool = False) -> list[tuple[list[tuple], np.ndarray]]:
    """Per session: its (DepthFrame, GroundTruth) pairs in stream order and its true
    camera_to_world (the depth frames withhold it). Each session has its own camera placement, or
    (``one_place``) all share one, 3 m in front, and the performers move in place (sim.postures
    ``in-place``): stills that differ only in body and pose, as a dataset recorded in one room
    gives them. ``in_place``: each from its own placement, performed in place."""
    import math

    from live.evaluation.skeleton import read_eval_session
    from sim.synth import CameraPlacement, SynthOptions, synthesize

    cache = assets.cache_dir() / "unrelated_frames"
    cache.mkdir(parents=True, exist_ok=True)
    out = []
    for i, clip in enumerate(CLIPS):
        path = cache / f"{camera}_{'one_place_' if one_place else 'in_place_' if in_place else ''}{i}.mcap"
        if not path.is_file():
            placement = CameraPlacement(3.0, 1.2, 0.0, 0.0) if one_place else \
                CameraPlacement(2.5 + 0.15 * i, 1.2, math.radians(-30 + 8 * i), 0.0)
            synthesize(SynthOptions(motion=str(assets.bvh_dir() / f"{clip}.bvh"), body=BODIES[i % len(BODIES)],
                                    camera=camera, seconds=4.0, seed=i, placement=placement, hide_extrinsics=True,
                                    posture="in-place" if one_place or in_place else "clip"), path)
        session = read_eval_session(path)
        out.append((session.pairs, session.true_camera_to_world))
    return out


def run_stage(frames: list[tuple], mode: str) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict]:
    """Frames ((DepthFrame, GroundTruth, true camera_to_world) each) through a fresh stage in one
    stream at 30 fps: [(estimate, truth in the world the stage solved in)], and its counters."""
    from dataclasses import replace

    from live.core.frames import FrameResult
    from live.evaluation.skeleton import truth_in_solved_frame
    from models.skeleton.runtime import SkeletonStage

    stage = SkeletonStage(temporal=False, filter=False, flip_guard=False) if mode == "per frame" \
        else SkeletonStage(lag=2 if mode == "lag 2" else 0)
    truth, skeletons = {}, []
    for k, (depth, gt, true_c2w) in enumerate(frames):
        result = FrameResult(t_ns=k * PERIOD_NS, depth=replace(depth, t_ns=k * PERIOD_NS))
        truth[result.t_ns] = (gt.joints, true_c2w)
        stage.process(result)
        if result.skeleton is not None:
            skeletons.append(result.skeleton)
    skeletons += stage.flush()
    pairs = []
    for sk in skeletons:
        joints, true_c2w = truth[sk.t_ns]
        pairs.append((sk.joints, truth_in_solved_frame(joints, sk.camera_to_world, true_c2w)))
    return pairs, stage.counters


def root_aligned(est: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """MPJPE (m) and PCK@10cm of (..., 22, 3) estimates with their pelvises moved onto the truth's."""
    aligned = est - est[..., :1, :] + gt[..., :1, :]
    return mpjpe(aligned, gt), pck(aligned, gt, 0.1)


def scores(pairs: list[tuple[np.ndarray, np.ndarray]], frames: int, counters: dict) -> str:
    err, share = root_aligned(np.stack([p for p, _ in pairs]), np.stack([t for _, t in pairs]))
    events = ", ".join(f"{k[9:]} {counters.get(k, 0)}" for k in ("temporal_jumps", "temporal_stills"))
    return f"{1000 * err:.1f} / {share:.3f}; {len(pairs)} of {frames}; {events}"


def stills_table(cameras: list[str], n_stills: int, one_place: bool, in_place: bool = False) -> list[str]:
    rows = ["| camera | mode | takes: MPJPE / PCK@10cm; frames; events | stills: the same |", "|---|---|---|---|"]
    for camera in cameras:
        takes = [[(d, gt, c2w) for d, gt in pairs] for pairs, c2w in sessions(camera, one_place, in_place)]
        rng = np.random.default_rng(0)
        stills = [takes[k % len(takes)][rng.integers(len(takes[k % len(takes)]))] for k in range(n_stills)]
        where = ", one place" if one_place else ", in place" if in_place else ""
        for mode in MODES:
            runs = [run_stage(take, mode) for take in takes]
            pairs = [p for r, _ in runs for p in r]
            counters = {k: sum(c.get(k, 0) for _, c in runs) for k in runs[0][1]}
            take_cell = scores(pairs, sum(map(len, takes)), counters)
            still_pairs, still_counters = run_stage(stills, mode)
            rows.append(f"| {camera}{where} | {mode} | {take_cell} | {scores(still_pairs, n_stills, still_counters)} |")
            print(rows[-1], flush=True)
    return rows


def sequences_table() -> list[str]:
    """The temporal models as the stage runs them, on held-out sequences (their found frames)."""
    from models.skeleton.runtime import SkeletonRegressor
    from models.skeleton.temporal import TemporalRefiner, temporal_model_path
    from models.train.train_skeleton_temporal import regress_sequences
    from research.facing_sequences import guarded, realism_sequences
    from sim.skeleton_sequences import SEQUENCE_FPS, generate_sequences

    regressor = assets.weight("skeleton.onnx")
    edge = SkeletonRegressor(regressor).edge_jump_share
    sets = {"realism (200)": realism_sequences(200, edge, 2),
            "clean validation (150)": generate_sequences("val", 150, seed=1, workers=2, edge_jump_share=edge)}
    period = int(round(1e9 / SEQUENCE_FPS))
    rows = ["| sequences | model | frames | root-aligned MPJPE / PCK@10cm | jumps, stills |", "|---|---|---|---|---|"]
    for name, data in sets.items():
        raw, conf = regress_sequences(data, regressor, 1)
        found, truth = data["found"], data["joints"].astype(np.float64)
        world = guarded(raw, found, True, None)
        err, share = root_aligned(world[found], truth[found])
        rows.append(f"| {name} | per frame | {int(found.sum())} | {1000 * err:.1f} / {share:.4f} | |")
        for lag in (0, 2):
            refiner = TemporalRefiner(temporal_model_path(lag))  # its counters add up over the sequences
            est, gt = [], []
            for s in range(len(world)):
                refiner.reset()
                out = [refiner(f * period, world[s, f], conf[s, f], data["to_world"][s, f])
                       for f in np.flatnonzero(found[s])]
                for r in [r for r in out if r is not None] + refiner.flush():
                    est.append(r.joints)
                    gt.append(truth[s, r.t_ns // period])
            err, share = root_aligned(np.stack(est), np.stack(gt))
            rows.append(f"| {name} | {'online' if lag == 0 else 'lag 2'} | {len(est)} | {1000 * err:.1f} / "
                        f"{share:.4f} | {refiner.jumps}, {refiner.stills} |")
        for row in rows[-3:]:
            print(row, flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.unrelated_frames", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cameras", nargs="+", default=["xtion", "kinect-v1", "oak-d"])
    ap.add_argument("--stills", type=int, default=96, help="stills drawn from each camera's sessions")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--one-place", action="store_true",
                       help="all sessions from one camera placement, performed in place")
    where.add_argument("--in-place", action="store_true",
                       help="each session from its own camera placement, performed in place")
    ap.add_argument("--sequences", action="store_true", help="also the temporal models on held-out sequences")
    args = ap.parse_args(argv)
    rows = stills_table(args.cameras, args.stills, args.one_place, args.in_place)
    if args.sequences:
        rows += [""] + sequences_table()
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
