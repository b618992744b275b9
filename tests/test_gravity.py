"""The camera's own IMU: gravity from still periods of the accelerometer (live.core.gravity)."""

import numpy as np
import pytest

from live.core.gravity import STANDARD_GRAVITY, GravityEstimator
from live.core.rotations import angle_deg, quat_from_axis_angle, quat_to_matrix

RATE_HZ = 100.0


def up_for_pitch(pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """World up in OpenCV camera axes for a camera pitched down by pitch_deg and rolled by roll_deg."""
    p, r = np.radians(pitch_deg), np.radians(roll_deg)
    up = np.array([0.0, -np.cos(p), -np.sin(p)])  # level camera: up is -y; pitched down: tilts to -z
    c, s = np.cos(r), np.sin(r)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ up


def still(up: np.ndarray, seconds: float, rng: np.random.Generator, t0_s: float = 0.0,
          acc_std: float = 0.03, bias: np.ndarray | None = None, gyro_std: float = 0.003):
    """(t_ns, acc, gyro) samples of a still camera reading +g along ``up``."""
    n = int(round(seconds * RATE_HZ))
    t = (t0_s + np.arange(n) / RATE_HZ) * 1e9
    acc = STANDARD_GRAVITY * up + (0 if bias is None else bias) + rng.normal(0, acc_std, (n, 3))
    gyro = rng.normal(0, gyro_std, (n, 3))
    return [(int(round(t[i])), acc[i], gyro[i]) for i in range(n)]


def turn(up0: np.ndarray, up1: np.ndarray, seconds: float, t0_s: float):
    """A camera turned from up0 to up1 at a constant rate (gyro on, the reading follows with a jolt)."""
    axis = np.cross(up0, up1)
    angle = np.arccos(np.clip(up0 @ up1, -1, 1))
    axis = axis / np.linalg.norm(axis)
    n = int(round(seconds * RATE_HZ))
    out = []
    for i in range(n):
        u = quat_to_matrix(quat_from_axis_angle(axis * angle * (i + 1) / n)) @ up0
        # The hand pushing the camera adds ~1 m/s^2 of linear acceleration.
        acc = STANDARD_GRAVITY * u + np.array([0.8, 0.3, -0.5]) * np.sin(np.pi * (i + 1) / n)
        out.append((int(round((t0_s + i / RATE_HZ) * 1e9)), acc, axis * angle / seconds))
    return out


def feed(est: GravityEstimator, samples, with_gyro: bool = True) -> None:
    for t, a, g in samples:
        est.add(t, a, g if with_gyro else None)


def test_still_camera_gives_up_within_a_fraction_of_a_degree():
    rng = np.random.default_rng(0)
    est = GravityEstimator()
    truth = up_for_pitch(30.0, roll_deg=4.0)
    samples = still(truth, 2.0, rng, bias=np.array([0.03, -0.02, 0.04]))
    feed(est, samples[:40])
    assert est.up_in_camera() is None  # 0.4 s: not yet a still window
    feed(est, samples[40:])
    up = est.up_in_camera()
    assert up is not None and abs(np.linalg.norm(up) - 1) < 1e-12
    assert angle_deg(up, truth) < 0.5
    assert est.updates == 1 and est.moves == 0 and est.rejected == 0


def test_level_camera_reads_up_as_minus_y():
    est = GravityEstimator()
    feed(est, still(up_for_pitch(0.0), 1.0, np.random.default_rng(1)))
    np.testing.assert_allclose(est.up_in_camera(), [0, -1, 0], atol=0.01)


def test_a_move_replaces_the_up_and_is_counted():
    rng = np.random.default_rng(2)
    est = GravityEstimator()
    before, after = up_for_pitch(10.0), up_for_pitch(35.0, roll_deg=-5.0)
    feed(est, still(before, 2.0, rng))
    assert angle_deg(est.up_in_camera(), before) < 0.5
    feed(est, turn(before, after, 0.6, t0_s=2.0))
    assert angle_deg(est.up_in_camera(), before) < 0.5  # moving: the old up stays until still again
    feed(est, still(after, 1.5, rng, t0_s=2.6))
    assert angle_deg(est.up_in_camera(), after) < 0.5
    assert est.moves == 1 and est.updates == 2


def test_a_return_to_the_same_pose_refines_instead_of_moving():
    rng = np.random.default_rng(3)
    est = GravityEstimator()
    up = up_for_pitch(20.0)
    feed(est, still(up, 1.0, rng))
    feed(est, [(t, a + np.array([3.0, 0.0, 0.0]), g) for t, a, g in still(up, 0.3, rng, t0_s=1.0)])  # a bump
    feed(est, still(up, 1.0, rng, t0_s=1.3))
    assert est.moves == 0 and est.updates == 1
    assert angle_deg(est.up_in_camera(), up) < 0.3


def test_motion_without_gyro_is_caught_by_the_accelerometer():
    rng = np.random.default_rng(4)
    est = GravityEstimator()
    before, after = up_for_pitch(0.0), up_for_pitch(25.0)
    feed(est, still(before, 1.0, rng), with_gyro=False)
    feed(est, turn(before, after, 0.5, t0_s=1.0), with_gyro=False)
    feed(est, still(after, 1.0, rng, t0_s=1.5), with_gyro=False)
    assert angle_deg(est.up_in_camera(), after) < 0.5 and est.moves == 1


def test_a_slow_turn_that_looks_still_is_a_move():
    # 2 deg/s: below the gyro threshold, every 0.5 s window is still, yet the camera turns 10 deg.
    est = GravityEstimator()
    rng = np.random.default_rng(5)
    start, end = up_for_pitch(0.0), up_for_pitch(10.0)
    feed(est, still(start, 1.0, rng))
    n = int(5.0 * RATE_HZ)
    axis = np.array([1.0, 0.0, 0.0])
    for i in range(n):
        u = quat_to_matrix(quat_from_axis_angle(axis * np.radians(10.0) * (i + 1) / n)) @ start
        est.add(int((1.0 + i / RATE_HZ) * 1e9), STANDARD_GRAVITY * u + rng.normal(0, 0.03, 3),
                axis * np.radians(2.0))
    feed(est, still(end, 1.0, rng, t0_s=6.0))
    assert angle_deg(end, up_for_pitch(10.0)) < 1e-9
    assert angle_deg(est.up_in_camera(), end) < 1.0 and est.moves >= 1


def test_a_shaking_camera_never_gives_an_up():
    rng = np.random.default_rng(6)
    est = GravityEstimator()
    for t, a, g in still(up_for_pitch(15.0), 3.0, rng, acc_std=1.5, gyro_std=0.3):
        est.add(t, a, g)
    assert est.up_in_camera() is None and est.still_samples == 0


def test_wrong_magnitude_is_not_gravity():
    # A reading far from 9.81 (wrong units, a free fall, a centrifuge) is never taken for gravity.
    rng = np.random.default_rng(7)
    est = GravityEstimator()
    feed(est, [(t, a * 0.5, g) for t, a, g in still(up_for_pitch(0.0), 2.0, rng)])
    assert est.up_in_camera() is None


def test_gaps_and_bad_samples():
    rng = np.random.default_rng(8)
    est = GravityEstimator()
    up = up_for_pitch(30.0)
    samples = still(up, 0.4, rng)
    feed(est, samples)
    # 1 s without samples, then 0.4 s more: the window restarts after a gap, so still no up.
    feed(est, still(up, 0.4, rng, t0_s=1.4))
    assert est.up_in_camera() is None
    est.add(int(1.9e9), np.array([np.nan, 0, 0]), None)
    est.add(int(1.9e9), np.zeros(2), None)
    assert est.rejected == 2
    feed(est, still(up, 0.6, rng, t0_s=1.8))
    assert angle_deg(est.up_in_camera(), up) < 1.0


@pytest.mark.parametrize("pitch", [-45.0, -30.0, 0.0, 20.0])
def test_pitches_and_noise_levels(pitch):
    rng = np.random.default_rng(int(pitch) + 100)
    for acc_std in (0.01, 0.05, 0.1):
        est = GravityEstimator()
        truth = up_for_pitch(pitch, roll_deg=2.0)
        feed(est, still(truth, 1.5, rng, acc_std=acc_std))
        assert angle_deg(est.up_in_camera(), truth) < 0.5


def test_camera_imu_packets_are_recognised_and_suit_packets_are_not():
    from live.core.frames import MocapPacket
    from live.core.gravity import camera_imu_sample

    acc = np.array([[0.0, -9.8, 0.0]])
    t, a, g = camera_imu_sample(MocapPacket(7, "oak_imu", sensors=np.zeros(1, np.int32), acc=acc))
    assert t == 7 and g is None and np.array_equal(a, acc[0])
    assert camera_imu_sample(MocapPacket(7, "oak_imu", raw=b"\x01", acc=acc)) is None  # a suit's bytes
    assert camera_imu_sample(MocapPacket(7, "xsens0", sensors=np.zeros(1, np.int32), acc=acc)) is None
    assert camera_imu_sample(MocapPacket(7, "oak_imu", sensors=np.zeros(2, np.int32), acc=np.ones((2, 3)))) is None
    assert camera_imu_sample(object()) is None


def test_skeleton_stage_hands_the_imu_up_to_the_finder():
    from models.skeleton.runtime import SkeletonStage
    from sim.camera_imu import CameraImu
    from sim.depth_camera import look_at_camera

    c2w = look_at_camera(3.0, 1.6, 0.3, np.radians(30.0))  # tilted 30 degrees down, yawed
    truth = c2w[:3, :3].T @ np.array([0.0, 1.0, 0.0])
    stage = SkeletonStage(temporal=False)
    assert stage.finder.gravity_up is None
    imu = CameraImu(c2w, camera="oak", seed=1)
    for packet in imu.packets_until(int(1.5e9)):
        stage.observe(packet)
    stage.observe(object())
    counters = stage.counters
    assert counters["camera_imu_samples"] == 151 and counters["gravity_updates"] == 1
    assert angle_deg(stage.finder.gravity_up, truth) < 1.0


def test_synthetic_camera_imu_gives_up_when_extrinsics_are_hidden(tmp_path, shared_bvh):
    """A camera tilted 30 degrees down whose depth stream hides its pose: the recorded camera IMU
    survives record -> replay, and the skeleton stage's finder gets an up within 1 degree."""
    import json

    from live.core.frames import DepthFrame, MocapPacket
    from live.io.session import SessionReader
    from models.skeleton.runtime import SkeletonStage
    from sim.synth import CameraPlacement, SynthOptions, synthesize

    base = dict(motion=str(shared_bvh / "cc_002_01.bvh"), seconds=0.5, start_s=1.0, seed=4,
                placement=CameraPlacement(distance=2.8, height=1.9, yaw=0.5, pitch=np.radians(30.0)),
                hide_extrinsics=True)
    with_imu, without = tmp_path / "imu.mcap", tmp_path / "plain.mcap"
    synthesize(SynthOptions(**base, camera_imu=True), with_imu)
    synthesize(SynthOptions(**base), without)

    reader = SessionReader(with_imu)
    streams = {s.name: s for s in reader.info.streams}
    assert streams["cam_imu"].kind == "imu" and streams["cam_imu"].meta["frame"] == "camera"
    assert json.loads(reader.info.extra["synthetic"])["camera_imu"] is True
    truth_c2w = np.asarray(streams["gt"].meta["camera_to_world"])
    truth_up = truth_c2w[:3, :3].T @ np.array([0.0, 1.0, 0.0])

    stage = SkeletonStage(temporal=False)
    packets, depth = [], []
    for _, frame in reader.frames():
        if isinstance(frame, DepthFrame):
            assert np.array_equal(frame.camera_to_world, np.eye(4))  # the pose is withheld
            depth.append(frame)
            stage.estimate(frame)
        else:
            stage.observe(frame)
            if isinstance(frame, MocapPacket):
                packets.append(frame)
    assert reader.error is None
    # 100 Hz from 1 s before the first frame to the last one; acc and gyro survive the recording.
    assert len(packets) == 100 + 14 * 100 // 30 + 1
    assert all(p.device == "cam_imu" and p.quats is None and p.acc.shape == (1, 3) for p in packets)
    assert np.all(np.diff([p.t_ns for p in packets]) > 0)
    assert angle_deg(stage.gravity.up_in_camera(), truth_up) < 1.0
    assert angle_deg(stage.finder.gravity_up, truth_up) < 1.0
    assert stage.counters["gravity_updates"] == 1 and stage.finder.up_source.startswith("imu")

    # The camera IMU draws its own random numbers: the depth frames are those of the plain session.
    plain = [f for _, f in SessionReader(without).frames() if isinstance(f, DepthFrame)]
    assert len(plain) == len(depth)
    assert all(np.array_equal(a.depth_mm, b.depth_mm) for a, b in zip(plain, depth))
