"""Per-frame cost of the self-contact correction in the retarget stage, beside the stage without it.

Run: .venv/bin/python benchmarks/bench_contacts.py [--frames 600] [--source BODY] [--targets A,B]
     [--retarget analytic|learned] [--performer true|fitted] [--also-held]
Timing (median / p95 ms, 10 warm-up frames skipped; wall clock, and the thread's CPU time, which
a machine busy with other jobs does not inflate), one process, the two configurations run
frame by frame in turn (so that a busy machine slows both alike), as the pipeline's retarget
stage runs them: the analytic retargeter (or ``--retarget learned``: the network, behind which the
contacts solve the performer's rotations themselves; both with foot lock + floor) from exact
skeletons, then LBS of
the avatar (~7k vertices), without and with the self-contacts (the performer's true body as in a
synthetic session; ``--performer fitted``: a template fitted to the skeleton, with the
estimated performer's wider contact settings, as a live depth or suit performer gets). The motion: clips with self-contacts, back to back at 30 fps (hands on the
belly, curled in: CMU subject 49; washing: subject 2; a walk whose hands pass the thighs:
subject 16), about a third of the frames in contact. Goal: the stage with contacts <= 2 ms p95.
``--also-held``: a third configuration in turn, the correction with ``let_go`` off (an arm's
correction held between contacts, as for an estimated performer), the baseline of letting go.
Also: building an avatar's surface (signed distance grids) with the cache cold, once per avatar.
BLAS runs single-threaded (OPENBLAS_NUM_THREADS=1 unless set), as the CLI runs it.
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

BVH = ROOT.parent / "shared" / "data" / "bvh"
#: (clip, first frame, frames at 30 fps): hands on the belly; washing; a walk.
CLIPS = (("mb_49_11.bvh", 120, 180), ("cc_002_10.bvh", 0, 240), ("mb_16_15.bvh", 0, 120))


def _motion_joints(source, frames: int) -> np.ndarray:
    from live.evaluation.retarget import _on_body, prepare_motion

    parts = []
    for clip, start, count in CLIPS:
        motion = prepare_motion(BVH / clip, 30.0)
        _, joints = _on_body(motion, source.rest_joints)
        parts.append(joints[start:start + count])
    joints = np.concatenate(parts)
    return np.concatenate([joints] * (1 + frames // len(joints)))[:frames]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--source", default="adult_male_average")
    ap.add_argument("--targets", default="child_girl_6y,tall_heavy_male",
                    help="avatars (default: the slimmest child and the heaviest adult of the library)")
    ap.add_argument("--retarget", default="analytic", choices=("analytic", "learned"))
    ap.add_argument("--performer", default="true", choices=("true", "fitted"),
                    help="the performer's surface: its true body, or a template fitted to its skeleton")
    ap.add_argument("--also-held", action="store_true",
                    help="also the correction with let_go off (held between contacts), in turn with the others")
    args = ap.parse_args()
    from dataclasses import replace

    from live.body.library import load_body
    from live.body.skinning import pose_transforms, skin
    from live.evaluation.retarget import make_retargeter
    from live.retarget.contacts_retargeter import ContactRetargeter, PerformerSurfaces
    from live.retarget.contacts_self import settings_for
    from live.retarget.contacts_surface import body_surface, build_surface_model

    src = load_body(args.source)
    joints = _motion_joints(src, args.frames)
    performer = body_surface(src) if args.performer == "true" else PerformerSurfaces()
    print(f"{len(joints)} frames from {src.name}; ms median / p95 (stage: {args.retarget} retarget step + LBS)")
    for name in args.targets.split(","):
        tgt = load_body(name)
        target = body_surface(tgt)
        plain = make_retargeter(args.retarget, src.rest_joints, tgt.rest_joints, 30.0)
        settings = settings_for(args.performer == "fitted")
        stages = {"without contacts": plain}
        for label, chosen in (("with contacts", settings), ("held between", replace(settings, let_go=False))):
            if label == "with contacts" or args.also_held:
                stages[label] = ContactRetargeter(make_retargeter(args.retarget, src.rest_joints, tgt.rest_joints,
                                                                  30.0), target, tgt.rest_joints, src.rest_joints,
                                                  performer, settings=chosen)
        kept = stages["with contacts"]
        times: dict[str, list[float]] = {label: [] for label in stages}
        cpu: dict[str, list[float]] = {label: [] for label in stages}
        for j in joints:
            for label, rt in stages.items():
                t0, c0 = time.perf_counter(), time.thread_time()
                _, _, posed = rt.step(j)
                skin(tgt.vertices, tgt.weights, pose_transforms(rt.last_globals, posed, tgt.rest_joints)[None])
                times[label].append(time.perf_counter() - t0)
                cpu[label].append(time.thread_time() - c0)
        print(f"  -> {tgt.name} ({len(tgt.vertices)} vertices), corrected frames "
              f"{kept.counters['frames_corrected']} of {len(joints)}, with a hand contact "
              f"{kept.counters['frames_with_hand_contacts']}")
        for name, table in (("wall", times), ("cpu", cpu)):
            stats = {}
            for label, ts in table.items():
                stats[label] = percentiles(np.array(ts[10:]) * 1e3, (50, 95))
                print(f"     {name} {label:18s} {stats[label]['p50']:7.3f} / {stats[label]['p95']:7.3f}")
            a, b = stats["without contacts"], stats["with contacts"]
            print(f"     {name} {'ratio':18s} {b['p50'] / a['p50']:7.2f}x / {b['p95'] / a['p95']:6.2f}x")
            if "held between" in stats:
                h = stats["held between"]
                print(f"     {name} {'ratio to held':18s} {b['p50'] / h['p50']:7.2f}x / {b['p95'] / h['p95']:6.2f}x")
    t0 = time.perf_counter()
    build_surface_model(load_body(args.targets.split(",")[-1]))
    print(f"  building an avatar's surface (cache cold, once per avatar): {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
