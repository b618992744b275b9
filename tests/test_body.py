"""The body library and numpy LBS: the file contract, the T-pose, skinning consistent with FK."""

import numpy as np
import pytest

from live.body import Body, list_presets, load_body, save_body
from live.errors import FormatError, UserInputError
from live.kinematics import forward_kinematics
from live.rotations import quat_identity, quat_normalize
from live.skeleton import JOINT_INDEX, NUM_JOINTS, PARENTS
from live.skinning import lbs

J = JOINT_INDEX


def test_library_has_varied_bodies():
    names = list_presets()
    assert len(names) >= 16
    heights = [load_body(n).height for n in names]
    assert min(heights) <= 1.1 and max(heights) >= 1.95
    assert load_body("default").name != load_body("performer").name


@pytest.mark.parametrize("name", list_presets())
def test_preset_follows_the_contract_and_the_tpose(name):
    b = load_body(name)
    assert b.vertices.dtype == np.float32 and b.vertices.shape[1] == 3
    assert b.faces.dtype == np.int32 and b.faces.max() < len(b.vertices)
    assert b.rest_joints.shape == (NUM_JOINTS, 3) and b.weights.shape == (len(b.vertices), NUM_JOINTS)
    np.testing.assert_allclose(b.weights.sum(axis=1), 1.0, atol=1e-4)
    np.testing.assert_array_equal(b.parents, PARENTS)
    assert abs(float(b.vertices[:, 1].min())) < 0.01  # feet on the floor
    r = b.rest_joints
    # Facing +z: toes ahead of ankles; subject's left on +x; arms horizontal, legs straight.
    assert r[J["left_foot"], 2] > r[J["left_ankle"], 2] and r[J["right_foot"], 2] > r[J["right_ankle"], 2]
    assert r[J["left_wrist"], 0] > 0.25 * b.height and r[J["right_wrist"], 0] < -0.25 * b.height
    for side in ("left", "right"):
        arm = r[J[f"{side}_wrist"]] - r[J[f"{side}_shoulder"]]
        leg = r[J[f"{side}_ankle"]] - r[J[f"{side}_hip"]]
        assert abs(arm[1]) < 0.02 * np.linalg.norm(arm)
        assert abs(leg[0]) < 0.02 * np.linalg.norm(leg) and leg[1] < 0
    assert r[J["head"], 1] > r[J["neck"], 1] > r[J["pelvis"], 1] > r[J["left_knee"], 1]


def test_lbs_identity_is_rest_and_matches_fk():
    b = load_body("performer")
    rest = lbs(b.vertices, b.weights, b.rest_joints, quat_identity((NUM_JOINTS,)), b.rest_joints[0])
    np.testing.assert_allclose(rest[0], b.vertices, atol=1e-5)
    rng = np.random.default_rng(0)
    q = quat_normalize(np.concatenate([np.ones((4, NUM_JOINTS, 1)) * 3, rng.normal(size=(4, NUM_JOINTS, 3))], -1))
    root = rng.normal(size=(4, 3))
    joints, _ = forward_kinematics(q, root, b.rest_joints)
    # Skinning the rest joints themselves, each bound to its parent bone, gives FK's joints.
    onehot = np.zeros((NUM_JOINTS, NUM_JOINTS), np.float32)
    onehot[0, 0] = 1
    onehot[np.arange(1, NUM_JOINTS), PARENTS[1:]] = 1
    skinned = lbs(b.rest_joints, onehot, b.rest_joints, q, root)
    np.testing.assert_allclose(skinned, joints, atol=1e-5)
    # Against a slow reference (per-vertex blend of 4x4 matrices).
    posed = lbs(b.vertices[:300], b.weights[:300], b.rest_joints, q[:1], root[:1])[0]
    from live.rotations import quat_to_matrix
    from live.kinematics import global_rotations

    g = quat_to_matrix(global_rotations(q[:1]))[0]
    ref = np.zeros((300, 3))
    for v in range(300):
        for j in range(NUM_JOINTS):
            t = joints[0, j] - g[j] @ b.rest_joints[j]
            ref[v] += b.weights[v, j] * (g[j] @ b.vertices[v] + t)
    np.testing.assert_allclose(posed, ref, atol=1e-4)


def test_bad_body_files(tmp_path):
    good = load_body("performer")
    p = tmp_path / "b.npz"
    save_body(p, good)
    assert load_body(p).name == good.name
    (tmp_path / "garbage.npz").write_bytes(b"PK\x03\x04 definitely not a zip")
    with pytest.raises(FormatError):
        load_body(tmp_path / "garbage.npz")
    bad = Body(good.vertices, good.faces, good.rest_joints, good.weights * 2, good.parents, "bad")
    save_body(tmp_path / "bad.npz", bad)
    with pytest.raises(FormatError, match="sum to 1"):
        load_body(tmp_path / "bad.npz")
    np.savez(tmp_path / "partial.npz", vertices=good.vertices)
    with pytest.raises(FormatError, match="faces"):
        load_body(tmp_path / "partial.npz")
    with pytest.raises(UserInputError):
        load_body("no_such_body")
    with pytest.raises(UserInputError):
        load_body(tmp_path / "missing.npz")
