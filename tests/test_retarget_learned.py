"""The learned online retargeter: ONNX step == torch window, explicit state, interface, accuracy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from live.core.errors import ModelError, UserInputError
from live.core.frames import GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.metrics import mpjpe
from live.core.rotations import quat_from_axis_angle
from live.core.skeleton import default_rest_joints
from live.retarget.learned import DEFAULT_MODEL, LearnedRetargeter, learned_retarget_motion

ROOT = Path(__file__).resolve().parents[1]
BVH = ROOT.parent / "shared" / "data" / "bvh"


def _motion(rng: np.random.Generator, frames: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Smooth random rotations (T, 22, 4) and a walking root (T, 3)."""
    t = np.linspace(0, 1, frames)[:, None, None]
    amp = rng.normal(0, 0.35, (1, 22, 3))
    phase = rng.uniform(0, 2 * np.pi, (1, 22, 3))
    rot = quat_from_axis_angle(amp * np.sin(2 * np.pi * t + phase))
    root = np.stack([0.4 * t[:, 0, 0], 0.9 + 0.02 * np.sin(6 * t[:, 0, 0]), 0.8 * t[:, 0, 0]], axis=1)
    return rot, root


@pytest.fixture(scope="module")
def random_model(tmp_path_factory) -> Path:
    """A small untrained network (random weights, seeded) exported like the real one."""
    torch = pytest.importorskip("torch")
    from models.train.retarget_nets import RetargetNet, export_onnx

    torch.manual_seed(0)
    net = RetargetNet(hidden=32)
    for p in net.head[-1].parameters():  # non-zero head, so the output depends on everything
        torch.nn.init.normal_(p, 0.0, 0.05)
    path = tmp_path_factory.mktemp("rt") / "retarget.onnx"
    export_onnx(net, str(path))
    return path


def test_onnx_steps_match_torch_window(random_model):
    """Online ONNX steps with carried state == the torch network over the whole window."""
    torch = pytest.importorskip("torch")
    from models.train.retarget_nets import RetargetNet

    torch.manual_seed(0)
    net = RetargetNet(hidden=32)
    for p in net.head[-1].parameters():
        torch.nn.init.normal_(p, 0.0, 0.05)
    net.eval()
    rng = np.random.default_rng(1)
    src_rest, tgt_rest = default_rest_joints(1.8), default_rest_joints(1.2)
    rot, root = _motion(rng)
    src, _ = forward_kinematics(rot, root, src_rest)
    with torch.no_grad():
        _, t_root, t_joints = net.retarget(torch.tensor(src[None], dtype=torch.float32),
                                           torch.tensor(src_rest[None]), torch.tensor(tgt_rest[None]))
    o_root, _, o_joints = learned_retarget_motion(random_model, src_rest, tgt_rest, src)
    np.testing.assert_allclose(o_joints, t_joints[0].numpy(), atol=2e-4)
    np.testing.assert_allclose(o_root, t_root[0].numpy(), atol=2e-4)


def test_state_reset_and_interface(random_model):
    rng = np.random.default_rng(2)
    src_rest, tgt_rest = default_rest_joints(1.7), default_rest_joints(1.5)
    rot, root = _motion(rng, 12)
    src, _ = forward_kinematics(rot, root, src_rest)
    rt = LearnedRetargeter(random_model, src_rest, tgt_rest)
    first = [rt.step(j) for j in src]
    r, q, j = first[-1]
    assert r.shape == (3,) and q.shape == (22, 4) and j.shape == (22, 3)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    # The output joints are FK of the output rotations on the target T-pose (a valid pose).
    np.testing.assert_allclose(forward_kinematics(q, r, tgt_rest)[0], j, atol=1e-9)
    # State matters: the same frame after a history differs from a fresh start ...
    fresh = LearnedRetargeter(random_model, src_rest, tgt_rest).step(src[-1])
    assert np.abs(fresh[2] - j).max() > 1e-6
    # ... and reset() gives exactly the fresh result again.
    rt.reset()
    again = [rt.step(x) for x in src]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a[2], b[2])
    # Rotations + root in == their FK joints in; process() on frames == step().
    rt.reset()
    by_rot = rt.step(rot[0], root[0])
    np.testing.assert_allclose(by_rot[2], first[0][2], atol=1e-9)
    rt.reset()
    pose = rt.process(SkeletonFrame(t_ns=0, joints=src[0].astype(np.float32), confidence=np.ones(22, np.float32)))
    assert pose.t_ns == 0 and pose.joints.shape == (22, 3)
    pose = rt.process(GroundTruth(t_ns=33_333_333, joints=src[1], rotations=rot[1], root=root[1]))
    assert pose.rotations.shape == (22, 4)
    with pytest.raises(UserInputError):
        rt.step(np.zeros((21, 3)))
    with pytest.raises(UserInputError):
        rt.step(rot[0])


def test_missing_model_is_a_model_error(tmp_path):
    with pytest.raises(ModelError):
        LearnedRetargeter(tmp_path / "none.onnx", default_rest_joints(), default_rest_joints())


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed retarget.onnx")
def test_committed_model_on_held_out_clip():
    """The committed network on a held-out CMU subject (12) moved to a much smaller body."""
    from live.evaluation.retarget import grounded
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion

    clip = BVH / "mb_12_01.bvh"
    if not clip.is_file():
        clip = sorted(BVH.glob("*_12_*.bvh"))[0]
    motion = grounded(resample(load_motion(clip), 30.0))
    n = min(150, motion.num_frames)
    src_rest = motion.rest_joints
    tgt_rest = default_rest_joints(1.25)
    ratio = tgt_rest[0, 1] / src_rest[0, 1]
    gt, _ = forward_kinematics(motion.rotations[:n], motion.root[:n] * ratio, tgt_rest)
    _, _, pred = learned_retarget_motion(None, src_rest, tgt_rest, motion.joints[:n])
    err = mpjpe(pred, gt)
    # A sanity bound, not the goal: the target is a generic T-pose, not a library body like the
    # training ones (the held-out figures are in the card: 22.5 mm on library bodies). The
    # model trained with white source noise gave 50 mm here, the depth-noise one 55 mm.
    assert err < 0.065, f"MPJPE {err:.3f} m"
    # Reasonable motion: no frame jumps more than the truth does, by a wide margin.
    assert np.abs(np.diff(pred, axis=0)).max() < np.abs(np.diff(gt, axis=0)).max() + 0.1


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed retarget.onnx")
@pytest.mark.parametrize("kind", ["analytic", "learned"])
def test_step_globals_skin_like_the_quaternions(kind):
    """The live stage skins with each step's own global rotations: the same mesh as LBS from
    the step's quaternions and root."""
    from live.body.skinning import lbs, pose_transforms, skin
    from live.retarget.retargeter import AnalyticRetargeter

    rng = np.random.default_rng(5)
    src = default_rest_joints()
    dst = src * 0.8
    dst[:, 1] -= dst[:, 1].min() - src[:, 1].min()
    rot, root = _motion(rng, 12)
    joints, _ = forward_kinematics(rot, root, src)
    rt = AnalyticRetargeter(src, dst) if kind == "analytic" else LearnedRetargeter(None, src, dst)
    verts = (dst[rng.integers(0, 22, 300)] + rng.normal(0, 0.03, (300, 3))).astype(np.float32)
    weights = rng.random((300, 22)).astype(np.float32) ** 6
    weights /= weights.sum(1, keepdims=True)
    for j in joints:
        r, q, posed = rt.step(j)
        fast = skin(verts, weights, pose_transforms(rt.last_globals, posed, dst)[None])
        np.testing.assert_allclose(fast, lbs(verts, weights, dst, q[None], r[None]), atol=2e-5)


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed retarget.onnx")
def test_learned_with_foot_placement_holds_sliding_feet_above_the_floor():
    """The network's output through the analytic foot placement (as the retarget stage runs it):
    a standing source whose pelvis sways (its feet slide with it) gives avatar feet that stay
    put and never go below the floor."""
    from live.core.skeleton import NUM_JOINTS
    from live.retarget.contacts import FEET

    src = default_rest_joints()
    dst = default_rest_joints(1.4)
    t = 60
    rot = np.zeros((t, NUM_JOINTS, 4))
    rot[..., 0] = 1.0
    root = np.tile(src[0].astype(np.float64), (t, 1))
    root[:, 0] += 0.03 * np.sin(np.linspace(0, 2 * np.pi, t))
    root[:, 1] -= 0.03  # and pushed into the floor
    joints, _ = forward_kinematics(rot, root, src)
    raw = LearnedRetargeter(None, src, dst)
    placed = LearnedRetargeter(None, src, dst, foot_lock=True, floor=True)
    out_raw = np.stack([raw.step(j)[2] for j in joints])
    out = np.stack([placed.step(j)[2] for j in joints])
    ankles, feet = FEET[:, 0], FEET.ravel()
    assert np.ptp(out_raw[:, ankles, 0], axis=0).min() > 0.02  # the network slides with the source
    assert np.abs(out[8:, ankles] - out[8, ankles]).max() < 0.01  # locked
    assert out[:, feet, 1].min() > -1e-9 and placed.contact.all()
