"""The pipeline commands (demo, replay, render, record, run): each takes the parsed arguments and
returns an exit code. The other commands are in session_commands, device_commands and tool_commands."""

from __future__ import annotations

import sys
from pathlib import Path

from live.app.running import (
    DEMO_SESSION,
    EXIT_DATA_LOSS,
    count_trigger_frames,
    parse_speed,
    run_pipeline,
    write_stats,
)
from live.app.sources import open_replay, open_source
from live.core.errors import UserInputError
from live.core.report import p50_p95


def _run_options(args, out: Path, video: Path | None = None, sources=()):
    from live.app.assemble import RunOptions, take_fps

    return RunOptions(out=out, fps=take_fps(sources), avatar=args.avatar, retarget=args.retarget, foot_lock=not args.no_foot_lock,
                      hand_ik=args.hand_ik, model=args.model, threads=args.threads, lag=args.lag, vmc=args.vmc,
                      contacts=getattr(args, "contacts", None) or "auto",
                      camera_height=getattr(args, "camera_height", None),
                      check_extrinsics=not getattr(args, "trust_extrinsics", False),
                      vmc_rate=args.vmc_rate, vmc_mtu=getattr(args, "vmc_mtu", None), viewer=args.viewer, video=video or args.video,
                      bvh_names=getattr(args, "bvh_names", "avatar"))


def replay_speed(args) -> str:
    """--speed as given; unset: as fast as possible, but recorded timing when frames go to a VMC
    receiver (it applies each bundle as it arrives: a 10 s take sent in 1 s plays in 1 s)."""
    given = getattr(args, "speed", None)
    if given is not None:
        return given
    return "1" if getattr(args, "vmc", None) else "max"


def _replay(target: str, args, out: Path, video: Path | None = None) -> dict:
    from live.app.assemble import build

    speed = parse_speed(replay_speed(args))
    source = open_replay(target, speed=speed)
    out.mkdir(parents=True, exist_ok=True)
    total = count_trigger_frames(Path(target)) if Path(target).is_file() else len(getattr(source, "images", []))
    stages, sinks, parts = build(_run_options(args, out, video, [source]))
    for stream in source.streams() if hasattr(source, "streams") else []:
        if stream.kind == "gt" and "camera_to_world" in stream.meta:  # extrinsics withheld from the depth
            parts["accuracy"].set_true_camera(stream.meta["camera_to_world"])
    if "retarget" in parts:
        _performer_body(source, parts["retarget"])
    only = getattr(args, "only", None)
    if only is None and _suit_without_camera(source):
        only = "imu"  # an imported suit recording: nothing else would make a skeleton
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


def _performer_body(source, stage) -> None:
    """A synthetic session's true body for the performer's self-contacts (the retarget stage
    fits a template to the estimated skeleton otherwise)."""
    reader = getattr(source, "reader", None)
    data = reader.body_npz() if reader is not None and stage.contacts else None
    if data is None:
        return
    from live.body.library import body_from_npz_bytes
    from live.core.errors import FormatError

    try:
        stage.set_performer_body(body_from_npz_bytes(data))
    except FormatError:
        pass  # a damaged attachment: the fitted template serves


def _exit_for(stats: dict) -> int:
    """EXIT_DATA_LOSS when a replayed session had damaged regions the reader skipped, or a depth
    folder images it could not use."""
    damaged = any(src.get("counters", {}).get("damaged_regions") or src.get("counters", {}).get("bad_images")
                  for src in stats["sources"].values())
    return EXIT_DATA_LOSS if damaged else 0


def _suit_without_camera(source) -> bool:
    """A session with a suit stream and no depth stream (``livecap import``)."""
    from live.imu.stage import is_suit_stream

    streams = source.streams() if hasattr(source, "streams") else []
    return any(is_suit_stream(s) for s in streams) and not any(s.kind == "depth" for s in streams)


def _capture_mode_stages(mode: str, source, stages: list, args) -> list:
    """Swap the skeleton stage for the IMU-only or fused one (``replay --only``)."""
    from live.imu.stage import build_stages, is_suit_stream

    suit = [s for s in source.streams() if is_suit_stream(s)]
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
    for stage in rest:
        if getattr(stage, "name", "") == "retarget":
            stage.estimated = False  # the suit's or the fused skeleton, not the depth stage's estimate
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
            rows.append((f"{name} p50/p95 ms", p50_p95(lat)))
    acc = stats.get("accuracy") or {}
    if acc.get("frames_scored"):
        rows.append(("skeleton MPJPE / PA-MPJPE", f"{acc['mpjpe_mm']:.1f} / {acc['pa_mpjpe_mm']:.1f} mm "
                     f"({acc['frames_scored']} frames with ground truth)"))
    e2e = stats["end_to_end"]["latency_ms"]
    if e2e.get("count"):
        rows.append(("end-to-end p50/p95 ms", p50_p95(e2e)))
    details = (stats["stages"].get("skeleton") or {}).get("details") or {}
    if details.get("given_pose_turned_deg"):
        seen = "floor" if details.get("up_source") == "given+floor" else "walls"
        rows.append(("camera pose", f"the given pose is {details['given_pose_turned_deg']:.1f} degrees off the {seen} "
                     "in view: solved in the room's up, reported in the given world (--trust-extrinsics: as given)"))
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
    return _exit_for(stats)


def cmd_replay(args) -> int:
    stats = _replay(args.session, args, args.out)
    if not args.quiet:
        _print_summary(stats)
    return _exit_for(stats)


def _open_sources(specs: list[str]):
    return [open_source(s) for s in specs]


def _report_recording(recording: dict, command: str) -> int:
    """Print what a recording went through; EXIT_DATA_LOSS when a source died or a stream got
    no data (the gaps are stored in the session too)."""
    for s in recording["streams"]:
        refused = f", {s['refused']} refused (over the size limits)" if s["refused"] else ""
        print(f"  {s['kind']:<6} {s['name']:<12} {s['messages']:>7} messages  {s['seconds']:8.2f} s{refused}")
    for line in recording["warnings"]:
        print(f"  note: {line}")
    for line in recording["problems"]:
        print(f"livecap {command}: {line}", file=sys.stderr)
    return EXIT_DATA_LOSS if recording["problems"] else 0


def cmd_record(args) -> int:
    sources = _open_sources(args.source)
    stats = run_pipeline(sources, [], [], mode="latest", record=args.out, seconds=args.seconds,
                         progress=not args.quiet)
    print(f"livecap record: {stats['recorded_messages']} messages into {args.out}")
    return _report_recording(stats["recording"], "record")


def cmd_run(args) -> int:
    from live.app.assemble import build

    sources = _open_sources(args.source)
    stages, sinks, parts = build(_run_options(args, args.out, sources=sources))
    stats = run_pipeline(sources, stages, sinks, mode="latest", record=args.record,
                         seconds=args.seconds, progress=not args.quiet)
    _add_skeleton_lag(stats, parts)
    write_stats(args.out, stats)
    _print_summary(stats)
    if args.record is not None:
        print(f"  recorded {stats['recorded_messages']} messages into {args.record}")
        return _report_recording(stats["recording"], "run")
    return 0


def cmd_render(args) -> int:
    import tempfile

    if args.out.suffix.lower() != ".mp4":
        raise UserInputError(f"--out must be an .mp4 file, not {args.out}")
    with tempfile.TemporaryDirectory(prefix="livecap-render-") as tmp:
        stats = _replay(args.session, args, Path(tmp), video=args.out)
    print(f"livecap render: {stats['frames']} frames -> {args.out}")
    return _exit_for(stats)
