"""Average a fine-tuned skeleton regressor's weights with those it started from, and measure it.

    python -m research.weight_average --base BASE.onnx --tuned TUNED.onnx [--alpha 0.5] --out DIR [--val 1200]

Writes DIR/skeleton.onnx, (1 - alpha) x BASE's weights + alpha x TUNED's
(models.train.weight_average; the same network in both), and its card: TUNED's card (its
network, preprocessing, recipe, data and training) with "weight_average" (alpha, both parents'
sha256 and cards' commands), this command as "command" and "metrics" measured again on the card's validation
sets (the 1200-sample sets research.measure_skeleton draws, sampled by the shipped finder).
The stage takes temporal models only when trained behind this very file or validated behind it:
train them next, or measure the shipped ones behind it (`python -m research.validate_temporal
--regressor DIR/skeleton.onnx --trained-behind BASE.onnx --card`).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from live.core import assets


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m research.weight_average", description=__doc__.splitlines()[0])
    p.add_argument("--base", type=Path, default=assets.weight("skeleton.onnx"),
                   help="the weights the fine-tune started from (its --init)")
    p.add_argument("--tuned", type=Path, required=True, help="the fine-tuned regressor (its card beside it)")
    p.add_argument("--alpha", type=float, default=0.5, help="the fine-tune's share of every weight (0..1)")
    p.add_argument("--out", type=Path, required=True, help="folder for skeleton.onnx and its card")
    p.add_argument("--val", type=int, default=1200, help="validation samples to measure on (the card's sets)")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    for path in (args.base, args.tuned, args.tuned.with_suffix(".json")):
        if not path.is_file():
            p.error(f"no file {path}")

    import onnx

    from models.skeleton.temporal import file_sha256
    from models.train.train_skeleton import onnx_results
    from models.train.weight_average import average_weights
    from research.measure_skeleton import validation_sets

    tuned_card = json.loads(args.tuned.with_suffix(".json").read_text())
    base_card_path = args.base.with_suffix(".json")
    base_card = json.loads(base_card_path.read_text()) if base_card_path.is_file() else {}
    parents = {"base": {"file": str(args.base), "sha256": file_sha256(args.base),
                        "command": base_card.get("command")},
               "tuned": {"file": str(args.tuned), "sha256": file_sha256(args.tuned),
                         "command": tuned_card.get("command")}}
    averaged = average_weights(onnx.load(str(args.base)), onnx.load(str(args.tuned)), args.alpha)
    args.out.mkdir(parents=True, exist_ok=True)
    out = args.out / "skeleton.onnx"
    onnx.save(averaged, str(out))
    card = dict(tuned_card)
    card["weight_average"] = {
        "alpha": args.alpha, **parents,
        "note": "every float weight (1 - alpha) x base's + alpha x tuned's (WiSE-FT, Wortsman et al. 2022): "
                "the fine-tune's gains on its new views, less of its drift elsewhere; 'recipe', 'training' and "
                "'data' are the fine-tune's (its command under 'tuned')"}
    card["command"] = "python -m research.weight_average " + shlex.join(argv if argv is not None else sys.argv[1:])
    card.pop("metrics_current_finder", None)  # the tuned file's, not this one's
    card["metrics"] = onnx_results(out, validation_sets(args.val, args.workers, card["preprocess"]["edge_jump_share"]),
                                   int(card["num_points"]))
    out.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    for split, m in card["metrics"].items():
        if "mpjpe_mm" in m and "pck_10cm" in m:
            print(f"{split:11s} MPJPE {m['mpjpe_mm']} mm, PA-MPJPE {m['pa_mpjpe_mm']} mm, PCK@10cm {m['pck_10cm']:.3f}")
    print(f"wrote {out}")
    return card


if __name__ == "__main__":
    main()
