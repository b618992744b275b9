"""One function per CLI command; each takes the parsed arguments and returns an exit code."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from live.app.running import DEMO_SESSION, count_trigger_frames, parse_speed, run_pipeline, write_stats
from live.core.errors import UserInputError


def _replay_source(target: str, speed: float | None):
    path = Path(target)
    if path.is_dir():
        from sim.depth_folder import DepthFolderSource

        return DepthFolderSource(path, speed=speed)
    if not path.exists():
        raise UserInputError(f"no such session or folder: {path}")
    from sim.replay import ReplaySource

    return ReplaySource(path, speed=speed)


def _run_options(args, out: Path, video: Path | None = None):
    from live.app.assemble import RunOptions

    return RunOptions(out=out, avatar=args.avatar, retarget=args.retarget, foot_lock=not args.no_foot_lock,
                      hand_ik=args.hand_ik, model=args.model, threads=args.threads, lag=args.lag, vmc=args.vmc,
                      vmc_rate=args.vmc_rate, viewer=args.viewer, video=video or args.video)


def _replay(target: str, args, out: Path, video: Path | None = None) -> dict:
    from live.app.assemble import build

    speed = parse_speed(args.speed)
    source = _replay_source(target, speed)
    out.mkdir(parents=True, exist_ok=True)
    total = count_trigger_frames(Path(target)) if Path(target).is_file() else len(getattr(source, "images", []))
    stages, sinks, parts = build(_run_options(args, out, video))
    only = getattr(args, "only", None)
    if only is not None:
        stages = _capture_mode_stages(only, source, stages, args)
    stats = run_pipeline([source], stages, sinks, mode="every", progress_total=total, progress=not args.quiet)
    damage = getattr(source, "error", None)
    stats["session_error"] = damage
    stats["accuracy"] = parts["accuracy"].summary()
    _add_skeleton_lag(stats, parts)
    stats["outputs"] = [p.name for p in parts["results"].written] + ([Path(video).name] if video else [])
    write_stats(out, stats)
    if damage:
        print(f"livecap: {damage}", file=sys.stderr)
    return stats


def _capture_mode_stages(mode: str, source, stages: list, args) -> list:
    """Swap the skeleton stage for the IMU-only or fused one (``replay --only``)."""
    from live.imu.stage import build_stages

    suit = [s for s in source.streams() if s.kind == "serial"]
    if mode in ("imu", "fused") and not suit:
        raise UserInputError(f"--only {mode} needs a session with an IMU suit stream")
    depth_stage = next((s for s in stages if getattr(s, "name", "") == "skeleton"), None)
    if mode in ("depth", "fused") and depth_stage is None:
        raise UserInputError(f"--only {mode} needs the skeleton model (models/weights/skeleton.onnx)")
    if mode == "depth":
        return stages
    if mode == "fused" and depth_stage.lag_s > 0:
        raise UserInputError("--only fused works with the online skeleton (--lag 0): the suit's samples "
                             "would meet depth skeletons from earlier frames")
    capture = build_stages(mode, calibration=args.calibration, depth_stage=depth_stage,
                           stream_meta=suit[0].meta if suit else None)
    rest = [s for s in stages if getattr(s, "name", "") not in ("skeleton", "cloud")]
    return capture + rest


def _add_skeleton_lag(stats: dict, parts: dict) -> None:
    """The latency a lagging temporal model adds on top of the measured ones (it estimates an
    earlier frame, so no stage timing shows it)."""
    if "skeleton" in parts:
        stats["skeleton_lag_ms"] = round(1000 * parts["skeleton"].lag_s, 1)


def _print_summary(stats: dict) -> None:
    rows = [("frames", str(stats["frames"])), ("fps", f"{stats['fps']:.1f}")]
    for name, st in stats["stages"].items():
        lat = st["latency_ms"]
        if lat.get("count"):
            rows.append((f"{name} p50/p95 ms", f"{lat['p50']:.2f} / {lat['p95']:.2f}"))
    acc = stats.get("accuracy") or {}
    if acc.get("frames_scored"):
        rows.append(("skeleton MPJPE / PA-MPJPE", f"{acc['mpjpe_mm']:.1f} / {acc['pa_mpjpe_mm']:.1f} mm "
                     f"({acc['frames_scored']} frames with ground truth)"))
    e2e = stats["end_to_end"]["latency_ms"]
    if e2e.get("count"):
        rows.append(("end-to-end p50/p95 ms", f"{e2e['p50']:.2f} / {e2e['p95']:.2f}"))
    if stats.get("skeleton_lag_ms"):
        rows.append(("skeleton lag", f"{stats['skeleton_lag_ms']:.0f} ms (--lag: each skeleton is of an earlier "
                     "frame; add it to the latencies above)"))
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")


def cmd_demo(args) -> int:
    session = args.session or DEMO_SESSION
    if not Path(session).is_file():
        raise UserInputError(f"the demo session is missing: {session} (regenerate it with `livecap synth`, see README)")
    video = None if args.no_video else args.out / "demo.mp4"
    stats = _replay(str(session), args, args.out, video=video)
    print(f"livecap demo: replayed {Path(session).name}")
    _print_summary(stats)
    print(f"  wrote {args.out / 'stats.json'}" + "".join(f", {args.out / n}" for n in stats["outputs"]))
    return 0


def cmd_replay(args) -> int:
    stats = _replay(args.session, args, args.out)
    if not args.quiet:
        _print_summary(stats)
    return 0


def _open_sources(specs: list[str]):
    from live.core.sources import open_source

    return [open_source(s) for s in specs]


def cmd_record(args) -> int:
    sources = _open_sources(args.source)
    stats = run_pipeline(sources, [], [], mode="latest", record=args.out, seconds=args.seconds,
                         progress=not args.quiet)
    print(f"livecap record: {stats['recorded_messages']} messages into {args.out}")
    return 0


def cmd_run(args) -> int:
    from live.app.assemble import build

    sources = _open_sources(args.source)
    stages, sinks, parts = build(_run_options(args, args.out))
    stats = run_pipeline(sources, stages, sinks, mode="latest", record=args.record,
                         seconds=args.seconds, progress=not args.quiet)
    _add_skeleton_lag(stats, parts)
    write_stats(args.out, stats)
    _print_summary(stats)
    return 0


def cmd_export(args) -> int:
    if args.foxglove is not None:
        from live.io.foxglove import export_foxglove

        res = export_foxglove(args.session, args.foxglove, results_dir=args.results, max_points=args.max_points)
        print(f"livecap export: {sum(res.messages.values())} Foxglove messages -> {res.path}")
        if res.skipped:
            print(f"  not exported (no Foxglove schema): {res.skipped}")
        if res.error:
            print(f"livecap export: {res.error}", file=sys.stderr)
        return 0
    if args.out is None:
        raise UserInputError("export needs --out DIR (npz files) or --foxglove OUT.mcap")
    from live.io.export import export_session

    written, damage = export_session(args.session, args.out)
    for p in written:
        print(p)
    if damage:
        print(f"livecap export: {damage}", file=sys.stderr)
    return 0


def cmd_info(args) -> int:
    from live.io.session import SessionReader

    reader = SessionReader(args.session)
    counts: dict[str, int] = {}
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for stream, frame in reader.frames():
        counts[stream.name] = counts.get(stream.name, 0) + 1
        first.setdefault(stream.name, frame.t_ns)
        last[stream.name] = frame.t_ns
    info = reader.info
    doc = {
        "path": str(args.session), "livecap_version": info.version, "start_wall_time_ns": info.start_wall_time_ns,
        "streams": [{"name": s.name, "kind": s.kind, "messages": counts.get(s.name, 0),
                     "duration_s": round((last.get(s.name, 0) - first.get(s.name, 0)) / 1e9, 3), "meta": s.meta}
                    for s in info.streams],
        "extra": info.extra, "attachments": sorted(reader.attachments), "damage": reader.error,
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{args.session}: livecap {info.version or '?'} session")
    for s in doc["streams"]:
        print(f"  {s['kind']:<6} {s['name']:<12} {s['messages']:>7} messages  {s['duration_s']:8.2f} s")
    if doc["attachments"]:
        print(f"  attachments: {', '.join(doc['attachments'])}")
    if reader.error:
        print(f"  damaged: {reader.error}")
    return 0


def cmd_devices(args) -> int:
    from drivers.discovery import format_device_list, list_devices

    print(format_device_list(list_devices()))
    return 0


def cmd_synth(args) -> int:
    import math

    from sim.synth import CameraPlacement, SynthOptions, synthesize

    if not Path(args.motion).is_file():
        raise UserInputError(f"no such motion file: {args.motion}")
    opts = SynthOptions(motion=args.motion, body=args.body, camera=args.camera, seconds=args.seconds,
                        fps=args.fps, seed=args.seed, imu=args.imu, start_s=args.start, noise=not args.no_noise,
                        max_range_m=args.max_range,
                        placement=CameraPlacement(args.distance, args.height, math.radians(args.yaw)))
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


def cmd_render(args) -> int:
    import tempfile

    if args.out.suffix.lower() != ".mp4":
        raise UserInputError(f"--out must be an .mp4 file, not {args.out}")
    with tempfile.TemporaryDirectory(prefix="livecap-render-") as tmp:
        stats = _replay(args.session, args, Path(tmp), video=args.out)
    print(f"livecap render: {stats['frames']} frames -> {args.out}")
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


def cmd_calibrate(args) -> int:
    import threading

    from live.imu.calibration import CalibrationCollector
    from live.imu.layout import load_suit_layout
    from live.core.skeleton import default_rest_joints
    from live.core.sources import open_source

    source = open_source(args.source)
    collector = CalibrationCollector(load_suit_layout(args.layout), args.pose,
                                     default_rest_joints(args.height), hold_s=2.0)
    stop = threading.Event()
    found = []

    def emit(packet) -> None:
        if getattr(packet, "decoded", False) and not found:
            cal = collector.feed(packet)
            if cal is not None:
                found.append(cal)
                stop.set()

    print(f"livecap calibrate: hold a {args.pose} still for 2 s ...", file=sys.stderr)
    timer = threading.Timer(args.timeout, stop.set)
    timer.daemon = True
    timer.start()
    try:
        source.run(emit, stop)
    finally:
        timer.cancel()
    if not found:
        raise UserInputError(f"no still {args.pose} held for 2 s within {args.timeout:g} s")
    found[0].save(args.out)
    print(f"livecap calibrate: saved {args.out}")
    return 0
