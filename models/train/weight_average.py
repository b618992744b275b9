"""The weights of two trainings of one network, averaged (WiSE-FT, Wortsman et al., CVPR 2022).

A fine-tune on new views (raised legs, kicks) gains there and drifts elsewhere (close-ups); the
average of its weights and those it started from keeps most of the gain and little of the drift,
because both lie in one basin of the loss. ``average_weights`` works on the exported ONNX graphs:
the same network (the same nodes, ops and shapes) in both, every float weight interpolated, every
other constant (shapes, indices) required equal. ``research.weight_average`` writes the averaged
file with its card, measured again.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import numpy_helper

from live.core.errors import UserInputError


def _weights(model: onnx.ModelProto) -> dict[str, onnx.TensorProto]:
    """The graph's constant tensors by name: initialisers and Constant nodes' values (the
    exporter folds weights into either)."""
    out = {t.name: t for t in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type == "Constant":
            for attr in node.attribute:
                if attr.name == "value":
                    out[node.output[0]] = attr.t
    return out


def average_weights(base: onnx.ModelProto, tuned: onnx.ModelProto, alpha: float) -> onnx.ModelProto:
    """A copy of ``base`` whose float weights are (1 - alpha) x base's + alpha x tuned's.

    Raises UserInputError when the two are not the same network."""
    if not 0.0 <= alpha <= 1.0:
        raise UserInputError(f"alpha {alpha} is not in [0, 1]")
    if [(n.op_type, n.name) for n in base.graph.node] != [(n.op_type, n.name) for n in tuned.graph.node]:
        raise UserInputError("the two models are not the same network (their graphs' nodes differ)")
    out = onnx.ModelProto()
    out.CopyFrom(base)
    tuned_weights = _weights(tuned)
    for name, tensor in _weights(out).items():
        a = numpy_helper.to_array(tensor)
        b = numpy_helper.to_array(tuned_weights[name]) if name in tuned_weights else None
        if b is None or a.shape != b.shape or a.dtype != b.dtype:
            raise UserInputError(f"the two models are not the same network (weight {name!r} missing or of another shape)")
        if a.dtype.kind != "f":
            if not np.array_equal(a, b):
                raise UserInputError(f"the two models are not the same network (constant {name!r} differs)")
            continue
        mixed = ((1.0 - alpha) * a + alpha * b).astype(a.dtype)
        tensor.CopyFrom(numpy_helper.from_array(mixed, tensor.name))
    return out


__all__ = ["average_weights"]
