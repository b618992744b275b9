"""Train the skeleton regressors, evaluate them on held-out data, export ONNX + model cards.

    python -m models.train.train_skeleton [--quick] [--model ours|baseline|both]

Data comes from ``sim.skeleton_data.generate`` (cached under .cache/skeleton_data). Each model is
trained on the same samples, evaluated on the validation splits (unseen CMU subjects and unseen
bodies: "val" = OAK-D at 1.5-4 m, "val_upper" = close-ups with the legs out of frame), exported
to ONNX (opset 17, checked against onnxruntime) and described by a JSON model card. ``--quick``
(a few hundred samples, one epoch) writes to .cache/skeleton_quick unless --out is given, so a
smoke test never replaces the committed weights. Seeded: the same command gives the same data
and (on the same machine and thread count) the same weights.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from live.core import assets
from live.core.skeleton import UPPER_BODY_JOINTS
from models.train.skeleton_nets import build, count_parameters, export_onnx

WEIGHTS = assets.weights_dir()


@dataclass(frozen=True)
class Recipe:
    """Everything that decides a trained model (written into the card)."""

    kind: str
    epochs: int
    batch: int
    lr: float
    loss: str
    num_points: int
    schedule: str
    max_steps: int | None = None  # cap on optimiser steps (the CPU budget), None = all epochs
    net: dict = field(default_factory=dict)  # constructor options of the network
    augment: dict = field(default_factory=dict)  # models.train.point_augment.Augment fields; {} = none


RECIPES = {
    # The shipped model: a voting net with one local refinement stage (32 nearest points per
    # joint); at 12 epochs it gave 54.8 mm against 70.2 mm without (docs/skeleton.md).
    "ours": Recipe("ours", epochs=70, batch=64, lr=3e-3, loss="l1", num_points=256, schedule="cosine",
                   net={"refine_k": 32, "refine_width": 96}),
    # The reference recipe: Adam at 1e-4, MSE, constant rate. It costs ~6x our model per sample
    # on this CPU, so its share of the training budget is a step cap (see docs/skeleton.md).
    "baseline": Recipe("baseline", epochs=1, batch=32, lr=1e-4, loss="mse", num_points=256,
                       schedule="constant", max_steps=200),
}


def _batches(data: dict, recipe: Recipe, rng: np.random.Generator):
    """Shuffled training batches: a random subset of the stored points per sample and a random
    mirror (x -> -x, left/right swapped) per sample, then the recipe's augmentation
    (models.train.point_augment), if any. Yields (points B x N x 3, joints B x 22 x 3)."""
    from models.train.point_augment import Augment, augment_batch
    from sim.skeleton_data import mirror

    aug = Augment(**{k: tuple(v) if isinstance(v, list) else v for k, v in recipe.augment.items()})

    pts_all, jts_all = data["points"], data["joints"]
    order = rng.permutation(len(pts_all))
    stored = pts_all.shape[1]
    for s in range(0, len(order) - recipe.batch + 1, recipe.batch):
        idx = order[s:s + recipe.batch]
        pick = np.argsort(rng.random((len(idx), stored)), axis=1)[:, :recipe.num_points]
        pts = np.take_along_axis(pts_all[idx], pick[..., None], axis=1)
        jts = jts_all[idx].copy()
        m = rng.random(len(idx)) < 0.5
        pts[m], jts[m] = mirror(pts[m], jts[m])
        if aug.active:
            pts, jts = augment_batch(pts, jts, rng, aug)
        yield torch.from_numpy(pts), torch.from_numpy(jts)


def train_model(recipe: Recipe, train: dict, seed: int, progress: bool = True,
                init: Path | None = None) -> tuple[torch.nn.Module, dict]:
    """Train one network; returns it (eval mode) and a log of the run. ``init``: start from the
    weights of an ONNX export of the same network, either form (the training graph with its
    BatchNorm statistics, or the deployed one, unfolded on the first training clouds), instead of
    a random initialisation: a fine-tune; the optimiser state starts afresh."""
    from tqdm import tqdm

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = build(recipe.kind, **recipe.net)
    if init is not None:
        from models.train.reexport_skeleton import load_export

        # The file is read at the point count it was exported with, which may differ from this
        # recipe's: the weights do not depend on it.
        n_init = _card_points(init, recipe.num_points)
        model = load_export(init, model, n_init, train["points"][:256, :n_init]).train()
    opt = torch.optim.Adam(model.parameters(), lr=recipe.lr)
    steps_per_epoch = len(train["points"]) // recipe.batch
    total = max(steps_per_epoch * recipe.epochs, 1)
    if recipe.max_steps is not None:
        total = min(total, recipe.max_steps)
    sched = (torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=recipe.lr, total_steps=total, pct_start=0.05)
             if recipe.schedule == "cosine" else None)
    loss_fn = torch.nn.L1Loss() if recipe.loss == "l1" else torch.nn.MSELoss()
    log = {"epoch_loss": [], "steps": 0}
    t0 = time.monotonic()
    bar = tqdm(total=total, desc=f"train {recipe.kind}", unit="step", disable=not progress, mininterval=10.0)
    model.train()
    for _ in range(recipe.epochs):
        running, n = 0.0, 0
        for pts, jts in _batches(train, recipe, rng):
            if log["steps"] + n >= total:
                break
            if hasattr(model, "stages"):  # a cascade: its earlier estimates are supervised too
                *coarse, pred = model.stages(pts)
                loss = loss_fn(pred, jts) + sum(0.5 * loss_fn(c, jts) for c in coarse)
            else:
                loss = loss_fn(model(pts), jts)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if sched is not None:
                sched.step()
            running += loss.item()
            n += 1
            bar.update(1)
            bar.set_postfix(loss=f"{running / n:.4f}", refresh=False)
        log["epoch_loss"].append(round(running / max(n, 1), 6))
        log["steps"] += n
        if not progress:  # one line per epoch for logs of background runs
            print(f"{recipe.kind} epoch {len(log['epoch_loss'])}/{recipe.epochs}: loss "
                  f"{log['epoch_loss'][-1]:.4f}, {time.monotonic() - t0:.0f} s", flush=True)
    bar.close()
    log["seconds"] = round(time.monotonic() - t0, 1)
    return model.eval(), log


def _card_points(onnx_path: Path, default: int) -> int:
    """The point count a regressor export was trained on (its card's; ``default`` without one)."""
    card = onnx_path.with_suffix(".json")
    return int(json.loads(card.read_text()).get("num_points", default)) if card.is_file() else default


@torch.no_grad()
def predict(model: torch.nn.Module, points: np.ndarray, num_points: int, batch: int = 256) -> np.ndarray:
    """Person-frame joints (S, 22, 3) for stored samples (S, >=N, 3), on their first N points
    (the stored sample is a random draw, so its first N points are a random N-point sample)."""
    out = [model(torch.from_numpy(np.ascontiguousarray(points[s:s + batch, :num_points]))).numpy()
           for s in range(0, len(points), batch)]
    return np.concatenate(out).astype(np.float64)


def metrics(pred: np.ndarray, gt: np.ndarray, visible: np.ndarray | None = None) -> dict:
    """MPJPE, PA-MPJPE (mm), PCK@10cm, per-joint MPJPE (mm) of S x 22 x 3 predictions."""
    from live.core.metrics import mpjpe, pa_mpjpe, pck, per_joint_mpjpe
    from live.core.skeleton import JOINT_NAMES

    out = {"frames": int(len(pred)), "mpjpe_mm": round(1000 * mpjpe(pred, gt), 1),
           "pa_mpjpe_mm": round(1000 * pa_mpjpe(pred, gt), 1), "pck_10cm": round(pck(pred, gt, 0.1), 4),
           "per_joint_mm": {n: round(1000 * float(e), 1) for n, e in zip(JOINT_NAMES, per_joint_mpjpe(pred, gt))}}
    up = list(UPPER_BODY_JOINTS)
    out["upper_body_mpjpe_mm"] = round(1000 * mpjpe(pred[:, up], gt[:, up]), 1)
    if visible is not None:
        err = np.linalg.norm(pred - gt, axis=-1)
        out["visible_joint_mpjpe_mm"] = round(1000 * float(err[visible].mean()), 1)
        if (~visible).any():
            out["unseen_joint_mpjpe_mm"] = round(1000 * float(err[~visible].mean()), 1)
    return out


VAL_SPLITS = ("val", "val_upper", "val_real")


def split_results(split: str, pred: np.ndarray, d: dict) -> dict:
    """The card's metrics of one validation split: {split: ...}, for "val" also "val_1.5-4m"
    (the goal's setting: the performer 1.5-4 m from the camera), and per body and per camera
    (MPJPE, PA-MPJPE, PCK@10cm) as "<split>_by_body" / "<split>_by_camera"."""
    gt = d["joints"].astype(np.float64)
    out = {split: metrics(pred, gt, d["visible"])}
    if split == "val":
        m = (d["distance"] >= 1.5) & (d["distance"] <= 4.0)
        out["val_1.5-4m"] = metrics(pred[m], gt[m], d["visible"][m])
    for key in ("body", "camera"):
        groups = {}
        for name in np.unique(d[key]):
            m = d[key] == name
            full = metrics(pred[m], gt[m])
            groups[str(name)] = {k: full[k] for k in ("frames", "mpjpe_mm", "pa_mpjpe_mm", "pck_10cm")}
        out[f"{split}_by_{key}"] = groups
    return out


def onnx_results(path: Path, data: dict[str, dict], num_points: int) -> dict:
    """The card's validation results (split_results of every split of ``data``) of the ONNX file
    ``path``, run as the runtime runs it."""
    from models.skeleton.runtime import SkeletonRegressor

    reg = SkeletonRegressor(path)
    out = {}
    for split, d in data.items():
        pts = d["points"][:, :num_points]
        out.update(split_results(split, np.concatenate([reg(pts[a:a + 256]) for a in range(0, len(pts), 256)]), d))
    return out


def check_onnx(path: Path, model: torch.nn.Module, points: np.ndarray) -> float:
    """Max |onnxruntime - torch| (m) on a few real samples: the export must be exact."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = np.ascontiguousarray(points, np.float32)
    ref = predict(model, x, x.shape[1])
    got = sess.run(None, {"points": x})[0]
    return float(np.abs(got - ref).max())


def _parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="train_skeleton", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smoke run: a few hundred samples, 1 epoch")
    p.add_argument("--model", choices=("ours", "baseline", "both"), default="both")
    p.add_argument("--n-train", type=int, default=None)
    p.add_argument("--n-val", type=int, default=None)
    p.add_argument("--epochs", type=int, default=None, help="override the recipe's epochs")
    p.add_argument("--lr", type=float, default=None, help="override the recipe's peak learning rate")
    p.add_argument("--init", type=Path, default=None, metavar="ONNX",
                   help="fine-tune: start from an export of the same network, e.g. the shipped one (docs/skeleton.md)")
    p.add_argument("--num-points", type=int, default=None, metavar="N",
                   help="points the network reads per cloud (default 256; at most the 512 stored per sample)")
    p.add_argument("--net", type=json.loads, default=None, metavar="JSON",
                   help='override the network options of "ours", e.g. \'{"refine_k": 0}\' (ablations)')
    p.add_argument("--augment", type=json.loads, default=None, metavar="JSON",
                   help='per-sample augmentation (models.train.point_augment.Augment), e.g. '
                        '\'{"tilt_deg": 3, "jitter_mm": 6, "hole_share": 0.3}\'')
    p.add_argument("--anny", type=int, default=None, metavar="N",
                   help="on-demand Anny phenotypes among the training bodies (default 64; 0 with --quick)")
    p.add_argument("--anny-share", type=float, default=0.3,
                   help="share of the training jobs on an Anny phenotype instead of a preset")
    p.add_argument("--realism", action=argparse.BooleanOptionalAction, default=True,
                   help="training scenes as users' sensors see people: five sensor models, flying pixels, "
                        "holes, clothes, occluders, any camera height and pitch, hidden extrinsics "
                        "(sim.sensor_realism; default on)")
    p.add_argument("--hard-share", type=float, default=0.0, metavar="S",
                   help="share of the realism training jobs drawn toward the views the regressor gets most "
                        "wrong: seated and crouching, close-ups, occluders, steep pitch (sim.sensor_realism.HARD_VIEWS)")
    p.add_argument("--knee-up-share", type=float, default=0.0, metavar="S",
                   help="share of the realism training jobs whose performer raises the knees in turn, a knee held "
                        "toward the camera (sim.postures knee-up): the clips hold few limbs seen end-on")
    p.add_argument("--kick-share", type=float, default=0.0, metavar="S",
                   help="share of the realism training jobs whose performer kicks to the front in turn, a leg "
                        "pointing at the camera (sim.postures kick)")
    p.add_argument("--clean", type=int, default=0, metavar="N",
                   help="N more training samples without realism (the default sensor model, extrinsics given; "
                        "seed + 10), mixed in so the clean views stay as good")
    p.add_argument("--edge-share", type=float, default=None, metavar="S",
                   help="leave depth-edge pixels (a 4-neighbour more than S of their range nearer or farther) "
                        "out of every sample; the card tells the runtime to do the same")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None, help="where to write .onnx and .json")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-cache", action="store_true", help="do not read or write .cache/skeleton_data")
    p.add_argument("--mirror-average", action="store_true",
                   help="export ours with mirror test-time averaging (models.train.mirror_average): -1.3 mm "
                        "per frame for twice the model time, over the 2 ms goal on slower machines")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> dict:
    """Entry point of ``livecap train skeleton``; returns {kind: card}."""
    from models.skeleton.temporal import file_sha256
    from sim.skeleton_data import VAL_SUBJECTS, describe, generate, split_bodies

    args = _parse(argv)
    torch.set_num_threads(args.threads)
    n_train = args.n_train or (240 if args.quick else 20000)
    n_val = args.n_val or (60 if args.quick else 1200)
    out_dir = args.out or (assets.cache_dir("skeleton_quick") if args.quick else WEIGHTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    t0 = time.monotonic()
    anny = args.anny if args.anny is not None else (0 if args.quick else 64)
    if anny and args.anny_share > 0:  # the training split's phenotypes, built once into the body cache
        from models.train.anny_bodies import ensure_built
        from sim.skeleton_data import anny_phenotypes

        ensure_built(anny_phenotypes(anny, args.seed), progress)
    data = {split: generate(split, n, seed=args.seed + k, workers=args.workers, progress=progress,
                            cache=not args.no_cache, anny=anny, anny_share=args.anny_share,
                            realism=args.realism, edge_jump_share=args.edge_share,
                            hard_share=args.hard_share, knee_up_share=args.knee_up_share,
                            kick_share=args.kick_share)  # generate() draws them for training jobs only
            for k, (split, n) in enumerate((("train", n_train), ("val", n_val),
                                            ("val_upper", max(n_val // 3, 12)), ("val_real", n_val)))}
    if args.clean and args.realism:
        if anny and args.anny_share > 0:
            from models.train.anny_bodies import ensure_built
            from sim.skeleton_data import anny_phenotypes

            ensure_built(anny_phenotypes(anny, args.seed + 10), progress)
        clean = generate("train", args.clean, seed=args.seed + 10, workers=args.workers, progress=progress,
                         cache=not args.no_cache, anny=anny, anny_share=args.anny_share,
                         edge_jump_share=args.edge_share)
        data["train"] = {k: (data["train"][k] + clean[k] if np.ndim(v) == 0
                             else np.concatenate([data["train"][k], clean[k]]))
                         for k, v in data["train"].items()}
    data_seconds = round(time.monotonic() - t0, 1)
    from live.body.library import list_presets
    from models.train.mirror_average import apply_mirror_average

    kinds = ("ours", "baseline") if args.model == "both" else (args.model,)
    cards: dict[str, dict] = {}
    for kind in kinds:
        recipe = RECIPES[kind]
        if args.quick or args.epochs:
            recipe = Recipe(**{**recipe.__dict__, "epochs": args.epochs or 1,
                               "max_steps": 4 if args.quick else recipe.max_steps})
        if args.net is not None and kind == "ours":
            recipe = Recipe(**{**recipe.__dict__, "net": args.net})
        if args.augment is not None:
            from models.train.point_augment import Augment

            try:  # unknown keys are a one-line error here, not mid-training
                Augment(**args.augment)
            except TypeError as e:
                raise SystemExit(f"--augment: {e}") from None
            recipe = Recipe(**{**recipe.__dict__, "augment": args.augment})
        if args.lr is not None:
            recipe = Recipe(**{**recipe.__dict__, "lr": args.lr})
        if args.num_points is not None:
            stored = data["train"]["points"].shape[1]
            if not 0 < args.num_points <= stored:
                raise SystemExit(f"--num-points {args.num_points}: the samples store {stored} points each")
            recipe = Recipe(**{**recipe.__dict__, "num_points": args.num_points})
        init = args.init if kind == "ours" else None
        model, log = train_model(recipe, data["train"], seed=args.seed, progress=progress, init=init)
        if init is not None:
            log["init"] = {"file": str(init), "sha256": file_sha256(init)}
        results = {}
        for split in VAL_SPLITS:
            results.update(split_results(split, predict(model, data[split]["points"], recipe.num_points),
                                         data[split]))
        name = "skeleton" if kind == "ours" else "skeleton_baseline"
        onnx_path = out_dir / f"{name}.onnx"
        export_onnx(model, str(onnx_path), recipe.num_points)
        diff = check_onnx(onnx_path, model, data["val"]["points"][:8, :recipe.num_points])
        cards[kind] = {
            "model": name, "kind": kind, "file": onnx_path.name,
            "architecture": type(model).__name__, "parameters": count_parameters(model),
            "input": {"name": "points", "shape": ["batch", recipe.num_points, 3], "dtype": "float32",
                      "frame": "person frame (models.skeleton.preprocess.PersonCloud): metres, origin on the "
                               "floor under the person, +y up, camera toward +z"},
            "output": {"name": "joints", "shape": ["batch", 22, 3], "frame": "person frame",
                       "order": "CONVENTIONS.md 22-joint skeleton"},
            "num_points": recipe.num_points, "preprocess": {"edge_jump_share": args.edge_share},
            "onnx_opset": 17, "onnx_max_abs_diff_m": diff,
            "recipe": recipe.__dict__, "training": log, "data_seconds": data_seconds,
            "data": {split: describe(d) for split, d in data.items()},
            "split": {"val_subjects": sorted(VAL_SUBJECTS), "val_bodies": split_bodies(list_presets(), "val"),
                      "train_bodies": split_bodies(list_presets(), "train"),
                      "train_anny": {"phenotypes": anny, "share": args.anny_share if anny else 0.0,
                                     "note": "random Anny phenotypes in the library's ranges, none within "
                                             "0.15 of a held-out preset in every key "
                                             "(sim.skeleton_data.anny_phenotypes)"},
                      "note": "val: OAK-D, camera 1.5-4 m from the performer, unseen subjects and bodies; "
                              "val_upper: close-ups (0.8-1.4 m, legs out of frame), same held-out sets; "
                              "val_real: the same held-out sets seen as users' sensors see people "
                              "(sim.sensor_realism), per camera and per body"},
            "metrics": results, "seed": args.seed, "threads": args.threads,
            "command": "python -m models.train.train_skeleton "
                       + shlex.join(argv if argv is not None else sys.argv[1:]),
            "software": {"torch": torch.__version__, "python": platform.python_version()},
        }
        if kind == "ours" and args.mirror_average:  # models.train.mirror_average
            cards[kind]["test_time_mirror"] = apply_mirror_average(onnx_path, results)
            results = onnx_results(onnx_path, {s: data[s] for s in VAL_SPLITS}, recipe.num_points)
            cards[kind]["metrics"] = results
        (out_dir / f"{name}.json").write_text(json.dumps(cards[kind], indent=1) + "\n")
        v = results["val_1.5-4m"]
        print(f"{kind}: val MPJPE {v['mpjpe_mm']} mm, PA-MPJPE {v['pa_mpjpe_mm']} mm, "
              f"PCK@10cm {v['pck_10cm']:.3f}; upper-body close-ups "
              f"{results['val_upper']['upper_body_mpjpe_mm']} mm; val_real MPJPE "
              f"{results['val_real']['mpjpe_mm']} mm, PCK@10cm {results['val_real']['pck_10cm']:.3f} "
              f"({log['seconds']} s) -> {onnx_path}", flush=True)
    return cards


if __name__ == "__main__":
    main()
