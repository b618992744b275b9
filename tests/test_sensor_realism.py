"""Training scenes as users' sensors see people: clothes, occluders, bystanders, hidden extrinsics."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from live.body.library import load_body
from live.core.skeleton import JOINT_INDEX
from sim import sensor_realism
from sim.clothing import Outfit, dress, random_outfit, vertex_normals
from sim.depth_camera import closed_mesh_winding, look_at_camera
from sim.skeleton_data import REALISM_CAMERAS, plan_jobs, run_job


@pytest.fixture(scope="module")
def body():
    return load_body("adult_male_average")


def _volume(v: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (np.asarray(v, np.float64)[faces[:, k]] for k in range(3))
    return abs(float(np.einsum("fc,fc->f", a, np.cross(b, c)).sum()) / 6.0)


def test_vertex_normals_point_out_of_a_closed_body(body):
    v = np.asarray(body.vertices, np.float32)
    out = closed_mesh_winding(v, body.faces)
    assert out != 0
    n = vertex_normals(v, body.faces) * out
    assert np.linalg.norm(n, axis=1) == pytest.approx(1.0, abs=1e-5)
    # everything moved 1 cm along its normal: the body grows by about its area x 1 cm
    grown = _volume(v + 0.01 * n, body.faces) - _volume(v, body.faces)
    assert 0.01 < grown < 0.03  # m^3: an adult's skin is about 1.9 m^2


def test_an_outfit_moves_its_regions_outward_and_nothing_else(body):
    v = np.asarray(body.vertices, np.float32)
    joints = np.asarray(body.rest_joints)
    out = closed_mesh_winding(v, body.faces)
    assert np.array_equal(dress(v, body.faces, body.weights, joints, Outfit(), out), v)
    top = dress(v, body.faces, body.weights, joints, Outfit(top=0.04), out)
    moved = np.linalg.norm(top - v, axis=1)
    w = np.asarray(body.weights)
    torso = w[:, JOINT_INDEX["spine2"]] > 0.99
    feet = w[:, JOINT_INDEX["left_foot"]] + w[:, JOINT_INDEX["left_ankle"]] > 0.99
    assert moved[torso] == pytest.approx(0.04, abs=1e-3)
    assert moved[feet].max() < 1e-6
    hair = dress(v, body.faces, body.weights, joints, Outfit(hair=0.05), out)
    head = w[:, JOINT_INDEX["head"]] > 0.99
    crown = head & (v[:, 1] > v[head, 1].max() - 0.02)
    chin = head & (v[:, 1] < joints[JOINT_INDEX["neck"], 1] + 0.02)
    assert np.linalg.norm(hair - v, axis=1)[crown].mean() > 3 * np.linalg.norm(hair - v, axis=1)[chin].mean()


def test_random_outfits_are_seeded_and_within_their_ranges():
    a = [random_outfit(np.random.default_rng(s)) for s in range(50)]
    assert a == [random_outfit(np.random.default_rng(s)) for s in range(50)]
    assert max(o.top for o in a) <= 0.05 and any(o.skirt > 0 for o in a) and any(o.top == 0 for o in a)


def test_a_desk_stands_between_camera_and_performer(body):
    c2w = look_at_camera(1.0, 1.3, 0.7)
    joints = np.repeat(np.asarray(body.rest_joints, np.float64)[None], 10, axis=0)
    for seed in range(40):
        extras = sensor_realism.random_extras(np.random.default_rng(seed), body, joints, np.arange(3), c2w, True)
        for box in extras.boxes:
            c = np.asarray(box.center)[[0, 2]]
            eye = c2w[[0, 2], 3]
            assert 0.2 < c @ eye / np.linalg.norm(eye) < np.linalg.norm(eye)  # on the camera's side
        v, f = extras.mesh(np.asarray(body.vertices, np.float32), body, joints[0], 1)
        assert f.max() < len(v) and len(v) >= len(body.vertices)


def test_realism_jobs_use_every_sensor_and_give_samples(monkeypatch):
    jobs = plan_jobs("val_real", 400, 0)
    assert {j.camera for j in jobs} == set(REALISM_CAMERAS) and all(j.realism for j in jobs)
    assert not any(j.realism for j in plan_jobs("val", 40, 0))
    # Hidden extrinsics on every frame: the truth is moved into the world the finder estimated,
    # so it lies on the person's points (top of the head at the top of the cloud, pelvis inside).
    monkeypatch.setattr(sensor_realism, "HIDE_EXTRINSICS_SHARE", 1.0)
    job = next(j for j in jobs if not j.closeup)
    out = run_job(replace(job, camera="xtion"))
    assert len(out["frame"]) >= 4
    pts, joints = out["points"], out["joints"]
    top = np.percentile(pts[:, :, 1], 99, axis=1)
    assert np.abs(top - joints[:, JOINT_INDEX["head"], 1] - 0.1).max() < 0.2
    centre = np.median(pts[:, :, [0, 2]], axis=1)
    assert np.linalg.norm(joints[:, 0, [0, 2]] - centre, axis=1).max() < 0.3
    assert (joints[:, JOINT_INDEX["head"], 1] > joints[:, 0, 1] + 0.3).all()
    # Every sample carries its view's conditions, for errors reported per condition.
    from sim.skeleton_data import VIEW_KEYS

    assert all(len(out[k]) == len(out["frame"]) for k in VIEW_KEYS)
    assert out["hidden_extrinsics"].all()
    # pitch: + looking up (sensor_realism draws 20 degrees up to 45 down)
    assert -45.5 <= float(out["pitch_deg"][0]) <= 20.5 and 0.5 <= float(out["camera_height_m"][0]) <= 2.5


def test_realism_sequences_keep_each_frames_truth_in_the_finders_world(monkeypatch):
    from sim.skeleton_sequences import SEQUENCE_FRAMES, run_sequence_job

    monkeypatch.setattr(sensor_realism, "HIDE_EXTRINSICS_SHARE", 1.0)
    job = plan_jobs("train", 5, 3, frames_per_job=1, realism=True)[0]
    out = run_sequence_job(job)
    found = out["found"]
    assert found.sum() >= SEQUENCE_FRAMES // 2
    # the truth expressed through each found frame's person frame stands upright over its origin
    inv = np.linalg.inv(out["to_world"][found])
    local = np.einsum("fij,fkj->fki", inv[:, :3, :3], out["joints"][found]) + inv[:, None, :3, 3]
    assert (local[:, JOINT_INDEX["head"], 1] > local[:, 0, 1] + 0.3).all()
    assert np.abs(local[:, 0, [0, 2]]).max() < 0.6


def test_a_knee_up_job_gives_samples_of_a_performer_raising_a_knee():
    from live.core.skeleton import JOINT_INDEX as J

    job = next(j for j in plan_jobs("train", 400, 0, realism=True, knee_up_share=1.0) if not j.closeup)
    out = run_job(replace(job, camera="xtion"))
    assert len(out["frame"]) >= 4 and set(out["posture"]) == {"knee-up"}
    joints = out["joints"]
    raised = np.maximum(*(joints[:, J[f"{s}_knee"], 1] - joints[:, J[f"{s}_hip"], 1] for s in ("left", "right")))
    hanging = np.minimum(*(joints[:, J[f"{s}_knee"], 1] - joints[:, J[f"{s}_hip"], 1] for s in ("left", "right")))
    assert (hanging < -0.25).all() and raised.max() > hanging.max() + 0.1  # one leg stands, the other rises
