"""Assemble stages and sinks from command-line options (one place for demo, replay and run)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from live.core import assets
from live.core.errors import UserInputError
from live.io.results import DEFAULT_FPS, ResultsWriter
from live.pipeline.stages import CloudStage, RetargetStage

DEFAULT_SKELETON_MODEL = assets.weight("skeleton.onnx")


@dataclass
class RunOptions:
    out: Path
    avatar: str | None = None
    retarget: str = "analytic"
    foot_lock: bool = True
    hand_ik: bool = False
    #: Self-contacts kept on the avatar: "auto" (on when the avatar has a mesh), "on", "off".
    contacts: str = "auto"
    model: Path | None = None
    threads: int = 1
    lag: int = 0
    #: The camera's height above the floor (m), for depth without a camera pose and no floor in view.
    camera_height: float | None = None
    #: Check a camera pose the depth carries against the floor and walls in view (else taken as is).
    check_extrinsics: bool = True
    vmc: str | None = None
    vmc_rate: float = 60.0
    vmc_mtu: int | None = None
    viewer: str | None = None
    video: Path | None = None
    #: The take's frame rate (the depth stream's, see take_fps): avatar.bvh's Frame Time and the
    #: video's rate. None: avatar.bvh from the frames' timestamps, the video at DEFAULT_FPS.
    fps: float | None = None
    #: avatar.bvh's joint names: "avatar" (the avatar file's own bone names, when it has them) or
    #: "canonical" (the 22 canonical names).
    bvh_names: str = "avatar"


def parse_host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); an IPv6 address in brackets: ``[::1]:39539``."""
    host, sep, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not port.isdigit() or not host:
        raise UserInputError(f"--vmc wants HOST:PORT (e.g. 127.0.0.1:39539 or [::1]:39539), not {text!r}")
    return host, int(port)


def take_fps(sources) -> float | None:
    """The take's frame rate: the first depth stream's ``fps`` (session metadata, a depth folder's
    intrinsics.json, a camera's mode); None when no source says. Replays of a session and of its
    depth folder get the same."""
    for source in sources:
        for stream in source.streams() if hasattr(source, "streams") else []:
            fps = stream.meta.get("fps") if stream.kind == "depth" else None
            if isinstance(fps, int | float) and not isinstance(fps, bool) and 0 < fps < float("inf"):
                return float(fps)
    return None


def build(opts: RunOptions) -> tuple[list, list, dict]:
    """(stages, sinks, parts) for a run; parts holds named stages/sinks the caller reports on."""
    parts: dict = {}
    stages: list = []
    model = opts.model or DEFAULT_SKELETON_MODEL
    if opts.model is not None and not Path(opts.model).is_file():
        raise UserInputError(f"no such skeleton model: {opts.model}")
    if Path(model).is_file():
        from models.skeleton.runtime import SkeletonStage

        stages.append(SkeletonStage(model_path=model, threads=opts.threads, lag=opts.lag,
                                    camera_height_m=opts.camera_height, check_extrinsics=opts.check_extrinsics))
        parts["skeleton"] = stages[-1]
    elif opts.lag:
        raise UserInputError("--lag needs the skeleton model (models/weights/skeleton.onnx)")
    else:
        # No skeleton model: the pipeline still turns every depth frame into a world cloud.
        stages.append(CloudStage())
    vmc_address = parse_host_port(opts.vmc) if opts.vmc else None
    body = None
    # VMC carries an avatar's bones: without one there would be nothing to send.
    avatar = opts.avatar or ("default" if vmc_address is not None else None)
    if avatar:
        body = _load_avatar(avatar)
        skin = opts.viewer is not None or opts.video is not None
        stages.append(RetargetStage(body, kind=opts.retarget, foot_lock=opts.foot_lock, hand_ik=opts.hand_ik,
                                    skin=skin, contacts=opts.contacts))
        parts["avatar"] = body
        parts["retarget"] = stages[-1]
    names = body.joint_names if body is not None and opts.bvh_names == "avatar" else None
    results = ResultsWriter(opts.out, avatar_rest_joints=None if body is None else body.rest_joints, fps=opts.fps,
                            avatar_joint_names=names)
    parts["results"] = results
    from live.pipeline.accuracy import AccuracySink

    accuracy = AccuracySink()
    parts["accuracy"] = accuracy
    sinks: list = [results, accuracy]
    if vmc_address is not None:
        from live.outputs.vmc import VmcSink

        host, port = vmc_address
        sinks.append(VmcSink(host, port, rate_hz=opts.vmc_rate or None, max_bundle_bytes=opts.vmc_mtu,
                             avatar_rest_joints=None if body is None else body.rest_joints,
                             extra_bones=() if body is None else body.extra_bones,
                             rig=None if body is None else body.rig))
        if not opts.avatar:  # said once the address is known good: a mistake stays one line
            print("livecap: --vmc without --avatar: sending the default avatar (choose one with --avatar)",
                  file=sys.stderr, flush=True)
    if opts.viewer:
        from live.outputs.viewer import RerunSink

        sinks.append(RerunSink.from_spec(opts.viewer, avatar_faces=None if body is None else body.faces))
    if opts.video:
        from live.outputs.render import VideoSink

        sinks.append(VideoSink(opts.video, fps=opts.fps or DEFAULT_FPS, avatar_faces=None if body is None else body.faces,
                               avatar_look=None if body is None else body.look))
    return stages, sinks, parts


def _load_avatar(spec: str):
    from live.body.avatar import load_avatar

    return load_avatar(spec)
