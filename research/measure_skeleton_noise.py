"""Measure the depth skeleton stage's error as a noise model for training the retargeter.

    python -m research.measure_skeleton_noise [--frames 240] [--model PATH] [--lag L]

Training clips on training bodies (never the held-out ones), virtual OAK-D, the shipped skeleton
stage with its default filter (and its temporal model of lag L, default 0: the online stage
that live puppeteering runs). Prints, per joint, the error's standard deviation per axis (mm,
about its mean: the bias is not noise), its frame-to-frame correlation and its acceleration error;
``models.train.train_retarget.DEPTH_NOISE_MM`` / ``DEPTH_NOISE_CORR`` hold the rounded figures.
"""

from __future__ import annotations

import argparse

import numpy as np

#: (clip, body) pairs of the training splits (CMU subject 2, two training bodies).
PAIRS = (("cc_002_05.bvh", "heavy_male"), ("cc_002_05.bvh", "petite_female"),
         ("mb_02_01.bvh", "heavy_male"), ("mb_02_01.bvh", "petite_female"))


def error_statistics(errors: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per-joint std per axis (m), lag-1 correlation and mean |second difference| (m/frame^2) of
    error sequences (each T x 22 x 3), each centred on its own mean."""
    centred = [e - e.mean(axis=0) for e in errors]
    flat = np.concatenate(centred)
    std = np.sqrt((flat ** 2).sum(-1).mean(0) / 3)
    corr = np.mean([(x[1:] * x[:-1]).sum((0, 2)) / (x * x).sum((0, 2)) for x in centred], axis=0)
    acc = np.mean([np.linalg.norm(e[2:] - 2 * e[1:-1] + e[:-2], axis=-1).mean(0) for e in errors], axis=0)
    return {"std": std, "corr": corr, "acc": acc}


def main(argv: list[str] | None = None) -> dict[str, np.ndarray]:
    from live.body.library import list_presets, load_body
    from live.core.skeleton import JOINT_NAMES
    from live.evaluation.retarget import _on_body, depth_skeletons, prepare_motion
    from sim.skeleton_data import BVH_DIR, VAL_SUBJECTS, list_clips, split_bodies

    ap = argparse.ArgumentParser(prog="python -m research.measure_skeleton_noise", description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--model", default=None, help="skeleton .onnx (default: the shipped one)")
    ap.add_argument("--lag", type=int, default=0, help="temporal model lag in frames (default 0)")
    args = ap.parse_args(argv)
    held_out = {c.file for c in list_clips() if c.subject in VAL_SUBJECTS}
    train_bodies = set(split_bodies(list_presets(), "train"))
    errors = []
    for k, (clip, body_name) in enumerate(PAIRS):
        assert clip not in held_out and body_name in train_bodies
        motion = prepare_motion(BVH_DIR / clip, 30.0, args.frames)
        body = load_body(body_name)
        pred, found = depth_skeletons(motion, body, seed=k, skeleton_model=args.model, lag=args.lag)
        _, truth = _on_body(motion, body.rest_joints)
        errors.append((pred - truth)[found])
    stats = error_statistics(errors)
    for name, s, c, a in zip(JOINT_NAMES, stats["std"], stats["corr"], stats["acc"]):
        print(f"{name:15s} std/axis {1000 * s:5.1f} mm   lag-1 correlation {c:.2f}   acc {1000 * a:5.1f} mm/frame^2")
    print("DEPTH_NOISE_MM =", tuple(int(round(1000 * s)) for s in stats["std"]))
    print(f"DEPTH_NOISE_CORR ~ {float(np.mean(stats['corr'])):.2f}")
    return stats


if __name__ == "__main__":
    main()
