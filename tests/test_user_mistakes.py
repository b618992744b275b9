"""Every command tried with bad values, as a careless user would: each answer is one line on
stderr and exit status 2, never a traceback (docs/reliability.md, "User mistakes").

The commands run in-process through live.app.cli.main (fd-level capture, so a library printing
from C also counts as a second line). The output rules are checked too: a results folder is
reused, an existing output file is refused unless --force, an input is never overwritten.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from live.app.cli import main
from live.core.frames import DepthFrame
from live.core.protocols import StreamInfo
from live.io.session import SessionWriter

K = np.array([[200.0, 0, 32], [0, 200.0, 20], [0, 0, 1]])
GOOD_META = {"fx": 200, "fy": 200, "cx": 32, "cy": 20, "width": 64, "height": 40, "fps": 15}
BVH_HEAD = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
}
MOTION
"""


def _bvh(frames: str = "3", frame_time: str = "0.0333333", rows: list[str] | None = None) -> str:
    rows = ["0 90 0 0 0 0 0 0 0"] * 3 if rows is None else rows
    return BVH_HEAD + f"Frames: {frames}\nFrame Time: {frame_time}\n" + "\n".join(rows) + "\n"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder with one small session, a file, a folder and the variants below."""
    d = tmp_path_factory.mktemp("mistakes")
    rng = np.random.default_rng(3)
    with SessionWriter(d / "s.mcap", [StreamInfo("cam", "depth", {"fps": 30})]) as w:
        for i in range(4):
            w.write(DepthFrame(1_000 + i * 33_000_000, "cam", depth_mm=rng.integers(500, 4000, (40, 64)).astype(np.uint16),
                               intrinsics=K))
    # A suit stream with no data: enough for --only imu to read its calibration file.
    with SessionWriter(d / "suit.mcap", [StreamInfo("suit", "serial", {"protocol": "xbus", "baud": 115200})]):
        pass
    (d / "file").write_text("x")
    (d / "folder").mkdir()
    (d / "folder.mp4").mkdir()
    (d / "folder.mcap").mkdir()
    (d / "garbage.mcap").write_bytes(b"garbage" * 10)
    (d / "nonutf8.json").write_bytes(b"\xff\xfe\x00{")
    (d / "list.json").write_text("[1, 2]")
    (d / "nan_cal.json").write_text(json.dumps({"pose": "tpose", "sensors": [1], "segments": ["pelvis"],
                                                "heading": [[1, 0, 0, 0]], "offset": [[1, 0, 0, 0]],
                                                "rest_joints": [[0, 0, 0]] * 22}).replace("[1, 0, 0, 0]]", "[NaN, 0, 0, 0]]"))
    (d / "bad_segment.json").write_text(json.dumps({"pose": "tpose", "sensors": [1], "segments": ["nose"],
                                                    "heading": [[1, 0, 0, 0]], "offset": [[1, 0, 0, 0]],
                                                    "rest_joints": [[0, 0, 0]] * 22}))
    for name, text in {"ft_huge": _bvh(frame_time="1000000"), "ft_tiny": _bvh(frame_time="1e-300"),
                       "ft_nan": _bvh(frame_time="nan"), "frames_huge": _bvh(frames="100000000000"),
                       "frames_neg": _bvh(frames="-3"), "values_nan": _bvh(rows=["nan 0 0 0 0 0 0 0 0"] * 3),
                       "values_short": _bvh(rows=["1 2 3"] * 3), "truncated": _bvh(rows=["0 90 0 0 0 0 0 0 0"]),
                       "long_day": _bvh(frames="100000", frame_time="1"), "no_hierarchy": "MOTION\nFrames: 1\n"}.items():
        (d / f"{name}.bvh").write_text(text)
    (d / "binary.bvh").write_bytes(b"\x00\xff" * 100)
    _npz_declaring(d / "bomb.npz", "vertices.npy", "<f4", (2**40, 3))
    _npz_declaring(d / "object.npz", "vertices.npy", "|O", (3,))
    (d / "not_zip.npz").write_bytes(b"garbage")
    (d / "bomb.ply").write_text("ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
                                "property float y\nproperty float z\nend_header\n")
    (d / "short.ply").write_text("ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\n"
                                 "property float y\nproperty float z\nend_header\n")
    (d / "garbage.ply").write_text("ply\ngarbage")
    (d / "bomb.off").write_text("OFF\n2000000000 2000000000 0\n1 2 3\n")
    (d / "bomb.stl").write_bytes(b"\0" * 80 + (2**31).to_bytes(4, "little"))
    return d


def _npz_declaring(path: Path, member: str, descr: str, shape: tuple) -> None:
    """A tiny .npz whose member's header declares ``shape`` (no data behind it)."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(member, buf.getvalue())


def _folder(root: Path, name: str, meta: dict | str | None = None, image=None, drop: tuple = ()) -> str:
    d = root / name
    d.mkdir()
    m = dict(GOOD_META)
    if isinstance(meta, dict):
        m.update(meta)
    for k in drop:
        m.pop(k)
    (d / "intrinsics.json").write_text(meta if isinstance(meta, str) else json.dumps(m))
    rng = np.random.default_rng(0)
    for i in range(3):
        img = image if image is not None else rng.integers(500, 3000, size=(40, 64)).astype(np.uint16)
        cv2.imwrite(str(d / f"{i:04d}.png"), img)
    return str(d)


NAN_META = '{"fx": 200, "fy": 200, "cx": 32, "cy": 20, "width": 64, "height": 40, "fps": NaN}'
FOLDERS = {
    "fps 0": {"fps": 0}, "fps string": {"fps": "abc"}, "fps negative": {"fps": -5}, "fps NaN": NAN_META,
    "fps 1e308": {"fps": 1e308}, "fps 1e-300": {"fps": 1e-300}, "fps true": {"fps": True},
    "camera_to_world string": {"camera_to_world": "abc"}, "camera_to_world ragged": {"camera_to_world": [[1, 2], [3]]},
    "camera_to_world scaled": {"camera_to_world": (2 * np.eye(4)).tolist()},
    "timestamps string": {"timestamps_ns": "abc"}, "timestamps of strings": {"timestamps_ns": ["a", "b", "c"]},
    "timestamps decreasing": {"timestamps_ns": [3, 2, 1]}, "timestamps beyond int64": {"timestamps_ns": [0, 10**30, 2 * 10**30]},
    "timestamps fractional": {"timestamps_ns": [0.5, 1.5, 2.5]}, "timestamps too few": {"timestamps_ns": [1, 2]},
    "timestamps span 31 years": {"timestamps_ns": [0, 10**18, 2 * 10**18]},
    "fx 0": {"fx": 0}, "fx negative": {"fx": -3}, "fx string": {"fx": "abc"}, "width 0": {"width": 0},
    "width fractional": {"width": 64.5}, "width 1e9": {"width": 10**9, "height": 10**9},
    "size unlike the images": {"width": 640, "height": 400}, "not an object": "[1, 2]", "not JSON": "{",
}


def _cases():
    """(id, argv builder) for every bad command; builders take (work folder, tmp_path)."""
    s = lambda w: str(w / "s.mcap")  # noqa: E731
    cases = {
        # --out rules
        "replay --out is a file": lambda w, t: ["replay", s(w), "--out", str(w / "file")],
        "demo --out is a file": lambda w, t: ["demo", "--out", str(w / "file"), "--no-video"],
        "run --out is a file": lambda w, t: ["run", "--source", f"replay:{s(w)}", "--out", str(w / "file")],
        "export --out is a file": lambda w, t: ["export", s(w), "--out", str(w / "file")],
        "export --foxglove is a folder": lambda w, t: ["export", s(w), "--foxglove", str(w / "folder.mcap")],
        "synth --out is a folder": lambda w, t: ["synth", "--motion", str(w / "ft_huge.bvh"), "--out", str(w / "folder.mcap")],
        "record --out is a folder": lambda w, t: ["record", "--source", f"replay:{s(w)}", "--out", str(w / "folder")],
        "render --out is a folder": lambda w, t: ["render", s(w), "--out", str(w / "folder.mp4")],
        "run --record is a folder": lambda w, t: ["run", "--source", f"replay:{s(w)}", "--out", str(t / "o"),
                                                  "--record", str(w / "folder")],
        "replay --video is a folder": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--video", str(w / "folder.mp4")],
        "calibrate --out is a folder": lambda w, t: ["calibrate", "--source", "serial:/dev/null:xbus", "--out", str(w / "folder")],
        "--viewer save: is a folder": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--viewer", f"save:{w / 'folder'}"],
        "record --out is its input": lambda w, t: ["record", "--source", f"replay:{s(w)}", "--out", s(w), "--force"],
        "export --foxglove is its input": lambda w, t: ["export", s(w), "--foxglove", s(w), "--force"],
        "synth --out exists": lambda w, t: ["synth", "--motion", str(w / "ft_huge.bvh"), "--out", str(w / "file")],
        "render --out exists": lambda w, t: ["render", s(w), "--out", str(w / "file")],
        "--out under a file": lambda w, t: ["replay", s(w), "--out", str(w / "file" / "sub")],
        # numbers
        "synth --fps -5": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--fps", "-5"],
        "synth --fps 0": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--fps", "0"],
        "synth --fps nan": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--fps", "nan"],
        "synth --fps 1e9": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--fps", "1e9"],
        "synth --start -5": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--start", "-5"],
        "synth --start nan": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--start", "nan"],
        "synth --seconds -1": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--seconds", "-1"],
        "synth --seconds 1e12": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--seconds", "1e12"],
        "synth --seconds inf": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--seconds", "inf"],
        "synth --distance -3": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--distance", "-3"],
        "synth --height 1e6": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--height", "1e6"],
        "synth --yaw inf": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--yaw", "inf"],
        "synth --max-range -1": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--max-range", "-1"],
        "synth --seed -1": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--seed", "-1"],
        "synth --seed 2^80": lambda w, t: ["synth", "--motion", "m.bvh", "--out", "x.mcap", "--seed", str(2**80)],
        "replay --threads -5": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--threads", "-5"],
        "replay --threads 1000000": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--threads", "1000000"],
        "replay --speed nan": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--speed", "nan"],
        "replay --speed -1": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--speed", "-1"],
        "replay --speed 1e-300": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--speed", "1e-300"],
        "replay --speed fast": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--speed", "fast"],
        "replay --lag -1": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--lag", "-1"],
        "replay --lag 5": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--lag", "5"],
        "replay --vmc-rate nan": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--vmc-rate", "nan"],
        "record --seconds -1": lambda w, t: ["record", "--source", f"replay:{s(w)}", "--out", str(t / "r.mcap"), "--seconds", "-1"],
        "record --seconds nan": lambda w, t: ["record", "--source", f"replay:{s(w)}", "--out", str(t / "r.mcap"), "--seconds", "nan"],
        "record --seconds 1e12": lambda w, t: ["record", "--source", f"replay:{s(w)}", "--out", str(t / "r.mcap"), "--seconds", "1e12"],
        "run --seconds -1": lambda w, t: ["run", "--source", f"replay:{s(w)}", "--out", str(t / "o"), "--seconds", "-1"],
        "calibrate --height -1": lambda w, t: ["calibrate", "--source", "serial:/dev/null:xbus", "--out", "c.json", "--height", "-1"],
        "calibrate --timeout nan": lambda w, t: ["calibrate", "--source", "serial:/dev/null:xbus", "--out", "c.json", "--timeout", "nan"],
        "eval skeleton --threads 0": lambda w, t: ["eval", "skeleton", s(w), "--threads", "0"],
        "eval retarget --max-frames -1": lambda w, t: ["eval", "retarget", "--motion", "m.bvh", "--max-frames", "-1"],
        "export --max-points 0": lambda w, t: ["export", s(w), "--foxglove", str(t / "f.mcap"), "--max-points", "0"],
        # options and values
        "unknown option": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--frob"],
        "unknown command": lambda w, t: ["frobnicate"],
        "missing --out": lambda w, t: ["replay", s(w)],
        "bad --retarget": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--retarget", "magic"],
        "bad --vmc": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--vmc", "nohost"],
        "bad --vmc port": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--vmc", "127.0.0.1:99999"],
        "bad --viewer": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--viewer", "cloud"],
        "bad --viewer web address": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--viewer", "web:example.com"],
        "bad source": lambda w, t: ["record", "--source", "xyz", "--out", str(t / "r.mcap")],
        "source folder missing": lambda w, t: ["record", "--source", "folder:/no/such", "--out", str(t / "r.mcap")],
        "source replay is a folder": lambda w, t: ["record", "--source", f"replay:{w / 'folder'}", "--out", str(t / "r.mcap")],
        "source sim of binary": lambda w, t: ["record", "--source", f"sim:{w / 'binary.bvh'}", "--out", str(t / "r.mcap")],
        "source oak with escapes": lambda w, t: ["record", "--source", "oak:\x1b[2J", "--out", str(t / "r.mcap")],
        "render --out not mp4": lambda w, t: ["render", s(w), "--out", str(t / "x.avi")],
        "export without --out": lambda w, t: ["export", s(w)],
        "model is a folder": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--model", str(w / "folder")],
        "model is garbage": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--model", str(w / "file")],
        # files
        "session missing": lambda w, t: ["replay", "/no/such.mcap", "--out", str(t / "o")],
        "session garbage": lambda w, t: ["replay", str(w / "garbage.mcap"), "--out", str(t / "o")],
        "info of garbage": lambda w, t: ["info", str(w / "garbage.mcap")],
        "info of a folder": lambda w, t: ["info", str(w / "folder")],
        "export of garbage": lambda w, t: ["export", str(w / "garbage.mcap"), "--out", str(t / "o")],
        "eval of garbage": lambda w, t: ["eval", "skeleton", str(w / "garbage.mcap")],
        "calibration not UTF-8": lambda w, t: ["replay", str(w / "suit.mcap"), "--out", str(t / "o"), "--only", "imu",
                                               "--calibration", str(w / "nonutf8.json")],
        "layout not UTF-8": lambda w, t: ["calibrate", "--source", "serial:/dev/null:xbus", "--out", str(t / "c.json"),
                                          "--layout", str(w / "nonutf8.json")],
        "layout a list": lambda w, t: ["calibrate", "--source", "serial:/dev/null:xbus", "--out", str(t / "c.json"),
                                       "--layout", str(w / "list.json")],
        "avatar npz declaring 12 TiB": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "bomb.npz")],
        "avatar npz with objects": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "object.npz")],
        "avatar npz not a zip": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "not_zip.npz")],
        "avatar PLY declaring 2e9 vertices": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "bomb.ply")],
        "avatar PLY shorter than declared": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "short.ply")],
        "avatar PLY garbage": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "garbage.ply")],
        "avatar OFF declaring 2e9 vertices": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "bomb.off")],
        "avatar STL declaring 2^31 faces": lambda w, t: ["replay", s(w), "--out", str(t / "o"), "--avatar", str(w / "bomb.stl")],
        # eval retarget loads both bodies before it reads the motion
        "body npz declaring 12 TiB": lambda w, t: ["eval", "retarget", "--motion", str(w / "truncated.bvh"),
                                                  "--target-body", str(w / "bomb.npz")],
        "unknown body": lambda w, t: ["eval", "retarget", "--motion", str(w / "truncated.bvh"), "--source-body", "nobody"],
        "motion missing": lambda w, t: ["synth", "--motion", "/no/such.bvh", "--out", str(t / "x.mcap")],
        "motion is a folder": lambda w, t: ["synth", "--motion", str(w / "folder"), "--out", str(t / "x.mcap")],
        "eval retarget motion frame time 1e6": lambda w, t: ["eval", "retarget", "--motion", str(w / "ft_huge.bvh")],
    }
    for name in ("ft_huge", "ft_tiny", "ft_nan", "frames_huge", "frames_neg", "values_nan", "values_short", "truncated",
                 "long_day", "no_hierarchy", "binary"):
        cases[f"BVH {name}"] = lambda w, t, n=name: ["synth", "--motion", str(w / f"{n}.bvh"), "--out", str(t / "x.mcap")]
    cal = {"calibration is a list": "list.json", "calibration with NaN": "nan_cal.json",
           "calibration with an unknown segment": "bad_segment.json"}
    for label, name in cal.items():
        # the calibration is read before the session's streams are looked at
        cases[label] = lambda w, t, n=name: ["replay", str(w / "suit.mcap"), "--out", str(t / "o"), "--only", "imu",
                                             "--calibration", str(w / n)]
    for label, meta in FOLDERS.items():
        cases[f"depth folder {label}"] = lambda w, t, m=meta: ["replay", _folder(t, "depth", m), "--out", str(t / "o")]
    cases["depth folder without fx"] = lambda w, t: ["replay", _folder(t, "depth", drop=("fx",)), "--out", str(t / "o")]
    cases["depth folder of 8-bit PNGs"] = lambda w, t: ["replay", _folder(t, "depth", image=np.full((40, 64), 9, np.uint8)),
                                                       "--out", str(t / "o")]
    cases["depth folder of RGB PNGs"] = lambda w, t: ["replay", _folder(t, "depth", image=np.full((40, 64, 3), 9, np.uint16)),
                                                     "--out", str(t / "o")]
    cases["depth folder as a source, fps 0"] = lambda w, t: ["record", "--source", f"folder:{_folder(t, 'depth', {'fps': 0})}",
                                                             "--out", str(t / "r.mcap")]
    return cases


CASES = _cases()


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_mistake_is_one_line_and_exit_2(case, work, tmp_path, capfd, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = CASES[case](work, tmp_path)
    status = main(argv)
    out, err = capfd.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err and "Traceback" not in out
    assert status == 2, f"{case}: exit {status}, stderr {err!r}"
    assert len(lines) == 1 and "error:" in lines[0], f"{case}: stderr {err!r}"
    assert "\x1b" not in err  # escape sequences from the input are printed as \x1b


def test_a_results_folder_is_reused_and_an_output_file_needs_force(work, tmp_path, capfd):
    out = tmp_path / "results"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    assert main(["replay", str(work / "s.mcap"), "--out", str(out), "--quiet"]) == 0
    assert (out / "stats.json").is_file() and (out / "notes.txt").read_text() == "kept"
    fox = tmp_path / "fox.mcap"
    fox.write_text("old")
    assert main(["export", str(work / "s.mcap"), "--foxglove", str(fox)]) == 2
    assert fox.read_text() == "old"
    assert main(["export", str(work / "s.mcap"), "--foxglove", str(fox), "--force"]) == 0
    assert fox.read_bytes().startswith(b"\x89MCAP")


def test_info_prints_escape_sequences_from_a_session_as_text(tmp_path, capfd):
    name = "cam\x1b]0;pwned\x07\x1b[2J\u202e"
    path = tmp_path / "names.mcap"
    with SessionWriter(path, [StreamInfo(name, "depth", {"fps": 30})]) as w:
        w.write(DepthFrame(1_000, name, depth_mm=np.full((40, 64), 1000, np.uint16), intrinsics=K))
    assert main(["info", str(path)]) == 0
    out, err = capfd.readouterr()
    assert "\x1b" not in out + err and "\u202e" not in out
    assert "cam\\x1b]0;pwned\\x07\\x1b[2J\\u202e" in out
