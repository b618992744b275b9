"""Depth-chain source skeletons for training the learned retargeter (models.train.chain_sources)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

body_mod = pytest.importorskip("live.body.library")

from live.core.kinematics import forward_kinematics  # noqa: E402
from live.core.skeleton import pelvis_height  # noqa: E402
from models.train.chain_sources import plan_runs, run_chain  # noqa: E402

CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "bvh" / "cc_002_05.bvh"  # a training subject


@pytest.fixture(scope="module")
def data():
    """One clip in load_clips' layout (grounded, 30 fps)."""
    if not CLIP.is_file():
        pytest.skip("no CMU clips in ../shared")
    from live.evaluation.retarget import grounded
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion

    m = grounded(resample(load_motion(CLIP), 30.0))
    return {"rotations": m.rotations.astype(np.float32), "root": m.root.astype(np.float32),
            "offsets": np.array([0, m.num_frames]), "rest": m.rest_joints[None].astype(np.float32),
            "names": np.array([CLIP.name]), "subject": np.array([2])}


def test_plan_is_seeded_and_uses_only_the_given_bodies(data):
    a = plan_runs(data, np.array([0]), ["heavy_male", "petite_female"], 3, 90, seed=5)
    b = plan_runs(data, np.array([0]), ["heavy_male", "petite_female"], 3, 90, seed=5)
    assert a == b and len(a) == 3
    n_clip = int(data["offsets"][1])
    for r in a:
        assert r["body"] in ("heavy_male", "petite_female")
        assert 0 <= r["start"] and r["start"] + r["frames"] <= n_clip and r["frames"] == min(90, n_clip)
        assert 1.5 <= r["distance"] <= 4.0 and abs(r["yaw"]) <= np.pi / 2


def test_chain_joints_lie_in_the_clips_own_coordinates(data):
    """The stage's joints are compared with the truth frame by frame in training: they must be
    the same motion, on the same body, in the same coordinates (a wrong shift or scale would
    teach the retargeter an offset)."""
    from live.body.library import mean_rest_template
    from sim.skeleton_data import split_bodies

    run = plan_runs(data, np.array([0]), ["heavy_male"], 1, 45, seed=0)[0]
    template = mean_rest_template(tuple(split_bodies(body_mod.list_presets(), "train")))
    out = run_chain(run, data, template)
    assert out["joints"].shape == (45, 22, 3) and out["found"].shape == (45,) and out["found"].mean() > 0.8
    body = body_mod.load_body("heavy_male")
    lo, hi = run["start"], run["start"] + run["frames"]
    rest_clip = data["rest"][0]
    root = data["root"][lo:hi] * (pelvis_height(body.rest_joints) / pelvis_height(rest_clip))
    truth = forward_kinematics(data["rotations"][lo:hi], root, body.rest_joints)[0]
    err = np.linalg.norm(out["joints"] - truth, axis=-1)[out["found"]]
    assert err.mean() < 0.1, err.mean()
    # The performer's T-pose, estimated from the joints seen, is about the body's size.
    assert abs(pelvis_height(out["rest"]) / pelvis_height(body.rest_joints) - 1) < 0.1
