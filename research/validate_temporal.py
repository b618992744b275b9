"""The shipped temporal models behind other per-frame regressors, on their own validation sequences.

    python -m research.validate_temporal --regressor NEW.onnx [--card] [--workers 2]

A temporal model is trained on one regressor's outputs; a regressor fine-tuned from that one makes
errors of the same kind, and the temporal model may correct them as well. This measures it: the
temporal cards' 150 held-out validation sequences (unseen subjects and bodies, OAK-D 1.5-4 m;
seed 1, cached under .cache/skeleton_data), each temporal model (online and lag 2) behind the
regressor it was trained behind and behind ``--regressor``. The question is compatibility, not
which regressor is better: with ``--card``, a temporal model that takes at least 90 % as much off
the new regressor's MPJPE and PA-MPJPE as off its own regressor's records it in its card's
``validated_behind`` (the runtime then runs it behind that regressor) with these figures.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from live.core import assets

KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "pck_10cm", "acc_mm_per_frame2")


def behind(regressor: Path, temporal: Path, val: dict) -> dict:
    """On-performer metrics of the regressor alone ("per_frame") and with the temporal model."""
    from models.skeleton.temporal import TemporalRefiner
    from models.train.train_skeleton_temporal import (
        build_examples,
        refine_onnx,
        regress_sequences,
        to_world_of,
        validation_results,
    )
    from sim.skeleton_sequences import SEQUENCE_FPS

    world, conf = regress_sequences(val, regressor, 1)
    lag = TemporalRefiner(temporal).lag
    ex = build_examples(val, world, conf, TemporalRefiner(temporal).window, SEQUENCE_FPS, lag)
    res = validation_results(val, ex, world, {"temporal": to_world_of(ex, refine_onnx(temporal, ex["features"]),
                                                                      world.shape)})
    return {k: {m: res["on_performer"][k][m] for m in KEYS} for k in ("per_frame", "temporal")}


def main(argv: list[str] | None = None) -> int:
    from models.skeleton.temporal import file_sha256
    from sim.skeleton_sequences import generate_sequences

    ap = argparse.ArgumentParser(prog="python -m research.validate_temporal", description=__doc__.split("\n\n")[0])
    ap.add_argument("--regressor", type=Path, required=True, help="the new per-frame regressor (ONNX)")
    ap.add_argument("--trained-behind", type=Path, default=None,
                    help="the regressor the temporal models were trained behind (default: the shipped one)")
    ap.add_argument("--card", action="store_true", help="record a no-worse result in the temporal cards")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    from models.skeleton.runtime import SkeletonRegressor

    own = args.trained_behind or assets.weight("skeleton.onnx")

    def sequences(regressor: Path) -> dict:
        """The validation sequences as the finder samples them for this regressor."""
        share = SkeletonRegressor(regressor).edge_jump_share
        return generate_sequences("val", 150, seed=1, workers=args.workers, progress=True, edge_jump_share=share)

    command = "python -m research.validate_temporal " + shlex.join(argv if argv is not None else sys.argv[1:])
    for name in ("skeleton_temporal.onnx", "skeleton_temporal_lag2.onnx"):
        path = assets.weight(name)
        card = json.loads(path.with_suffix(".json").read_text())
        if card.get("regressor_sha256") != file_sha256(own):
            print(f"{name}: not trained behind {own}; skipped")
            continue
        before, after = behind(own, path, sequences(own)), behind(args.regressor, path, sequences(args.regressor))
        for label, res in (("own regressor", before), ("new regressor", after)):
            for k, m in res.items():
                print(f"{name:28s} {label:13s} {k:9s} " + "  ".join(f"{key} {m[key]}" for key in KEYS), flush=True)
        gains = {k: (before["per_frame"][k] - before["temporal"][k], after["per_frame"][k] - after["temporal"][k])
                 for k in ("mpjpe_mm", "pa_mpjpe_mm")}
        ok = all(new >= 0.9 * own for own, new in gains.values())
        print(f"{name}: takes off " + ", ".join(f"{k} {own:.1f} mm behind its own regressor, {new:.1f} behind "
                                               f"the new one" for k, (own, new) in gains.items())
              + ("" if ok else ": NOT compatible"))
        if args.card and ok:
            entry = {"file": args.regressor.name, "sha256": file_sha256(args.regressor), "command": command,
                     "val_on_performer": {"behind_trained_regressor": before, "behind_this_regressor": after}}
            card["validated_behind"] = [v for v in card.get("validated_behind", []) if v["sha256"] != entry["sha256"]]
            card["validated_behind"].append(entry)
            path.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
