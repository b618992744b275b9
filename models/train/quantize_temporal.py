"""Quantize the shipped temporal skeleton models' weights without retraining; update their cards.

    python -m models.train.quantize_temporal [--lag 0 2] [--workers 2]

Each ``models/weights/skeleton_temporal*.onnx`` still in float32 gets its MLP's weights in
8-bit blocks (``models.train.quantize``, what ``train_skeleton_temporal`` now exports directly;
the linear filter path stays float32), and its card's validation metrics are measured again on
the deployed file beside the float32 one (``temporal_float32``), on the card's own validation
sequences (``sim.skeleton_sequences``, cached). A file that is quantized already is left alone.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np


def quantize_shipped(lag: int, workers: int, threads: int) -> dict | None:
    """Quantize one shipped temporal model in place and rewrite its card; None when it is
    quantized already."""
    import onnx

    from models.skeleton.runtime import DEFAULT_MODEL
    from models.skeleton.temporal import temporal_model_path
    from models.train.quantize import quantize_matmuls
    from models.train.train_skeleton_temporal import (build_examples, quantization_deviation, quantized_layer,
                                                      refine_onnx, regress_sequences, to_world_of,
                                                      validation_results)
    from sim.skeleton_sequences import generate_sequences

    path = temporal_model_path(lag)
    if any(n.op_type == "MatMulNBits" for n in onnx.load(str(path)).graph.node):
        print(f"{path.name}: quantized already")
        return None
    card_path = path.with_suffix(".json")
    card = json.loads(card_path.read_text())
    val = generate_sequences("val", card["data"]["val"]["sequences"], seed=card["seed"] + 1, workers=workers)
    world, conf = regress_sequences(val, DEFAULT_MODEL, threads)
    ex = build_examples(val, world, conf, card["window"], card["fps"], card["lag"])
    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / path.name
        shutil.copyfile(path, fp32)
        quantization = quantize_matmuls(fp32, path, quantize=quantized_layer)
        reference = refine_onnx(fp32, ex["features"])
    deployed = refine_onnx(path, ex["features"])
    card["metrics"]["val"] = validation_results(val, ex, world, {
        "temporal": to_world_of(ex, deployed, world.shape),
        "temporal_float32": to_world_of(ex, reference, world.shape)})
    card["float32_onnx_max_abs_diff_m"] = card.pop("onnx_max_abs_diff_m")
    card["onnx_max_abs_diff_m"] = float(np.abs(deployed - reference).max())  # against the float32 export
    card["quantization_deviation_m"] = quantization_deviation(deployed, reference)
    card["quantization"] = {**quantization, "by": "python -m models.train.quantize_temporal (float32 export "
                                                   "quantized without retraining)"}
    card_path.write_text(json.dumps(card, indent=1) + "\n")
    return card


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="quantize_temporal", description=__doc__.splitlines()[0])
    p.add_argument("--lag", type=int, nargs="+", default=[0, 2])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    for lag in args.lag:
        card = quantize_shipped(lag, args.workers, args.threads)
        if card is None:
            continue
        m = card["metrics"]["val"]["on_performer"]
        for name in ("temporal_float32", "temporal"):
            r = m[name]
            print(f"lag {lag} {name:17s} MPJPE {r['mpjpe_mm']:5.1f}  PA-MPJPE {r['pa_mpjpe_mm']:5.1f}  "
                  f"Acc {r['acc_mm_per_frame2']:5.2f} mm/frame^2", flush=True)


if __name__ == "__main__":
    main()
