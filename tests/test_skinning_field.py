"""The skinning field runtime: contract (shapes, rows sum to 1, invariances) and the committed model."""

from __future__ import annotations

import numpy as np
import pytest

from live.body.skinning_field import DEFAULT_MODEL, SkinningFieldModel
from live.core.errors import ModelError, UserInputError
from live.core.skeleton import default_rest_joints


@pytest.fixture(scope="module")
def random_field(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from models.train.retarget_nets import SkinningField, export_skinning_onnx

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("sf") / "skinning_field.onnx"
    export_skinning_onnx(SkinningField(hidden=32), str(path))
    return path


def _points(rng: np.random.Generator, rest: np.ndarray, n: int = 500) -> np.ndarray:
    return rest[rng.integers(0, 22, n)] + rng.normal(0, 0.04, (n, 3))


def test_contract_and_invariances(random_field):
    rng = np.random.default_rng(0)
    rest = default_rest_joints(1.7)
    pts = _points(rng, rest)
    field = SkinningFieldModel(random_field, chunk=128)
    w = field.weights(pts, rest)
    assert w.shape == (500, 22) and w.dtype == np.float32
    assert (w >= 0).all()
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)
    # Chunking does not change the answer.
    np.testing.assert_allclose(SkinningFieldModel(random_field).weights(pts, rest), w, atol=1e-6)
    # Distances over the leg length: a uniformly scaled body gets the same weights ...
    np.testing.assert_allclose(field.weights(pts * 0.6, rest * 0.6), w, atol=1e-5)
    # ... and a horizontal shift of points and joints together changes nothing.
    shift = np.array([0.3, 0.0, -0.7])
    np.testing.assert_allclose(field.weights(pts + shift, rest + shift), w, atol=1e-5)
    with pytest.raises(UserInputError):
        field.weights(pts[:, :2], rest)
    with pytest.raises(UserInputError):
        field.weights(pts, rest[:21])


def test_missing_model(tmp_path):
    with pytest.raises(ModelError):
        SkinningFieldModel(tmp_path / "nope.onnx")


@pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed skinning_field.onnx")
def test_committed_field_on_held_out_body():
    """On a held-out preset: mostly the right dominant bone, and LBS with the predicted weights
    close to LBS with the true ones on a bent pose."""
    from live.body.library import list_presets, load_body
    from live.body.skinning import lbs
    from live.core.metrics import mpvd
    from live.core.rotations import quat_from_axis_angle
    from sim.skeleton_data import split_bodies

    body = load_body(split_bodies(list_presets(), "val")[0])
    w = SkinningFieldModel().weights(body.vertices, body.rest_joints)
    true = np.asarray(body.weights)
    assert (w.argmax(1) == true.argmax(1)).mean() > 0.8
    aa = np.zeros((1, 22, 3))
    aa[0, 4] = (1.2, 0, 0)  # left knee bent
    aa[0, 18] = (0, 1.2, 0)  # left elbow bent
    aa[0, 3] = (0.4, 0, 0)  # spine forward
    rot = quat_from_axis_angle(aa)
    root = np.asarray(body.rest_joints)[None, 0]
    err = mpvd(lbs(body.vertices, w, body.rest_joints, rot, root), lbs(body.vertices, true, body.rest_joints, rot, root))
    assert err < 0.01, f"MPVD {err * 1000:.1f} mm"
