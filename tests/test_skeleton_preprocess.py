"""Finding the person in a depth frame: clutter, walls, no one in view, unknown floor, filters."""

from __future__ import annotations

import numpy as np
import pytest

from live.core.frames import DepthFrame
from live.core.skeleton import LEFT_RIGHT_SWAP, default_rest_joints
from models.skeleton import point_sample
from models.skeleton.background import BackgroundModel
from models.skeleton.filters import BoneLengthKeeper, FlipGuard, OneEuroFilter, joint_confidence
from models.skeleton.point_sample import R2_STEP, R2_VISITS, fine_sample, r2_grid_order
from models.skeleton.preprocess import PersonFinder
from models.skeleton.preprocess_config import PreprocessConfig
from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera
from sim.room import Box, Room, capsule_body

JOINTS = default_rest_joints(1.75).astype(np.float64)
# Arms down a little so that the capsule person is a compact, human-like cluster.
PERSON = capsule_body(JOINTS)
ROOM = Room(width=9.0, depth=9.0, boxes=(Box((1.6, 0.4, -0.8), (0.8, 0.8, 0.8)),
                                         Box((-2.0, 0.6, 0.5), (1.2, 1.2, 0.6))))


def frame(c2w: np.ndarray, mesh=PERSON, room=ROOM, t_ns: int = 1_000, noise=None, seed: int = 0,
          identity_extrinsics: bool = False) -> DepthFrame:
    cam = VirtualDepthCamera("oak-d", c2w, noise=noise or NoiseModel(), seed=seed)
    depth = cam.render(*mesh, room=room) if mesh is not None else cam.render(
        np.zeros((3, 3), np.float32), np.zeros((0, 3), np.int32), room=room)
    return DepthFrame(t_ns=t_ns, sensor="cam", camera_to_world=np.eye(4) if identity_extrinsics else c2w,
                      depth_mm=depth, intrinsics=cam.intrinsics)


FRONT = look_at_camera(3.0, 1.3, 0.4)


def test_person_found_in_clutter_and_mapped_back_exactly():
    finder = PersonFinder()
    cloud = finder.find(frame(FRONT))
    assert cloud is not None and cloud.points.shape == (512, 3) and cloud.points.dtype == np.float32
    # The person frame: origin on the floor under the person, camera toward +z.
    assert np.hypot(*cloud.to_world[[0, 2], 3]) < 0.15
    assert 1.6 < cloud.height_m < 1.95
    cam_local = np.linalg.inv(cloud.to_world) @ np.r_[FRONT[:3, 3], 1.0]
    assert abs(cam_local[0]) < 1e-6 and cam_local[2] > 2.5
    # Every sample point maps back onto the person (within the sensor noise of the capsules).
    world = cloud.points @ cloud.to_world[:3, :3].T + cloud.to_world[:3, 3]
    assert np.all(np.abs(world[:, [0, 2]]).max(axis=1) < 0.9)
    assert world[:, 1].min() > 0.0 and world[:, 1].max() < 1.95
    assert finder.counters.found == 1


def test_sample_is_deterministic_per_frame():
    f = frame(FRONT)
    a, b = PersonFinder().find(f), PersonFinder().find(f)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.to_world, b.to_world)


def test_nobody_in_view_gives_none():
    finder = PersonFinder()
    assert finder.find(frame(FRONT, mesh=None)) is None
    assert finder.counters.nobody == 1 and finder.counters.found == 0


def test_wall_right_behind_the_person_is_not_the_person():
    room = Room(width=6.0, depth=6.0, boxes=())  # back wall at z = -3, 0.4 m behind the person
    person = capsule_body(JOINTS + [0.0, 0.0, -2.6])
    c2w = look_at_camera(2.5, 1.3, 0.2, target=(0.0, 1.0, -2.6))
    cloud = PersonFinder().find(frame(c2w, mesh=person, room=room))
    assert cloud is not None and np.hypot(cloud.to_world[0, 3], cloud.to_world[2, 3] + 2.6) < 0.15
    assert cloud.height_m < 1.95


def test_big_box_with_more_points_loses_to_the_person():
    room = Room(width=9.0, depth=9.0, boxes=(Box((1.3, 0.55, 1.0), (1.0, 1.1, 1.0)),))
    cloud = PersonFinder().find(frame(look_at_camera(3.5, 1.5, 0.3), room=room))
    assert cloud is not None and np.hypot(*cloud.to_world[[0, 2], 3]) < 0.15


def test_unknown_extrinsics_floor_by_ransac():
    finder = PersonFinder()
    cloud = finder.find(frame(FRONT, identity_extrinsics=True, room=Room(width=9.0, depth=9.0)))
    assert cloud is not None
    # Heights are above the estimated floor: the head is ~1.75 m high whatever the camera pose.
    assert 1.6 < cloud.height_m < 1.95
    assert finder.up_source == "floor" and finder.ground.floor_seen
    # The camera_to_world the frame was solved in: the camera ~1.5 m above the floor, level-ish.
    assert cloud.camera_to_world is not None and abs(cloud.camera_to_world[1, 3] - FRONT[1, 3]) < 0.05


def test_close_up_with_legs_out_of_frame_is_still_found():
    c2w = look_at_camera(1.0, 1.5, 0.0, target=(0.0, 1.35, 0.0))
    cloud = PersonFinder().find(frame(c2w))
    assert cloud is not None
    assert cloud.points[:, 1].min() > 0.5  # only the upper body is seen


def test_background_model_removes_static_scene():
    bg = BackgroundModel()
    empty = frame(FRONT, mesh=None)
    bg.learn(empty.depth_mm)
    finder = PersonFinder(background=bg)
    cloud = finder.find(frame(FRONT))
    assert cloud is not None and np.hypot(*cloud.to_world[[0, 2], 3]) < 0.15
    assert PersonFinder(background=bg).find(empty) is None


def test_one_euro_is_smooth_when_still_and_follows_motion():
    rng = np.random.default_rng(0)
    f = OneEuroFilter(min_cutoff=1.0, beta=0.5)
    noisy = JOINTS + rng.normal(0, 0.01, (60,) + JOINTS.shape)
    out = np.array([f(x, i / 30) for i, x in enumerate(noisy)])
    assert np.std(out[30:] - JOINTS, axis=0).mean() < 0.5 * np.std(noisy[30:] - JOINTS, axis=0).mean()
    fast = OneEuroFilter(min_cutoff=1.0, beta=3.0)  # beta: less lag at speed
    moving = [JOINTS + [0.03 * i, 0, 0] for i in range(60)]  # 0.9 m/s
    out = np.array([fast(x, i / 30) for i, x in enumerate(moving)])
    assert np.abs(out[-1] - moving[-1]).max() < 0.03


def test_flip_guard_gives_way_to_a_mirrored_first_frame():
    """One mirrored first frame must not mirror the whole take: after max_run frames that all
    disagree with it, the guard follows the estimates."""
    guard = FlipGuard(max_run=3)
    guard(JOINTS[LEFT_RIGHT_SWAP])  # the first estimate, mirrored
    out = [guard(JOINTS + 0.002 * i) for i in range(1, 8)]
    assert guard.flips == 2 and guard.recoveries == 1
    assert all(np.abs(o - (JOINTS + 0.002 * i)).max() < 1e-12 for i, o in enumerate(out[2:], start=3))
    # A glitch of one frame after that is still undone.
    fixed = guard(JOINTS[LEFT_RIGHT_SWAP] + 0.016)
    assert guard.flips == 3 and np.abs(fixed - (JOINTS + 0.016)).max() < 1e-12


def test_flip_guard_and_bone_keeper():
    guard = FlipGuard()
    walk = JOINTS.copy()
    guard(walk)
    fixed = guard(walk[LEFT_RIGHT_SWAP] + 0.005)
    assert guard.flips == 1 and np.abs(fixed - walk).max() < 0.01
    keeper = BoneLengthKeeper(warmup_frames=5)
    conf = np.ones(22, np.float32)
    for _ in range(6):
        keeper(JOINTS, conf)
    stretched = JOINTS.copy()
    stretched[20] += [0.1, 0.0, 0.0]  # the left wrist 10 cm too far
    out = keeper(stretched, conf)
    assert abs(np.linalg.norm(out[20] - out[18]) - np.linalg.norm(JOINTS[20] - JOINTS[18])) < 1e-6


def test_joint_confidence_support():
    pts = np.random.default_rng(0).normal(JOINTS[15], 0.03, (50, 3))
    conf = joint_confidence(JOINTS, pts)
    assert conf[15] == pytest.approx(1.0) and conf[7] == 0.0 and conf.dtype == np.float32


def test_fast_helpers_match_numpy():
    from models.skeleton.preprocess import _is_identity, _median

    rng = np.random.default_rng(1)
    for n in (1, 2, 7, 1000, 1001):
        x = rng.normal(size=n).astype(np.float32)
        assert _median(x) == float(np.median(x))
    for m in (np.eye(4), np.eye(4) + 1e-9, np.eye(4) * (1 + 2e-5), np.diag([1.0, 1, 1, 0.5])):
        assert _is_identity(m) == np.allclose(m, np.eye(4))


def test_joint_confidence_counts_points_within_the_radius():
    rng = np.random.default_rng(2)
    pts = rng.normal(JOINTS[12], 0.15, (256, 3)).astype(np.float32)
    near = (np.linalg.norm(pts[None].astype(np.float64) - JOINTS[:, None], axis=-1) < 0.12).sum(1)
    assert np.array_equal(joint_confidence(JOINTS, pts), np.clip(near / 6.0, 0, 1).astype(np.float32))


def walking_frames(n: int, speed_m_s: float = 0.6, jump_at: int | None = None, jump_m: float = 0.0):
    """n frames at 30 fps of the capsule person walking along x in front of FRONT (a jump of
    jump_m along x from frame jump_at on)."""
    out = []
    for k in range(n):
        x = -0.4 + speed_m_s * k / 30.0 + (jump_m if jump_at is not None and k >= jump_at else 0.0)
        out.append(frame(FRONT, mesh=capsule_body(JOINTS + [x, 0.0, 0.0]), t_ns=1_000_000_000 + k * 33_333_333,
                         seed=k))
    return out


def test_tracking_window_finds_what_the_whole_image_search_finds():
    frames = walking_frames(45)
    tracking, whole = PersonFinder(), PersonFinder(PreprocessConfig(track_margin_m=None))
    for f in frames:
        a, b = tracking.find(f), whole.find(f)
        assert a is not None and b is not None
        np.testing.assert_array_equal(a.to_world, b.to_world)
        np.testing.assert_allclose(a.points, b.points, atol=1e-6)
    c = tracking.counters
    # Whole-image searches: the first frames (no 0.3 s motion cue yet), then one per second.
    assert c.tracked + c.full_searches == c.frames == 45
    assert c.tracked >= 30 and 9 <= c.full_searches <= 14
    assert whole.counters.tracked == 0 and whole.counters.full_searches == 45


def test_tracking_finds_a_performer_who_left_the_window():
    frames = walking_frames(24, jump_at=20, jump_m=1.2)
    finder = PersonFinder()
    for f in frames[:20]:
        finder.find(f)
    assert finder.counters.tracked > 0
    full = finder.counters.full_searches
    cloud = finder.find(frames[20])  # the window around the old place holds nobody now
    assert cloud is not None and abs(cloud.to_world[0, 3] - (-0.4 + 0.6 * 20 / 30 + 1.2)) < 0.15
    assert finder.counters.full_searches == full + 1


def test_fine_sample_draws_distinct_person_pixels_even_from_a_mostly_empty_box(monkeypatch):
    f = frame(FRONT)
    finder = PersonFinder()
    cfg = finder.config
    c2w = np.asarray(f.camera_to_world, np.float64)
    found = finder._search(f, cfg.coarse_stride, c2w, None, None, 10)
    h, w = (-(-n // cfg.coarse_stride) for n in f.depth_mm.shape)
    drawn = []
    real = point_sample._person_points
    monkeypatch.setattr(point_sample, "_person_points", lambda idx, *a: drawn.append(len(idx)) or real(idx, *a))
    s = cfg.pixel_stride
    rays = finder._world_rays(f.intrinsics, f.depth_mm[::s, ::s].shape, c2w, s)
    for box in (found.box, (0, h - 1, 0, w - 1)):  # the person's box; the whole image (person ~5 %)
        pts = fine_sample(f, c2w, box, found.labels, found.lab, found.origin, np.random.default_rng(3), rays, cfg,
                          finder.background)
        assert pts.shape == (cfg.num_points, 3)
        assert len(np.unique(pts, axis=0)) == cfg.num_points  # without replacement
        # Every point lies in the person's cells, above the floor.
        i = np.floor((pts[:, 0] - found.origin[0]) / cfg.cell_m).astype(int)
        j = np.floor((pts[:, 2] - found.origin[1]) / cfg.cell_m).astype(int)
        assert np.all(found.labels[j, i] == found.lab) and np.all(pts[:, 1] > cfg.floor_margin_m)
    # One quick pass of at most 6n box pixels for the person's box; for the whole image it starts
    # over on all of them.
    assert len(drawn) == 3 and max(drawn[:2]) <= R2_VISITS * cfg.num_points and drawn[2] > 20 * cfg.num_points


def test_r2_order_spreads_any_prefix_evenly_and_is_distinct():
    rows, cols = 40, 60
    rng = np.random.default_rng(0)
    def empty_blocks(cells: np.ndarray) -> int:  # of the 150 blocks of 4 x 4 cells
        return int((np.bincount((cells // cols // 4) * (cols // 4) + (cells % cols) // 4, minlength=150) == 0).sum())

    r2_empty, random_empty = [], []
    for _ in range(50):
        offset = rng.random(2)
        order = r2_grid_order(rows, cols, 600, offset)
        assert len(np.unique(order)) == len(order) and order.min() >= 0 and order.max() < rows * cols
        # The cells in the order the sequence first visits them.
        k = (np.arange(1, 601)[:, None] * R2_STEP + offset) % 1.0
        visits = (k[:, 0] * rows).astype(int) * cols + (k[:, 1] * cols).astype(int)
        _, first = np.unique(visits, return_index=True)
        np.testing.assert_array_equal(order, visits[np.sort(first)])
        assert len(order) > 550  # few repeats to drop
        # 300 visits over 150 blocks: each block's share is 2.
        r2_empty.append(empty_blocks(order[:300]))
        random_empty.append(empty_blocks(rng.choice(rows * cols, 300, replace=False)))
    # A uniform random draw leaves ~e^-2 = 13 % of the blocks empty (~18 here); R2 about 2.
    assert np.mean(r2_empty) < 4 and np.mean(random_empty) > 12 and max(r2_empty) < min(random_empty)
    # A random offset visits every cell with the same probability.
    hits = np.zeros(rows * cols)
    for _ in range(1000):
        hits[r2_grid_order(rows, cols, 120, rng.random(2))] += 1
    assert hits.min() > 0 and hits.std() / hits.mean() < 0.25


def test_ransac_plane_is_deterministic_and_fits_a_noisy_floor():
    from models.skeleton.ground import ransac_plane

    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-2, 2, 3000), 1.4 + rng.normal(0, 0.01, 3000), rng.uniform(1, 5, 3000)]
    clutter = rng.uniform([-2, -0.5, 1], [2, 1.3, 5], (1500, 3))
    pts = np.vstack([floor, clutter])
    runs = [ransac_plane(pts, 0.02, 200, np.random.default_rng(0)) for _ in range(2)]
    (n, d, inliers), (n2, d2, inliers2) = runs
    assert np.array_equal(n, n2) and d == d2 and np.array_equal(inliers, inliers2)
    assert abs(abs(n[1]) - 1.0) < 1e-3 and abs(abs(d) - 1.4) < 0.005  # the plane y = 1.4 (camera axes)


def test_edge_pixels_mark_both_sides_of_a_jump_not_slopes_or_holes():
    from models.skeleton.depth_edges import edge_pixels

    z = np.full((6, 8), 2.0, np.float32)
    z[:, 5:] = 3.0  # a wall 1 m behind: a jump of half the range
    z[3, 1] = 0.0  # a hole is no edge
    edge = edge_pixels(z, 0.15)
    assert edge[:, 4].all() and edge[:, 5].all()
    assert not edge[:, :4].any() and not edge[:, 6:].any()
    slope = np.tile(np.linspace(2.0, 2.5, 8, dtype=np.float32), (6, 1))  # 7 cm steps
    assert not edge_pixels(slope, 0.15).any()


def test_edge_share_keeps_depth_edge_pixels_out_of_the_sample():
    from models.skeleton.depth_edges import edge_pixels

    camera = look_at_camera(2.0, 1.3, 0.4)
    noise = NoiseModel(flying_pixels=0.6, edge_jump_px=0.0, occlusion=False)  # depth across every edge
    f = frame(camera, room=Room(width=5.0, depth=5.0, boxes=()), noise=noise, seed=3)
    z = f.depth_mm[::2, ::2].astype(np.float32) * np.float32(0.001)  # the sample's pixel stride
    edge = edge_pixels(np.where((z > 0.3) & (z < 6.0), z, np.float32(0)), 0.15)

    def on_edges(share):
        cloud = PersonFinder(PreprocessConfig(edge_jump_share=share)).find(f)
        world = cloud.points @ cloud.to_world[:3, :3].T + cloud.to_world[:3, 3]
        cam = (world - camera[:3, 3]) @ camera[:3, :3]
        k = f.intrinsics
        u = np.rint(cam[:, 0] / cam[:, 2] * k[0, 0] + k[0, 2]).astype(int)
        v = np.rint(cam[:, 1] / cam[:, 2] * k[1, 1] + k[1, 2]).astype(int)
        return int(edge[v // 2, u // 2].sum())

    assert on_edges(None) > 0
    assert on_edges(0.15) == 0


def test_edge_test_at_pixels_matches_a_whole_image_reference():
    from models.skeleton.depth_edges import edge_pixels_at

    rng = np.random.default_rng(0)
    z = (rng.random((40, 30)) * 3).astype(np.float32)
    z[rng.random(z.shape) < 0.2] = 0.0
    share = np.float32(0.15)
    # Reference: each pixel against its right / lower neighbour, marked on both sides.
    ref = np.zeros(z.shape, bool)
    for a, b in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:, :], np.s_[:-1, :])):
        both = (z[a] > 0) & (z[b] > 0)
        jump = np.abs(z[a] - z[b])
        ref[a] |= both & (jump > z[a] * share)
        ref[b] |= both & (jump > z[b] * share)
    idx = rng.choice(z.size, 300, replace=False)
    np.testing.assert_array_equal(edge_pixels_at(z, z > 0, idx, 0.15), ref.reshape(-1)[idx])


def test_floor_without_one_in_view_lies_under_the_feet_or_below_a_close_up():
    from models.skeleton.ground import ASSUMED_STATURE_M, FEET_BELOW_LOWEST_M, floor_under_person

    # A whole body (or a crouch ending inside the image): just below its lowest points.
    assert floor_under_person(0.4, 2.1) == pytest.approx(0.4 - FEET_BELOW_LOWEST_M)
    assert floor_under_person(0.4, 1.4) == pytest.approx(0.4 - FEET_BELOW_LOWEST_M)
    # An upper body cut by the image's bottom edge: an average stature below the top of the head.
    assert floor_under_person(0.9, 1.6, cut_below=True) == pytest.approx(1.6 - ASSUMED_STATURE_M)


def test_a_given_camera_height_places_a_floor_out_of_view():
    # A seated performer's upper body (the head about 1.3 m up), the floor out of view, no extrinsics.
    seated = capsule_body(JOINTS - np.array([0.0, 0.45, 0.0]))
    top = float(seated[0][:, 1].max())
    c2w = look_at_camera(1.4, 1.1, 0.0, target=(0.0, 1.0, 0.0))
    f = frame(c2w, mesh=seated, room=Room(width=9.0, depth=9.0, floor=False), identity_extrinsics=True)
    guessed = PersonFinder().find(f)
    finder = PersonFinder()
    finder.ground.camera_height_m = float(c2w[1, 3])
    without_imu = finder.find(f)
    finder = PersonFinder()
    finder.ground.camera_height_m = float(c2w[1, 3])
    finder.gravity_up = c2w[1, :3]  # world up in camera axes, as the camera's IMU gives it
    given = finder.find(f)
    assert guessed is not None and given is not None and not finder.ground.floor_seen
    # Without the height the floor is a standing person's; with it and the IMU's up, the real one;
    # without the IMU the height is not used (up is a guess there too).
    assert abs(guessed.height_m - 1.70) < 0.1 and abs(given.height_m - top) < 0.06
    assert without_imu is not None and without_imu.height_m == pytest.approx(guessed.height_m)
    assert given.camera_to_world is not None and given.camera_to_world[1, 3] == pytest.approx(c2w[1, 3])
