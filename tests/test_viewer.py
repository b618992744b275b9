"""Rerun viewer output: save mode writes an .rrd that the rerun CLI reads back with our entities."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import struct
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from live.core.errors import UserInputError
from live.core.frames import AvatarPose, DepthFrame, FrameResult, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_from_axis_angle
from live.core.skeleton import default_rest_joints
from live.outputs.render import bone_mesh

rr = pytest.importorskip("rerun", reason="rerun-sdk (the viewer extra) is not installed")

from live.outputs.viewer import (  # noqa: E402
    LEFT_RGB,
    LOOPBACK,
    RIGHT_RGB,
    RerunSink,
    ViewerSpec,
    confidence_rgb,
    parse_viewer_spec,
    rerun_binary,
    spawn_command,
)


def _rerun_cli() -> str:
    try:
        return rerun_binary()
    except UserInputError:
        pytest.skip("the rerun command-line tool is not installed")


def _results(n):
    rng = np.random.default_rng(0)
    rest = default_rest_joints()
    k = np.array([[300.0, 0, 319.5], [0, 300.0, 199.5], [0, 0, 1]])
    depth_mm = np.zeros((400, 640), np.uint16)
    depth_mm[100:300, 200:400] = 2000
    out = []
    for i in range(n):
        rot = quat_from_axis_angle(rng.normal(0, 0.2, (22, 3)))
        root = np.array([0.0, 0.95, 0.01 * i])
        joints, _ = forward_kinematics(rot, root, rest)
        verts, faces = bone_mesh(joints)
        t_ns = 7_000_000_000 + i * 33_333_333
        out.append(FrameResult(
            t_ns=t_ns,
            depth=DepthFrame(t_ns=t_ns, sensor="cam", depth_mm=depth_mm, intrinsics=k),
            skeleton=SkeletonFrame(t_ns=t_ns, joints=joints, confidence=np.full(22, 0.8)),
            avatar=AvatarPose(t_ns=t_ns, root=root, rotations=rot, joints=joints, vertices=verts),
            latency_ms={"skeleton": 10.0 + i, "retarget": 0.5},
        ))
    return out, faces


def test_save_mode_logs_every_stream(tmp_path):
    results, faces = _results(6)
    path = tmp_path / "run.rrd"
    with RerunSink("save", path, avatar_faces=faces) as sink:
        for r in results:
            sink.send(r)
        sink.send(FrameResult(t_ns=1))  # empty frame: nothing to log, not an error
    assert sink.errors == 0 and sink.frames == 7
    assert path.stat().st_size > 20_000

    cli = _rerun_cli()
    summary = subprocess.run([cli, "rrd", "print", str(path)], capture_output=True, text=True, timeout=60)
    assert summary.returncode == 0, summary.stderr
    rows = {}
    for line in summary.stdout.splitlines():
        if line.startswith("Chunk(") and " rows " in line:
            n = int(line.split(" with ")[1].split(" rows")[0])
            entity = line.split(" - ")[1].strip()
            rows[entity] = rows.get(entity, 0) + n
    for entity in ("/world/depth", "/world/performer/joints", "/world/performer/bones",
                   "/world/avatar/joints", "/world/avatar/bones", "/world/avatar/mesh",
                   "/latency/skeleton", "/latency/retarget"):
        assert rows.get(entity) == 6, (entity, rows)
    assert "/world/camera" in rows  # logged once: the camera does not move

    table = subprocess.run([cli, "rrd", "print", "-vvv", "--entity", "/latency/skeleton", str(path)],
                           capture_output=True, text=True, timeout=60)
    assert table.returncode == 0, table.stderr
    for i in range(6):
        assert f"{10.0 + i}" in table.stdout


def test_bad_settings_are_user_errors(tmp_path):
    with pytest.raises(UserInputError):
        RerunSink("cloud")
    with pytest.raises(UserInputError):
        RerunSink("save")
    with pytest.raises(UserInputError):
        RerunSink("save", tmp_path / "missing" / "run.rrd")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening_addresses(port: int) -> set[str]:
    """Local addresses with a TCP listener on port, from /proc/net/tcp (IPv4)."""
    found = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        addr, p = local.split(":")
        if state == "0A" and int(p, 16) == port:  # 0A = LISTEN
            found.add(socket.inet_ntoa(struct.pack("<I", int(addr, 16))))
    return found


@pytest.fixture
def web_sink():
    _rerun_cli()
    sink = RerunSink("web", web_port=_free_port(), grpc_port=_free_port())
    yield sink
    sink.close()


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_web_mode_serves_the_viewer_on_localhost_only(capsys, web_sink):
    assert f"(this machine only): open {web_sink.url}" in capsys.readouterr().err
    assert web_sink.url.startswith("http://127.0.0.1:")
    results, _ = _results(2)
    for r in results:
        web_sink.send(r)
    assert web_sink.errors == 0
    web_port = int(web_sink.url.split(":")[2].split("/")[0])
    grpc_port = int(web_sink.url.rsplit(":", 1)[1].split("/")[0])
    for port in (web_port, grpc_port):
        assert _listening_addresses(port) == {"127.0.0.1"}
    with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as page:
        assert page.status == 200
        assert b"<html" in page.read().lower()
    proc = web_sink._proc
    web_sink.close()
    assert proc.poll() is not None  # the viewer process this sink started is gone
    with pytest.raises(ProcessLookupError):
        os.killpg(proc.pid, 0)  # and so is its whole process group


@pytest.mark.parametrize("text, spec", [
    ("spawn", ViewerSpec("spawn", bind=LOOPBACK)), ("web", ViewerSpec("web", bind=LOOPBACK)),
    ("web:0.0.0.0", ViewerSpec("web", bind="0.0.0.0")), ("web:192.168.1.20", ViewerSpec("web", bind="192.168.1.20")),
    ("web:::", ViewerSpec("web", bind="::")), ("save:x/run.rrd", ViewerSpec("save", path=Path("x/run.rrd"))),
])
def test_viewer_specs_listen_on_loopback_unless_told(text, spec):
    assert parse_viewer_spec(text) == spec


@pytest.mark.parametrize("text", ["cloud", "save:", "web:example.com", "web:999.1.1.1", "spawn:localhost:9"])
def test_bad_viewer_specs_are_user_errors(text):
    with pytest.raises(UserInputError):
        parse_viewer_spec(text)


def test_spawned_viewer_listens_on_loopback_only():
    cmd = spawn_command(9876)
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and cmd[cmd.index("--port") + 1] == "9876"


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_spawn_mode_logs_into_a_viewer_already_listening_on_its_port():
    # A native viewer needs a display; a gRPC server started the same way stands in for it.
    port = _free_port()
    proc = subprocess.Popen([_rerun_cli(), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 15
        while not _listening_addresses(port) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # waiting for another process to listen: nothing to wait on but time
        assert _listening_addresses(port), "the rerun gRPC server did not start"
        sink = RerunSink("spawn", grpc_port=port)
        results, _ = _results(2)
        for r in results:
            sink.send(r)
        sink.close()
        assert sink.errors == 0 and sink.frames == 2
        assert _listening_addresses(port) == {"127.0.0.1"}
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_web_mode_serves_the_local_network_when_asked(capsys):
    _rerun_cli()
    web_port, grpc_port = _free_port(), _free_port()
    sink = RerunSink("web", web_port=web_port, grpc_port=grpc_port, bind="0.0.0.0")
    try:
        for port in (web_port, grpc_port):
            assert _listening_addresses(port) == {"0.0.0.0"}
        err = capsys.readouterr().err
        assert f"open {sink.url}" in err and "listening on 0.0.0.0" in err
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as page:
            assert page.status == 200
    finally:
        sink.close()


_BROWSER = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
# Chromium flags for a headless browser with WebGL2 on the CPU (SwiftShader through ANGLE): without
# them the viewer's canvas has no context and the page shows a loading error, not our data.
_BROWSER_FLAGS = ("--headless=new", "--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                  "--use-gl=angle", "--disable-background-networking", "--disable-component-update",
                  "--no-first-run", "--window-size=1280,720")


def _screenshots(browser: str, url: str, profile: Path, timeout_s: float):
    """Screenshots (BGR arrays) of url in headless Chromium, taken over the DevTools protocol about
    once a second, for up to timeout_s of wall time (a loaded 2-core machine needs tens of seconds
    to start the viewer's wasm app; a fixed virtual-time budget shot the loading screen)."""
    import base64
    import json
    import time

    import cv2
    websocket = pytest.importorskip("websocket", reason="websocket-client (the dev extra) is not installed")
    port = _free_port()
    proc = subprocess.Popen([browser, *_BROWSER_FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}", url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + timeout_s
    ws = None
    try:
        while ws is None and time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                    pages = [t for t in json.load(r) if t["type"] == "page"]
                ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=30, suppress_origin=True)
            except (OSError, IndexError, websocket.WebSocketException):
                time.sleep(0.5)
        msg_id = 0
        while ws is not None and time.monotonic() < deadline:
            msg_id += 1
            ws.send(json.dumps({"id": msg_id, "method": "Page.captureScreenshot", "params": {"format": "png"}}))
            reply = json.loads(ws.recv())
            while reply.get("id") != msg_id:
                reply = json.loads(ws.recv())
            png = np.frombuffer(base64.b64decode(reply["result"]["data"]), np.uint8)
            yield cv2.imdecode(png, cv2.IMREAD_COLOR)
            time.sleep(1.0)
    finally:
        if ws is not None:
            ws.close()
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _skeleton_pixels(img_bgr: np.ndarray) -> tuple[int, int, int]:
    """Pixels below the viewer's top bar in the left and right bone colours and in the colour of
    joints of confidence 0.8 (what ``_results`` logs)."""
    rgb = img_bgr[40:, :, ::-1].astype(np.int16)
    colours = (LEFT_RGB, RIGHT_RGB, tuple(confidence_rgb(np.array([0.8]))[0]))
    return tuple(int((np.abs(rgb - np.array(c, np.int16)).max(-1) <= 20).sum()) for c in colours)


@pytest.mark.skipif(_BROWSER is None, reason="no headless Chromium installed: the web-viewer screenshot test needs one (lead's call)")
def test_web_viewer_screenshot(web_sink, tmp_path):
    import cv2

    results, _ = _results(3)
    for r in results:
        web_sink.send(r)
    # The page must draw our skeleton (both sides' bones and the joints in the 3D view), not merely load.
    img, counts = None, (0, 0, 0)
    for img in _screenshots(_BROWSER, web_sink.url, tmp_path / "profile", timeout_s=150):
        counts = _skeleton_pixels(img)
        if min(counts) >= 30:
            break
    assert img is not None, "Chromium never answered on its DevTools port"
    cv2.imwrite(str(tmp_path / "viewer.png"), img)
    assert min(counts) >= 30, f"the viewer did not draw the skeleton (pixels left/right/joints {counts}); see {tmp_path / 'viewer.png'}"
