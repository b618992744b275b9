"""research.compare_skeleton's scores and groups (the held-out tables of docs/results.md)."""

from __future__ import annotations

import numpy as np

from research.compare_skeleton import groups, markdown, scores


def test_root_alignment_removes_a_shift_of_the_whole_skeleton():
    rng = np.random.default_rng(0)
    gt = rng.normal(0, 0.3, (10, 22, 3))
    pred = gt + np.array([0.2, 0.0, 0.0])  # every joint 20 cm off: the root was placed wrong
    s = scores(pred, gt, gt[:, :1] - pred[:, :1])
    assert abs(s["mpjpe_mm"] - 200.0) < 0.1 and s["pck_10cm"] == 0.0
    assert s["root_aligned_mpjpe_mm"] == 0.0 and s["root_aligned_pck_10cm"] == 1.0
    assert s["pa_mpjpe_mm"] < 1e-6 + 0.1


def test_val_real_groups_by_view_condition():
    n = 6
    d = {"camera": np.array(["xtion", "oak-d"] * 3), "body": np.array(["a"] * n),
         "posture": np.array(["clip", "seated", "clip", "clip", "crouching", "clip"]),
         "hidden_extrinsics": np.array([True, False] * 3), "closeup": np.zeros(n, bool),
         "pitch_deg": np.array([-30.0, -10, 0, 10, 20, 0]), "distance": np.array([1.5, 2.5, 3.5, 4.5, 2.2, 2.8])}
    g = dict(groups(d, "val_real"))
    assert g["posture:seated"].sum() == 1 and g["extrinsics hidden:True"].sum() == 3
    assert g["pitch deg:-5..5"].sum() == 2 and g["distance m:2..3"].sum() == 3
    assert "occluder:True" not in g  # data without that key: no group
    assert g["posture:clip, extrinsics hidden:True"].sum() == 2 and "posture:seated, extrinsics hidden:True" not in g
    assert set(dict(groups(d, "val"))) == {"camera:oak-d", "camera:xtion", "body:a"}
    table = markdown({"val_real": {"m.onnx": {k: scores(np.zeros((1, 22, 3)), np.zeros((1, 22, 3)), np.zeros((1, 1, 3)))
                                              for k in ("all", *g)}}})
    assert "posture:seated" in table and "root-aligned" in table


def test_views_like_the_real_xtion_frames_and_the_turned_share():
    n = 5
    d = {"camera": np.array(["xtion"] * n), "body": np.array(["a"] * n),
         "posture": np.array(["clip", "in-place", "seated", "clip", "clip"]),
         "hidden_extrinsics": np.array([False, False, False, True, False]), "closeup": np.zeros(n, bool),
         "occluder": np.array([False, False, False, False, True]),
         "pitch_deg": np.zeros(n), "distance": np.full(n, 3.0)}
    g = dict(groups(d, "val_real"))
    assert g["views like the real Xtion frames"].tolist() == [True, True, False, False, False]
    from live.core.skeleton import default_rest_joints

    gt = np.stack([default_rest_joints()] * 2)
    facing_away = gt * np.array([-1.0, 1.0, -1.0])  # turned 180 degrees about the vertical
    s = scores(np.stack([gt[0], facing_away[1]]), gt, np.zeros((2, 1, 3)))
    assert s["turned_45_share"] == 0.5
    assert scores(gt[:, :14], gt[:, :14], np.zeros((2, 1, 3)))["turned_45_share"] is None  # not 22 joints


def test_mirrored_readings_read_a_cloud_and_its_mirror_image_the_same_two_ways():
    from models.skeleton.runtime import DEFAULT_MODEL, SkeletonRegressor
    from research.compare_skeleton import mirrored_readings, predict
    from sim.skeleton_data import mirror

    rng = np.random.default_rng(3)
    n = SkeletonRegressor(DEFAULT_MODEL).num_points
    pts = rng.normal([0.0, 1.0, 0.0], [0.15, 0.45, 0.08], (4, n, 3))
    pts[:, :60, 0] += rng.uniform(0.3, 0.6, (4, 1))  # one arm out: not its own mirror image
    pts[:, :60, 1] = rng.uniform(1.3, 1.5, (4, 60))
    pts = pts.astype(np.float32)
    direct = predict(DEFAULT_MODEL, pts)
    r = mirrored_readings(DEFAULT_MODEL, {"points": pts, "joints": direct})
    assert r["frames"] == 4 and r["direct"] == 1.0 and r["better_of_two"] == 1.0
    assert 0 <= r["apart_90"] <= 4 and r["average"] <= 1.0 and r["fits_the_cloud_better"] <= 1.0
    # The mirror image's mirrored reading is the cloud's direct one, mirrored: it scores 1 there.
    flipped, truth = mirror(pts, direct)
    m = mirrored_readings(DEFAULT_MODEL, {"points": flipped, "joints": truth})
    assert m["better_of_two"] == 1.0 and m["apart_90"] == r["apart_90"]


def test_knee_up_views_score_the_stage_on_held_out_knee_raises_seen_from_in_front(tmp_path):
    import shutil

    from live.core.heading import body_heading
    from models.skeleton.runtime import DEFAULT_MODEL
    from research.knee_up_views import scenes, solve

    built = scenes(2, 6, seed=1)
    for scene, frames in built:
        assert frames == 6 and scene.motion.name.endswith("(knee-up)")
        to_camera = scene.camera.camera_to_world[[0, 2], 3] - scene.joints[0, 0, [0, 2]]
        facing = body_heading(scene.joints[:1])[0]
        ahead = (np.sin(facing) * to_camera[0] + np.cos(facing) * to_camera[1]) / np.linalg.norm(to_camera)
        assert ahead > np.cos(np.radians(60))  # the camera stands in front of the performer
    # The same network under another name reads the very frames the first one read: same scores.
    copy = tmp_path / "copy.onnx"
    shutil.copy(DEFAULT_MODEL, copy)
    shutil.copy(DEFAULT_MODEL.with_suffix(".json"), copy.with_suffix(".json"))
    rows = solve([DEFAULT_MODEL, copy], built)
    row = rows[str(DEFAULT_MODEL)]
    assert row["frames"] + row["frames_missed"] == 12 and 0.0 < row["mpjpe_mm"] < 300.0
    assert row["knees_mm"] > 0.0 and row["ankles_mm"] > 0.0
    assert rows[str(copy)] == row
