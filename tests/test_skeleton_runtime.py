"""The live skeleton stage with the committed ONNX models on rendered OAK-D frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from live.core.errors import ModelError
from live.core.frames import DepthFrame, FrameResult
from live.core.metrics import mpjpe
from models.skeleton.runtime import BASELINE_MODEL, DEFAULT_MODEL, SkeletonRegressor, SkeletonStage

BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bvh"
CLIP = "cc_007_03.bvh"  # a validation subject (7): never seen in training
LEGS = [4, 5, 7, 8, 10, 11]
UPPER = [0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21]


def render(distance: float, height: float, n: int, target=(0.0, 1.0, 0.0), body_only: bool = True,
           seed: int = 0) -> tuple[list[DepthFrame], np.ndarray]:
    """n consecutive OAK-D frames of a held-out body performing a held-out clip, and the truth."""
    from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera
    from sim.room import Box, Room
    from sim.skeleton_data import body_by_name, clip_motion, grounded_joints
    from sim.synth import SyntheticScene

    body = body_by_name(_held_out_body())
    motion = clip_motion(CLIP)
    root, joints = grounded_joints(motion, body)
    start = 60
    c = joints[start:start + n, 0].mean(axis=0)
    shift = np.array([c[0], 0.0, c[2]])
    c2w = look_at_camera(distance, height, 0.6, target=target)
    cam = VirtualDepthCamera("oak-d", c2w, noise=NoiseModel(), seed=seed)
    scene = SyntheticScene(motion=motion, body=body, camera=cam, root=root - shift, joints=joints - shift)
    room = Room(boxes=(Box((2.0, 0.4, -1.2), (0.8, 0.8, 0.8)),))
    frames, truth = [], []
    for k, i in enumerate(range(start, start + n, 2)):  # 30 fps from the 60 fps clip
        depth = cam.render(scene.vertices(i), body.faces, room=room)
        frames.append(DepthFrame(t_ns=1_000_000_000 + k * 33_333_333, sensor="oak", camera_to_world=c2w,
                                 depth_mm=depth, intrinsics=cam.intrinsics))
        truth.append(scene.joints[i])
    return frames, np.asarray(truth)


@pytest.fixture(scope="module")
def walk():
    return render(2.6, 1.4, 40)


def test_regressor_single_and_batch_agree(walk):
    from models.skeleton.preprocess import PersonFinder
    from models.skeleton.preprocess_config import PreprocessConfig

    reg = SkeletonRegressor()
    assert reg.num_points == reg.card["num_points"]
    clouds = [PersonFinder(PreprocessConfig(num_points=reg.num_points)).find(f) for f in walk[0][:3]]
    batch = reg(np.stack([c.points for c in clouds]))
    assert batch.shape == (3, 22, 3) and batch.dtype == np.float32
    np.testing.assert_allclose(reg(clouds[1].points), batch[1], atol=1e-5)


def test_stage_follows_a_held_out_performer(walk):
    frames, truth = walk
    stage = SkeletonStage()
    out = []
    for f in frames:
        result = FrameResult(t_ns=f.t_ns, depth=f)
        assert stage.process(result)
        assert result.skeleton.joints.shape == (22, 3) and result.skeleton.t_ns == f.t_ns
        assert np.all((result.skeleton.confidence >= 0) & (result.skeleton.confidence <= 1))
        out.append(result.skeleton.joints)
    err = mpjpe(np.asarray(out[5:]), truth[5:])
    # A sanity bound around the model card's held-out figure (~42 mm), not the goal.
    assert err < 0.12, f"MPJPE {err * 1000:.0f} mm"
    assert stage.counters["skeletons"] == len(frames) and stage.counters["nobody"] == 0


def test_raw_stage_is_jumpier_than_filtered(walk):
    frames, truth = walk
    raw = SkeletonStage(temporal=False, filter=False, keep_bones=False)
    smooth = SkeletonStage()
    a = np.asarray([raw.estimate(f).joints for f in frames], np.float64)
    b = np.asarray([smooth.estimate(f).joints for f in frames], np.float64)

    def jerk(x):
        return np.linalg.norm(np.diff(x - truth, 2, axis=0), axis=-1).mean()

    assert jerk(b) < jerk(a)


def test_nobody_in_view_no_skeleton_no_crash(walk):
    from sim.depth_camera import VirtualDepthCamera, look_at_camera
    from sim.room import Room

    c2w = look_at_camera(2.6, 1.4, 0.6)
    cam = VirtualDepthCamera("oak-d", c2w, seed=1)
    empty = cam.render(np.zeros((3, 3), np.float32), np.zeros((0, 3), np.int32), room=Room())
    stage = SkeletonStage()
    result = FrameResult(t_ns=5, depth=DepthFrame(t_ns=5, sensor="oak", camera_to_world=c2w, depth_mm=empty,
                                                   intrinsics=cam.intrinsics))
    assert stage.process(result) is False and result.skeleton is None
    assert stage.process(FrameResult(t_ns=6)) is False
    assert stage.counters["nobody"] == 1


def test_close_up_upper_body_with_low_leg_confidence():
    frames, truth = render(1.1, 1.5, 16, target=(0.0, 1.3, 0.0))
    stage = SkeletonStage()
    skels = [stage.estimate(f) for f in frames]
    assert all(s is not None for s in skels)
    joints = np.asarray([s.joints for s in skels])
    conf = np.asarray([s.confidence for s in skels])
    assert conf[:, LEGS].mean() < 0.2
    assert conf[:, [12, 15, 16, 17]].mean() > 0.5
    err = mpjpe(joints[4:, UPPER], truth[4:, UPPER])
    # Sanity bound (the card's held-out close-up figure is 46 mm for the upper body).
    assert err < 0.16, f"upper-body MPJPE {err * 1000:.0f} mm"


def test_missing_model_is_a_model_error(tmp_path):
    with pytest.raises(ModelError, match="no skeleton model"):
        SkeletonRegressor(tmp_path / "none.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(ModelError, match="cannot load"):
        SkeletonRegressor(bad)


def test_the_finder_samples_as_the_model_card_says(tmp_path):
    import json
    import shutil

    shutil.copy(DEFAULT_MODEL, tmp_path / "edges.onnx")
    card = json.loads(DEFAULT_MODEL.with_suffix(".json").read_text())
    card["preprocess"] = {"edge_jump_share": 0.2}
    (tmp_path / "edges.json").write_text(json.dumps(card))
    stage = SkeletonStage(tmp_path / "edges.onnx", temporal=False)
    assert stage.finder.config.edge_jump_share == 0.2
    assert stage.finder.config.num_points == stage.regressor.num_points
    shipped = SkeletonRegressor().edge_jump_share
    assert SkeletonStage(temporal=False).finder.config.edge_jump_share == shipped


def test_evaluate_sessions_compares_both_models(tmp_path):
    from live.evaluation.skeleton import evaluate_sessions, format_report
    from sim.synth import CameraPlacement, SynthOptions, synthesize

    session = tmp_path / "s.mcap"
    # A held-out subject (8) whose clip stands on the floor as loaded (synth does not re-ground).
    synthesize(SynthOptions(motion=str(BVH / "mb_08_04.bvh"), body=_held_out_body(), seconds=0.5, start_s=1.8,
                            seed=3, placement=CameraPlacement(distance=2.5, height=1.3, yaw=1.4)), session)
    report = evaluate_sessions([session], compare_baseline=True)
    assert set(report["models"]) == {"ours", "baseline"}
    ours = report["models"]["ours"]
    assert ours["frames"] == 15 and ours["frames"] - ours["no_skeleton"] >= 10
    assert 0 < ours["mpjpe_mm"] < 150 and ours["pa_mpjpe_mm"] <= ours["mpjpe_mm"]
    assert set(ours["latency_ms"]) == {"p50", "p95", "p99"} and ours["acc_mm_per_frame2"] is not None
    assert ours["turned_45_share"] <= 0.2  # a clean session from the side: the body read the right way round
    text = format_report(report)
    assert "MPJPE (mm)" in text and "baseline" in text and "left_wrist" in text and "turned > 45 deg" in text
    assert DEFAULT_MODEL.is_file() and BASELINE_MODEL.is_file()


def _held_out_body() -> str:
    from live.body.library import list_presets
    from sim.skeleton_data import split_bodies

    return split_bodies(list_presets(), "val")[0]
