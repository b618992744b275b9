"""Avatars from presets, body files, and T-pose meshes / point clouds (skeleton fit + skinning field)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from live.core.errors import FormatError, UserInputError

body_mod = pytest.importorskip("live.body.library")
pytest.importorskip("live.body.skinning")

from live.body.avatar import fit_skeleton, load_avatar, normalise_figure, skeleton_template  # noqa: E402
from live.body.skinning_field import DEFAULT_MODEL  # noqa: E402

needs_field = pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed skinning_field.onnx")


def _held_out() -> str:
    from sim.skeleton_data import split_bodies

    return split_bodies(body_mod.list_presets(), "val")[0]


def test_preset_and_body_file_pass_through():
    name = sorted(body_mod.list_presets())[0]
    a, b = load_avatar(name), body_mod.load_body(name)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.weights, b.weights)


def test_template_fit_on_held_out_bodies():
    """The template (mean over the other presets) fitted to each held-out preset's mesh lands
    within a few centimetres of its true T-pose joints."""
    from sim.skeleton_data import split_bodies

    for name in split_bodies(body_mod.list_presets(), "val"):
        body = body_mod.load_body(name)
        tpl = skeleton_template.__wrapped__(exclude=(name,))
        v = normalise_figure(body.vertices)
        shift = v[0] - np.asarray(body.vertices, np.float64)[0]  # normalisation is a translation here
        joints = fit_skeleton(v, tpl) - shift
        err = np.linalg.norm(joints - body.rest_joints, axis=1)
        assert err.mean() < 0.03 and err.max() < 0.08, f"{name}: mean {err.mean():.3f} max {err.max():.3f} m"


def _write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray | None) -> None:
    import open3d as o3d

    if faces is None:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vertices.astype(np.float64)))
        assert o3d.io.write_point_cloud(str(path), cloud)
    else:
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices.astype(np.float64)),
                                         o3d.utility.Vector3iVector(faces.astype(np.int32)))
        assert o3d.io.write_triangle_mesh(str(path), mesh)


@needs_field
@pytest.mark.parametrize("suffix,cloud,unit", [(".obj", False, 100.0), (".ply", True, 1.0)])
def test_mesh_and_cloud_avatars(tmp_path, suffix, cloud, unit):
    """A held-out body written as an OBJ mesh in centimetres, or a PLY point cloud, moved away from
    the origin: the avatar is back in metres on the floor, with a close skeleton and weights that
    pose it close to the true skinning."""
    from live.body.skinning import lbs
    from live.core.metrics import mpvd
    from live.core.rotations import quat_from_axis_angle

    body = body_mod.load_body(_held_out())
    offset = np.array([0.5, 0.3, -1.0])
    path = tmp_path / f"figure{suffix}"
    _write_mesh(path, (np.asarray(body.vertices, np.float64) + offset) * unit, None if cloud else body.faces)
    avatar = load_avatar(path)
    assert avatar.name == "figure"
    assert avatar.faces.shape == ((0, 3) if cloud else body.faces.shape)
    assert abs(avatar.vertices[:, 1].min()) < 1e-6
    assert abs(np.ptp(avatar.vertices[:, 1]) - np.ptp(body.vertices[:, 1])) < 1e-3
    np.testing.assert_allclose(avatar.weights.sum(axis=1), 1.0, atol=1e-5)
    # Normalisation is a translation; the file may reorder vertices: match them by position.
    from scipy.spatial import cKDTree

    lo_a, hi_a = avatar.vertices.min(0), avatar.vertices.max(0)
    lo_b, hi_b = body.vertices.min(0), body.vertices.max(0)
    shift = 0.5 * (lo_a + hi_a) - 0.5 * (lo_b + hi_b)
    dist, match = cKDTree(body.vertices).query(avatar.vertices - shift)
    assert dist.max() < 1e-3
    body = body_mod.Body(vertices=body.vertices[match], faces=np.zeros((0, 3), np.int32),
                         rest_joints=body.rest_joints, weights=body.weights[match], parents=body.parents,
                         name=body.name, phenotype=None)
    err = np.linalg.norm(avatar.rest_joints - shift - body.rest_joints, axis=1)
    assert err.mean() < 0.03
    aa = np.zeros((1, 22, 3))
    aa[0, 1] = (-0.8, 0, 0)  # left hip forward
    aa[0, 16] = (0, 0, -0.9)  # left shoulder down
    rot = quat_from_axis_angle(aa)
    posed = lbs(avatar.vertices, avatar.weights, avatar.rest_joints, rot, avatar.rest_joints[None, 0])
    truth = lbs(body.vertices, body.weights, body.rest_joints, rot, body.rest_joints[None, 0])
    assert mpvd(posed - shift, truth) < 0.03


def test_bad_files(tmp_path):
    with pytest.raises(UserInputError):
        load_avatar(tmp_path / "missing.obj")
    tiny = tmp_path / "tiny.ply"
    _write_mesh(tiny, np.random.default_rng(0).random((10, 3)), None)
    with pytest.raises(FormatError):
        load_avatar(tiny)
