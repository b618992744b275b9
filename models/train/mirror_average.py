"""Mirror test-time averaging baked into a deployed skeleton model, without retraining.

Why: the regressor was trained with mirror augmentation (x -> -x in the person frame, left and
right swapped), so the mirrored view is a second valid input of the same pose, and its error is
only partly shared with the direct one. The new graph runs the network once on a batch of both
(the points and their mirror image), mirrors the second answer back and averages the two:
on the per-frame validation set -1.3 mm MPJPE and PA-MPJPE for a batch of two instead of one.
The file keeps its input ("points" (B, N, 3)) and output ("joints" (B, 22, 3)), so the runtime
does not change; the card records the wrap and the re-measured metrics. A file already wrapped
is refused (averaging twice changes nothing but the cost).

Not the shipped default: it doubles the model's time (docs/skeleton.md, "Mirror averaging").
``python -m models.train.train_skeleton --mirror-average`` exports the wrapped form;
``python -m research.mirror_average --out DIR`` wraps an existing model into its own folder and
re-measures it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

PREFIX = "mirror_average/"

#: The card's metrics that the wrap record keeps from before the wrap.
RECORD_KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "pck_10cm", "upper_body_mpjpe_mm")


def wrap_with_mirror_average(model):
    """The ONNX model ``model`` (input points (B, N, 3) -> joints (B, 22, 3), person frame) as
    joints = (f(p) + M f(M p)) / 2, M the mirror x -> -x with left/right joints swapped."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from live.core.skeleton import LEFT_RIGHT_SWAP

    graph = model.graph
    (inp,), (out,) = graph.input, graph.output
    both, inner_out = PREFIX + "both", PREFIX + "joints_of_both"
    for node in graph.node:  # the network now reads the batch of both and writes its own output
        node.input[:] = [both if i == inp.name else i for i in node.input]
        node.output[:] = [inner_out if o == out.name else o for o in node.output]
    consts = {"flip": np.array([-1.0, 1.0, 1.0], np.float32), "half": np.array(0.5, np.float32),
              "pair_shape": np.array([2, -1, 22, 3], np.int64), "swap": np.asarray(LEFT_RIGHT_SWAP, np.int64),
              "direct": np.array(0, np.int64), "mirrored": np.array(1, np.int64)}
    graph.initializer.extend(numpy_helper.from_array(v, PREFIX + k) for k, v in consts.items())
    c = {k: PREFIX + k for k in consts}
    n = PREFIX
    head = [
        helper.make_node("Mul", [inp.name, c["flip"]], [n + "mirrored_points"], name=n + "mirror_points"),
        helper.make_node("Concat", [inp.name, n + "mirrored_points"], [both], axis=0, name=n + "batch_both"),
    ]
    tail = [
        helper.make_node("Reshape", [inner_out, c["pair_shape"]], [n + "pair"], name=n + "split_pair"),
        helper.make_node("Gather", [n + "pair", c["direct"]], [n + "direct_joints"], axis=0, name=n + "take_direct"),
        helper.make_node("Gather", [n + "pair", c["mirrored"]], [n + "mirrored_joints"], axis=0,
                         name=n + "take_mirrored"),
        helper.make_node("Gather", [n + "mirrored_joints", c["swap"]], [n + "swapped"], axis=1, name=n + "swap_sides"),
        helper.make_node("Mul", [n + "swapped", c["flip"]], [n + "unmirrored"], name=n + "mirror_back"),
        helper.make_node("Add", [n + "direct_joints", n + "unmirrored"], [n + "sum"], name=n + "add"),
        helper.make_node("Mul", [n + "sum", c["half"]], [out.name], name=n + "average"),
    ]
    nodes = head + list(graph.node) + tail
    del graph.node[:]
    graph.node.extend(nodes)
    del graph.output[:]
    graph.output.append(helper.make_tensor_value_info(out.name, TensorProto.FLOAT, ["batch", 22, 3]))
    del graph.value_info[:]  # shapes inside the network changed batch size; let the checker re-infer
    onnx.checker.check_model(model)
    return model


def is_wrapped(model) -> bool:
    return any(node.name.startswith(PREFIX) for node in model.graph.node)


def apply_mirror_average(path: Path, single: dict) -> dict:
    """Wrap the ONNX file ``path`` in place; returns the card's "test_time_mirror" record, with
    ``single`` (the card's metrics before the wrap) in it. The caller re-measures the file."""
    import onnx

    onnx.save(wrap_with_mirror_average(onnx.load(str(path))), str(path))
    return {"what": "the graph averages the network's joints on the points and on their mirror image "
                    "(x -> -x, left/right swapped back): one batch of two per frame",
            "module": "models.train.mirror_average",
            "metrics_without": {split: {k: m[k] for k in RECORD_KEYS} for split, m in single.items()}}
