"""models.train.weight_average: two trainings of one network, their weights averaged."""

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from live.core.errors import UserInputError  # noqa: E402
from models.train.weight_average import average_weights  # noqa: E402


def _net(w: np.ndarray, b: np.ndarray, shape=(1, 2)) -> onnx.ModelProto:
    """y = reshape(x @ w + b): weights in Constant nodes, as the exporter leaves them."""
    nodes = [helper.make_node("Constant", [], ["w"], value=numpy_helper.from_array(w.astype(np.float32), "w")),
             helper.make_node("Constant", [], ["b"], value=numpy_helper.from_array(b.astype(np.float32), "b")),
             helper.make_node("Constant", [], ["s"], value=numpy_helper.from_array(np.array(shape, np.int64), "s")),
             helper.make_node("MatMul", ["x", "w"], ["xw"], name="mm"),
             helper.make_node("Add", ["xw", "b"], ["z"], name="add"),
             helper.make_node("Reshape", ["z", "s"], ["y"], name="reshape")]
    graph = helper.make_graph(nodes, "net", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 2])])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def _run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    import onnxruntime as ort

    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})[0]


def test_the_average_interpolates_every_float_weight_and_runs():
    rng = np.random.default_rng(0)
    w0, b0, w1, b1 = rng.normal(size=(3, 2)), rng.normal(size=2), rng.normal(size=(3, 2)), rng.normal(size=2)
    base, tuned = _net(w0, b0), _net(w1, b1)
    x = rng.normal(size=(1, 3)).astype(np.float32)
    assert np.allclose(_run(average_weights(base, tuned, 0.0), x), _run(base, x))
    assert np.allclose(_run(average_weights(base, tuned, 1.0), x), _run(tuned, x), atol=1e-6)
    mid = average_weights(base, tuned, 0.25)
    assert np.allclose(_run(mid, x), x @ (0.75 * w0 + 0.25 * w1) + (0.75 * b0 + 0.25 * b1), atol=1e-5)
    # The inputs are left as they were.
    assert np.allclose(_run(base, x), x @ w0 + b0, atol=1e-5)


def test_two_different_networks_are_refused():
    rng = np.random.default_rng(1)
    w, b = rng.normal(size=(3, 2)), rng.normal(size=2)
    with pytest.raises(UserInputError, match="not the same network"):
        average_weights(_net(w, b), _net(w, b, shape=(2, 1)), 0.5)  # a shape constant differs
    with pytest.raises(UserInputError, match="not the same network"):
        average_weights(_net(w, b), _net(rng.normal(size=(3, 3)), rng.normal(size=3)), 0.5)
    with pytest.raises(UserInputError, match="alpha"):
        average_weights(_net(w, b), _net(w, b), 1.5)


def test_research_weight_average_writes_the_file_and_a_card_measured_again(tmp_path):
    import json
    import shutil

    pytest.importorskip("torch")
    from live.core import assets
    from research.weight_average import main

    tuned = tmp_path / "tuned" / "skeleton.onnx"
    tuned.parent.mkdir()
    shutil.copy(assets.weight("skeleton.onnx"), tuned)
    shutil.copy(assets.weight("skeleton.json"), tuned.with_suffix(".json"))
    card = main(["--tuned", str(tuned), "--alpha", "0.5", "--out", str(tmp_path / "out"), "--val", "24",
                 "--workers", "1"])
    out = tmp_path / "out" / "skeleton.onnx"
    # A network averaged with itself is itself (x / 2 + x / 2 is exact in float32).
    a, b = onnx.load(str(out)), onnx.load(str(assets.weight("skeleton.onnx")))
    assert a.SerializeToString() == b.SerializeToString()
    written = json.loads(out.with_suffix(".json").read_text())
    assert written["weight_average"]["alpha"] == 0.5 and written["command"].startswith("python -m research.weight_average")
    assert written["weight_average"]["base"]["sha256"] == written["weight_average"]["tuned"]["sha256"]
    assert 0 < written["metrics"]["val"]["mpjpe_mm"] < 100 and card["metrics"] == written["metrics"]
