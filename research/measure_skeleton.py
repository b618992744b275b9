"""Re-measure a skeleton model's per-frame validation metrics with the shipped person finder.

    python -m research.measure_skeleton [--model models/weights/skeleton.onnx] [--val 1200] [--temporal] [--card]

Why: a card's metrics were measured on the samples the person finder drew when the model was
trained; a finder that samples differently (such as its evenly spread fine sample,
docs/skeleton.md) changes what the same weights see. This draws the card's validation sets again
(the same frames: train_skeleton's seeds 1 and 2, never cached) with the shipped finder
(models/skeleton/preprocess.py) and scores the model on them.
``--temporal`` also scores the shipped temporal models (online and lag 2) behind it on their
150 held-out validation sequences, sampled again the same way. ``--card`` records the results in
the cards as "metrics_current_finder", beside the training-time "metrics", with this command.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from live.core import assets

KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "pck_10cm", "upper_body_mpjpe_mm")


def validation_sets(n_val: int, workers: int = 2, edge_jump_share: float | None = None) -> dict[str, dict]:
    """The card's validation sets as train_skeleton draws them (seeds 1 and 2 beside training's 0),
    sampled by the shipped finder with the model's settings (never read from the cache)."""
    from sim.skeleton_data import generate

    return {"val": generate("val", n_val, seed=1, workers=workers, cache=False, edge_jump_share=edge_jump_share),
            "val_upper": generate("val_upper", max(n_val // 3, 12), seed=2, workers=workers, cache=False,
                                  edge_jump_share=edge_jump_share)}


def temporal_results(regressor: Path, workers: int = 2) -> dict[Path, dict]:
    """{temporal model path: its on-performer validation metrics} for the shipped temporal models
    behind ``regressor``, on the temporal cards' validation sequences drawn by the shipped finder."""
    from models.skeleton.runtime import SkeletonRegressor
    from models.skeleton.temporal import TemporalRefiner, temporal_model_path
    from models.train.train_skeleton_temporal import (
        build_examples,
        refine_onnx,
        regress_sequences,
        to_world_of,
        validation_results,
    )
    from sim.skeleton_sequences import SEQUENCE_FPS, generate_sequences

    val = generate_sequences("val", 150, seed=1, workers=workers, cache=False,
                             edge_jump_share=SkeletonRegressor(regressor).edge_jump_share)
    world, conf = regress_sequences(val, regressor, 1)
    out = {}
    for lag in (0, 2):
        path = temporal_model_path(lag, regressor)
        if not path.is_file():
            continue
        ex = build_examples(val, world, conf, TemporalRefiner(path).window, SEQUENCE_FPS, lag)
        res = validation_results(val, ex, world, {"temporal": to_world_of(ex, refine_onnx(path, ex["features"]),
                                                                          world.shape)})
        out[path] = {k: res["on_performer"][k] for k in ("per_frame", "temporal")}
    return out


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m research.measure_skeleton", description=__doc__.splitlines()[0])
    p.add_argument("--model", type=Path, default=assets.weight("skeleton.onnx"))
    p.add_argument("--val", type=int, default=1200, help="validation samples (the card's sets: 1200)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--temporal", action="store_true", help="also the shipped temporal models behind it")
    p.add_argument("--card", action="store_true", help="record the results in the models' cards")
    args = p.parse_args(argv)
    card_path = args.model.with_suffix(".json")
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    from models.skeleton.runtime import SkeletonRegressor
    from models.train.train_skeleton import onnx_results

    share = SkeletonRegressor(args.model).edge_jump_share  # the finder settings it was trained with
    results = onnx_results(args.model, validation_sets(args.val, args.workers, share), int(card.get("num_points", 256)))
    results = {split: m for split, m in results.items() if "mpjpe_mm" in m}  # not the per-body / camera groups
    for split, m in results.items():
        before = card.get("metrics", {}).get(split, {})
        print(f"{split:11s} " + "  ".join(f"{k} {before.get(k, '-')} -> {m[k]}" for k in KEYS), flush=True)
    command = "python -m research.measure_skeleton " + shlex.join(argv if argv is not None else sys.argv[1:])
    note = ("the card's validation {} sampled again by the shipped person finder (models/skeleton/preprocess.py); "
            "'metrics' are those of training time")
    if args.card:
        card["metrics_current_finder"] = {"command": command, "note": note.format("frames"),
                                          **{split: {k: m[k] for k in KEYS} for split, m in results.items()}}
        card_path.write_text(json.dumps(card, indent=1) + "\n")
    for path, res in (temporal_results(args.model, args.workers) if args.temporal else {}).items():
        for name, m in res.items():
            print(f"{path.name:28s} {name:9s} MPJPE {m['mpjpe_mm']:5.1f}  PA-MPJPE {m['pa_mpjpe_mm']:5.1f}  "
                  f"PCK {m['pck_10cm']:.3f}  Acc {m['acc_mm_per_frame2']:5.2f} mm/frame^2", flush=True)
        if args.card:
            tcard = json.loads(path.with_suffix(".json").read_text())
            tcard["metrics_current_finder"] = {"command": command, "note": note.format("sequences"),
                                               "val": {"on_performer": res}}
            path.with_suffix(".json").write_text(json.dumps(tcard, indent=1) + "\n")
    return results


if __name__ == "__main__":
    main()
