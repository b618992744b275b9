"""The Retargeter protocol: both retargeters implement it, and the retarget stage uses nothing else."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from live.core.frames import AvatarPose, FrameResult, GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_from_axis_angle
from live.core.skeleton import NUM_JOINTS, default_rest_joints
from live.pipeline.stages import RetargetStage
from live.retarget.interface import Retargeter
from live.retarget.learned import DEFAULT_MODEL, LearnedRetargeter
from live.retarget.retargeter import AnalyticRetargeter

SRC, DST = default_rest_joints(1.8), default_rest_joints(1.5)


def _joints(frames: int = 12, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, frames)[:, None, None]
    rot = quat_from_axis_angle(rng.normal(0, 0.3, (1, NUM_JOINTS, 3)) * np.sin(2 * np.pi * t))
    root = np.stack([0.3 * t[:, 0, 0], 0.95 + 0.0 * t[:, 0, 0], 0.2 * t[:, 0, 0]], axis=1)
    return forward_kinematics(rot, root, SRC)[0]


def _frames(joints: np.ndarray) -> list[SkeletonFrame]:
    return [SkeletonFrame(t_ns=10**9 + i * 33_333_333, joints=j.astype(np.float32), confidence=np.ones(22, np.float32))
            for i, j in enumerate(joints)]


def _learned(source_rest):
    if not DEFAULT_MODEL.is_file():
        pytest.skip("no shipped retargeting model")
    return LearnedRetargeter(None, source_rest, DST, foot_lock=True, floor=True)


@pytest.mark.parametrize("make", [lambda rest: AnalyticRetargeter(rest, DST), _learned], ids=["analytic", "learned"])
def test_both_retargeters_are_retargeters_and_set_source_rest_is_a_fresh_start(make):
    other = default_rest_joints(1.6)
    moved = make(SRC)
    assert isinstance(moved, Retargeter)
    moved.set_source_rest(other)
    fresh = make(other)
    for frame in _frames(_joints()):
        a, b = moved.process(frame), fresh.process(frame)
        assert isinstance(a, AvatarPose) and a.t_ns == frame.t_ns
        np.testing.assert_array_equal(a.joints, b.joints)
        np.testing.assert_array_equal(a.rotations, b.rotations)
    assert moved.last_globals is not None and moved.last_globals.shape == (22, 3, 3)


def test_process_takes_the_interval_from_timestamps():
    """process == step with dt from consecutive t_ns (None for the first and a repeated stamp)."""
    frames = _frames(_joints())
    a, b = AnalyticRetargeter(SRC, DST), AnalyticRetargeter(SRC, DST)
    last = None
    for f in frames[:6] + [frames[5]] + frames[6:]:
        dt = None if last is None or f.t_ns <= last else (f.t_ns - last) / 1e9
        last = f.t_ns
        root, rot, joints = b.step(f.joints, dt=dt)
        pose = a.process(f)
        np.testing.assert_array_equal(pose.joints, joints)
        np.testing.assert_array_equal(pose.root, root)
    a.reset()
    assert a.clock.last_t_ns is None


class _FrozenRetargeter:
    """Implements the protocol; any attribute written from outside after construction fails."""

    def __init__(self, rest):
        object.__setattr__(self, "calls", [("init", np.array(rest))])
        object.__setattr__(self, "last_globals", np.tile(np.eye(3), (22, 1, 1)))

    def __setattr__(self, name, value):
        raise AttributeError(f"the stage wrote retargeter.{name}")

    def reset(self):
        self.calls.append(("reset",))

    def set_source_rest(self, rest_joints):
        self.calls.append(("set_source_rest", np.array(rest_joints)))

    def process(self, frame):
        self.calls.append(("process", frame.t_ns))
        return AvatarPose(t_ns=frame.t_ns, root=np.zeros(3), rotations=np.tile([1.0, 0, 0, 0], (22, 1)),
                          joints=np.asarray(frame.joints, np.float64))


def test_the_stage_only_talks_to_the_interface(monkeypatch):
    avatar = SimpleNamespace(rest_joints=DST, faces=())
    stage = RetargetStage(avatar, warmup=3)
    made = []
    monkeypatch.setattr(stage, "_make", lambda rest: made.append(_FrozenRetargeter(rest)) or made[-1])
    frames = _frames(_joints(5))
    for f in frames:
        assert stage.process(FrameResult(t_ns=f.t_ns, skeleton=f))
    (rt,) = made
    kinds = [c[0] for c in rt.calls]
    assert kinds == ["init", "process", "set_source_rest", "process", "set_source_rest", "process", "process",
                     "process"]
    assert [c[1] for c in rt.calls if c[0] == "process"] == [f.t_ns for f in frames]


def test_the_stage_gives_what_the_retargeter_gives():
    """After the warm-up the stage's poses are the retargeter's own, as float32."""
    avatar = SimpleNamespace(rest_joints=DST, faces=())
    stage = RetargetStage(avatar, warmup=1)
    frames = _frames(_joints())
    results = [FrameResult(t_ns=f.t_ns, skeleton=f) for f in frames]
    for r in results:
        stage.process(r)
    from live.retarget.analytic import estimate_rest_joints

    ref = AnalyticRetargeter(estimate_rest_joints(np.asarray(frames[0].joints, np.float64)[None]), DST)
    for r, f in zip(results, frames):
        pose = ref.process(f)
        assert r.avatar.t_ns == f.t_ns and r.avatar.joints.dtype == np.float32
        np.testing.assert_array_equal(r.avatar.joints, np.asarray(pose.joints, np.float32))


def test_the_stage_retargets_ground_truth_joints():
    avatar = SimpleNamespace(rest_joints=DST, faces=())
    stage = RetargetStage(avatar, warmup=1, use_truth=True)
    j = _joints(2)
    truth = GroundTruth(t_ns=5, joints=j[0], rotations=np.tile([1.0, 0, 0, 0], (22, 1)), root=j[0, 0])
    assert not stage.process(FrameResult(t_ns=5))
    r = FrameResult(t_ns=5, truth=truth)
    assert stage.process(r) and r.avatar.t_ns == 5
