"""The other renderer of the held-out depth test (research.other_renderer): its camera, sensors,
rooms, plan, scores, and one small case through the skeleton stage."""

import json

import numpy as np
import pytest

from research.other_renderer import (
    GROUP_INDEX,
    Case,
    folder_frames,
    load_case,
    plan_cases,
    score,
    solve,
)
from research.other_renderer_scene import (
    FOCAL_640,
    KINECT_BASELINE_M,
    SENSORS,
    Scene,
    box,
    ideal_depth,
    make_camera,
    nguyen_axial_m,
    phasor_mix,
    quantise_disparity,
    random_room,
    structured_light,
    time_of_flight,
)

HELD_OUT_BODIES = {"adult_male_average", "elderly_female_heavy", "short_male", "teen_girl_14y"}


def _facing_wall(sensor: str, distance: float, blocker: bool = False):
    """A 320x240 camera 1.5 m high looking along -z at a wall ``distance`` away (its front face),
    optionally a 0.4 m cube 1 m in front of the wall."""
    wall = box((10.0, 10.0, 0.1), np.array([0.0, 1.5, -distance - 0.05]))
    meshes = [wall] + ([box((0.4, 0.4, 0.4), np.array([0.0, 1.5, -distance + 1.2]))] if blocker else [])
    cam = make_camera(sensor, 320, 240, np.array([0.0, 1.5, 0.0]), np.pi, 0.0)
    return Scene(meshes, [0.7] * len(meshes)), cam


def test_camera_axes_and_projection():
    cam = make_camera("structured-light", 640, 480, np.array([1.0, 1.2, 3.0]), 0.3, np.radians(-20.0))
    rot = cam.camera_to_world[:3, :3]
    assert np.allclose(rot.T @ rot, np.eye(3)) and np.isclose(np.linalg.det(rot), 1.0)
    forward = rot[:, 2]
    assert forward[1] < 0  # negative pitch looks down
    assert rot[1, 0] == pytest.approx(0.0)  # image x stays level
    assert rot[1, 1] < 0  # image y points down the world
    point = cam.camera_to_world[:3, 3] + 2.0 * forward
    p = (point - cam.camera_to_world[:3, 3]) @ rot
    assert p[0] / p[2] * cam.fx + cam.cx == pytest.approx(cam.cx)
    assert cam.fx == pytest.approx(FOCAL_640["structured-light"])


def test_ideal_depth_is_the_distance_along_the_optical_axis():
    scene, cam = _facing_wall("structured-light", 2.5)
    z = ideal_depth(scene, cam)
    assert z.shape == (240, 320)
    assert np.allclose(z, 2.5, atol=1e-5)  # z, not the ray length, in every pixel


def test_disparity_quantisation_steps():
    fb = FOCAL_640["structured-light"] * KINECT_BASELINE_M
    z = np.linspace(2.9, 3.1, 500)
    q = np.unique(quantise_disparity(z, FOCAL_640["structured-light"]))
    d = fb / q * 8
    assert np.allclose(d, np.round(d), atol=1e-6)  # every depth is f b / (k / 8)
    assert np.diff(q).mean() == pytest.approx(3.0**2 / fb / 8, rel=0.1)  # ~25 mm steps at 3 m


def test_structured_light_noise_grows_with_the_square_of_depth():
    rng = np.random.default_rng(0)
    sds = {}
    for distance in (1.5, 3.5):
        scene, cam = _facing_wall("structured-light", distance)
        z = structured_light(scene, cam, rng)
        assert (z > 0).mean() > 0.99
        assert z[z > 0].mean() == pytest.approx(distance, abs=0.01)
        sds[distance] = z[z > 0].std()
    assert sds[3.5] == pytest.approx(float(np.hypot(nguyen_axial_m(np.array(3.5), np.array(0.0)),
                                                     3.5**2 / (FOCAL_640["structured-light"] * 0.075) / 8 / 12**0.5)),
                                      rel=0.25)
    assert sds[3.5] > 3.0 * sds[1.5]


def test_projector_shadow_lies_on_one_side_of_an_object():
    scene, cam = _facing_wall("structured-light", 3.0, blocker=True)
    z = structured_light(scene, cam, np.random.default_rng(1))
    row = z[120]
    block = np.flatnonzero((row > 0) & (row < 2.5))
    holes = np.flatnonzero(row == 0)
    assert len(holes) >= 3
    assert holes.min() > block.max()  # the projector sits to the camera's left: the shadow falls right


def test_phasor_mix_of_one_return_is_exact_and_of_two_lies_near_them():
    r, a = phasor_mix(np.array([[2.0, 2.0]]), np.array([[1.0, 1.0]]))
    assert r[0] == pytest.approx(2.0) and a[0] == pytest.approx(2.0)
    r, a = phasor_mix(np.array([[2.0, 2.1]]), np.array([[1.0, 1.0]]))
    assert 2.0 < r[0] < 2.1 and a[0] < 2.0  # in between, and weaker than either alone would add to


def test_time_of_flight_has_flying_pixels_at_depth_edges_only():
    scene, cam = _facing_wall("time-of-flight", 3.0, blocker=True)
    z = time_of_flight(scene, cam, np.random.default_rng(2))
    flying = (z > 0) & (np.abs(z - 1.8) > 0.05) & (np.abs(z - 3.0) > 0.05)
    assert flying.sum() > 10
    plain, _ = _facing_wall("time-of-flight", 3.0)
    z0 = time_of_flight(plain, cam, np.random.default_rng(2))
    assert np.abs(z0[z0 > 0] - 3.0).max() < 0.05 and (z0 > 0).mean() > 0.99


def test_rooms_keep_the_performer_and_the_line_of_sight_clear():
    camera_xz = np.array([2.0, 2.5])
    toward = camera_xz / np.linalg.norm(camera_xz)
    side = np.array([toward[1], -toward[0]])
    for seed in range(12):
        room = random_room(np.random.default_rng(seed), camera_xz)
        again = random_room(np.random.default_rng(seed), camera_xz)
        assert room.items == again.items and np.array_equal(room.meshes[-1][0], again.meshes[-1][0])
        assert len(room.meshes) == len(room.albedo)
        for v, _ in room.meshes:
            xz = v[:, [0, 2]].astype(np.float64)
            if np.ptp(xz, axis=0).max() >= 9.9:
                continue  # the floor and the walls
            assert np.linalg.norm(xz, axis=1).min() > 0.5
            along, off = xz @ toward, np.abs(xz @ side)
            assert not np.any((along > 0.5) & (along < np.linalg.norm(camera_xz) - 0.3) & (off < 0.6))


def test_plan_holds_out_clips_and_bodies_and_covers_every_combination():
    from sim.skeleton_data import list_clips

    subjects = {c.file: c.subject for c in list_clips()}
    cases = plan_cases(32, seed=0)
    assert cases == plan_cases(32, seed=0)
    assert {c.body for c in cases} == HELD_OUT_BODIES
    assert {subjects[c.clip] for c in cases} <= {7, 8, 12, 16}
    assert len({(c.body, c.sensor, c.width, c.hide_extrinsics) for c in cases}) == 32
    assert {c.sensor for c in cases} == set(SENSORS)


def test_score_root_aligns_counts_nobody_and_elsewhere():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(5, 22, 3))
    pred = gt + np.array([0.3, 0.0, 0.0])  # a pure shift: nothing after root alignment
    pred[1] = np.nan
    pred[2] += 1.0  # the whole skeleton on something else: counted, still scored
    pred[3, GROUP_INDEX["limbs"]] += np.array([0.0, 0.08, 0.0])
    m = score(pred, gt)
    assert (m["frames"], m["nobody"], m["elsewhere"]) == (5, 1, 1)
    assert m["torso_mm"] == 0.0 and m["head_mm"] == 0.0
    assert m["limbs_mm"] == pytest.approx(80.0 / 4, abs=0.1)
    assert m["pck_10cm"] == 1.0


def test_a_case_renders_to_a_depth_folder_the_stage_solves(tmp_path):
    case = Case(0, "mb_12_01.bvh", "teen_girl_14y", "structured-light", 320, 240, True, 5)
    data, folder = load_case(case, 3, cache=tmp_path)
    assert data["depth"].shape == (3, 240, 320) and data["depth"].dtype == np.uint16
    meta = json.loads((folder / "intrinsics.json").read_text())
    assert "camera_to_world" not in meta and meta["width"] == 320  # hidden, as a user's folder has it
    frames = folder_frames(folder)
    assert len(frames) == 3 and np.array_equal(frames[0].depth_mm, data["depth"][0])
    again, _ = load_case(case, 3, cache=tmp_path)  # cached
    assert np.array_equal(again["depth"], data["depth"])
    out = solve(frames, data["joints"], data["camera_to_world"], None)
    m = score(out["pred"], out["gt"])
    assert (m["frames"], m["nobody"], m["elsewhere"]) == (3, 0, 0)
    assert m["mpjpe_mm"] < 100.0
    assert np.isfinite(out["solved_c2w"]).all()  # the world the stage estimated without extrinsics
