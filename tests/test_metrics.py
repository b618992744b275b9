"""live.core.metrics against hand-computed cases and the invariances each metric promises."""

import numpy as np
import pytest

from live.core import metrics
from live.core.errors import UserInputError
from live.core.rotations import quat_from_axis_angle, quat_to_matrix


def _random_points(seed: int, t: int = 5, n: int = 22) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(t, n, 3))


def test_mpjpe_hand_computed():
    gt = np.zeros((2, 2, 3))
    pred = gt.copy()
    pred[0, 0] = (3.0, 4.0, 0.0)  # 5 m off
    pred[1, 1] = (0.0, 0.0, 1.0)  # 1 m off
    assert metrics.mpjpe(pred, gt) == pytest.approx(6.0 / 4.0)
    np.testing.assert_allclose(metrics.per_joint_mpjpe(pred, gt), [2.5, 0.5])
    assert metrics.pck(pred, gt, threshold=1.5) == pytest.approx(0.75)
    assert metrics.pck(pred, gt, threshold=0.5) == pytest.approx(0.5)
    # A single frame (N, 3) is accepted too.
    assert metrics.mpjpe(pred[0], gt[0]) == pytest.approx(2.5)


def test_pa_mpjpe_invariant_to_similarity_of_pred():
    rng = np.random.default_rng(1)
    gt = _random_points(2)
    noisy = gt + rng.normal(scale=0.01, size=gt.shape)
    rot = quat_to_matrix(quat_from_axis_angle(rng.normal(size=(len(gt), 3))))
    moved = 2.7 * np.einsum("tij,tnj->tni", rot, noisy) + rng.normal(size=(len(gt), 1, 3))
    assert metrics.pa_mpjpe(gt @ rot[0].T * 0.3 + 5.0, gt) < 1e-9
    assert metrics.pa_mpjpe(moved, gt) == pytest.approx(metrics.pa_mpjpe(noisy, gt), rel=1e-9)
    assert metrics.pa_mpjpe(noisy, gt) <= metrics.mpjpe(noisy, gt)
    assert metrics.mpjpe(moved, gt) > 1.0


def test_procrustes_does_not_reflect():
    gt = _random_points(3, t=1)
    mirrored = gt * np.array([-1.0, 1.0, 1.0])
    aligned = metrics.procrustes_align(mirrored, gt)
    # A proper rotation cannot undo a mirror, so some error must remain.
    assert metrics.mpjpe(aligned, gt) > 0.1


def test_pa_mpjpe_hand_computed_scale_and_offset():
    gt = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    pred = gt * 3.0 + np.array([1.0, 2.0, 3.0])
    assert metrics.pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-12)


def test_acceleration_error_units_and_invariance():
    t = np.arange(10, dtype=np.float64)
    gt = np.zeros((10, 1, 3))
    pred = np.zeros((10, 1, 3))
    pred[:, 0, 0] = 0.5 * 0.02 * t**2  # constant acceleration 0.02 m/frame^2
    assert metrics.acceleration_error(pred, gt) == pytest.approx(0.02)
    with pytest.raises(TypeError):  # one unit: per frame^2, never per second^2
        metrics.acceleration_error(pred, gt, fps=30.0)
    # Constant velocity and offsets have no acceleration.
    lin = np.random.default_rng(4).normal(size=(1, 4, 3)) + t[:, None, None] * 0.1
    assert metrics.acceleration_error(lin + 3.0, lin * 0 + 1.0) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(UserInputError):
        metrics.acceleration_error(gt[:2], gt[:2])


def test_pa_acceleration_error_ignores_rigid_offsets():
    rng = np.random.default_rng(5)
    gt = np.cumsum(rng.normal(scale=0.01, size=(8, 22, 3)), axis=0)
    rot = quat_to_matrix(quat_from_axis_angle(rng.normal(size=(8, 3))))
    moved = np.einsum("tij,tnj->tni", rot, gt) * 1.3 + 2.0
    assert metrics.pa_acceleration_error(moved, gt) < 1e-9
    assert metrics.acceleration_error(moved, gt) > 0.01


def test_mpvd_and_pa_mpvd_match_joint_versions():
    gt = _random_points(6, n=50)
    pred = gt + 0.05
    assert metrics.mpvd(pred, gt) == pytest.approx(np.sqrt(3) * 0.05)
    assert metrics.pa_mpvd(pred, gt) == pytest.approx(0.0, abs=1e-9)


def test_mdel_hand_computed_and_rigid_invariance():
    # Four points on a line 1 m apart, k=1: every point's nearest neighbour is 1 m away.
    ref = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    stretched = ref * 1.5  # every edge grows by 0.5 m
    assert metrics.mdel(stretched[None], ref, k=1) == pytest.approx(0.5)
    # Rigid motion keeps all edge lengths.
    rng = np.random.default_rng(7)
    cloud = rng.normal(size=(200, 3))
    rot = quat_to_matrix(quat_from_axis_angle(rng.normal(size=3)))
    frames = np.stack([cloud @ rot.T + 1.0, cloud])
    assert metrics.mdel(frames, cloud) == pytest.approx(0.0, abs=1e-12)
    # Frame-by-frame ground truth, and precomputed edges, give the same answer.
    edges = metrics.knn_edges(cloud, k=6)
    assert edges.shape == (200, 6) and not np.any(edges == np.arange(200)[:, None])
    noisy = frames + rng.normal(scale=0.01, size=frames.shape)
    assert metrics.mdel(noisy, frames, edges=edges) == pytest.approx(metrics.mdel(noisy, cloud, edges=edges), rel=1e-9)
    assert metrics.mdel(noisy, cloud) > 0.001


def test_shape_errors_are_user_input_errors():
    with pytest.raises(UserInputError):
        metrics.mpjpe(np.zeros((2, 22, 3)), np.zeros((3, 22, 3)))
    with pytest.raises(UserInputError):
        metrics.mdel(np.zeros((1, 5, 3)), np.zeros((4, 3)))


def test_turned_share_counts_frames_whose_body_faces_elsewhere():
    """A body turned 30 degrees is not counted at 45, one turned 90 or read facing away (180) is;
    neither a translation nor a crouch counts."""
    from live.core.heading import yaw_matrix
    from live.core.skeleton import default_rest_joints

    rest = default_rest_joints()
    frames = [rest @ yaw_matrix(np.radians(a)).T + [0.3, 0.0, -1.0] for a in (0.0, 30.0, 90.0, 180.0)]
    pred = np.stack(frames)
    gt = np.stack([rest] * 4)
    assert metrics.turned_share(pred, gt, 45.0) == pytest.approx(0.5)
    assert metrics.turned_share(pred, gt, 100.0) == pytest.approx(0.25)
    assert metrics.turned_share(gt * [1.0, 0.6, 1.0], gt) == 0.0


def test_body_heading_is_zero_facing_plus_z_and_follows_a_yaw():
    from live.core.heading import body_heading, yaw_matrix
    from live.core.skeleton import default_rest_joints

    rest = default_rest_joints()
    assert abs(body_heading(rest)) < 1e-9
    turned = np.stack([rest @ yaw_matrix(a).T for a in (0.5, -2.0)])
    np.testing.assert_allclose(body_heading(turned), [0.5, -2.0], atol=1e-9)


def test_segment_distances_paired_and_all_against_all():
    from live.core.geometry import segment_distances

    a, b = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    p = np.array([[0.5, 0.2, 0.0], [-0.3, 0.0, 0.4], [1.0, 0.0, 0.0]])
    assert np.allclose(segment_distances(p, a, b), [0.2, 0.5, 0.0])  # along, beyond an end, at an end
    segs_a, segs_b = np.stack([a, a]), np.stack([b, [0.0, 1.0, 0.0]])
    d = segment_distances(p[:, None], segs_a[None], segs_b[None])
    assert d.shape == (3, 2) and np.isclose(d[0, 1], np.hypot(0.5, 0.0)) and np.isclose(d[1, 1], 0.5)
