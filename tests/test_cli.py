"""The CLI: replay writes stats.json, depth folders replay like sessions, mistakes are one line."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from live.app.cli import main
from live.core.frames import DepthFrame
from live.core.protocols import StreamInfo
from live.io.session import SessionWriter

ROOT = Path(__file__).resolve().parent.parent
K = np.array([[200.0, 0, 32], [0, 200.0, 20], [0, 0, 1]])


def _session(path, n=12, size=(40, 64)):
    rng = np.random.default_rng(3)
    with SessionWriter(path, [StreamInfo("cam", "depth", {"fps": 30})]) as w:
        for i in range(n):
            img = rng.integers(500, 4000, size=size).astype(np.uint16)
            img[:5] = 0
            w.write(DepthFrame(1_000 + i * 33_000_000, "cam", depth_mm=img, intrinsics=K))
    return path


def test_replay_writes_stats(tmp_path, capsys):
    s = _session(tmp_path / "s.mcap")
    assert main(["replay", str(s), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    stats = json.loads((tmp_path / "out" / "stats.json").read_text())
    assert stats["frames"] == 12
    first = next(iter(stats["stages"].values()))
    assert first["frames_in"] == 12
    assert stats["end_to_end"]["latency_ms"]["count"] == 12
    for key in ("p50", "p95", "p99"):
        assert key in first["latency_ms"]


def test_replay_of_depth_folder(tmp_path, capsys):
    folder = tmp_path / "depth"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(5):
        cv2.imwrite(str(folder / f"{i:04d}.png"), rng.integers(0, 3000, size=(40, 64)).astype(np.uint16))
    (folder / "0003.png").write_bytes(b"garbage, not a png")  # counted, skipped
    (folder / "intrinsics.json").write_text(json.dumps({"fx": 200, "fy": 200, "cx": 32, "cy": 20,
                                                        "width": 64, "height": 40, "fps": 15}))
    # A skipped image is data lost: exit 1 and one line naming it; the other frames replay.
    assert main(["replay", str(folder), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "skipped 1 of 5 images" in err[0] and "0003.png: not a PNG file" in err[0]
    stats = json.loads((tmp_path / "out" / "stats.json").read_text())
    assert stats["frames"] == 4
    assert stats["sources"]["depth"]["counters"]["bad_images"] == 1


def test_truncated_session_replays_and_reports(tmp_path, capsys):
    s = _session(tmp_path / "s.mcap", n=40, size=(200, 320))  # ~2 frames per chunk
    data = s.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 3 // 4])
    assert main(["replay", str(cut), "--out", str(tmp_path / "out"), "--quiet"]) == 1  # data lost
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "truncated" in err[0]
    stats = json.loads((tmp_path / "out" / "stats.json").read_text())
    assert 0 < stats["frames"] < 40 and stats["session_error"]


def test_info_and_export(tmp_path, capsys):
    s = _session(tmp_path / "s.mcap")
    assert main(["info", str(s), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["streams"][0]["messages"] == 12
    assert main(["export", str(s), "--out", str(tmp_path / "exp")]) == 0
    z = np.load(tmp_path / "exp" / "depth_cam.npz")
    assert z["offsets"].shape == (13,) and z["points"].shape[1] == 3
    assert z["offsets"][-1] == len(z["points"])


@pytest.mark.parametrize("argv", [
    ["replay", "/no/such/file.mcap", "--out", "/tmp/x"],
    ["replay", "README.md", "--out", "/tmp/x"],
    ["replay", "README.md", "--out", "/tmp/x", "--speed", "fast"],
    ["info", "/no/such.mcap"],
])
def test_user_mistakes_are_one_line(argv, capsys):
    code = main([a if not a.endswith(".md") else str(ROOT / a) for a in argv])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("livecap ")


def test_every_command_has_help():
    for cmd in ["demo", "replay", "record", "run", "export", "info", "devices", "synth", "render", "eval",
                "calibrate"]:
        out = subprocess.run([sys.executable, "-m", "live.app.cli", cmd, "--help"], cwd=ROOT,
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0 and "usage" in out.stdout


def test_importing_runtime_packages_never_imports_torch():
    code = ("import sys, live, live.app.cli, live.pipeline.runner, live.io.session, drivers, models, sim, sim.replay;"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr


_BLAS_CHECK = """
import os, sys
import live.app.cli as cli
assert "numpy" not in sys.modules
assert [os.environ.get(v) for v in cli.BLAS_THREAD_VARIABLES] == [None, "3", None], "import changed the environment"
assert cli.main([]) == 2  # no command: the help
assert "numpy" not in sys.modules  # so the limits still apply to the commands' numpy
assert [os.environ.get(v) for v in cli.BLAS_THREAD_VARIABLES] == ["1", "3", "1"]
"""


def test_the_cli_limits_blas_threads_in_main_not_on_import():
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    env["OMP_NUM_THREADS"] = "3"  # a user's own setting wins
    proc = subprocess.run([sys.executable, "-c", _BLAS_CHECK], cwd=ROOT, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr



class _ClosedPipe:
    """A stdout whose reader has gone (what `| head` leaves once head exits)."""

    def write(self, text):
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self):
        raise BrokenPipeError(32, "Broken pipe")


def test_closed_stdout_pipe_exits_quietly_with_141(monkeypatch, capsys):
    """`livecap info X --json | head`: no traceback, exit 128 + SIGPIPE like `cat`."""
    from live.app.running import DEMO_SESSION

    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert main(["info", str(DEMO_SESSION), "--json"]) == 141
    assert capsys.readouterr().err == ""


def _bvh_frame_time(path):
    return next(float(line.split(":")[1]) for line in path.read_text().splitlines() if line.startswith("Frame Time:"))


def test_outputs_take_the_takes_frame_rate_from_sessions_and_depth_folders(tmp_path):
    """A 15 fps take: avatar.bvh says 1/15 s per frame and the video lasts n / 15 s, whether the
    take is replayed from a session or from a depth folder."""
    av = pytest.importorskip("av")
    rng = np.random.default_rng(5)
    images = [rng.integers(500, 4000, size=(40, 64)).astype(np.uint16) for _ in range(9)]
    session = tmp_path / "s.mcap"
    with SessionWriter(session, [StreamInfo("cam", "depth", {"fps": 15.0})]) as w:
        for i, img in enumerate(images):
            w.write(DepthFrame(i * 66_666_667, "cam", depth_mm=img, intrinsics=K))
    folder = tmp_path / "depth"
    folder.mkdir()
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)
    (folder / "intrinsics.json").write_text(json.dumps({"fx": 200, "fy": 200, "cx": 32, "cy": 20,
                                                        "width": 64, "height": 40, "fps": 15}))
    for name, target in (("session", session), ("folder", folder)):
        out = tmp_path / name
        assert main(["replay", str(target), "--out", str(out), "--quiet", "--avatar", "default",
                     "--video", str(tmp_path / f"{name}.mp4")]) == 0
        assert _bvh_frame_time(out / "avatar.bvh") == pytest.approx(1 / 15, abs=1e-8)
        with av.open(str(tmp_path / f"{name}.mp4")) as f:
            s = f.streams.video[0]
            assert s.codec_context.name == "h264"
            assert float(s.duration * s.time_base) == pytest.approx(9 / 15, abs=1e-3)


def test_replay_with_the_camera_height_places_a_floor_out_of_view(tmp_path, shared_bvh):
    # A seated performer close to a camera on a desk: no floor returned, no extrinsics, the
    # camera's IMU streamed (it gives up; the height is used with it).
    session = tmp_path / "seated.mcap"
    assert main(["synth", "--motion", str(shared_bvh / "cc_002_01.bvh"), "--out", str(session), "--seconds", "0.5", "--camera-imu",
                 "--posture", "seated", "--floor", "none", "--hide-extrinsics", "--distance", "1.6", "--height", "1.1",
                 "--pitch", "-10"]) == 0
    details = {}
    for name, extra in (("guessed", []), ("given", ["--camera-height", "1.1"])):
        out = tmp_path / name
        assert main(["replay", str(session), "--out", str(out), "--quiet", *extra]) == 0
        details[name] = json.loads((out / "stats.json").read_text())["stages"]["skeleton"]["details"]
    assert details["given"]["up_source"] == details["guessed"]["up_source"] == "imu"
    assert details["given"]["camera_height_m"] == pytest.approx(1.1) and details["given"]["camera_height_given_m"] == 1.1
    # Guessed, the floor is a standing person's (1.70 m below the head): far from the real one.
    assert details["guessed"]["camera_height_given_m"] is None
    assert abs(details["guessed"]["camera_height_m"] - 1.1) > 0.2
    assert main(["replay", str(session), "--out", str(tmp_path / "bad"), "--camera-height", "-1"]) == 2
