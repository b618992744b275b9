"""The ``livecap batch`` command line. Each item runs `livecap replay` or `livecap synth` with the
options given here: the tables below declare those options once, for the parser and for the
item's command line (``passthrough``)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from live.app import arguments as arg

#: (flag, argparse keywords) of the replay options a batch passes on to every session's replay.
REPLAY_OPTIONS: tuple[tuple[str, dict], ...] = (
    ("--avatar", {"help": "retarget onto this avatar (a body preset, a body .npz, a mesh, a VRM): see `livecap replay`"}),
    ("--retarget", {"choices": ["analytic", "learned"], "help": "retargeter (default analytic)"}),
    ("--no-foot-lock", {"action": "store_true", "help": "do not lock feet in contact with the floor"}),
    ("--hand-ik", {"action": "store_true", "help": "hands reach where the performer's hands reach (scaled)"}),
    ("--model", {"type": Path, "help": "skeleton model (.onnx; default: the shipped one)"}),
    ("--threads", {"type": arg.threads, "help": "onnxruntime threads per session (default 1); also the CPUs each "
                   "Ray task asks for"}),
    ("--lag", {"type": arg.lag, "metavar": "FRAMES", "help": "skeleton lag in frames (0 or 2): see `livecap replay`"}),
    ("--camera-height", {"type": arg.camera_height, "metavar": "M",
                         "help": "the depth camera's height above the floor, m, used with the camera's IMU, for "
                         "depth without a camera pose that cannot see the floor: see `livecap replay`"}),
    ("--only", {"choices": ["depth", "imu", "fused"], "help": "with depth + IMU sessions: depth only, suit only, or fused"}),
    ("--calibration", {"type": Path, "help": "suit calibration (from `livecap calibrate`)"}),
    ("--bvh-names", {"choices": ["avatar", "canonical"], "help": "avatar.bvh's joint names (default avatar)"}),
)

#: Options that may name a file.
FILE_OPTIONS = frozenset({"--avatar", "--model", "--calibration"})

#: The same for the synth options every item of a synthetic data set shares.
SYNTH_OPTIONS: tuple[tuple[str, dict], ...] = (
    ("--seconds", {"type": arg.positive_seconds, "help": "length of each item (default: the whole clip)"}),
    ("--start", {"type": arg.start_seconds, "help": "start this many seconds into each clip"}),
    ("--fps", {"type": arg.fps, "help": "sensor rate (default: the camera preset's)"}),
    ("--imu", {"choices": ["xbus", "lines"], "help": "also stream a simulated IMU suit"}),
    ("--camera-imu", {"action": "store_true", "help": "also stream the camera's own IMU"}),
    ("--distance", {"type": arg.camera_distance, "help": "camera distance from the performance centre, m (default 3)"}),
    ("--height", {"type": arg.camera_height, "help": "camera height above the floor, m (default 1.2)"}),
    ("--yaw", {"type": arg.angle_degrees, "help": "camera angle around the performer, degrees (default 0)"}),
    ("--pitch", {"type": float, "metavar": "DEG", "help": "camera tilt, degrees, negative looks down"}),
    ("--posture", {"choices": ["clip", "in-place", "seated", "crouching", "knee-up", "kick"], "help": "see `livecap synth`"}),
    ("--floor", {"choices": ["seen", "none"], "help": "none: the sensor returns nothing from the floor"}),
    ("--hide-extrinsics", {"action": "store_true", "help": "the depth stream carries an identity camera_to_world"}),
    ("--no-noise", {"action": "store_true", "help": "ideal depth (no sensor noise)"}),
    ("--max-range", {"type": arg.depth_range, "help": "depth threshold in metres"}),
)


def _dest(flag: str) -> str:
    return flag.lstrip("-").replace("-", "_")


def passthrough(args: argparse.Namespace, table: tuple[tuple[str, dict], ...]) -> list[str]:
    """The options of ``table`` that were given, as command-line arguments (defaults left out, so
    an item's command line is the one a person would type)."""
    out: list[str] = []
    for flag, spec in table:
        value = getattr(args, _dest(flag), None)
        if spec.get("action") == "store_true":
            out += [flag] if value else []
        elif value is not None:
            # A file is given by its absolute path: workers may run in another folder.
            text = os.path.abspath(value) if flag in FILE_OPTIONS and Path(value).is_file() else str(value)
            out += [flag, text]
    return out


def _add_execution_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output folder (a local path or an fsspec URL the workers reach)")
    p.add_argument("--ray", default=None, metavar="local|auto|ADDRESS",
                   help="run on Ray (the cluster extra): a local Ray on this machine's cores (the default when Ray "
                   "is installed), the running cluster (auto), or the cluster at ADDRESS (HOST:6379, ray://HOST:10001)")
    p.add_argument("--workers", type=arg.number(int, low=1, high=4096), default=None, metavar="N",
                   help="without --ray: N local worker processes (1: one after the other in this process); "
                   "with --ray local: N CPUs for the local Ray (default: this machine's cores)")
    p.add_argument("--retries", type=arg.number(int, low=0, high=100), default=3,
                   help="run an item again when its worker process dies, up to this many times (default 3)")
    p.add_argument("--shard", default=None, metavar="I/N", help="only items I, I+N, I+2N, ... (0 <= I < N): "
                   "split a batch between independent jobs; records go to batch-shard-I-of-N.json")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no summary")


def add_batch_parser(sub) -> None:
    """``livecap batch replay|synth`` on the CLI's subparsers."""
    p = sub.add_parser("batch", help="replay many sessions, or write a synthetic data set, on Ray or local processes",
                       description="Run many sessions through `livecap replay`, or many items through `livecap synth`, "
                       "on Ray (a local Ray or a cluster; the cluster extra) or a local process pool. Outputs are "
                       "those of the single commands, byte for byte; DIR/batch.json records every item. A batch run "
                       "again skips the items already made with the same inputs, models and options.")
    what = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    r = what.add_parser("replay", help="replay sessions (every frame, deterministic) into DIR/<name>/",
                        description="Replay each session or depth folder at --speed max into DIR/<name>/ (name: the "
                        "file's name without .mcap), exactly as `livecap replay` writes it.")
    r.add_argument("sessions", nargs="*", help=".mcap sessions or depth folders (paths or URLs)")
    r.add_argument("--list", type=Path, default=None, metavar="FILE",
                   help="also the sessions named in FILE, one a line (# comments; relative to FILE's folder)")
    for flag, spec in REPLAY_OPTIONS:
        r.add_argument(flag, default=None, **spec)
    _add_execution_options(r)
    s = what.add_parser("synth", help="write a synthetic data set: clips x bodies x cameras x seeds",
                        description="Write DIR/<clip>__<body>__<camera>__s<seed>.mcap for every combination, each "
                        "exactly as `livecap synth` writes it with the same options (same seed, same bytes).")
    s.add_argument("--motion", nargs="+", required=True, help="BVH clips, or folders of them")
    s.add_argument("--body", nargs="+", default=["performer"], help="body presets, body .npz files or anny: specs "
                   "(default: performer)")
    s.add_argument("--camera", nargs="+", default=["oak-d"], help="camera presets (default: oak-d)")
    s.add_argument("--seeds", default="0", metavar="N|A-B|A,B,...",
                   help="noise seeds: N = 0..N-1, A-B = A..B, or a list (default: 0)")
    for flag, spec in SYNTH_OPTIONS:
        s.add_argument(flag, default=None, **spec)
    _add_execution_options(s)
