"""Bodies read facing elsewhere, over time: held-out sequences as users' sensors see people.

    python -m research.facing_sequences [--sequences 200] [--workers 2] [--json FILE]

Sequences (48 frames at 30 fps) of the held-out clips and bodies seen as val_real sees them
(five sensors, clothes, occluders, any camera height and pitch, extrinsics often hidden;
``sim.sensor_realism``), seed 5, cached under .cache/skeleton_data. The shipped regressor runs on
every frame the finder found, then each shipped temporal model (online and lag 2) as the stage
runs it. Per frame: is the body turned more than 45 degrees from the truth's
(``live.core.metrics.turned``)? Prints, for the regressor alone and behind each temporal
model: the share of frames turned, how long the turned runs last (a glitch of a frame or two
that the history could hold off, or a view read the wrong way throughout), and how many
sequences are turned on most of their frames; MPJPE / PCK@10cm after root alignment. The
estimates go through the stage's flip guard, and, compared with it, through a guard that holds the
last skeleton through sudden turns (``--facing TURN_DEG:MAX_RUN ...``, ``FacingGuard``).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.heading import body_heading, wrap_angle
from live.core.metrics import turned

#: Seed of the held-out realism sequences (val_real's per-frame data uses 3; the clean validation
#: sequences of the temporal cards 1).
SEED = 5


def realism_sequences(n: int, edge_jump_share: float | None, workers: int) -> dict[str, np.ndarray]:
    """n held-out sequences with realism (val_real's jobs, one sequence each), cached."""
    from sim.sensor_realism import REALISM_VERSION
    from sim.skeleton_data import CACHE_DIR, plan_jobs, run_jobs, save_cache
    from sim.skeleton_sequences import run_sequence_job

    path = CACHE_DIR / f"facing_sequences_{n}_{SEED}_{edge_jump_share}_{REALISM_VERSION}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    jobs = plan_jobs("val_real", n, SEED + 1000, frames_per_job=1, edge_jump_share=edge_jump_share)[:n]
    results = run_jobs(run_sequence_job, jobs, workers, "facing sequences")
    data = {k: np.stack([r[k] for r in results]) for k in results[0]}
    for key in ("clip", "body", "camera"):
        data[key] = np.array([getattr(j, key) for j in jobs])
    data["closeup"] = np.array([j.closeup for j in jobs], bool)
    save_cache(path, data)
    return data


def turned_frames(world: np.ndarray, truth: np.ndarray, found: np.ndarray) -> np.ndarray:
    """(S, F) bool: found frames whose body is turned more than 45 degrees from the truth's."""
    with np.errstate(invalid="ignore"):  # frames not found are NaN
        return found & turned(world, truth, 45.0)


def runs(flags: np.ndarray, found: np.ndarray) -> list[int]:
    """Lengths of the runs of turned frames (found frames only, in order) over all sequences."""
    lengths = []
    for s in range(len(flags)):
        n = 0
        for f in np.flatnonzero(found[s]):
            if flags[s, f]:
                n += 1
            elif n:
                lengths.append(n)
                n = 0
        if n:
            lengths.append(n)
    return lengths


def summary(world: np.ndarray, data: dict, found: np.ndarray) -> dict:
    truth = data["joints"].astype(np.float64)
    flags = turned_frames(world, truth, found)
    lengths = np.array(runs(flags, found) or [0])
    per_seq = flags.sum(1) / np.maximum(found.sum(1), 1)
    w, t = world[found], truth[found]
    aligned = w + (t[:, :1] - w[:, :1])
    err = np.linalg.norm(aligned - t, axis=-1)
    return {"frames": int(found.sum()), "turned_share": round(float(flags[found].mean()), 4),
            "turned_runs": int((lengths > 0).sum()),
            "runs_1_2_frames": int(((lengths > 0) & (lengths <= 2)).sum()),
            "runs_3_8_frames": int(((lengths > 2) & (lengths <= 8)).sum()),
            "runs_over_8_frames": int((lengths > 8).sum()),
            "turned_frames_in_runs_over_8": int(lengths[lengths > 8].sum()),
            "sequences_mostly_turned": int((per_seq > 0.5).sum()),
            "root_aligned_mpjpe_mm": round(1000 * float(err.mean()), 1),
            "root_aligned_pck_10cm": round(float((err < 0.1).mean()), 3),
            "pck_turned": round(float((err[flags[found]] < 0.1).mean()), 3) if flags[found].any() else None}


@dataclass
class FacingGuard:
    """Hold the skeleton through a frame or a few whose body turns further than a performer turns
    in a frame (measured here, not in the stage: it gained nothing; docs/results.md).

    An estimate whose heading (across hips and shoulders) is more than ``max_turn_deg`` from the
    last one kept is replaced by that one, moved with the new estimate's pelvis, for at most
    ``max_run`` estimates in a row; then the guard follows the estimates again."""

    max_turn_deg: float = 90.0
    max_run: int = 4
    _prev: np.ndarray | None = None
    _run: int = 0

    def __call__(self, joints: np.ndarray) -> np.ndarray:
        if self._prev is not None:
            if abs(wrap_angle(body_heading(joints) - body_heading(self._prev))) > math.radians(self.max_turn_deg):
                self._run += 1
                if self._run <= self.max_run:
                    return self._prev + (joints[0] - self._prev[0])
            self._run = 0
        self._prev = joints
        return joints


def guarded(world: np.ndarray, found: np.ndarray, flips: bool, facing: dict | None) -> np.ndarray:
    """The per-frame estimates (S, F, 22, 3) through the stage's guards, as it runs them before
    the temporal model: the flip guard, then (``facing``: its settings) the facing guard; one
    pair per sequence, over its found frames."""
    from models.skeleton.filters import FlipGuard

    out = world.copy()
    for s in range(len(world)):
        flip, turn = FlipGuard(), FacingGuard(**facing) if facing is not None else None
        for f in np.flatnonzero(found[s]):
            j = flip(world[s, f]) if flips else world[s, f]
            out[s, f] = turn(j) if turn is not None else j
    return out


def measure(n: int, workers: int, variants: dict[str, dict | None]) -> dict:
    from models.skeleton.runtime import SkeletonRegressor
    from models.skeleton.temporal import TemporalRefiner
    from models.train.train_skeleton_temporal import build_examples, refine_onnx, regress_sequences, to_world_of
    from sim.skeleton_sequences import SEQUENCE_FPS

    regressor = assets.weight("skeleton.onnx")
    data = realism_sequences(n, SkeletonRegressor(regressor).edge_jump_share, workers)
    raw, conf = regress_sequences(data, regressor, 1)
    out = {"regressor alone": summary(raw, data, data["found"])}
    for label, facing in variants.items():
        world = guarded(raw, data["found"], True, facing)
        out[f"{label}: regressor + guards"] = summary(world, data, data["found"])
        for name in ("skeleton_temporal.onnx", "skeleton_temporal_lag2.onnx"):
            path = assets.weight(name)
            model = TemporalRefiner(path)
            ex = build_examples(data, world, conf, model.window, SEQUENCE_FPS, model.lag)
            refined = to_world_of(ex, refine_onnx(path, ex["features"]), world.shape)
            estimated = np.zeros(data["found"].shape, bool)
            estimated[ex["seq"], ex["frame"]] = True
            out[f"{label}: behind {name}"] = summary(refined, data, estimated)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.facing_sequences", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--facing", nargs="*", default=["90:4"],
                    help="facing guard settings to compare, TURN_DEG:MAX_RUN each (and always the flip guard alone)")
    args = ap.parse_args(argv)
    variants = {"flip guard": None}
    for turn, run in [tuple(map(float, v.split(":"))) for v in args.facing]:
        variants[f"facing guard {turn:g} deg, {int(run)} frames"] = {"max_turn_deg": turn, "max_run": int(run)}
    result = measure(args.sequences, args.workers, variants)
    for name, row in result.items():
        print(f"{name}: " + ", ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
