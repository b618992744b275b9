"""Where the whole chain's PA-Acc comes from, and what the skeleton stage would have to give for
a goal (such as PA-Acc <= 4 mm/frame^2 from depth).

    python -m research.acc_budget [--all-clips] [--lag 2] [--frames 300] [--json FILE]

On the runs of ``live.evaluation.retarget.held_out_table`` (held-out clips x held-out bodies, the
shipped skeleton stage behind the virtual OAK-D), the source skeletons go through both
retargeters as they are and after two kinds of change:

- *scaled error*: truth + alpha x (estimate - truth). The error keeps its structure (which
  joints, how it moves from frame to frame) and is alpha times as large: the chain's figures
  behind a skeleton stage alpha times as wrong. alpha 0 is the exact skeleton with the T-pose
  still estimated from it, as live.
- *offline smoothing*: the estimate smoothed by a centred Gaussian of sigma frames, a look-ahead
  no live stage has: what more smoothing of the shipped stage's estimates can give.

Two rows describe the ground truth itself: the mean |acceleration| of its joints (the PA-Acc of
an estimate that never accelerates is of that size), and the PA-Acc of the truth after a light
centred Gaussian (sigma 0.6 frames): acceleration a smooth estimate cannot follow.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from live.core.metrics import acceleration_error, mpjpe, pa_acceleration_error

#: Scales of the skeleton's error tried (1 = as shipped, 0 = exact joints).
ALPHAS = (1.0, 0.75, 0.65, 0.5, 0.0)
#: Offline Gaussian widths (frames) tried on the estimate.
SIGMAS = (1.0, 1.5)
#: A light smoothing of the truth: what of its acceleration lies in the last frame-to-frame wiggle.
TRUTH_SIGMA = 0.6
RETARGETERS = ("analytic", "learned")
#: The smoothness figure of every row (mm/frame^2, as live.evaluation.retarget.score keys it).
ACC = "pa_acc_mm_per_frame2"


def scaled_error(estimate: np.ndarray, truth: np.ndarray, alpha: float) -> np.ndarray:
    """truth + alpha (estimate - truth), joints (T, J, 3): the same error, alpha times as large."""
    truth = np.asarray(truth, np.float64)
    return truth + float(alpha) * (np.asarray(estimate, np.float64) - truth)


def smoothed(joints: np.ndarray, sigma: float) -> np.ndarray:
    """Joints (T, J, 3) smoothed along time by a centred Gaussian of ``sigma`` frames (the ends
    repeat the first / last frame)."""
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(np.asarray(joints, np.float64), float(sigma), axis=0, mode="nearest")


def variants(alphas=ALPHAS, sigmas=SIGMAS) -> dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """name -> f(estimate, truth) giving the source skeletons that go to the retargeters."""
    out: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {}
    for a in alphas:
        out["as shipped" if a == 1.0 else f"error x {a:g}"] = lambda e, t, a=a: scaled_error(e, t, a)
    for s in sigmas:
        out[f"offline Gaussian, sigma {s:g} frames"] = lambda e, t, s=s: smoothed(e, s)
    return out


def budget(clips=None, *, max_frames: int = 300, lag: int = 0, seed: int = 0, alphas=ALPHAS, sigmas=SIGMAS,
           bvh_dir=None, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The figures of the module docstring, averaged over the runs (metres, mm/frame^2):
    {"variants": {name: {"skeleton": {mpjpe, pa_acc_mm_per_frame2}, "analytic": {...}, "learned": {...}}},
    "truth": {"acc_mm_per_frame2", "pa_acc_lost_to_smoothing_mm_per_frame2", "sigma"}, "runs", "lag",
    "clips", "frames"}."""
    from live.evaluation.retarget import (
        HELD_OUT_CLIPS,
        _on_body,
        estimated_rest,
        held_out_runs,
        score,
        source_skeletons,
    )

    clips = HELD_OUT_CLIPS if clips is None else tuple(clips)
    make = variants(alphas, sigmas)
    per_run: dict[str, dict[str, list[dict]]] = {n: {k: [] for k in ("skeleton", *RETARGETERS)} for n in make}
    truth_acc, truth_lost = [], []
    for run in held_out_runs(clips, max_frames=max_frames, bvh_dir=bvh_dir, seed=seed):
        estimate, _, found = source_skeletons(run.motion, run.source, "depth", seed=run.seed, lag=lag)
        _, truth = _on_body(run.motion, run.source.rest_joints)
        truth_acc.append(1000 * acceleration_error(np.zeros_like(truth), truth))  # = mean |acc| of the truth
        truth_lost.append(1000 * pa_acceleration_error(smoothed(truth, TRUTH_SIGMA), truth))
        for name, fn in make.items():
            src = fn(estimate, truth)
            per_run[name]["skeleton"].append({"mpjpe": mpjpe(src, truth),
                                              ACC: 1000 * pa_acceleration_error(src, truth)})
            rest = estimated_rest(src, found)
            for kind in RETARGETERS:
                r = score(run.motion, run.target, src, rest, kind)
                per_run[name][kind].append({"mpjpe": r["mpjpe"], ACC: r[ACC]})
        if progress is not None:
            progress(run.name)
    mean = {name: {k: {m: float(np.mean([r[m] for r in rows])) for m in ("mpjpe", ACC)}
                   for k, rows in by_kind.items()} for name, by_kind in per_run.items()}
    return {"variants": mean, "truth": {"acc_mm_per_frame2": float(np.mean(truth_acc)),
                                        "pa_acc_lost_to_smoothing_mm_per_frame2": float(np.mean(truth_lost)),
                                        "sigma": TRUTH_SIGMA},
            "runs": len(truth_acc), "lag": lag, "clips": len(clips), "frames": max_frames}


def format_budget(result: dict[str, Any]) -> str:
    """The budget as a Markdown table (mm, mm/frame^2)."""
    head = ("| source skeletons | skeleton MPJPE | skeleton PA-Acc | analytic MPJPE | analytic PA-Acc "
            "| learned MPJPE | learned PA-Acc |")
    lines = [f"{result['clips']} held-out clips x {result['frames']} frames, {result['runs']} runs, "
             f"skeleton stage lag {result['lag']}", "", head, "|" + "---|" * (head.count("|") - 1)]
    for name, v in result["variants"].items():
        cells = " | ".join(f"{1000 * v[k]['mpjpe']:.1f} | {v[k][ACC]:.2f}" for k in ("skeleton", *RETARGETERS))
        lines.append(f"| {name} | {cells} |")
    t = result["truth"]
    lines += ["", f"Ground truth (source joints): mean |acceleration| {t['acc_mm_per_frame2']:.2f} mm/frame^2; "
              f"a centred Gaussian of {t['sigma']:g} frames on it alone gives PA-Acc {t['pa_acc_lost_to_smoothing_mm_per_frame2']:.2f}.",
              "Lengths in mm; PA-Acc in mm/frame^2 at 30 fps."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    import argparse
    import json
    from pathlib import Path

    from tqdm import tqdm

    from live.body.library import list_presets
    from live.evaluation.retarget import HELD_OUT_CLIPS, all_held_out_clips
    from sim.skeleton_data import split_bodies

    cli = argparse.ArgumentParser(prog="python -m research.acc_budget", description=__doc__.splitlines()[0])
    cli.add_argument("--frames", type=int, default=300, help="frames per clip (default 300)")
    cli.add_argument("--lag", type=int, default=0, help="skeleton stage lag in frames (0 online, 2 the smoother)")
    cli.add_argument("--all-clips", action="store_true", help="every clip of the held-out subjects (23)")
    cli.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the figures as JSON")
    cli.add_argument("--no-progress", action="store_true")
    a = cli.parse_args(argv)
    clips = all_held_out_clips() if a.all_clips else HELD_OUT_CLIPS
    total = len(split_bodies(list_presets(), "val")) * len(clips)
    with tqdm(total=total, desc="acc budget", unit="run", disable=a.no_progress) as bar:
        result = budget(clips, max_frames=a.frames, lag=a.lag, progress=lambda _: bar.update(1))
    print(format_budget(result))
    if a.json is not None:
        a.json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
