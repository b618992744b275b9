"""Skeleton regressors side by side on the held-out validation sets, per split, sensor and body.

    python -m research.compare_skeleton [--models A.onnx B.onnx ...] [--val 1200] [--json FILE]
                                        [--mirrored-readings]

The sets are train_skeleton's (seeds 1, 2 and 3 beside training's 0; cached under
.cache/skeleton_data): "val" (OAK-D 1.5-4 m, the default sensor model), "val_upper" (close-ups)
and "val_real" (the same unseen clips and bodies as users' sensors see people: five sensors,
clothes, occluders, any camera height and pitch, 40 % without extrinsics; sim.sensor_realism).
Prints markdown tables (MPJPE / PA-MPJPE mm, PCK@10cm) for docs/results.md: in the person frame,
and after root alignment (the pelvis moved onto the truth's, as real labelled benchmarks score),
per sensor and body, and on val_real per view condition (posture, extrinsics hidden, something in
front, a person behind, clothes, close-up, camera pitch and distance: ``sim.skeleton_data.VIEW_KEYS``)
and per posture with extrinsics given or hidden (``CROSSED``), and the views like the real Xtion
frames' (``like_real_xtion``). Each cell also gives the share of frames whose body is turned more
than 45 degrees from the truth's (``live.core.metrics.turned_share``).

``--mirrored-readings`` also reads each val_real cloud mirrored (x -> -x, the answer mirrored
back) and prints how often the two readings face more than 90 degrees apart, and PCK@10cm after
root alignment of the direct reading, of the one facing the camera more where they disagree, of
the one whose bones lie nearer the cloud (``models.skeleton.body_fit``), of their average and of
the better of the two per frame (known only from the truth): whether the network is torn between
front and back on the frames it turns, or sure of the wrong one.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.metrics import mpjpe, pa_mpjpe, pck, turned_share
from live.core.skeleton import NUM_JOINTS

SPLITS = (("val", 1), ("val_upper", 2), ("val_real", 3))


#: val_real's view-condition groups: (name, key of the data, bins or None for its own values).
CONDITIONS = (("posture", "posture", None), ("extrinsics hidden", "hidden_extrinsics", None),
              ("occluder", "occluder", None), ("bystander", "bystander", None), ("dressed", "dressed", None),
              ("close-up", "closeup", None), ("pitch deg", "pitch_deg", (-90, -25, -5, 5, 15, 90)),
              ("distance m", "distance", (0.0, 2.0, 3.0, 4.0, 9.0)))
#: Pairs of val_real's conditions also scored together: up and the floor are the finder's own
#: guess when extrinsics are hidden, and how good a guess that is depends on the posture.
CROSSED = (("posture", "posture", "extrinsics hidden", "hidden_extrinsics"),)


def scores(pred: np.ndarray, gt: np.ndarray, root_shift: np.ndarray) -> dict:
    """MPJPE / PA-MPJPE / PCK@10cm of pred (T, J, 3) against gt, and the same two after root
    alignment: pred + root_shift ((T, 1, 3): the truth's pelvis less the predicted one), as real
    labelled benchmarks score; and the share of frames whose body is turned more than 45 degrees
    from the truth's (read facing away: no alignment of the root repairs them)."""
    aligned = pred + root_shift
    return {"frames": int(len(pred)), "mpjpe_mm": round(1000 * mpjpe(pred, gt), 1),
            "pa_mpjpe_mm": round(1000 * pa_mpjpe(pred, gt), 1), "pck_10cm": round(pck(pred, gt, 0.1), 3),
            "root_aligned_mpjpe_mm": round(1000 * mpjpe(aligned, gt), 1),
            "root_aligned_pck_10cm": round(pck(aligned, gt, 0.1), 3),
            "turned_45_share": round(turned_share(pred, gt, 45.0), 3) if pred.shape[1] == NUM_JOINTS else None}


def groups(d: dict, split: str) -> list[tuple[str, np.ndarray]]:
    """(group name, sample mask) of a split's data: every sensor and body; on val_real also
    each view condition (CONDITIONS), for data that carries them."""
    out = []
    for key in ("camera", "body"):
        out += [(f"{key}:{v}", d[key] == v) for v in np.unique(d[key])]
    if split != "val_real":
        return out
    for name, key, bins in CONDITIONS:
        if key not in d:
            continue
        if bins is None:
            out += [(f"{name}:{v}", d[key] == v) for v in np.unique(d[key])]
        else:
            x = d[key]
            out += [(f"{name}:{lo:g}..{hi:g}", (x >= lo) & (x < hi)) for lo, hi in zip(bins[:-1], bins[1:])
                    if ((x >= lo) & (x < hi)).any()]
    for name_a, key_a, name_b, key_b in CROSSED:
        if key_a in d and key_b in d:
            out += [(f"{name_a}:{a}, {name_b}:{b}", m) for a in np.unique(d[key_a]) for b in np.unique(d[key_b])
                    if (m := (d[key_a] == a) & (d[key_b] == b)).any()]
    if all(k in d for k in ("posture", "distance", "pitch_deg", "occluder", "closeup", "hidden_extrinsics")):
        out.append(("views like the real Xtion frames", like_real_xtion(d)))
    return out


def like_real_xtion(d: dict) -> np.ndarray:
    """Samples of val_real seen as ../shared/data/real_depth's Xtion frames see their performer
    (and as benchmarks of that sensor do): standing or in place, 2-4 m away, the camera level or
    a little down (pitch -25..5 degrees), nothing in front, not a close-up, extrinsics given."""
    return (np.isin(d["posture"], ["clip", "in-place"]) & (d["distance"] >= 2.0) & (d["distance"] < 4.0)
            & (d["pitch_deg"] > -25.0) & (d["pitch_deg"] < 5.0) & ~d["occluder"].astype(bool)
            & ~d["closeup"].astype(bool) & ~d["hidden_extrinsics"].astype(bool))


def predict(model: Path, points: np.ndarray) -> np.ndarray:
    from models.skeleton.runtime import SkeletonRegressor

    reg = SkeletonRegressor(model)
    n = reg.num_points
    return np.concatenate([reg(points[a:a + 256, :n]) for a in range(0, len(points), 256)]).astype(np.float64)


def mirrored_readings(model: Path, d: dict) -> dict:
    """The direct and the mirrored reading of val_real's clouds side by side
    (``--mirrored-readings``): frames whose readings face more than 90 degrees apart, and
    root-aligned PCK@10cm of each way of choosing between them."""
    from live.core.heading import body_heading, wrap_angle
    from models.skeleton.body_fit import body_fit
    from sim.skeleton_data import mirror

    gt = d["joints"].astype(np.float64)
    direct = predict(model, d["points"])
    mirrored_points, _ = mirror(d["points"], d["joints"])
    _, back = mirror(mirrored_points, predict(model, mirrored_points))

    def aligned_pck(pred: np.ndarray) -> np.ndarray:
        aligned = pred + gt[:, :1] - pred[:, :1]
        return (np.linalg.norm(aligned - gt, axis=-1) < 0.1).mean(axis=1)

    facing_direct, facing_back = body_heading(direct), body_heading(back)
    apart = np.abs(wrap_angle(facing_direct - facing_back)) > np.pi / 2
    toward = apart & (np.abs(facing_back) < np.abs(facing_direct))  # heading 0: facing +z, the camera
    p_direct, p_back = aligned_pck(direct), aligned_pck(back)
    fit_direct, fit_back = ([body_fit(j, p) for j, p in zip(pred, d["points"])] for pred in (direct, back))
    return {"frames": int(len(gt)), "apart_90": int(apart.sum()),
            "direct": round(float(p_direct.mean()), 3),
            "facing_camera_where_apart": round(float(np.where(toward, p_back, p_direct).mean()), 3),
            "fits_the_cloud_better": round(float(np.where(np.less(fit_back, fit_direct), p_back, p_direct).mean()), 3),
            "average": round(float(aligned_pck((direct + back) / 2).mean()), 3),
            "better_of_two": round(float(np.maximum(p_direct, p_back).mean()), 3)}


def compare(models: list[Path], n_val: int, workers: int = 2, mirrored: bool = False) -> dict:
    from live.core.skeleton import UPPER_BODY_JOINTS
    from models.skeleton.runtime import SkeletonRegressor
    from sim.skeleton_data import generate

    out: dict = {}
    readings: dict = {}
    for split, seed in SPLITS:
        n = max(n_val // 3, 12) if split == "val_upper" else n_val
        joints = list(UPPER_BODY_JOINTS) if split == "val_upper" else slice(None)
        for model in models:
            # The same held-out scenes, sampled as the finder does for this model.
            d = generate(split, n, seed=seed, workers=workers, progress=True,
                         edge_jump_share=SkeletonRegressor(model).edge_jump_share)
            gt = d["joints"].astype(np.float64)
            pred = predict(model, d["points"])
            shift = gt[:, :1] - pred[:, :1]
            row = {"all": scores(pred[:, joints], gt[:, joints], shift)}
            for name, m in groups(d, split):
                row[name] = scores(pred[m][:, joints], gt[m][:, joints], shift[m])
            if mirrored and split == "val_real":
                readings[model.name] = mirrored_readings(model, d)
            out.setdefault(split, {})[model.name if model.name not in out.get(split, {}) else str(model)] = row
    if readings:
        out["mirrored_readings"] = readings
    return out


def markdown(results: dict) -> str:
    lines = []
    for split, by_model in results.items():
        if split == "mirrored_readings":
            lines.append("\n**val_real, direct and mirrored readings** (frames; readings facing over 90 degrees "
                         "apart; root-aligned PCK@10cm: direct, the one facing the camera where apart, "
                         "the one whose bones lie nearer the cloud, average, better of two)\n")
            lines += [f"- {m}: {r['frames']}; {r['apart_90']}; {r['direct']:.3f}, "
                      f"{r['facing_camera_where_apart']:.3f}, {r['fits_the_cloud_better']:.3f}, "
                      f"{r['average']:.3f}, {r['better_of_two']:.3f}"
                      for m, r in by_model.items()]
            continue
        names = list(by_model)
        groups = list(next(iter(by_model.values())))
        lines.append(f"\n**{split}** (MPJPE / PA-MPJPE mm, PCK@10cm; root-aligned MPJPE mm / PCK@10cm"
                     f"{'; upper body' if split == 'val_upper' else '; frames turned over 45 degrees'})\n")
        lines.append("| group | frames | " + " | ".join(names) + " |")
        lines.append("|---|---|" + "---|" * len(names))
        for g in groups:
            cells = [f"{r['mpjpe_mm']} / {r['pa_mpjpe_mm']} / {r['pck_10cm']:.3f}; "
                     f"{r['root_aligned_mpjpe_mm']} / {r['root_aligned_pck_10cm']:.3f}"
                     + (f"; {100 * r['turned_45_share']:.0f} %" if r.get("turned_45_share") is not None else "")
                     for r in (by_model[m][g] for m in names)]
            lines.append(f"| {g} | {by_model[names[0]][g]['frames']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.compare_skeleton", description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=Path, nargs="+", default=[assets.weight("skeleton.onnx")])
    ap.add_argument("--val", type=int, default=1200, help="samples per validation set (the card's: 1200)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--mirrored-readings", action="store_true",
                    help="also read val_real's clouds mirrored: is the network torn between front and back?")
    args = ap.parse_args(argv)
    missing = [m for m in args.models if not m.is_file()]
    if missing:
        ap.error(f"no model file {missing[0]}")
    results = compare(args.models, args.val, args.workers, args.mirrored_readings)
    print(markdown(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
