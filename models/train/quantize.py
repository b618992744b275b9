"""Weight-only int8 quantization of an exported MLP with onnxruntime's MatMulNBits.

Why: the temporal skeleton model runs once per frame on one window (a batch of one), so each
call streams its whole weight matrices through the core; between two frames the person finder
and the regressor push them out of the caches, and 5.5 MB of float32 weights then come from
memory on every frame (0.9 ms in the stage against 0.18 ms in a tight loop). Blockwise 8-bit
weights (scales per 32 inputs, onnxruntime's int8 kernel, ``accuracy_level`` 4) are a quarter
of that. Only layers whose rounding the model absorbs are quantized: ``quantize`` selects them
by node name, the others stay float32 (the temporal model's linear filter path, whose output is
added to the estimate as it is).

    quantize_matmuls(src_path, dst_path, quantize=lambda name: name.startswith("/mlp/"))
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

BLOCK_SIZE = 32
BITS = 8
ACCURACY_LEVEL = 4  # int8 compute: the only fast MatMulNBits kernel for 8-bit weights on x86


def gemms_as_matmuls(model, select: Callable[[str], bool]) -> list[str]:
    """Rewrite the selected Gemm nodes (weights an initializer, no transA, alpha = beta = 1) as
    MatMul + Add in place, the form MatMulNBits replaces; returns the new MatMul names."""
    from onnx import helper, numpy_helper

    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    nodes, rewritten = [], []
    for node in graph.node:
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        if (node.op_type != "Gemm" or not select(node.name) or node.input[1] not in inits
                or attrs.get("transA", 0) or attrs.get("alpha", 1.0) != 1.0 or attrs.get("beta", 1.0) != 1.0):
            nodes.append(node)
            continue
        w = numpy_helper.to_array(inits[node.input[1]])
        w = w.T.copy() if attrs.get("transB", 0) else w
        w_name, mm_out = f"{node.input[1]}_kn", f"{node.output[0]}_matmul"
        graph.initializer.append(numpy_helper.from_array(w, w_name))
        nodes.append(helper.make_node("MatMul", [node.input[0], w_name], [mm_out], name=f"{node.name}_matmul"))
        if len(node.input) > 2 and node.input[2]:
            nodes.append(helper.make_node("Add", [mm_out, node.input[2]], [node.output[0]], name=f"{node.name}_bias"))
        else:
            nodes[-1].output[0] = node.output[0]
        rewritten.append(f"{node.name}_matmul")
    del graph.node[:]
    graph.node.extend(nodes)
    # Transposed originals that no node reads any more would only bloat the file.
    used = {i for n in graph.node for i in n.input}
    keep = [i for i in graph.initializer if i.name in used]
    del graph.initializer[:]
    graph.initializer.extend(keep)
    return rewritten


def quantize_matmuls(src: Path, dst: Path, quantize: Callable[[str], bool]) -> dict:
    """Write ``dst``: ``src`` with the weights of the Gemm/MatMul layers whose node name
    ``quantize`` selects in 8-bit blocks (MatMulNBits); returns what the card records."""
    import onnx
    from onnxruntime.quantization.matmul_nbits_quantizer import DefaultWeightOnlyQuantConfig, MatMulNBitsQuantizer

    logging.getLogger("onnxruntime.quantization").setLevel(logging.WARNING)  # one INFO line per node
    model = onnx.load(str(src))
    if any(n.op_type == "MatMulNBits" for n in model.graph.node):
        raise ValueError(f"{src} is quantized already")
    selected = gemms_as_matmuls(model, quantize)
    selected += [n.name for n in model.graph.node if n.op_type == "MatMul" and quantize(n.name)
                 and n.name not in selected]
    others = [n.name for n in model.graph.node if n.op_type in ("Gemm", "MatMul") and n.name not in selected]
    config = DefaultWeightOnlyQuantConfig(block_size=BLOCK_SIZE, is_symmetric=True, accuracy_level=ACCURACY_LEVEL,
                                          bits=BITS)
    quantizer = MatMulNBitsQuantizer(model, algo_config=config, nodes_to_exclude=others)  # it reads MatMuls only
    quantizer.process()
    quantizer.model.save_model_to_file(str(dst), False)
    out = onnx.load(str(dst))
    done = sum(n.op_type == "MatMulNBits" for n in out.graph.node)
    if done != len(selected):
        raise RuntimeError(f"quantized {done} of the {len(selected)} selected layers of {src}")
    return {"method": "onnxruntime MatMulNBits, weight-only, symmetric", "bits": BITS, "block_size": BLOCK_SIZE,
            "accuracy_level": ACCURACY_LEVEL, "layers": selected, "float32_layers": others}


__all__ = ["quantize_matmuls", "gemms_as_matmuls"]
