"""Result files: the writer's incremental chunks, the final files, the reader's contract checks,
and what a killed run leaves."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from live.core import assets
from live.core.errors import FormatError
from live.core.frames import AvatarPose, FrameResult, SkeletonFrame
from live.core.skeleton import PARENTS, default_rest_joints
from live.io.results import PARTIAL_DIR, ResultsWriter, assemble_results, read_avatar, read_skeleton

ROOT = Path(__file__).resolve().parents[1]
REST = default_rest_joints(1.6)


def _result(i: int, avatar: bool = True) -> FrameResult:
    rng = np.random.default_rng(i)
    t = 10**9 + i * 33_333_333
    skel = SkeletonFrame(t_ns=t, joints=rng.normal(size=(22, 3)), confidence=rng.uniform(size=22))
    pose = None
    if avatar:
        q = rng.normal(size=(22, 4))
        pose = AvatarPose(t_ns=t, root=rng.normal(size=3), rotations=q / np.linalg.norm(q, axis=1, keepdims=True),
                          joints=None if i % 5 == 3 else rng.normal(size=(22, 3)))
    return FrameResult(t_ns=t, skeleton=skel, avatar=pose)


class _Clock:
    """Wall time that advances ``step`` seconds each time it is read."""

    def __init__(self, step: float):
        self.now, self.step = 0.0, step

    def __call__(self) -> float:
        self.now += self.step
        return self.now


def _write(out: Path, n: int, step: float, close: bool = True) -> ResultsWriter:
    w = ResultsWriter(out, avatar_rest_joints=REST, fps=30.0, clock=_Clock(step))
    for i in range(n):
        w.send(_result(i))
    if close:
        w.close()
    return w


def test_round_trip_through_the_reader(tmp_path):
    w = _write(tmp_path, 12, 0.3)
    assert [p.name for p in w.written] == ["skeleton.npz", "avatar.npz", "avatar.bvh"]
    assert not (tmp_path / PARTIAL_DIR).exists()
    skel, avatar = read_skeleton(tmp_path / "skeleton.npz"), read_avatar(tmp_path / "avatar.npz")
    assert len(skel) == len(avatar) == 12 and skel.camera_to_world is None
    assert skel.t_ns.dtype == np.int64 and skel.joints.dtype == np.float32 and skel.confidence.shape == (12, 22)
    np.testing.assert_array_equal(skel.t_ns, [_result(i).t_ns for i in range(12)])
    np.testing.assert_array_equal(skel.joints[7], np.float32(_result(7).skeleton.joints))
    assert np.isnan(avatar.joints[3]).all() and np.isfinite(avatar.joints[4]).all()
    np.testing.assert_array_equal(avatar.rest_joints, np.float32(REST))
    np.testing.assert_array_equal(avatar.parents, PARENTS)
    assert avatar.rotations.shape == (12, 22, 4) and avatar.root.shape == (12, 3)


def test_chunking_never_changes_the_bytes(tmp_path):
    """Every frame its own chunk, a chunk a second, or all frames in one: the same files."""
    outs = []
    for step in (5.0, 0.3, 0.0):
        out = tmp_path / f"s{step}"
        _write(out, 17, step)
        outs.append(out)
    for name in ("skeleton.npz", "avatar.npz", "avatar.bvh"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes() == (outs[2] / name).read_bytes()


def test_a_writer_never_closed_leaves_all_but_the_last_second(tmp_path):
    # 0.25 s a frame: chunks after frames 4 and 8; frame 9 is younger than a second and lost.
    w = _write(tmp_path, 10, 0.25, close=False)
    assert w.skel_t == [_result(9).t_ns]  # only what the last second brought is still in memory
    assert not (tmp_path / "skeleton.npz").exists()
    files = assemble_results(tmp_path)
    assert sorted(p.name for p in files) == ["avatar.bvh", "avatar.npz", "skeleton.npz"]
    skel = read_skeleton(tmp_path / "skeleton.npz")
    np.testing.assert_array_equal(skel.t_ns, [_result(i).t_ns for i in range(9)])
    assert len(read_avatar(tmp_path / "avatar.npz")) == 9
    # The same bytes as a run of those 9 frames closed normally.
    _write(tmp_path / "nine", 9, 0.0)
    for name in ("skeleton.npz", "avatar.npz", "avatar.bvh"):
        assert (tmp_path / name).read_bytes() == (tmp_path / "nine" / name).read_bytes()


def test_a_new_run_drops_the_chunks_an_old_one_left(tmp_path):
    _write(tmp_path, 10, 0.25, close=False)  # crashed, chunks left behind
    _write(tmp_path, 3, 0.1)  # a new run into the same folder
    assert len(read_skeleton(tmp_path / "skeleton.npz")) == 3 and not (tmp_path / PARTIAL_DIR).exists()


def test_skeleton_only_and_no_rest_pose(tmp_path):
    w = ResultsWriter(tmp_path, clock=_Clock(0.6))
    for i in range(4):
        w.send(_result(i, avatar=i < 2))
    w.close()
    assert [p.name for p in w.written] == ["skeleton.npz", "avatar.npz"]  # no rest pose, no BVH
    assert len(read_skeleton(tmp_path / "skeleton.npz")) == 4
    assert not read_avatar(tmp_path / "avatar.npz").rest_joints.any()
    empty = ResultsWriter(tmp_path / "empty")
    empty.close()
    assert empty.written == [] and not any((tmp_path / "empty").iterdir())


def _npz(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


def test_the_reader_checks_the_contract(tmp_path):
    t = np.arange(3, dtype=np.int64)
    j = np.zeros((3, 22, 3), np.float32)
    c = np.ones((3, 22), np.float32)
    p = tmp_path / "s.npz"
    assert len(read_skeleton(_npz(p, t_ns=t, joints=j, confidence=c, camera_to_world=np.tile(np.eye(4), (3, 1, 1))))) == 3
    assert read_skeleton(p).camera_to_world.dtype == np.float32
    cases = [
        (dict(t_ns=t, joints=j), "missing arrays confidence"),
        (dict(t_ns=t, joints=j[:, :21], confidence=c), r"joints is \(3, 21, 3\), expected \(3, 22, 3\)"),
        (dict(t_ns=t, joints=j, confidence=c[:2]), r"confidence is \(2, 22\), expected \(3, 22\)"),
        (dict(t_ns=t[:, None], joints=j, confidence=c), r"t_ns is \(3, 1\), expected \(T,\)"),
        (dict(t_ns=t.astype(np.float64), joints=j, confidence=c), "t_ns has dtype float64, expected int64"),
        (dict(t_ns=t, joints=j.astype(np.int32), confidence=c), "joints has dtype int32, expected float32"),
        (dict(t_ns=t, joints=j, confidence=c, camera_to_world=np.eye(4)), "camera_to_world is"),
    ]
    for arrays, message in cases:
        with pytest.raises(FormatError, match=message):
            read_skeleton(_npz(p, **arrays))
    p.write_bytes(b"garbage")
    with pytest.raises(FormatError, match="not a readable"):
        read_skeleton(p)
    with pytest.raises(FileNotFoundError):
        read_skeleton(tmp_path / "missing.npz")

    a = dict(t_ns=t, rotations=np.zeros((3, 22, 4), np.float32), root=np.zeros((3, 3), np.float32), joints=j,
             rest_joints=np.zeros((22, 3), np.float32), parents=PARENTS)
    assert len(read_avatar(_npz(p, **a))) == 3
    with pytest.raises(FormatError, match="parents are not"):
        read_avatar(_npz(p, **{**a, "parents": np.arange(22) - 1}))
    with pytest.raises(FormatError, match=r"rotations is \(3, 22, 3\)"):
        read_avatar(_npz(p, **{**a, "rotations": np.zeros((3, 22, 3), np.float32)}))
    with pytest.raises(FormatError, match="missing arrays parents"):
        read_avatar(_npz(p, **{k: v for k, v in a.items() if k != "parents"}))


_KILLED_WRITER = """
import os, signal, sys, time
sys.path.insert(0, {root!r})
sys.path.insert(0, {tests!r})
from test_results import REST, _result
from live.io.results import ResultsWriter

w = ResultsWriter({out!r}, avatar_rest_joints=REST)
start = time.monotonic()
i = 0
while time.monotonic() - start < 2.5:
    w.send(_result(i))
    i += 1
    time.sleep(1 / 30)
print(i, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_killed_process_loses_at_most_about_a_second(tmp_path):
    out = tmp_path / "out"
    code = _KILLED_WRITER.format(root=str(ROOT), tests=str(ROOT / "tests"), out=str(out))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    sent = int(proc.stdout.split()[0])
    assemble_results(out)
    skel = read_skeleton(out / "skeleton.npz")
    # Frames come every ~1/30 s: the last second is at most ~30-40 frames on a busy machine.
    assert 0 < len(skel) <= sent and sent - len(skel) <= 45
    np.testing.assert_array_equal(skel.t_ns, [_result(i).t_ns for i in range(len(skel))])
    assert len(read_avatar(out / "avatar.npz")) == len(skel) and (out / "avatar.bvh").is_file()


def test_a_killed_replay_is_recovered(tmp_path):
    """``livecap replay`` at recorded speed, killed once two chunks are on disk."""
    session = assets.demo_session()
    if not Path(session).is_file():
        pytest.skip("no demo session")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "live.app.cli", "replay", str(session), "--out", str(out), "--speed", "1",
           "--avatar", "default", "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (out / PARTIAL_DIR / "avatar-000001.npz").exists():
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert not (out / "skeleton.npz").exists()
    assemble_results(out)
    skel, avatar = read_skeleton(out / "skeleton.npz"), read_avatar(out / "avatar.npz")
    assert len(skel) >= 20 and len(avatar) >= 20 and np.all(np.diff(skel.t_ns) > 0)
    assert (out / "avatar.bvh").read_text().startswith("HIERARCHY")


def test_avatar_bvh_frame_time_from_the_frames_when_the_source_does_not_say(tmp_path):
    from live.io.results import take_fps

    assert take_fps(np.array([0, 66_666_667, 133_333_333, 300_000_000])) == pytest.approx(15.0, rel=1e-6)
    assert take_fps(np.array([7])) == 30.0 and take_fps(np.array([5, 5])) == 30.0
    rest = default_rest_joints()
    for fps, expected in ((None, 1 / 15), (24.0, 1 / 24)):
        out = tmp_path / str(fps)
        writer = ResultsWriter(out, avatar_rest_joints=rest, fps=fps)
        for i in range(5):
            writer.send(FrameResult(t_ns=i * 66_666_667, avatar=AvatarPose(
                t_ns=i * 66_666_667, root=np.zeros(3), rotations=np.tile([1.0, 0, 0, 0], (22, 1)), joints=rest)))
        writer.close()
        line = next(x for x in (out / "avatar.bvh").read_text().splitlines() if x.startswith("Frame Time:"))
        assert float(line.split(":")[1]) == pytest.approx(expected, abs=1e-8)


def test_avatar_bvh_under_the_avatars_own_names(tmp_path):
    """The same motion under the avatar file's bone names: both BVHs parse to the same joint
    positions, only the names differ, and a recovered run keeps the names."""
    from live.core.skeleton import JOINT_NAMES
    from live.io.bvh_kinematics import bvh_forward_kinematics
    from live.io.bvh_reader import read_bvh

    names = tuple(f"J_Bip_{n}" for n in JOINT_NAMES)
    clips = {}
    for kind, given in (("canonical", None), ("avatar", names)):
        w = ResultsWriter(tmp_path / kind, avatar_rest_joints=REST, fps=30.0, avatar_joint_names=given,
                          clock=_Clock(0.4))
        for i in range(6):
            w.send(_result(i))
        w.close()
        clips[kind] = read_bvh(tmp_path / kind / "avatar.bvh")
    # The reader lists joints in file order (depth first): the same order in both files.
    assert set(clips["canonical"].skeleton.names) == set(JOINT_NAMES)
    assert clips["avatar"].skeleton.names == tuple(names[JOINT_NAMES.index(n)] for n in clips["canonical"].skeleton.names)
    np.testing.assert_array_equal(clips["avatar"].channels, clips["canonical"].channels)
    pos = {k: bvh_forward_kinematics(c)[0] for k, c in clips.items()}
    np.testing.assert_allclose(pos["avatar"], pos["canonical"], atol=1e-6)
    # A run killed before close: the chunks still carry the names.
    w = ResultsWriter(tmp_path / "killed", avatar_rest_joints=REST, fps=30.0, avatar_joint_names=names,
                      clock=_Clock(0.6))
    for i in range(6):
        w.send(_result(i))
    assemble_results(tmp_path / "killed")
    assert read_bvh(tmp_path / "killed" / "avatar.bvh").skeleton.names == clips["avatar"].skeleton.names


@pytest.mark.parametrize("bad", [("pelvis",) * 22, ("has space",) + ("x",) * 21, ("a",)])
def test_bvh_names_must_be_22_unique_words(tmp_path, bad):
    from live.io.bvh_writer import write_canonical_bvh

    with pytest.raises(ValueError):
        write_canonical_bvh(tmp_path / "x.bvh", np.tile([1.0, 0, 0, 0], (2, 22, 1)), np.zeros((2, 3)), REST, 30.0,
                            names=bad)
