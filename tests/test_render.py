"""Rendered video output: the rasteriser's coverage and depth, frame composition, mp4 writing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from live.core.depth import intrinsics_matrix
from live.core.errors import UserInputError
from live.core.frames import AvatarPose, DepthFrame, FrameResult, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_from_axis_angle
from live.core.skeleton import default_rest_joints
from live.outputs.raster import look_at, orient_outward, project, rasterize, world_to_camera
from live.outputs.render import (
    RenderOptions,
    VideoSink,
    avatar_camera,
    bone_mesh,
    compose_frame,
    frames_to_video,
    splat_points,
)

K = intrinsics_matrix(300.0, 300.0, 319.5, 199.5)  # a 640 x 400 image
SIZE = (640, 400)


def _pixel_inside(uv, px, py):
    """Reference point-in-triangle test on pixel centres (px, py), either winding."""
    def edge(a, b):
        return (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])
    e = np.stack([edge(uv[0], uv[1]), edge(uv[1], uv[2]), edge(uv[2], uv[0])])
    return np.all(e > 0, axis=0) | np.all(e < 0, axis=0)


def test_rasteriser_fills_exactly_the_triangle_pixels_at_its_depth():
    # Vertices chosen so no pixel centre falls on an edge.
    uv = np.array([[100.3, 50.2], [400.7, 120.6], [180.1, 330.9]])
    z = 2.0
    tri = np.column_stack([(uv[:, 0] - K[0, 2]) * z / K[0, 0], (uv[:, 1] - K[1, 2]) * z / K[1, 1], np.full(3, z)])
    for faces in (np.array([[0, 1, 2]]), np.array([[0, 2, 1]])):
        r = rasterize(tri, faces, K, SIZE)
        py, px = np.mgrid[0:SIZE[1], 0:SIZE[0]]
        expected = _pixel_inside(uv, px, py)
        np.testing.assert_array_equal(r.mask, expected)
        np.testing.assert_allclose(r.depth[expected], z, rtol=1e-6)
        assert np.all(np.isinf(r.depth[~expected]))
        np.testing.assert_allclose(r.bary[expected].sum(-1), 1.0, atol=1e-5)


def test_nearer_triangle_wins_whatever_the_draw_order():
    def quad(z, x0, x1):
        pts = np.array([[x0, -0.5, z], [x1, -0.5, z], [x1, 0.5, z], [x0, 0.5, z]])
        return pts
    verts = np.concatenate([quad(3.0, -1.0, 0.5), quad(2.0, -0.5, 1.0)])
    near_faces = np.array([[4, 5, 6], [4, 6, 7]])
    far_faces = np.array([[0, 1, 2], [0, 2, 3]])
    for faces in (np.concatenate([far_faces, near_faces]), np.concatenate([near_faces, far_faces])):
        r = rasterize(verts, faces, K, SIZE)
        u_overlap = project(np.array([0.0, 0.0, 2.0]), K).round().astype(int)
        u_far_only = project(np.array([-0.8, 0.0, 3.0]), K).round().astype(int)
        assert r.depth[u_overlap[1], u_overlap[0]] == pytest.approx(2.0)
        assert r.depth[u_far_only[1], u_far_only[0]] == pytest.approx(3.0)
        near_ids = np.flatnonzero((faces >= 4).all(axis=1))
        assert r.face[u_overlap[1], u_overlap[0]] in near_ids


def test_depth_is_perspective_correct_on_a_slanted_triangle():
    verts = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 4.0], [0.0, 1.0, 3.0]])
    r = rasterize(verts, np.array([[0, 1, 2]]), K, SIZE)
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    v, u = np.nonzero(r.mask)
    rays = np.column_stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(len(u))])
    z_true = (n @ verts[0]) / (rays @ n)  # ray-plane intersection, z of the ray is 1 per unit
    np.testing.assert_allclose(r.depth[v, u], z_true, rtol=1e-5)


def _pose(seed=0):
    rng = np.random.default_rng(seed)
    rot = quat_from_axis_angle(rng.normal(0, 0.25, (22, 3)))
    rot[0] = quat_from_axis_angle(np.array([0.0, 0.3, 0.0]))
    root = np.array([0.1, 0.95, 0.2])
    joints, _ = forward_kinematics(rot, root, default_rest_joints())
    return rot, root, joints


def test_culling_a_closed_mesh_changes_nothing_visible():
    _, _, joints = _pose()
    v, f = bone_mesh(joints, radius=0.06, sides=10)
    np.testing.assert_array_equal(orient_outward(v, f), f)  # built wound outwards
    c2w = look_at([0.5, 1.2, 3.0], [0.0, 1.0, 0.0])
    v_cam = world_to_camera(v, c2w)
    full = rasterize(v_cam, f, K, SIZE)
    culled = rasterize(v_cam, f, K, SIZE, cull_backfaces=True)
    assert full.mask.sum() > 2000
    # Prisms of different bones interpenetrate at joints, so allow a sliver of difference.
    assert (full.mask != culled.mask).sum() <= 0.005 * full.mask.sum()
    both = full.mask & culled.mask
    np.testing.assert_allclose(culled.depth[both], full.depth[both], atol=1e-4)


def _frame(with_mesh=True, depth_image=True, seed=0):
    rot, root, joints = _pose(seed)
    c2w = look_at([0.0, 1.0, 3.5], [0.1, 0.9, 0.2])
    if depth_image:
        depth = DepthFrame(t_ns=0, sensor="test", camera_to_world=c2w,
                           depth_mm=np.zeros((400, 640), np.uint16), intrinsics=K)
    else:
        depth = DepthFrame(t_ns=0, sensor="test", camera_to_world=c2w, points=np.zeros((0, 3), np.float32), intrinsics=K)
    conf = np.ones(22)
    skel = SkeletonFrame(t_ns=0, joints=joints, confidence=conf)
    verts = bone_mesh(joints)[0] if with_mesh else None
    avatar = AvatarPose(t_ns=0, root=root, rotations=rot, joints=joints, vertices=verts)
    return FrameResult(t_ns=1_000_000_000, depth=depth, skeleton=skel, avatar=avatar,
                       latency_ms={"skeleton": 4.0, "retarget": 1.0}), c2w


def test_skeleton_is_drawn_where_the_joints_project():
    result, c2w = _frame()
    opts = RenderOptions(size=(1280, 400), avatar_faces=bone_mesh(result.skeleton.joints)[1])
    img = compose_frame(result, opts, t0_ns=0)
    assert img.shape == (400, 1280, 3) and img.dtype == np.uint8
    uv = np.rint(project(world_to_camera(result.skeleton.joints, c2w), K)).astype(int)
    assert np.all((uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 60) & (uv[:, 1] < 400))
    left = img[:, :639]
    for u, v in uv:
        # Confidence 1 paints the joint dot green (BGR).
        b, g, r = left[v, u].astype(int)
        assert g > 150 and g > r + 80 and g > b + 80, (u, v, left[v, u])
    # The depth image is empty: away from the skeleton and the captions, the panel stays black.
    drawn = left.any(axis=2)
    drawn[:60] = False
    far = np.ones_like(drawn)
    for u, v in uv:
        far[max(v - 40, 0):v + 40, max(u - 40, 0):u + 40] = False
    assert not drawn[far].any()
    assert drawn.sum() > 500


def test_avatar_panel_shades_the_mesh_from_the_virtual_camera():
    result, _ = _frame()
    faces = bone_mesh(result.skeleton.joints)[1]
    img = compose_frame(result, RenderOptions(size=(1280, 400), avatar_faces=faces))
    right = img[:, 641:]
    k, c2w = avatar_camera(result.avatar.root, RenderOptions(), (640, 400))
    u, v = np.rint(project(world_to_camera(result.avatar.joints[6], c2w), k)).astype(int)  # spine2
    assert not np.array_equal(right[v, u - 1], [40, 40, 40])  # shaded, not background
    shaded = np.any(right != (40, 40, 40), axis=2)
    shaded[:70] = False  # latency captions
    assert 2000 < shaded.sum() < 0.5 * shaded.size
    # Without a mesh the panel still shows the avatar (prisms around its bones).
    no_mesh, _ = _frame(with_mesh=False)
    img2 = compose_frame(no_mesh, RenderOptions(size=(1280, 400)))
    assert np.any(img2[100:, 641:] != (40, 40, 40), axis=2).sum() > 1000


def test_points_only_depth_is_projected_with_the_intrinsics():
    p = np.array([[0.2, -0.1, 1.5], [-0.5, 0.3, 3.0]], dtype=np.float32)
    img = splat_points(p, K, SIZE)
    uv = np.rint(project(p, K)).astype(int)
    assert img[uv[0, 1], uv[0, 0]] == 1500 and img[uv[1, 1], uv[1, 0]] == 3000
    assert (img > 0).sum() == 2
    depth = DepthFrame(t_ns=0, sensor="test", points=p, intrinsics=K)
    frame = FrameResult(t_ns=0, depth=depth)
    out = compose_frame(frame, RenderOptions(size=(1280, 400)))
    assert out[uv[0, 1], uv[0, 0]].any() and out[uv[1, 1], uv[1, 0]].any()


def test_frames_to_video_writes_a_readable_mp4(tmp_path):
    results = []
    for i in range(12):
        r, _ = _frame(seed=i)
        r.t_ns = 1_000_000_000 + i * 33_333_333
        results.append(r)
    faces = bone_mesh(results[0].skeleton.joints)[1]
    path = tmp_path / "out.mp4"
    n = frames_to_video(iter(results), path, fps=30, size=(640, 240), avatar_faces=faces)
    assert n == 12
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 12
    read = 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        assert frame.shape == (240, 640, 3)
        read += 1
    cap.release()
    assert read == 12


def test_video_sink_counts_errors_instead_of_raising(tmp_path):
    path = tmp_path / "sink.mp4"
    good, _ = _frame()
    faces = bone_mesh(good.skeleton.joints)[1]
    bad_avatar = AvatarPose(t_ns=0, root=np.zeros(3), rotations=np.zeros((22, 4)), vertices=np.zeros((5, 3)))
    with VideoSink(path, fps=30, size=(640, 240), avatar_faces=faces) as sink:
        sink.send(good)
        sink.send(FrameResult(t_ns=2, avatar=bad_avatar))  # faces index past 5 vertices
        sink.send(good)
    assert sink.frames == 2 and sink.errors == 1
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 2
    cap.release()
    with pytest.raises(UserInputError):
        VideoSink(tmp_path / "missing" / "x.mp4")
    with pytest.raises(UserInputError):
        VideoSink(tmp_path / "x.mp4", fps=0)


def test_captions_give_the_point_count_apart_from_the_timings():
    from live.outputs.render import _captions

    result = FrameResult(t_ns=2_000_000_000, latency_ms={"cloud": 2.0, "skeleton": 4.5}, points=12345)
    left, right = _captions(result, t0_ns=1_000_000_000)
    assert left == ["t   1.000 s", "no skeleton"]
    assert right == ["cloud    2.0 ms", "skeleton    4.5 ms", "total    6.5 ms", "points 12345"]
    assert _captions(FrameResult(t_ns=0), None)[1] == []


def _video_stream(path):
    av = pytest.importorskip("av")
    with av.open(str(path)) as f:
        s = f.streams.video[0]
        return s.codec_context.name, s.frames, float(s.duration * s.time_base), (s.width, s.height)


@pytest.mark.parametrize("fps", [15.0, 30.0])
def test_video_is_h264_and_lasts_as_long_as_the_take(tmp_path, fps):
    """Frame i at i / fps: 24 frames of a 15 fps take last 1.6 s, not 0.8 s at a fixed 30 fps."""
    pytest.importorskip("av")
    period = round(1e9 / fps)
    results = []
    for i in range(24):
        r, _ = _frame(seed=i)
        r.t_ns = 5_000_000_000 + i * period
        results.append(r)
    path = tmp_path / "take.mp4"
    assert frames_to_video(iter(results), path, fps=fps, size=(320, 120)) == 24
    codec, frames, seconds, size = _video_stream(path)
    assert codec == "h264" and frames == 24 and size == (320, 120)
    assert seconds == pytest.approx(24 / fps, abs=1e-3)


def test_odd_video_sizes_are_padded_for_h264(tmp_path):
    pytest.importorskip("av")
    r, _ = _frame()
    with VideoSink(tmp_path / "odd.mp4", fps=15, size=(161, 45)) as sink:
        assert sink.codec == "h264"
        sink.send(r)
        sink.send(r)
    assert sink.frames == 2 and sink.errors == 0
    assert _video_stream(tmp_path / "odd.mp4")[3] == (162, 46)


def test_without_pyav_the_video_is_mpeg4_and_one_line_says_so(tmp_path, monkeypatch, capsys):
    from live.outputs import render

    monkeypatch.setattr(render, "_h264_available", lambda: False)
    render._warn_no_h264.cache_clear()
    r, _ = _frame()
    with VideoSink(tmp_path / "old.mp4", fps=15, size=(320, 120)) as sink:
        sink.send(r)
    render._warn_no_h264.cache_clear()
    assert sink.codec == "mpeg4"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "browsers do not play" in err[0] and "pip install av" in err[0]
    cap = cv2.VideoCapture(str(tmp_path / "old.mp4"))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    cap.release()
    assert fourcc.lower() in ("mp4v", "fmp4")  # MPEG-4 Part 2 under either tag


def _textured_quad(texture, factor=(1.0, 1.0, 1.0), uv_shift=0.0):
    """A 2 x 2 m square at z = 3 facing the camera, its uv the unit square (shifted by whole turns:
    REPEAT wraps them back), and its look."""
    from live.body.body import AvatarLook

    verts = np.array([[-1.0, -1.0, 3.0], [1.0, -1.0, 3.0], [1.0, 1.0, 3.0], [-1.0, 1.0, 3.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    # Image v runs down, camera y runs down: uv = ((x + 1) / 2, (y + 1) / 2) puts texel (0, 0) top left.
    uv = (verts[:, :2] + 1.0) / 2.0 + uv_shift
    look = AvatarLook(uv=uv.astype(np.float32), face_material=np.zeros(2, np.int32),
                      colours=np.array([factor], np.float32), textures=(texture,),
                      uv_transforms=np.array([[0.0, 0.0, 1.0, 1.0]], np.float32))
    return verts, faces, look


def test_textures_are_drawn_where_their_uv_puts_them():
    from live.outputs.raster import shade_lambert, vertex_normals
    from live.outputs.texture import surface_albedo

    quadrants = np.zeros((2, 2, 3), np.uint8)
    quadrants[0, 0], quadrants[0, 1], quadrants[1, 0], quadrants[1, 1] = (0, 0, 255), (0, 255, 0), (255, 0, 0), (255, 255, 255)
    for shift, factor in ((0.0, (1.0, 1.0, 1.0)), (2.0, (1.0, 1.0, 1.0)), (-3.0, (0.5, 1.0, 1.0))):
        verts, faces, look = _textured_quad(quadrants, factor, shift)
        r = rasterize(verts, faces, K, SIZE)
        img = shade_lambert(r, vertex_normals(verts, faces), faces, light_dir=(0.0, 0.0, -1.0), ambient=0.0,
                            albedo=surface_albedo(r, faces, look, (0.5, 0.5, 0.5)))
        u0, u1 = np.rint(project(np.array([[-0.5, -0.5, 3.0], [0.5, 0.5, 3.0]]), K)).astype(int)
        for (x, y), texel in (((u0[0], u0[1]), quadrants[0, 0]), ((u1[0], u0[1]), quadrants[0, 1]),
                              ((u0[0], u1[1]), quadrants[1, 0]), ((u1[0], u1[1]), quadrants[1, 1])):
            want = texel * np.asarray(factor)
            np.testing.assert_allclose(img[y, x], want, atol=2, err_msg=f"shift {shift}, pixel {x, y}")


def test_a_material_without_texture_has_its_colour_and_no_material_the_default():
    from live.body.body import AvatarLook
    from live.outputs.texture import surface_albedo

    verts, faces, _ = _textured_quad(None)
    look = AvatarLook(uv=np.zeros((4, 2), np.float32), face_material=np.array([0, -1], np.int32),
                      colours=np.array([[0.2, 0.4, 0.6]], np.float32), textures=(None,),
                      uv_transforms=np.array([[0.0, 0.0, 1.0, 1.0]], np.float32))
    r = rasterize(verts, faces, K, SIZE)
    albedo = surface_albedo(r, faces, look, (0.9, 0.8, 0.7))
    tri = r.face.ravel()[np.flatnonzero(r.face.ravel() >= 0)]
    np.testing.assert_allclose(albedo[tri == 0], np.tile([0.2, 0.4, 0.6], ((tri == 0).sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(albedo[tri == 1], np.tile([0.9, 0.8, 0.7], ((tri == 1).sum(), 1)), atol=1e-6)


def test_a_vrm_avatar_is_drawn_with_its_own_textures():
    """Godette's palette texture colours her (blue hair, white and blue clothes): many more colours
    than one shaded tone gives, and her hair's blue where her head is."""
    from live.body.gltf_avatar import read_gltf_humanoid
    from live.core.assets import shared_data_dir

    path = shared_data_dir() / "avatars" / "godette_vrm0.vrm"
    if not path.is_file():
        pytest.skip("../shared/data/avatars/godette_vrm0.vrm is absent")
    body = read_gltf_humanoid(path).body
    root = body.rest_joints[0].astype(np.float64)
    avatar = AvatarPose(t_ns=0, root=root, rotations=np.tile([1.0, 0, 0, 0], (22, 1)),
                        joints=body.rest_joints, vertices=body.vertices)
    result = FrameResult(t_ns=0, avatar=avatar)
    plain = compose_frame(result, RenderOptions(size=(1280, 400), avatar_faces=body.faces))[:, 641:]
    textured = compose_frame(result, RenderOptions(size=(1280, 400), avatar_faces=body.faces,
                                                   avatar_look=body.look))[:, 641:]
    covered = np.any(plain != (40, 40, 40), axis=2)
    covered[:70] = False
    # Hue: one tone shaded has one hue; her textures give several (skin, blue, white, dark).
    hue = cv2.cvtColor(textured, cv2.COLOR_BGR2HSV)[..., 0][covered & (cv2.cvtColor(textured, cv2.COLOR_BGR2HSV)[..., 1] > 60)]
    assert len(np.unique(hue // 10)) >= 3
    # The top of her head is her blue hair (the plain render is one skin tone there).
    top = np.nonzero(covered.any(axis=1))[0][0]
    hair = textured[top:top + 12][covered[top:top + 12]].astype(int)
    assert np.mean(hair[:, 0] > hair[:, 2] + 30) > 0.8
    skin = plain[top:top + 12][covered[top:top + 12]].astype(int)
    assert np.mean(skin[:, 0] > skin[:, 2] + 30) < 0.05
