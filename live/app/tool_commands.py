"""``livecap synth``, ``livecap eval`` and ``livecap train``: data, accuracy and models."""

from __future__ import annotations

import sys
from pathlib import Path

from live.core.errors import UserInputError


def cmd_synth(args) -> int:
    import math

    from sim.synth import CameraPlacement, SynthOptions, synthesize

    if not Path(args.motion).is_file():
        raise UserInputError(f"no such motion file: {args.motion}")
    if args.pitch is not None and not -90.0 < args.pitch < 90.0:
        raise UserInputError(f"--pitch is a tilt between -90 and 90 degrees, not {args.pitch:g}")
    pitch = None if args.pitch is None else -math.radians(args.pitch)  # CameraPlacement tilts down
    opts = SynthOptions(motion=args.motion, body=args.body, camera=args.camera, seconds=args.seconds,
                        fps=args.fps, seed=args.seed, imu=args.imu, start_s=args.start, noise=not args.no_noise,
                        camera_imu=args.camera_imu,
                        max_range_m=args.max_range, posture=args.posture, floor=args.floor == "seen",
                        hide_extrinsics=args.hide_extrinsics,
                        placement=CameraPlacement(args.distance, args.height, math.radians(args.yaw), pitch))
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(desc="synth", unit="frame", leave=False, file=sys.stderr, disable=None)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.update(done - bar.n)

    try:
        summary = synthesize(opts, args.out, progress)
    finally:
        if bar is not None:
            bar.close()
    print(f"livecap synth: {summary['frames']} frames at {summary['fps']:g} fps of {Path(args.motion).name} "
          f"on {summary['body']} ({summary['camera']}) -> {args.out}")
    return 0


def cmd_eval(args) -> int:
    import json as _json

    if args.what == "skeleton":
        from live.evaluation.skeleton import evaluate_sessions, format_report

        for path in args.sessions:
            if not path.is_file():
                raise UserInputError(f"no such session: {path}")
        report = evaluate_sessions([str(p) for p in args.sessions], model_path=args.model,
                                   compare_baseline=args.compare == "baseline", threads=args.threads, lag=args.lag)
    elif args.what == "contacts":
        from live.body.avatar import load_avatar
        from live.evaluation.contacts import evaluate_contacts, format_report

        if not Path(args.motion).is_file():
            raise UserInputError(f"no such motion file: {args.motion}")
        report = evaluate_contacts(args.motion, load_avatar(args.source_body), load_avatar(args.target_body),
                                   from_=args.from_, retarget=args.retarget, max_frames=args.max_frames, lag=args.lag)
    else:
        from live.body.library import load_body
        from live.evaluation.retarget import evaluate_retarget, format_report

        if not Path(args.motion).is_file():
            raise UserInputError(f"no such motion file: {args.motion}")
        report = evaluate_retarget(args.motion, load_body(args.source_body), load_body(args.target_body),
                                   from_=args.from_, retarget=args.retarget, max_frames=args.max_frames,
                                   lag=args.lag)
        if report.get("bind_pose_frames_cut") and not args.json:
            print(f"{Path(args.motion).name}: its first {report['bind_pose_frames_cut']} frame(s), the exporter's "
                  "bind pose, cut (docs/motion.md)")
    print(_json.dumps(report, indent=2, default=str) if args.json else format_report(report))
    return 0


_TRAINERS = {"skeleton": "models.train.train_skeleton", "skeleton-temporal": "models.train.train_skeleton_temporal",
             "retarget": "models.train.train_retarget",
             "skinning": "models.train.train_skinning", "bodies": "models.train.export_bodies"}


def cmd_train(args) -> int:
    import importlib
    import importlib.util

    if importlib.util.find_spec("torch") is None:
        raise UserInputError("training needs the train extra: pip install -e '.[train]'")
    module = importlib.import_module(_TRAINERS[args.what])
    extra = [a for a in args.args if a != "--"]
    if args.quick:
        extra.append("--quick")
    module.main(extra)
    return 0
