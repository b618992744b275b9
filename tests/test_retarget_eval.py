"""Retargeting evaluation: ground truth, metrics, analytic vs learned, the depth chain, the report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from live.core.errors import UserInputError

body_mod = pytest.importorskip("live.body.library")
pytest.importorskip("live.body.skinning")

from live.evaluation.retarget import METRICS, evaluate_retarget, format_report, grounded  # noqa: E402
from live.motion.rig_mapping import load_motion  # noqa: E402
from live.retarget.learned import DEFAULT_MODEL  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT.parent / "shared" / "data" / "bvh" / "mb_12_01.bvh"  # held-out subject 12
SKELETON_MODEL = ROOT / "models" / "weights" / "skeleton.onnx"


@pytest.fixture(scope="module")
def motion():
    if not CLIP.is_file():
        pytest.skip("no CMU clips in ../shared")
    return load_motion(CLIP)


@pytest.fixture(scope="module")
def bodies():
    from sim.skeleton_data import split_bodies

    val = split_bodies(body_mod.list_presets(), "val")
    return body_mod.load_body(val[0]), body_mod.load_body(val[-1])


def test_grounded_puts_feet_on_floor(motion):
    g = grounded(motion)
    lowest = np.percentile(g.joints[:, :, 1].min(axis=1), 5)
    assert abs(lowest - g.rest_joints[:, 1].min()) < 1e-5
    np.testing.assert_allclose(g.joints - g.joints[:, :1], motion.joints - motion.joints[:, :1], atol=1e-5)


def test_same_body_is_exact(motion, bodies):
    """Source == target: the analytic retargeter reproduces the ground-truth joints up to its foot
    handling (checks the ground-truth convention end to end); vertices differ more because leaf
    rotations (head, wrists, feet) are not observable from joint positions."""
    r = evaluate_retarget(motion, bodies[0], bodies[0], retarget="analytic", max_frames=60)
    assert set(METRICS) <= set(r)
    assert r["frames"] == 60 and r["found"] == 1.0
    assert r["mpjpe"] < 0.01 and r["mpvd"] < 0.04 and r["mdel"] < 0.002


def test_analytic_from_skeleton_meets_goal(motion, bodies):
    r = evaluate_retarget(motion, bodies[0], bodies[1], retarget="analytic", max_frames=90)
    assert r["mpjpe"] <= 0.010, r
    assert r["pa_mpjpe"] <= r["mpjpe"] + 1e-9 or r["pa_mpjpe"] < 0.01
    assert r["source_body"] == bodies[0].name and r["target_body"] == bodies[1].name


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed retarget.onnx")
def test_learned_from_skeleton(motion, bodies):
    r = evaluate_retarget(motion, bodies[0], bodies[1], retarget="learned", max_frames=90)
    assert r["mpjpe"] < 0.05 and r["pa_mpjpe"] < 0.04, r
    assert all(np.isfinite(r[m]) for m in METRICS)


@pytest.mark.skipif(not SKELETON_MODEL.is_file(), reason="no committed skeleton.onnx")
def test_depth_chain_runs(motion, bodies):
    r = evaluate_retarget(motion, bodies[0], bodies[1], from_="depth", retarget="analytic", max_frames=8)
    assert r["frames"] == 8 and r["found"] > 0.5
    assert all(np.isfinite(r[m]) for m in METRICS)
    assert r["mpjpe"] < 0.3


def test_report_and_errors(motion, bodies):
    r = evaluate_retarget(motion, bodies[0], bodies[1], max_frames=10)
    text = format_report([r, r])
    assert text.count("| analytic |") == 2 and "| reference |" in text and "158.0" in text
    # Acceleration errors are in mm/frame^2, the unit in the key, printed as they are.
    assert {"acc_mm_per_frame2", "pa_acc_mm_per_frame2"} <= set(r) and not {"acc", "pa_acc"} & set(r)
    assert "| 158.0 | 43.0 | 21.0 | 8.0 | 134.0 | 40.0 | 0.524 |" in text
    assert f"| {r['acc_mm_per_frame2']:.1f} | {r['pa_acc_mm_per_frame2']:.1f} |" in text
    with pytest.raises(UserInputError):
        evaluate_retarget(motion, bodies[0], bodies[1], from_="imu", max_frames=10)
    with pytest.raises(UserInputError):
        evaluate_retarget(motion, bodies[0], bodies[1], retarget="magic", max_frames=10)


def test_a_leading_bind_pose_is_cut_and_reported(bodies):
    """mb_12_01 starts with the exporter's bind pose: the evaluation plays the take without it
    and says so."""
    if not CLIP.is_file():
        pytest.skip("no CMU clips in ../shared")
    r = evaluate_retarget(CLIP, bodies[0], bodies[1], retarget="analytic", max_frames=30)
    assert r["bind_pose_frames_cut"] == 1 and r["frames"] == 30
    assert r["mpjpe"] < 0.01  # no teleport left in the ground truth for the foot lock to fight
