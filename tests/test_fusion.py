"""Depth + IMU fusion on a synthetic session with ground truth: fused beats depth-only and
IMU-only, survives occlusions, learns the performer's proportions."""

import numpy as np
import pytest

from live.core.errors import UserInputError
from live.core.frames import FrameResult, SkeletonFrame
from live.core.heading import yaw_between, yaw_of
from live.core.skeleton import JOINT_INDEX, bone_lengths, default_rest_joints
from live.imu.stage import FusionStage, build_stages
from live.io.session import SessionReader
from live.motion.clips import resample
from live.motion.rig_mapping import load_motion
from live.pipeline.runner import Pipeline
from sim.imu_stream import MotionScene, NoisySkeletonStage, write_suit_session
from sim.replay import ReplaySource

REST = default_rest_joints(1.68)


def test_yaw_between_recovers_a_turn():
    rng = np.random.default_rng(0)
    pred = rng.normal(size=(5, 3))
    a = 0.7
    c, s = np.cos(a), np.sin(a)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    angle, evidence = yaw_between(pred, pred @ rot.T, np.ones(5))
    assert angle == pytest.approx(a) and evidence > 0


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_bvh):
    motion = resample(load_motion(shared_bvh / "cc_002_05.bvh"), 30.0)
    scene = MotionScene.of(motion, REST)
    path = tmp_path_factory.mktemp("fusion") / "s.mcap"
    write_suit_session(path, scene, seed=3, frames=360)
    meta = next(s.meta for s in SessionReader(path).info.streams if s.kind == "serial")
    return path, scene, meta


def _run_timed(path, stages):
    """(seconds from the take's start (F,), skeletons (F, 22, 3), truth (F, 22, 3)) of the depth
    frames with a skeleton."""
    rows = []
    Pipeline([ReplaySource(path)], stages, mode="every",
             on_result=lambda r: rows.append((r.skeleton.joints, r.truth.joints, r.t_ns))
             if r.depth is not None and r.skeleton is not None else None).run()
    t = (np.array([c for _, _, c in rows], np.float64) - 1e9) / 1e9
    return t, np.array([a for a, _, _ in rows], np.float64), np.array([b for _, b, _ in rows], np.float64)


def _run(path, stages):
    return _run_timed(path, stages)[1:]


@pytest.fixture(scope="module")
def results(session):
    path, scene, meta = session
    out = {}
    depth = NoisySkeletonStage(seed=1)
    depth_frames = []
    orig = depth.process

    def keep(result):
        ok = orig(result)
        depth_frames.append(result.skeleton)
        return ok

    depth.process = keep
    out["depth"] = _run(path, build_stages("depth", depth_stage=depth))
    imu = build_stages("imu", stream_meta=meta, height=1.75)
    imu[0].world_yaw = float(yaw_of(scene.motion.rotations[0, 0]))
    imu[0].start = scene.root[0]
    out["imu"] = _run(path, imu)
    fused = build_stages("fused", depth_stage=NoisySkeletonStage(seed=1), stream_meta=meta, height=1.75)
    out["fused"] = _run(path, fused)
    out["fusion_stage"] = fused[1]
    out["depth_frames"] = depth_frames
    return out


def test_fused_beats_depth_only_and_imu_only(results):
    err = {m: np.linalg.norm(results[m][0] - results[m][1], axis=-1).mean() for m in ("depth", "imu", "fused")}
    assert err["fused"] < 0.9 * err["depth"], err
    assert err["fused"] < 0.9 * err["imu"], err
    assert err["fused"] < 0.04, err


def test_fusion_rides_through_occlusions(results):
    conf = np.array([s.confidence for s in results["depth_frames"]])
    occluded = conf < 0.5
    assert occluded.any()
    pred_d, gt = results["depth"]
    pred_f, _ = results["fused"]
    e_d = np.linalg.norm(pred_d - gt, axis=-1)[occluded]
    e_f = np.linalg.norm(pred_f - gt, axis=-1)[occluded]
    assert e_f.mean() < 0.5 * e_d.mean()


def test_fusion_learns_heading(results, session):
    _, scene, _ = session
    fuser = results["fusion_stage"].fuser
    off = np.degrees(fuser.heading.yaw - yaw_of(scene.motion.rotations[0, 0]))
    assert abs((off + 180) % 360 - 180) < 8


def test_fusion_learns_the_performers_proportions(session):
    path, _, meta = session
    # A wrong height (1.90 m template for a 1.68 m performer) and an unbiased depth skeleton.
    stages = build_stages("fused", depth_stage=NoisySkeletonStage(bias_m=0.0, seed=2), stream_meta=meta,
                          height=1.90)
    _run(path, stages)
    learned = bone_lengths(stages[1].fuser.rest_joints())
    truth = bone_lengths(REST)
    template = bone_lengths(default_rest_joints(1.90))
    assert np.abs(learned - truth).mean() < 0.01 < np.abs(template - truth).mean()


def test_fusion_stage_passes_depth_through_until_calibrated():
    stage = FusionStage(height=1.7)
    skel = SkeletonFrame(0, np.zeros((22, 3), np.float32), np.ones(22, np.float32))
    r = FrameResult(t_ns=0, skeleton=skel)
    assert stage.process(r) is False and r.skeleton is skel


def test_build_stages_rejects_unknown_modes():
    with pytest.raises(UserInputError):
        build_stages("both")
    assert [s.name for s in build_stages("fused", depth_stage=NoisySkeletonStage())] == ["skeleton", "fusion"]
    assert JOINT_INDEX["pelvis"] == 0


def test_solve_joints_weighs_depth_against_bones():
    from live.imu.fusion import solve_joints

    rng = np.random.default_rng(0)
    x = rng.normal(size=(22, 3))
    bones = np.array([x[c] - x[p] for p, c in __import__("live.core.skeleton", fromlist=["BONES"]).BONES])
    # Bones alone (and a faint prior at the truth) give the truth; depth alone gives depth.
    assert np.allclose(solve_joints(np.zeros((22, 3)), np.zeros(22), bones, np.ones(21), x, 1e-6), x, atol=1e-5)
    noisy = x + rng.normal(0, 0.05, x.shape)
    assert np.allclose(solve_joints(noisy, np.ones(22), bones, np.zeros(21), x, 0.0), noisy)
    # Both: the well-known bones pull a lone bad depth joint back toward its place.
    bad = x.copy()
    bad[20] += 0.3
    fused = solve_joints(bad, np.ones(22), bones, np.full(21, 1000.0), x, 0.0)
    assert np.linalg.norm(fused[20] - x[20]) < 0.03  # its pull shared by all 22 joints (1/22 of 0.52 m)


def test_sensor_filter_learns_a_mounting_error_and_refuses_outliers():
    from live.core.rotations import quat_from_axis_angle, quat_rotate
    from live.imu.fusion_filters import SensorFilter

    rng = np.random.default_rng(1)
    error = quat_from_axis_angle(np.radians([6.0, -4.0, 3.0]))  # the true mounting correction
    f = SensorFilter(1, gate=3.0)
    offsets = np.array([[0.0, -0.4, 0.0], [0.1, 0.0, 0.3]])
    for _ in range(300):
        seg = quat_from_axis_angle(rng.normal(0, 0.8, 3))[None]
        truth = quat_rotate(np.broadcast_to(quat_multiply_(seg[0], error), (2, 4)), offsets)
        obs = truth + rng.normal(0, 0.01, truth.shape)
        u, H = f.jacobian(seg, np.zeros(2, np.int64), offsets)
        f.predict(1 / 30)
        f.update(H, u, np.zeros(2, np.int64), obs, np.full(2, 0.03 ** 2), np.arange(2))
    from live.core.rotations import quat_angle

    assert np.degrees(quat_angle(quat_multiply_(np.array([error[0], -error[1], -error[2], -error[3]]), f.mount[0]))) < 1.5
    # A bone far off (a lost limb reported anyway) is refused and changes nothing.
    before = f.mount.copy()
    u, H = f.jacobian(seg, np.zeros(1, np.int64), offsets[:1])
    ok = f.update(H, u, np.zeros(1, np.int64), -u, np.full(1, 0.03 ** 2), np.zeros(1, np.int64))
    assert not ok.any() and np.allclose(f.mount, before)


def quat_multiply_(a, b):
    from live.core.rotations import quat_multiply

    return quat_multiply(a, b)


def test_fusion_carries_a_limb_depth_lost_but_still_reports(session):
    """The regressor keeps reporting a limb it lost (off by ~30 cm, confidence kept) for 2 s:
    the suit carries the limb; depth alone fails."""
    path, scene, meta = session

    class LostArm(NoisySkeletonStage):
        def process(self, result):
            ok = super().process(result)
            t = (result.t_ns - 1_000_000_000) / 1e9
            if ok and 4.0 <= t < 6.0:
                arm = [JOINT_INDEX["left_elbow"], JOINT_INDEX["left_wrist"]]
                joints = np.asarray(result.skeleton.joints).copy()
                joints[arm] += np.array([0.2, -0.15, 0.15])
                result.skeleton = SkeletonFrame(result.t_ns, joints, np.ones(22, np.float32))
            return ok

    arm = [JOINT_INDEX["left_elbow"], JOINT_INDEX["left_wrist"]]
    depth_stage = LostArm(occlusion_every_s=0.0, seed=4)
    rows = []
    keep = depth_stage.process

    def record(result):
        ok = keep(result)
        rows.append((result.t_ns, None if result.skeleton is None else np.asarray(result.skeleton.joints).copy()))
        return ok

    depth_stage.process = record
    pred, gt = _run(path, build_stages("fused", depth_stage=depth_stage, stream_meta=meta, height=1.75))
    t = np.array([r[0] for r in rows if r[1] is not None])
    depth = np.array([r[1] for r in rows if r[1] is not None], np.float64)
    lost = ((t - 1_000_000_000) / 1e9 >= 4.0) & ((t - 1_000_000_000) / 1e9 < 6.0)
    e_depth = np.linalg.norm(depth[lost][:, arm] - gt[lost][:, arm], axis=-1).mean()
    e_fused = np.linalg.norm(pred[lost][:, arm] - gt[lost][:, arm], axis=-1).mean()
    assert e_depth > 0.2 and e_fused < 0.06, (e_depth, e_fused)


class _Shifted(NoisySkeletonStage):
    """Depth skeletons moved as a whole by ``shift`` (m) from ``start`` s for ``seconds``."""

    def __init__(self, shift, start, seconds, **kw):
        super().__init__(occlusion_every_s=0.0, seed=5, **kw)
        self.shift, self.start, self.seconds = np.asarray(shift, np.float64), start, seconds

    def process(self, result):
        ok = super().process(result)
        t = (result.t_ns - 1_000_000_000) / 1e9
        if ok and self.start <= t < self.start + self.seconds:
            result.skeleton = SkeletonFrame(result.t_ns, np.asarray(result.skeleton.joints) + self.shift,
                                            result.skeleton.confidence)
        return ok


def test_a_depth_skeleton_jumping_as_a_whole_is_left_to_the_suit(session):
    """A performer half out of view is read half a metre too low for two frames: the fusion keeps
    the suit's root (counted) instead of dropping the body with it."""
    path, _, meta = session
    stages = build_stages("fused", depth_stage=_Shifted([0.0, -0.45, 0.1], 5.0, 0.1), stream_meta=meta, height=1.75)
    t, pred, gt = _run_timed(path, stages)
    err = np.linalg.norm(pred - gt, axis=-1).mean(1)
    jumped = (t >= 5.0) & (t < 5.1)
    assert jumped.any() and err[jumped].max() < 0.1, err[jumped]
    assert stages[1].fuser.counters["root_jumps"] == int(jumped.sum())


def test_depth_that_keeps_saying_the_body_is_elsewhere_places_it_again(session):
    """Depth puts the whole body 0.6 m to the side for 2 s (the suit's root drifted, say): after
    root_jump_hold_s the fused body goes where depth says."""
    path, _, meta = session
    stages = build_stages("fused", depth_stage=_Shifted([0.6, 0.0, 0.0], 5.0, 2.0), stream_meta=meta, height=1.75)
    t, pred, gt = _run_timed(path, stages)
    pelvis_x = pred[:, 0, 0] - gt[:, 0, 0]
    hold = stages[1].fuser.root_jump_hold_s
    assert np.all(np.abs(pelvis_x[(t >= 5.0) & (t < 5.0 + hold - 0.1)]) < 0.15)
    assert np.all(np.abs(pelvis_x[(t >= 5.0 + hold + 0.2) & (t < 7.0)] - 0.6) < 0.1)
