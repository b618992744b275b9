"""The ``livecap`` command line. Every user mistake ends in one line and a non-zero exit."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from live import __version__
from live.app import arguments as arg
from live.core.errors import LivecapError
from live.core.text import PrintableWriter, printable, printable_text

EXIT_USER_ERROR = 2
LAG_HELP = ("skeleton lag in frames at 30 fps: 0 = online (default); 2 = the shipped smoother temporal model, "
            "each skeleton 67 ms later with ~40 %% less jitter")
#: Exit status when the machine, not the user, is at fault (out of memory): still one line.
EXIT_FAILURE = 1
VMC_MTU = arg.number(int, low=256, high=65507)  # live.outputs.vmc MIN_BUNDLE_BYTES..MAX_BUNDLE_BYTES
#: Exit status when the reader of stdout went away (``livecap info X --json | head``): 128 + SIGPIPE,
#: what a shell reports for `cat` in the same place, so `set -o pipefail` scripts see it as usual.
EXIT_BROKEN_PIPE = 141


class LivecapParser(argparse.ArgumentParser):
    """argparse with one-line errors: ``livecap CMD: error: ...`` and exit status 2 (the usage
    is a --help away)."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {printable(message)} (see {self.prog} --help)\n")


class PrintableFormatter(logging.Formatter):
    """Log lines with escape sequences shown as text (live.core.text.printable_text)."""

    def format(self, record: logging.LogRecord) -> str:
        return printable_text(super().format(record))


def _add_replay_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speed", type=arg.speed, default=None,
                   help="1.0 = recorded timing, 2 = twice as fast, max = as fast as possible (default; 1.0 with "
                   "--vmc, so receivers get the take at its own pace)")
    _add_output_options(p)


def _add_output_options(p: argparse.ArgumentParser, avatar_default: str | None = None) -> None:
    p.add_argument("--avatar", default=avatar_default, help="retarget onto this avatar: a body preset, a body .npz, "
                   "a T-pose mesh or point cloud (OBJ/PLY/GLB), or anny:k=v,... (train extra)")
    p.add_argument("--retarget", default="analytic", choices=["analytic", "learned"], help="retargeter (default analytic)")
    p.add_argument("--no-foot-lock", action="store_true", help="do not lock feet in contact with the floor")
    p.add_argument("--hand-ik", action="store_true", help="hands reach where the performer's hands reach (scaled)")
    p.add_argument("--contacts", choices=["on", "off"], default=None,
                   help="keep the performer's self-contacts (hands together, on hips, head, thighs) on the avatar "
                   "and its hands and forearms out of its body (default: on when the avatar has a mesh)")
    p.add_argument("--model", type=Path, default=None, help="skeleton model (.onnx; default: the shipped one)")
    p.add_argument("--threads", type=arg.threads, default=1, help="onnxruntime threads for the skeleton model "
                   f"(default 1, at most {arg.MAX_THREADS})")
    p.add_argument("--lag", type=arg.lag, default=0, metavar="FRAMES", help=LAG_HELP)
    p.add_argument("--camera-height", type=arg.camera_height, default=None, metavar="M",
                   help="the depth camera's height above the floor in metres, for depth without a camera pose "
                   "when the floor is not in view (a performer seated at a desk); used once the camera's IMU "
                   "gives up (an OAK streams it): otherwise the floor is guessed under the performer, for a "
                   "standing person")
    p.add_argument("--trust-extrinsics", action="store_true",
                   help="take a camera pose the depth carries as it is; by default it is checked against the floor "
                   "and walls in view and, where it is off by more than a few degrees or centimetres, the body is "
                   "solved in the room's up (the skeleton is reported in the given world either way)")
    p.add_argument("--vmc", default=None, metavar="HOST:PORT", help="send the avatar over the VMC protocol "
                   "(e.g. 127.0.0.1:39539); off unless given")
    p.add_argument("--vmc-rate", type=arg.vmc_rate, default=60.0, help="VMC send-rate limit in Hz (0 = every frame)")
    p.add_argument("--vmc-mtu", type=VMC_MTU, default=None, metavar="BYTES", help="split each VMC frame into bundles "
                   "of at most BYTES (e.g. 1400 over Wi-Fi or Ethernet; default: one bundle per frame, ~1,850 bytes)")
    p.add_argument("--viewer", nargs="?", const="spawn", default=None, metavar="spawn|web[:ADDR]|save:FILE.rrd",
                   help="show the live viewer (Rerun; the viewer extra): spawn the native viewer, serve the web "
                   "viewer on 127.0.0.1 (web:0.0.0.0 serves the local network), or save a recording")
    p.add_argument("--video", type=Path, default=None, help="also write a rendered video (.mp4)")
    p.add_argument("--bvh-names", choices=["avatar", "canonical"], default="avatar",
                   help="avatar.bvh's joint names: the avatar file's own bones (default, when a VRM / glTF "
                   "avatar has them) or the 22 canonical names")
    _add_force(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_force(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", action="store_true", help="overwrite output files that exist")


def _retarget_eval_arguments(e: argparse.ArgumentParser) -> None:
    """The options ``eval retarget`` and ``eval contacts`` share: a motion moved between two bodies."""
    e.add_argument("--motion", required=True, help="a BVH clip")
    e.add_argument("--source-body", default="performer", help="the performer's body (default: performer)")
    e.add_argument("--target-body", default="default", help="the avatar's body (default: default)")
    e.add_argument("--from", dest="from_", choices=["skeleton", "depth"], default="skeleton",
                   help="start from ground-truth skeletons or run the whole chain from the virtual camera")
    e.add_argument("--retarget", choices=["analytic", "learned"], default="analytic")
    e.add_argument("--max-frames", type=arg.max_frames, default=None)
    e.add_argument("--lag", type=arg.lag, default=0, metavar="FRAMES", help="with --from depth: " + LAG_HELP)
    e.add_argument("--json", action="store_true", help="machine-readable output")


def build_parser() -> argparse.ArgumentParser:
    parser = LivecapParser(prog="livecap", description="Open, ROS-free live human capture: depth cameras and "
                                     "IMU suits -> 3D skeleton -> retargeted avatar, live.")
    parser.add_argument("--version", action="version", version=f"livecap {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log warnings and details to stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("demo", help="replay the bundled session through the pipeline and write the results",
                       description="Replay the bundled demo session through the whole pipeline; writes stats.json "
                       "and the result files into --out.")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default: demo_out)")
    p.add_argument("--session", type=Path, default=None, help="another session to use instead of the bundled one")
    p.add_argument("--speed", type=arg.speed, default=None,
                   help="1.0 = recorded timing, max = as fast as possible (default; 1.0 with --vmc, so receivers "
                   "get the take at its own pace)")
    p.add_argument("--no-video", action="store_true", help="skip writing demo.mp4")
    _add_output_options(p, avatar_default="default")

    p = sub.add_parser("replay", help="replay a session or a depth PNG folder through the pipeline",
                       description="Replay SESSION.mcap (or a folder of 16-bit depth PNGs with intrinsics.json) "
                       "through the pipeline and write DIR/stats.json and the result files.")
    p.add_argument("session", help="a .mcap session or a depth folder")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--only", choices=["depth", "imu", "fused"], default=None,
                   help="with a depth + IMU session: skeleton from depth only, the suit only, or both fused")
    p.add_argument("--calibration", type=Path, default=None, help="suit calibration (from `livecap calibrate`)")
    _add_replay_options(p)

    p = sub.add_parser("record", help="record sources into a session file",
                       description="Record one or more sources (e.g. a camera and a suit) into an MCAP session.")
    p.add_argument("--source", action="append", required=True, help="source string (repeatable): oak, oak:MXID, "
                   "realsense, serial:PORT:xbus|lines[:baud], replay:S.mcap, folder:DIR, sim:CLIP.bvh")
    p.add_argument("--out", type=Path, required=True, help="session file to write (.mcap)")
    p.add_argument("--seconds", type=arg.positive_seconds, default=None,
                   help="stop after this many seconds (default: Ctrl-C)")
    _add_force(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("run", help="run the live pipeline on sources",
                       description="Run the live pipeline on one or more sources (latest-frame mode: bounded latency).")
    p.add_argument("--source", action="append", required=True, help="source string (repeatable), see `record`")
    p.add_argument("--out", type=Path, default=Path("run_out"), help="folder for stats.json and results")
    p.add_argument("--record", type=Path, default=None, help="also record the sources into this MCAP file")
    p.add_argument("--seconds", type=arg.positive_seconds, default=None,
                   help="stop after this many seconds (default: Ctrl-C)")
    _add_output_options(p)

    p = sub.add_parser("export", help="export a session's streams as .npz files",
                       description="Write one .npz per stream (gt.npz, depth_<s>.npz, serial_<d>.npz, imu_<d>.npz).")
    p.add_argument("session", type=Path)
    p.add_argument("--out", type=Path, default=None, help="output folder for the .npz files")
    p.add_argument("--foxglove", type=Path, default=None, metavar="OUT.mcap",
                   help="write a Foxglove-ready MCAP (PointCloud, SceneUpdate, FrameTransforms) instead")
    p.add_argument("--results", type=Path, default=None, help="with --foxglove: a replay's output folder "
                   "(skeleton.npz, avatar.npz) to include")
    p.add_argument("--max-points", type=arg.max_points, default=None,
                   help="with --foxglove: subsample clouds to this many points")
    _add_force(p)

    p = sub.add_parser("info", help="describe a session file", description="Print a session's streams, "
                       "message counts, duration and metadata.")
    p.add_argument("session", type=Path)
    p.add_argument("--json", action="store_true", help="machine-readable output")

    p = sub.add_parser("render", help="render a session or depth folder to a video",
                       description="Replay SESSION|FOLDER through the pipeline and write a video: the depth image with "
                       "the skeleton drawn over it beside the shaded avatar, with timing and confidence captions.")
    p.add_argument("session", help="a .mcap session or a depth folder")
    p.add_argument("--out", type=Path, required=True, help="video file to write (.mp4)")
    p.add_argument("--speed", type=arg.speed, default="max", help=argparse.SUPPRESS)
    _add_output_options(p, avatar_default="default")

    p = sub.add_parser("synth", help="write a synthetic session (a motion on a body, seen by a virtual camera)",
                       description="Render a BVH motion on a body with the virtual depth camera and write a session "
                       "exactly like a recorded one, plus ground truth (joints, rotations, body). Same seed, same bytes.")
    p.add_argument("--motion", required=True, help="a BVH clip")
    p.add_argument("--body", default="performer", help="body preset, body .npz, or anny:k=v,... (default: performer)")
    p.add_argument("--out", type=Path, required=True, help="session file to write (.mcap)")
    p.add_argument("--camera", default="oak-d", help="oak-d (default), oak-d-pro, kinect-v1")
    p.add_argument("--seconds", type=arg.positive_seconds, default=None, help="length (default: the whole clip)")
    p.add_argument("--start", type=arg.start_seconds, default=0.0, help="start this many seconds into the clip")
    p.add_argument("--fps", type=arg.fps, default=None, help="sensor rate (default: the camera preset's)")
    p.add_argument("--seed", type=arg.seed, default=0, help="noise seed (default 0)")
    p.add_argument("--imu", choices=["xbus", "lines"], default=None, help="also stream a simulated IMU suit")
    p.add_argument("--camera-imu", action="store_true", help="also stream the camera's own IMU (accelerometer and gyro of a still OAK, as <camera>_imu)")
    p.add_argument("--distance", type=arg.camera_distance, default=3.0,
                   help="camera distance from the performance centre, m")
    p.add_argument("--height", type=arg.camera_height, default=1.2, help="camera height above the floor, m")
    p.add_argument("--yaw", type=arg.angle_degrees, default=0.0,
                   help="camera angle around the performer, degrees (0 = in front)")
    p.add_argument("--pitch", type=float, default=None, metavar="DEG", help="camera tilt in degrees, negative looks "
                   "down, facing the performance centre (default: aimed at the centre, 1 m above the floor)")
    p.add_argument("--posture", choices=["clip", "in-place", "seated", "crouching", "knee-up", "kick"], default="clip",
                   help="the clip as recorded (default), in place, seated on a chair, crouching, or in place "
                   "raising the knees or kicking to the front in turn")
    p.add_argument("--floor", choices=["seen", "none"], default="seen",
                   help="none: the sensor returns nothing from the floor (a dark or shiny floor)")
    p.add_argument("--hide-extrinsics", action="store_true", help="the depth stream carries an identity "
                   "camera_to_world, as an uncalibrated camera does (the ground truth stays in the world)")
    p.add_argument("--no-noise", action="store_true", help="ideal depth (no sensor noise)")
    p.add_argument("--max-range", type=arg.depth_range, default=None, help="depth threshold in metres (farther "
                   "reads 0), like the device's threshold filter (default: the camera preset's range)")
    _add_force(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("eval", help="evaluate the skeleton regressor or a retargeter against ground truth",
                       description="eval skeleton: replay sessions with ground truth through the skeleton stage and "
                       "report MPJPE, PA-MPJPE, per-joint MPJPE, PCK@10cm, acceleration error and latency. "
                       "eval retarget: retarget a motion from one body to another and report MPJPE, PA-MPJPE, Acc, "
                       "PA-Acc, MPVD, PA-MPVD and MDEL. eval contacts: self-contacts kept and interpenetration, with "
                       "the correction on and off.")
    esub = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    e = esub.add_parser("skeleton", help="the depth -> skeleton stage")
    e.add_argument("sessions", nargs="+", type=Path, help="sessions with ground truth (e.g. from `livecap synth`)")
    e.add_argument("--model", type=Path, default=None, help="model to evaluate (default: the shipped one)")
    e.add_argument("--compare", choices=["baseline"], default=None, help="also evaluate the reference PointNet")
    e.add_argument("--threads", type=arg.threads, default=1)
    e.add_argument("--lag", type=arg.lag, default=0, metavar="FRAMES", help=LAG_HELP)
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e = esub.add_parser("retarget", help="retargeting from a source body to a target body")
    _retarget_eval_arguments(e)
    e = esub.add_parser("contacts", help="self-contacts and interpenetration of retargeting, correction on and off",
                        description="Retarget a motion from one body to another with the self-contact correction "
                        "and without; report hand-contact recall and precision, hand and forearm penetration and "
                        "the joint metrics of both (docs/retargeting.md, \"Self-contacts\").")
    _retarget_eval_arguments(e)

    p = sub.add_parser("train", help="train a model (needs the train extra: pip install 'livecap[train]')",
                       description="Train and export a model with its model card. Extra arguments go to the trainer "
                       "(see `livecap train WHAT -- --help`).")
    p.add_argument("what", choices=["skeleton", "skeleton-temporal", "retarget", "skinning", "bodies"])
    p.add_argument("--quick", action="store_true", help="a tiny run for smoke tests")
    p.add_argument("args", nargs=argparse.REMAINDER, help="more arguments for the trainer")

    p = sub.add_parser("calibrate", help="calibrate an IMU suit (hold a T-pose or N-pose for 2 s)",
                       description="Read the suit, wait for the performer to hold the pose still for 2 s, and save "
                       "the sensor-to-segment calibration as JSON.")
    p.add_argument("--source", required=True, help="serial source, e.g. serial:/dev/ttyUSB0:xbus")
    p.add_argument("--out", type=Path, required=True, help="calibration file to write (.json)")
    p.add_argument("--pose", choices=["tpose", "npose"], default="tpose")
    p.add_argument("--layout", default=None, help="suit layout JSON (default: the 15-sensor full-body layout)")
    p.add_argument("--height", type=arg.performer_height, default=1.75, help="performer height in metres")
    p.add_argument("--timeout", type=arg.positive_seconds, default=60.0, help="give up after this many seconds")
    _add_force(p)

    p = sub.add_parser("import", help="turn a recorded IMU suit (x-IMU3, Xsens MVNX, Xsens DOT) into a session",
                       description="Read a suit recording another program wrote and write a session that replay runs "
                       "like a live suit (docs/imu.md, \"Recorded suits\"). The segments come from the file's labels "
                       "(or --layout); the calibration from the file (MVNX) or from the still pose the take starts with.")
    p.add_argument("format", choices=["ximu3", "mvnx", "xsens-dot"], help="ximu3: the logged folder (one device "
                   "folder each); mvnx: an .mvnx file; xsens-dot: the DOT app's CSV files (or their folder)")
    p.add_argument("path", nargs="+", type=Path, help="the recording")
    p.add_argument("--out", type=Path, required=True, help="session file to write (.mcap)")
    p.add_argument("--layout", default=None, help="JSON {\"sensors\": {\"<id or label>\": \"<segment>\"}} when the "
                   "file's labels do not name segments")
    p.add_argument("--pose", choices=["tpose", "npose"], default=None,
                   help="the calibration pose the take starts with (default: the file's, else npose)")
    p.add_argument("--stream", choices=["segments", "sensors"], default="segments",
                   help="mvnx: MVN's solved segment orientations (default) or the raw sensor orientations")
    p.add_argument("--rate", type=arg.fps, default=None, metavar="HZ",
                   help="sample rate of the session (default: the recording's)")
    p.add_argument("--height", type=arg.performer_height, default=1.75, help="performer height in metres")
    _add_force(p)

    sub.add_parser("devices", help="list OAK and RealSense cameras and serial ports",
                   description="List connected OAK devices, RealSense devices and serial ports.")
    from live.app.batch_args import add_batch_parser  # argparse only: Ray is imported by the command

    add_batch_parser(sub)
    return parser


#: Which module holds each command's ``cmd_<name>`` function (imported when the command runs).
COMMAND_MODULES = {"demo": "commands", "replay": "commands", "render": "commands", "record": "commands",
                   "run": "commands", "export": "session_commands", "info": "session_commands",
                   "devices": "device_commands", "calibrate": "device_commands", "synth": "tool_commands",
                   "eval": "tool_commands", "train": "tool_commands", "batch": "batch", "import": "import_command"}


def _command(name: str):
    import importlib

    module = importlib.import_module(f"live.app.{COMMAND_MODULES[name]}")
    return getattr(module, f"cmd_{name.replace('-', '_')}")


#: BLAS / OpenMP thread pools the CLI limits to one thread.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads() -> None:
    """One BLAS thread unless the user set otherwise. The pipeline's matrices are small and it runs
    its own threads: BLAS thread pools only fight them for the cores (LBS is 4x faster
    single-threaded on a busy 2-core machine). Takes effect only before numpy is first imported,
    so ``main`` calls it before importing any command (importing this module changes nothing)."""
    for var in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(var, "1")


def _silence_stdout(stdout) -> None:
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real file descriptor (a test's StringIO)
        pass


def main(argv: list[str] | None = None) -> int:
    limit_blas_threads()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a bad option (one line printed), --help or --version
        return exc.code if isinstance(exc.code, int) else EXIT_USER_ERROR
    handler = logging.StreamHandler()
    handler.setFormatter(PrintableFormatter("livecap: %(message)s"))  # log lines may quote a file too
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, handlers=[handler])
    if args.command is None:
        parser.print_help()
        return EXIT_USER_ERROR

    def fail(message: str, status: int = EXIT_USER_ERROR) -> int:
        print(f"livecap {args.command}: error: {printable(message, max_chars=600)}", file=sys.stderr)
        return status

    # What a command prints can quote a file (stream names, metadata): never its escape sequences.
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = PrintableWriter(stdout), PrintableWriter(stderr, keep="\n\t\r")
    try:
        arg.check_outputs(args.command, args)
        return int(_command(args.command)(args) or 0)
    except LivecapError as exc:
        return fail(str(exc))
    except FileNotFoundError as exc:
        return fail(f"no such file: {exc.filename}")
    except (PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        return fail(f"cannot use {exc.filename}: {exc.strerror}")
    except MemoryError as exc:
        # Declared sizes are checked against ceilings before allocating (docs/reliability.md); if
        # the machine still runs out, say so in one line.
        return fail(f"out of memory ({exc or 'allocation failed'})", EXIT_FAILURE)
    except KeyboardInterrupt:
        print(f"livecap {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader closed the pipe: nothing left to say to it. Python's docs (signal, "Note on
        # SIGPIPE"): point stdout at devnull so the interpreter's final flush does not fail again.
        _silence_stdout(stdout)
        return EXIT_BROKEN_PIPE
    finally:
        sys.stdout, sys.stderr = stdout, stderr


if __name__ == "__main__":
    sys.exit(main())
