"""Live 3D viewer output with Rerun (the optional ``viewer`` extra: rerun-sdk).

``RerunSink`` logs, per frame, on the timelines ``sensor_time`` (seconds of the host monotonic
clock) and ``frame``:

    world                      right-handed, +Y up (static)
    world/camera               the depth camera pose (Transform3D) and, with intrinsics, a Pinhole
    world/depth                the depth cloud in the world frame (Points3D, decimated)
    world/performer/joints     the performer's 22 joints, coloured by confidence (Points3D)
    world/performer/bones      its bones (LineStrips3D, one strip per BONES pair)
    world/avatar/joints|bones  the posed avatar's skeleton
    world/avatar/mesh          its skinned mesh (Mesh3D), when AvatarPose.vertices and faces exist
    latency/<stage>            per-stage milliseconds (Scalars)

Modes (``--viewer spawn|web[:ADDR]|save:FILE.rrd``, parsed by ``parse_viewer_spec``):

- "spawn" starts the native viewer, listening for this sink on 127.0.0.1 only (``rerun --bind
  127.0.0.1``; Rerun's own spawn listens on every interface), or logs into a viewer already
  listening on that port. The viewer stays open after the run;
- "web" serves the web viewer and its gRPC proxy on 127.0.0.1 (a `rerun --serve-web --bind ...`
  process this sink owns and stops at close) and prints the URL to open; "web:0.0.0.0" serves
  every interface (a phone or laptop on the local network), "web:ADDR" one address;
- "save" writes an .rrd file to ``path``.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core.depth import points_to_world
from live.core.errors import UserInputError
from live.core.frames import FrameResult
from live.core.skeleton import BONES, JOINT_NAMES
from live.outputs.raster import vertex_normals

log = logging.getLogger(__name__)

MODES = ("spawn", "web", "save")
#: Where the viewer listens unless the user names an address.
LOOPBACK = "127.0.0.1"
_WILDCARDS = ("0.0.0.0", "::", "[::]")
_BONE_PAIRS = np.array(BONES, dtype=np.int64)
# Bone colours (RGB): the performer's left warm, right cool, centre light grey.
LEFT_RGB, RIGHT_RGB, CENTRE_RGB = (255, 160, 60), (60, 160, 255), (220, 220, 220)
_BONE_RGB = np.array(
    [LEFT_RGB if JOINT_NAMES[c].startswith("left") else RIGHT_RGB if JOINT_NAMES[c].startswith("right") else CENTRE_RGB
     for _, c in BONES],
    dtype=np.uint8,
)


def confidence_rgb(confidence: np.ndarray) -> np.ndarray:
    """(J, 3) uint8 joint colours from (J,) confidences: red at 0 to green at 1 (clipped)."""
    conf = np.clip(np.asarray(confidence, dtype=np.float64), 0.0, 1.0)
    return np.stack([255 * (1 - conf), 255 * conf, np.zeros_like(conf)], -1).astype(np.uint8)


def import_rerun():
    """The rerun module, or a UserInputError naming the extra to install."""
    try:
        import rerun as rr
    except ImportError as e:
        raise UserInputError("the viewer needs rerun-sdk: install livecap[viewer]") from e
    return rr


def rerun_binary() -> str:
    """Path of the rerun viewer executable. The rerun_cli package's binary is preferred to the
    `rerun` console script, which is a Python wrapper that would outlive a terminate()."""
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).with_name("rerun")
        if binary.exists():
            return str(binary)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise UserInputError("the 'rerun' command was not found: install livecap[viewer]")
    return found


@dataclass(frozen=True)
class ViewerSpec:
    """A parsed ``--viewer`` value: mode, the .rrd path (save) or the address to listen on."""

    mode: str
    path: Path | None = None
    bind: str = LOOPBACK


def parse_viewer_spec(text: str) -> ViewerSpec:
    """``spawn`` | ``web`` | ``web:ADDR`` | ``spawn:ADDR`` | ``save:FILE.rrd`` -> ViewerSpec."""
    mode, _, rest = text.partition(":")
    if mode not in MODES or (mode == "save" and not rest):
        raise UserInputError("--viewer wants spawn, web, web:ADDR (e.g. web:0.0.0.0 to serve the local network) "
                             "or save:FILE.rrd")
    if mode == "save":
        return ViewerSpec(mode, path=Path(rest))
    bind = rest or LOOPBACK
    if bind not in _WILDCARDS:
        try:
            socket.getaddrinfo(bind.strip("[]"), None, type=socket.SOCK_STREAM, flags=socket.AI_NUMERICHOST)
        except socket.gaierror:
            raise UserInputError(f"--viewer {mode}:ADDR wants an IP address to listen on, not {bind!r}") from None
    return ViewerSpec(mode, bind=bind)


def connect_host(bind: str) -> str:
    """The address this process reaches a server on that listens on ``bind``."""
    return LOOPBACK if bind in _WILDCARDS else bind.strip("[]")


def url_host(bind: str) -> str:
    """The host name to put in a URL for other machines: the address of the interface that routes
    to the network for a wildcard bind (no packet is sent), else the bound address."""
    if bind not in _WILDCARDS:
        host = bind.strip("[]")
        return f"[{host}]" if ":" in host else host
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: routing only, nothing is sent
            return s.getsockname()[0]
    except OSError:
        return socket.gethostname()


def _listening(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False


def _wait_for_port(host: str, port: int, proc: subprocess.Popen, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise UserInputError(f"the rerun {what} exited at start (code {proc.returncode})")
        if _listening(host, port):
            return
        time.sleep(0.05)  # waiting for another process to listen: nothing to wait on but time
    raise UserInputError(f"the rerun {what} did not listen on {host}:{port} within {timeout_s:.0f} s")


def spawn_command(port: int, bind: str = LOOPBACK) -> list[str]:
    """The native viewer's command line: what ``rerun.spawn`` runs, plus ``--bind``."""
    return [rerun_binary(), "--bind", bind, "--port", str(port), "--expect-data-soon",
            "--memory-limit", "75%", "--server-memory-limit", "1GiB"]


class RerunSink:
    """Logs FrameResults to Rerun. Never raises from send(); errors are counted and logged.

    mode: "spawn" | "web" | "save"; path: the .rrd file for "save". avatar_faces (F, 3): the
    avatar mesh's triangles (the mesh is logged only with them). max_points: the depth cloud is
    decimated (fixed stride) to at most this many points per frame.
    """

    def __init__(
        self,
        mode: str = "spawn",
        path: str | Path | None = None,
        avatar_faces: np.ndarray | None = None,
        max_points: int = 60_000,
        web_port: int = 9090,
        grpc_port: int = 9876,
        application_id: str = "livecap",
        bind: str = LOOPBACK,
    ) -> None:
        if mode not in MODES:
            raise UserInputError(f"unknown viewer mode {mode!r}: use one of {', '.join(MODES)}")
        if mode == "save" and path is None:
            raise UserInputError("viewer mode 'save' needs a path for the .rrd file")
        rr = import_rerun()
        self._rr = rr
        self.mode = mode
        self.path = None if path is None else Path(path)
        self._faces = None if avatar_faces is None else np.asarray(avatar_faces, dtype=np.uint32)
        self._max_points = int(max_points)
        self._proc: subprocess.Popen | None = None
        self._last_camera: tuple | None = None
        self.frames = 0
        self.errors = 0
        self.url: str | None = None
        self.bind = bind
        self._rec = rr.RecordingStream(application_id)
        if mode == "save":
            if not self.path.parent.exists():
                raise UserInputError(f"folder {self.path.parent} does not exist")
            self._rec.save(self.path)
        elif mode == "spawn":
            self._spawn_native(grpc_port, bind)
        else:
            self._start_web(web_port, grpc_port, bind)
        self._rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)

    @classmethod
    def from_spec(cls, text: str, **kwargs) -> RerunSink:
        """A sink for a ``--viewer`` value (``parse_viewer_spec``)."""
        spec = parse_viewer_spec(text)
        return cls(spec.mode, path=spec.path, bind=spec.bind, **kwargs)

    def _spawn_native(self, port: int, bind: str) -> None:
        # rerun.spawn() starts `rerun --port N`, which listens on every interface: anyone on the
        # network could log into the viewer. Started here with --bind; the viewer outlives the run
        # (its own session, not stopped at close), as Rerun's spawn does.
        host = connect_host(bind)
        if not _listening(host, port):
            env = dict(os.environ, RERUN_APP_ONLY="true")
            proc = subprocess.Popen(spawn_command(port, bind), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True, env=env)
            _wait_for_port(host, port, proc, timeout_s=15.0, what="viewer")
        self._rec.connect_grpc(f"rerun+http://{host}:{port}/proxy")

    def _start_web(self, web_port: int, grpc_port: int, bind: str) -> None:
        # The SDK's own serve_grpc/serve_web_viewer listen on every interface; the CLI takes
        # --bind, so the viewer is reachable from this machine only unless the user names an address.
        cmd = [rerun_binary(), "--serve-web", "--bind", bind, "--port", str(grpc_port),
               "--web-viewer-port", str(web_port)]
        # Its own process group, so that stopping it also stops anything it started.
        self._proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      start_new_session=True)
        host = connect_host(bind)
        try:
            _wait_for_port(host, grpc_port, self._proc, timeout_s=15.0, what="web viewer")
        except UserInputError:
            self._stop_web()
            raise
        self._rec.connect_grpc(f"rerun+http://{host}:{grpc_port}/proxy")
        public = url_host(bind)
        self.url = f"http://{public}:{web_port}/?url=rerun%2Bhttp://{public}:{grpc_port}/proxy"
        where = "this machine only" if bind == LOOPBACK else f"listening on {bind}"
        print(f"livecap: web viewer ({where}): open {self.url}", file=sys.stderr, flush=True)

    def _stop_web(self) -> None:
        if self._proc is None:
            return
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(self._proc.pid, sig)  # the group this sink created, by its id
            except ProcessLookupError:
                break
            try:
                self._proc.wait(timeout=5)
                break
            except subprocess.TimeoutExpired:
                continue
        self._proc = None

    def send(self, result: FrameResult) -> None:
        if self._rec is None:
            return
        try:
            self._log(result)
            self.frames += 1
        except Exception as e:  # a sink must never take the pipeline down
            self.errors += 1
            if self.errors == 1 or self.errors % 100 == 0:
                log.warning("rerun sink: %s (%d errors so far)", e, self.errors)

    def _log(self, result: FrameResult) -> None:
        rr, rec = self._rr, self._rec
        rec.set_time("sensor_time", duration=result.t_ns * 1e-9)
        rec.set_time("frame", sequence=self.frames)
        depth = result.depth
        if depth is not None:
            self._log_camera(depth)
            pts = depth.cloud()
            if len(pts) > self._max_points:
                pts = pts[:: int(np.ceil(len(pts) / self._max_points))]
            rec.log("world/depth", rr.Points3D(points_to_world(pts, depth.camera_to_world), radii=0.004,
                                               colors=(170, 170, 170)))
        if result.skeleton is not None:
            self._log_skeleton("world/performer", result.skeleton.joints, confidence_rgb(result.skeleton.confidence))
        avatar = result.avatar
        if avatar is not None:
            if avatar.joints is not None:
                self._log_skeleton("world/avatar", avatar.joints, (255, 255, 255))
            if avatar.vertices is not None and self._faces is not None:
                v = np.asarray(avatar.vertices, dtype=np.float32)
                rec.log("world/avatar/mesh", rr.Mesh3D(vertex_positions=v, triangle_indices=self._faces,
                                                        vertex_normals=vertex_normals(v, self._faces),
                                                        albedo_factor=(0.85, 0.72, 0.62, 1.0)))
        for stage, ms in result.latency_ms.items():
            rec.log(f"latency/{stage}", rr.Scalars(float(ms)))

    def _log_skeleton(self, entity: str, joints: np.ndarray, colours) -> None:
        rr = self._rr
        j = np.asarray(joints, dtype=np.float32)
        self._rec.log(f"{entity}/joints", rr.Points3D(j, radii=0.02, colors=colours))
        self._rec.log(f"{entity}/bones", rr.LineStrips3D(j[_BONE_PAIRS], radii=0.008, colors=_BONE_RGB))

    def _log_camera(self, depth) -> None:
        rr = self._rr
        m = np.asarray(depth.camera_to_world, dtype=np.float64)
        key = (m.tobytes(), None if depth.intrinsics is None else np.asarray(depth.intrinsics).tobytes())
        if key == self._last_camera:  # a fixed camera is logged once, not every frame
            return
        self._last_camera = key
        self._rec.log("world/camera", rr.Transform3D(translation=m[:3, 3], mat3x3=m[:3, :3]))
        if depth.intrinsics is not None:
            k = np.asarray(depth.intrinsics, dtype=np.float64)
            if depth.depth_mm is not None:
                h, w = depth.depth_mm.shape
            else:
                w, h = 2 * (k[0, 2] + 0.5), 2 * (k[1, 2] + 0.5)
            self._rec.log("world/camera", rr.Pinhole(image_from_camera=k, resolution=[w, h],
                                                     camera_xyz=rr.ViewCoordinates.RDF))

    def close(self) -> None:
        if self._rec is None:
            return
        try:
            self._rec.flush()
            self._rec.disconnect()
        except Exception as e:
            self.errors += 1
            log.warning("rerun sink: closing: %s", e)
        finally:
            self._rec = None
            self._stop_web()

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
