"""The virtual depth camera: geometry, sensor noise, determinism, camera placement."""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import pytest

from live.core.depth import depth_to_points, points_to_world
from live.core.errors import UserInputError
from live.core.skeleton import default_rest_joints
from sim.depth_camera import (
    PRESETS,
    NoiseModel,
    VirtualDepthCamera,
    closed_mesh_winding,
    get_preset,
    look_at_camera,
    random_camera_pose,
)
from sim.room import Box, Room, capsule_body, merge_meshes, random_room

OAK = PRESETS["oak-d"]
FB = OAK.fx * OAK.baseline_m
FRONT = look_at_camera(3.0, 1.0, 0.0, pitch=0.0)  # at (0, 1, 3) looking along -z
ONLY = dict(disparity_sigma_px=0.0, quantize=False, edge_jump_px=0.0, occlusion=False,
            grazing_deg=None, dropout=0.0)


def only(**kw) -> NoiseModel:
    """A noise model with everything off except the keyword arguments."""
    return NoiseModel(**{**ONLY, **kw})


def wall(z_front: float, half: float = 0.5, y: float = 1.0):
    """A thin box whose front face (towards +z) is at z_front, 2*half wide and high."""
    return Box((0.0, y, z_front - 0.05), (2 * half, 2 * half, 0.1)).mesh()


@pytest.fixture(scope="module")
def body():
    """The default body posed at rest if the body library is available, else capsules."""
    try:
        from live.body.library import load_body

        b = load_body("default")
        return np.asarray(b.vertices, np.float32), np.asarray(b.faces, np.int32)
    except (ImportError, OSError, ValueError):
        return capsule_body(default_rest_joints())


def surface_distance(points: np.ndarray, mesh) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh[0]), o3d.core.Tensor(mesh[1].astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_presets():
    assert set(PRESETS) >= {"oak-d", "oak-d-pro", "kinect-v1"}
    for p in PRESETS.values():
        hfov = np.degrees(2 * np.arctan(p.width / 2 / p.fx))
        assert 55 < hfov < 85 and p.kind in ("stereo", "tof")
        assert p.baseline_m == pytest.approx(0.075 if p.kind == "stereo" else 0.0)
        assert p.intrinsics.shape == (3, 3) and p.min_range_m < p.max_range_m
    assert (PRESETS["kinect-v1"].width, PRESETS["kinect-v1"].height) == (640, 480)
    assert (OAK.width, OAK.height) == (640, 400)
    with pytest.raises(UserInputError):
        get_preset("no-such-camera")


def test_plane_renders_at_its_depth_on_the_right_pixels():
    cam = VirtualDepthCamera("oak-d", FRONT, noise=NoiseModel.none())
    depth, mask = cam.render_with_labels(*wall(1.0), room=False)
    assert depth.dtype == np.uint16 and depth.shape == (400, 640)
    assert np.all(depth[mask] == 2000) and np.all(depth[~mask] == 0)
    # The square spans +-0.5 m at z = 2 m: columns/rows within fx * 0.25 px of the centre.
    rows, cols = np.nonzero(mask)
    half = OAK.fx * 0.5 / 2.0
    assert cols.min() == pytest.approx(OAK.cx - half, abs=1) and cols.max() == pytest.approx(OAK.cx + half, abs=1)
    assert rows.min() == pytest.approx(OAK.cy - half, abs=1) and rows.max() == pytest.approx(OAK.cy + half, abs=1)
    np.testing.assert_array_equal(cam.intrinsics, OAK.intrinsics)


def test_back_projected_points_lie_on_the_surfaces(body):
    cam = VirtualDepthCamera("oak-d", look_at_camera(2.5, 1.3, 0.4), noise=NoiseModel.none())
    depth, mask = cam.render_with_labels(*body)
    assert mask.sum() > 5000
    pts = depth_to_points(np.where(mask, depth, 0), cam.intrinsics)
    world = points_to_world(pts, cam.camera_to_world)
    dist = surface_distance(world, body)
    assert np.median(dist) < 0.002 and np.quantile(dist, 0.99) < 0.02
    # Everything else lies on the room (floor and walls).
    room = points_to_world(depth_to_points(np.where(mask, 0, depth), cam.intrinsics), cam.camera_to_world)
    assert np.quantile(surface_distance(room, Room().mesh()), 0.99) < 0.005


def test_tile_culling_matches_a_full_cast(body):
    """The per-frame shortcut (room cached, body rays only where the body projects) gives the
    same first hits as one scene holding everything."""
    room = Room(boxes=(Box((1.5, 0.4, -1.0), (0.8, 0.8, 0.8)),))
    cam = VirtualDepthCamera("kinect-v1", look_at_camera(3.0, 1.6, -0.7), noise=NoiseModel.none())
    z, cos, mask = cam.render_ideal(*body, room=room)
    v, f = merge_meshes([body, room.mesh()])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f.astype(np.uint32)))
    full = scene.cast_rays(o3d.core.Tensor(cam._rays))["t_hit"].numpy()
    np.testing.assert_allclose(z, full, rtol=1e-5)
    assert mask.sum() > 3000


def test_depth_noise_grows_with_z_squared():
    sigma = 0.2
    stds = []
    for z in (1.0, 3.0):
        cam = VirtualDepthCamera("oak-d", FRONT, noise=only(disparity_sigma_px=sigma, noise_block_px=1), seed=1)
        depth, mask = cam.render_with_labels(*wall(3.0 - z, half=0.3 * z), room=False)
        err = depth[mask].astype(np.float64) / 1000.0 - z
        assert abs(np.mean(err)) < 0.1 * np.std(err) + 0.001
        stds.append(np.std(err))
        assert np.std(err) == pytest.approx(z * z / FB * sigma, rel=0.1)
    assert stds[1] / stds[0] == pytest.approx(9.0, rel=0.15)


def test_disparity_quantisation():
    cam = VirtualDepthCamera("oak-d", FRONT, noise=only(quantize=True, disparity_sigma_px=0.3), seed=2)
    depth, mask = cam.render_with_labels(*wall(0.0), room=False)
    disp = FB * 1000.0 / depth[mask]
    frac = disp * 8 - np.rint(disp * 8)  # 3 subpixel bits; mm rounding moves it a little
    assert np.abs(frac).max() < 0.05 and len(np.unique(depth[mask])) > 3
    cam = VirtualDepthCamera("oak-d", FRONT, noise=only(quantize=True, subpixel=False, disparity_sigma_px=0.3))
    depth, mask = cam.render_with_labels(*wall(0.0), room=False)
    disp = FB * 1000.0 / depth[mask]
    assert np.abs(disp - np.rint(disp)).max() < 0.02  # whole pixels only


def test_depth_edges_are_invalid(body):
    cam = VirtualDepthCamera("oak-d", look_at_camera(2.5, 1.2, 0.0), noise=only(edge_jump_px=1.0, edge_width_px=1))
    depth, mask = cam.render_with_labels(*body)
    z, _, _ = cam.render_ideal(*body)
    disp = FB / z
    jump = np.zeros(mask.shape, bool)  # a pixel next to a neighbour > 1 px of disparity away
    for axis in (0, 1):
        step = np.abs(np.diff(disp, axis=axis)) > 1.0
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        jump[tuple(lo)] |= step
        jump[tuple(hi)] |= step
    border = mask & ~(np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1))
    assert (border & jump).sum() > 0.8 * border.sum() > 200  # the silhouette is a depth edge...
    assert np.all(depth[jump] == 0) and np.all(depth[~jump & np.isfinite(z)] > 0)  # only edges go
    assert (depth[mask] > 0).mean() > 0.8


def test_occlusion_shadow_is_beside_the_foreground():
    cam = VirtualDepthCamera("oak-d", FRONT, noise=only(occlusion=True))
    depth, mask = cam.render_with_labels(*wall(1.0, half=0.3), room=Room())
    row = int(round(OAK.cy))
    cols = np.nonzero(mask[row])[0]
    hidden = np.nonzero(depth[row] == 0)[0]
    assert np.all((hidden > cols.max()) & (hidden <= cols.max() + 20))
    # The band is as wide as the disparity step between the box (2 m) and the wall (7 m).
    assert len(hidden) == pytest.approx(FB / 2.0 - FB / 7.0, abs=1.5)


def test_grazing_angles_are_invalid():
    # A plane tilted so that the rays meet it between ~70 and ~90 degrees from its normal.
    tilt = np.radians(80.0)
    n = np.array([0.0, np.sin(tilt), np.cos(tilt)])
    a = np.cross(n, [1.0, 0.0, 0.0])
    c = np.array([0.0, 1.0, 0.0])
    quad = np.array([c - 2 * a - 1.0 * np.array([1, 0, 0]), c - 2 * a + np.array([1, 0, 0]),
                     c + 2 * a + np.array([1, 0, 0]), c + 2 * a - np.array([1, 0, 0])], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    cam = VirtualDepthCamera("oak-d", FRONT, noise=only(grazing_deg=80.0))
    z, cos, mask = cam.render_ideal(quad, faces, room=False)
    depth = cam.render(quad, faces, room=False)
    steep = mask & (cos < np.cos(np.radians(80.0)))
    assert steep.sum() > 100 and (mask & ~steep).sum() > 100
    assert np.all(depth[steep] == 0) and np.all(depth[mask & ~steep] > 0)


def test_dropouts_and_range_limits():
    cam = VirtualDepthCamera("oak-d", FRONT, noise=only(dropout=0.1), seed=3)
    depth, mask = cam.render_with_labels(*wall(0.0), room=False)
    assert (depth[mask] == 0).mean() == pytest.approx(0.1, abs=0.01)
    near = VirtualDepthCamera("oak-d", FRONT, noise=only())
    assert not near.render(*wall(2.8, half=0.05), room=False).any()  # 0.2 m < min range 0.35 m
    far_box = wall(-9.0, half=3.0)  # 12 m > max range 10 m
    assert not near.render(*far_box, room=False).any()
    unlimited = VirtualDepthCamera("oak-d", FRONT, noise=only(range_limits=False))
    assert unlimited.render(*far_box, room=False).max() == 12000


def test_same_seed_same_bytes(body):
    pose = look_at_camera(2.0, 1.0, 1.0)
    a = VirtualDepthCamera("oak-d-pro", pose, seed=7)
    b = VirtualDepthCamera("oak-d-pro", pose, seed=7)
    frames_a = [a.render(*body) for _ in range(2)]
    frames_b = [b.render(*body) for _ in range(2)]
    assert all(x.tobytes() == y.tobytes() for x, y in zip(frames_a, frames_b))
    assert frames_a[0].tobytes() != frames_a[1].tobytes()  # noise changes from frame to frame
    c = VirtualDepthCamera("oak-d-pro", pose, seed=8)
    assert c.render(*body).tobytes() != frames_a[0].tobytes()


def test_realistic_default_noise_keeps_most_of_the_body(body):
    cam = VirtualDepthCamera("oak-d", look_at_camera(2.5, 1.2, 0.0), seed=0)
    depth, mask = cam.render_with_labels(*body)
    kept = (depth[mask] > 0).mean()
    assert 0.6 < kept < 0.99
    world = points_to_world(depth_to_points(np.where(mask, depth, 0), cam.intrinsics), cam.camera_to_world)
    assert np.median(surface_distance(world, body)) < 0.03


def test_mesh_behind_or_around_the_camera():
    cam = VirtualDepthCamera("oak-d", FRONT, noise=NoiseModel.none())
    behind = Box((0.0, 1.0, 4.0), (1.0, 1.0, 0.5)).mesh()
    assert not cam.render_with_labels(*behind, room=False)[1].any()
    around = Box((0.0, 1.0, 3.0), (4.0, 4.0, 4.0)).mesh()  # the camera sits inside the box
    depth, mask = cam.render_with_labels(*around, room=False)
    assert mask.all() and np.all(depth == 2000)  # every ray meets the far face, z = 1 (2 m away)
    with pytest.raises(UserInputError):
        cam.render(np.zeros((3, 2), np.float32), np.zeros((1, 3), np.int32))
    with pytest.raises(UserInputError):
        cam.render(np.zeros((3, 3), np.float32), np.array([[0, 1, 3]], np.int32))
    with pytest.raises(UserInputError):
        VirtualDepthCamera("oak-d", np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(UserInputError):
        NoiseModel(dropout=1.5)


def test_look_at_camera_conventions():
    m = look_at_camera(3.0, 1.5, 0.0)
    np.testing.assert_allclose(m[:3, 3], [0.0, 1.5, 3.0])
    r = m[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert r[2, 2] < 0 and r[0, 0] == pytest.approx(1.0)  # looks along -z; image right = world +x
    assert r[1, 1] < 0  # image down is world down
    side = look_at_camera(2.0, 1.0, np.pi / 2, pitch=0.0)
    np.testing.assert_allclose(side[:3, 3], [2.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(side[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)
    down = look_at_camera(2.0, 1.0, 0.0, pitch=0.3)
    assert down[1, 2] == pytest.approx(-np.sin(0.3))


def test_random_camera_pose_sees_the_target():
    rng = np.random.default_rng(0)
    for _ in range(20):
        m = random_camera_pose(rng, pitch_jitter=0.05)
        eye = m[:3, 3]
        assert 0.5 <= eye[1] <= 2.0 and 1.5 <= np.hypot(eye[0], eye[2]) <= 4.0
        target_cam = m[:3, :3].T @ (np.array([0.0, 1.0, 0.0]) - eye)
        assert target_cam[2] > 0
        v = target_cam[1] / target_cam[2] * OAK.fy + OAK.cy
        u = target_cam[0] / target_cam[2] * OAK.fx + OAK.cx
        assert abs(u - OAK.cx) < 1e-6 and abs(v - OAK.cy) < OAK.fy * np.tan(0.05) + 1


def test_random_room_keeps_clutter_away(body):
    room = random_room(np.random.default_rng(4), n_boxes=(3, 3))
    assert len(room.boxes) == 3
    for b in room.boxes:
        assert np.hypot(b.center[0], b.center[2]) > 1.0 and b.center[1] == pytest.approx(b.size[1] / 2)
    cam = VirtualDepthCamera("oak-d", look_at_camera(2.5, 1.2, 0.5), seed=0)
    depth, mask = cam.render_with_labels(*body, room=room)
    assert mask.any() and (depth > 0).mean() > 0.5


def test_back_face_culling_is_safe(body):
    """Closed meshes drop their far side from the scene; open or inverted ones still render."""
    v, f = capsule_body(default_rest_joints())
    assert closed_mesh_winding(v, f) == 1 and closed_mesh_winding(v, f[:, ::-1]) == -1
    assert closed_mesh_winding(v, f[:-1]) == 0  # a hole
    cam = VirtualDepthCamera("oak-d", look_at_camera(2.0, 1.0, 2.0), noise=NoiseModel.none())
    ref = cam.render(v, f)
    for faces in (f[:, ::-1], f[:-1]):  # rounding of the hit distance may move 1 mm
        np.testing.assert_allclose(cam.render(v, faces).astype(np.int32), ref, rtol=0, atol=1)
    # A single quad is visible from both sides.
    bv, bf = Box((0.0, 1.0, 0.0), (1.0, 1.0, 1.0)).mesh()
    front = bf[(bv[bf][:, :, 2] > 0).all(axis=1)]  # the two triangles of the +z face
    assert len(front) == 2
    cam = VirtualDepthCamera("oak-d", FRONT, noise=NoiseModel.none())
    for faces in (front, front[:, ::-1]):
        assert (cam.render(bv, faces, room=False) == 2500).sum() > 10000


def test_docs_figure(tmp_path, shared_bvh):
    from research.figures import virtual_depth_figure

    out = virtual_depth_figure(tmp_path / "fig.png", shared_bvh / "cc_002_01.bvh", frame=10)
    img = cv2.imread(str(out))
    assert img.shape == (400, 2 * 640 + 6, 3) and img.std() > 20


def test_between_worlds_moves_points_through_the_camera():
    from live.core.depth import between_worlds, points_to_world

    true_c2w = look_at_camera(2.5, 1.4, 0.3)
    solved_c2w = look_at_camera(1.0, 0.9, -0.7)  # another world frame seeing the same camera
    cam = np.array([[0.1, -0.2, 2.0], [-0.3, 0.4, 3.1]])
    moved = between_worlds(points_to_world(cam, true_c2w), true_c2w, solved_c2w)
    np.testing.assert_allclose(moved, points_to_world(cam, solved_c2w), atol=1e-6)


def test_time_of_flight_noise_grows_linearly_with_range_and_has_no_disparity_steps():
    sds = []
    for z in (1.5, 3.0):  # a wall z metres in front of the camera, filling the view
        cam = VirtualDepthCamera("kinect-v2", FRONT, noise=NoiseModel(dropout=0.0, grazing_deg=None), seed=1)
        depth = cam.render(*wall(3.0 - z, half=4.0), room=False).astype(np.float64)
        inner = depth[150:270, 180:330]
        assert (inner > 0).all()
        sds.append(inner.std())
        # 1 mm steps: many distinct values, unlike a disparity sensor's few quantised depths
        assert len(np.unique(inner)) > 20
    assert sds[1] / sds[0] == pytest.approx(2.0, rel=0.15)
    assert sds[1] == pytest.approx(1000 * 3.0 * PRESETS["kinect-v2"].tof_sigma_m_per_m, rel=0.15)


def test_flying_pixels_lie_between_foreground_and_background():
    from sim.depth_camera import measure_depth

    z = np.full((60, 80), 3.0, np.float32)
    z[:, :40] = 1.0  # a vertical depth edge at column 40
    cos = np.ones_like(z)
    quiet = NoiseModel(disparity_sigma_px=0.0, quantize=False, edge_jump_px=0.0, occlusion=False,
                       grazing_deg=None, dropout=0.0)
    rng = np.random.default_rng(0)
    plain = measure_depth(z, cos, PRESETS["oak-d"], quiet, rng)
    assert set(np.unique(plain)) == {1000, 3000}
    from dataclasses import replace

    flying = measure_depth(z, cos, PRESETS["oak-d"], replace(quiet, flying_pixels=0.5), rng)
    between = (flying > 1000) & (flying < 3000)
    assert between[:, 39:41].mean() == pytest.approx(0.5, abs=0.15)  # only beside the edge
    assert not between[:, :38].any() and not between[:, 42:].any()


def test_hole_blobs_take_their_share_in_connected_patches():
    import cv2

    from sim.depth_camera import measure_depth

    z = np.full((200, 320), 2.0, np.float32)
    noise = NoiseModel(disparity_sigma_px=0.0, edge_jump_px=0.0, occlusion=False, grazing_deg=None,
                       dropout=0.0, hole_blobs=0.05)
    depth = measure_depth(z, np.ones_like(z), PRESETS["oak-d"], noise, np.random.default_rng(3))
    holes = depth == 0
    assert holes.mean() == pytest.approx(0.05, abs=0.01)
    n, _ = cv2.connectedComponents(holes.astype(np.uint8))
    assert n - 1 < holes.sum() / 20  # blobs of many pixels, not scattered single pixels
    with pytest.raises(UserInputError):
        NoiseModel(hole_blobs=1.5)
