"""Train the temporal skeleton model on the shipped regressor's outputs; export ONNX + card.

    python -m models.train.train_skeleton_temporal [--quick] [--window 16]

Data: consecutive-frame sequences from ``sim.skeleton_sequences`` (training clips and bodies;
validation on unseen CMU subjects and unseen bodies, OAK-D at 1.5-4 m). The per-frame regressor
(``models/weights/skeleton.onnx`` unless --regressor) is run on every stored person sample, so
the temporal model learns that regressor's real errors; its sha256 goes into the card and the
runtime uses the temporal model only behind the same regressor.

Loss, per training example of three consecutive frames: L1 of each frame's joints, plus the
acceleration error of the three (the jitter the retargeter and the avatar would show). Mirror
augmentation (x -> -x in the person frame, left/right swapped) is exact for whole windows.
``--quick`` writes to .cache/skeleton_temporal_quick unless --out is given.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from live.core import assets

WEIGHTS = assets.weights_dir()
FLIP = np.array([-1.0, 1.0, 1.0])
ON_PERFORMER_M = 0.6  # as sim.skeleton_data.run_job: a person this far off the pelvis is clutter


class TemporalRefineNet(nn.Module):
    """Window features (B, W*(22*4+1)) -> refined current joints (B, 22, 3).

    The past samples enter as their offsets from the newest estimate (x10: centimetres are
    numbers near 1), so a temporal filter is a linear function of the input; a linear path
    learns that filter fast and an MLP beside it learns what is not linear (occlusions,
    pose priors). Both start at zero: the untrained model is the per-frame estimate. No dropout:
    independent dropout masks on consecutive frames would be jitter the acceleration loss
    then fights."""

    def __init__(self, window: int, width: int = 512, depth: int = 3, dropout: float = 0.0):
        super().__init__()
        from models.skeleton.temporal import feature_size

        self.window = window
        layers: list[nn.Module] = []
        c = feature_size(window)
        for _ in range(depth):
            layers += [nn.Linear(c, width), nn.ReLU()] + ([nn.Dropout(dropout)] if dropout else [])
            c = width
        layers.append(nn.Linear(c, 66))
        self.mlp = nn.Sequential(*layers)
        self.linear = nn.Linear(feature_size(window), 66)
        for head in (layers[-1], self.linear):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.window
        joints = x[:, :w * 66].reshape(-1, w, 66)
        newest = joints[:, 0]
        offsets = (joints[:, 1:] - newest[:, None]) * 10.0
        z = torch.cat([newest, offsets.flatten(1), x[:, w * 66:]], dim=1)
        return (newest + self.linear(z) + self.mlp(z)).reshape(-1, 22, 3)


def regress_sequences(data: dict, regressor_path: Path, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame regressor outputs on every found frame: (joints world (S, F, 22, 3),
    confidence (S, F, 22)); NaN / 0 where the finder found nobody."""
    from models.skeleton.filters import joint_confidence
    from models.skeleton.runtime import SkeletonRegressor

    reg = SkeletonRegressor(regressor_path, threads=threads)
    s, f = data["found"].shape
    pts = data["points"][..., :reg.num_points, :].reshape(s * f, reg.num_points, 3)
    found = data["found"].reshape(-1)
    local = np.full((s * f, 22, 3), np.nan)
    idx = np.flatnonzero(found)
    for a in range(0, len(idx), 256):
        b = idx[a:a + 256]
        local[b] = reg(pts[b])
    conf = np.zeros((s * f, 22))
    for i in idx:
        conf[i] = joint_confidence(local[i], pts[i])
    tw = data["to_world"].reshape(s * f, 4, 4)
    world = np.einsum("nij,nkj->nki", tw[:, :3, :3], local) + tw[:, None, :3, 3]
    return world.reshape(s, f, 22, 3), conf.reshape(s, f, 22)


def build_examples(data: dict, world: np.ndarray, conf: np.ndarray, window: int, fps: float,
                   lag: int = 0) -> dict:
    """Inputs and targets as the runtime (TemporalRefiner) meets them: when found frame k arrives,
    the frame estimated is j, the newest found frame at least ``lag`` frames older (k itself at
    lag 0), once per j; the window is anchored lag samples after j. features (E, D) float32;
    raw (E, 22, 3) per-frame estimate of j and target (E, 22, 3) truth of j, both in frame k's
    person frame; seq / frame (E,) indices of j; to_world (E, 4, 4) of k; on_performer (E,)
    whether the finder's person is the performer (true pelvis within ON_PERFORMER_M of the
    person frame's origin; otherwise it picked clutter, and there is nothing to learn)."""
    from models.skeleton.temporal import sample_history, to_person_frame

    feats, raw, target, seq, frame, tws = [], [], [], [], [], []
    t_all = data["t_ns"] * 1e-9
    for s in range(len(data["found"])):
        found = np.flatnonzero(data["found"][s])
        last_j = -1
        for n, k in enumerate(found):
            m = int(np.searchsorted(found, k - lag, side="right")) - 1
            if m < 0 or found[m] <= last_j:
                continue
            j = last_j = int(found[m])
            hist = found[:n + 1]
            tw = data["to_world"][s, k]
            win = sample_history(t_all[s, hist], world[s, hist], conf[s, hist], t_all[s, j] + lag / fps, tw,
                                 window, fps)
            feats.append(win.features())
            raw.append(win.joints[lag])
            target.append(to_person_frame(data["joints"][s, j], tw))
            seq.append(s)
            frame.append(j)
            tws.append(tw)
    target = np.asarray(target)
    return {"features": np.asarray(feats, np.float32), "raw": np.asarray(raw), "target": target,
            "seq": np.asarray(seq), "frame": np.asarray(frame), "to_world": np.asarray(tws),
            "on_performer": np.hypot(target[:, 0, 0], target[:, 0, 2]) < ON_PERFORMER_M}


def triples(ex: dict) -> np.ndarray:
    """(M, 3) example indices of three consecutive found frames of one sequence, all three on
    the performer."""
    key = {(int(s), int(k)): i for i, (s, k, ok) in enumerate(zip(ex["seq"], ex["frame"], ex["on_performer"]))
           if ok}
    out = []
    for (s, k), i in key.items():
        a, b = key.get((s, k - 2)), key.get((s, k - 1))
        if a is not None and b is not None:
            out.append((a, b, i))
    return np.asarray(out, np.int64).reshape(-1, 3)


def mirror_features(x: np.ndarray, window: int) -> np.ndarray:
    """Mirror a batch of window features: x -> -x of every joint, left/right swapped."""
    from live.core.skeleton import LEFT_RIGHT_SWAP

    b = len(x)
    j = x[:, :window * 66].reshape(b, window, 22, 3)[:, :, LEFT_RIGHT_SWAP] * FLIP.astype(np.float32)
    c = x[:, window * 66:window * 88].reshape(b, window, 22)[:, :, LEFT_RIGHT_SWAP]
    return np.concatenate([j.reshape(b, -1), c.reshape(b, -1), x[:, window * 88:]], axis=1)


def train(ex: dict, window: int, epochs: int, lr: float, acc_weight: float, seed: int, net: dict,
          progress: bool) -> tuple[TemporalRefineNet, dict]:
    from tqdm import tqdm

    from live.core.skeleton import LEFT_RIGHT_SWAP

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    tri = triples(ex)
    # Frame k-2 and k-1 outputs are compared with frame k's in frame k's person frame.
    inv = np.linalg.inv(ex["to_world"])
    rel = np.einsum("mij,mnjk->mnik", inv[tri[:, 2]], ex["to_world"][tri])  # (M, 3, 4, 4)
    model = TemporalRefineNet(window, **net)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    batch = 256
    steps = max(len(tri) // batch, 1) * epochs
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    flip = np.diag([-1.0, 1.0, 1.0, 1.0])
    log = {"epoch_loss": []}
    t0 = time.monotonic()
    bar = tqdm(total=steps, desc="train temporal", unit="step", disable=not progress, mininterval=5.0)
    model.train()
    for _ in range(epochs):
        order = rng.permutation(len(tri))
        running, n = 0.0, 0
        for a in range(0, len(order) - batch + 1, batch):
            idx = tri[order[a:a + batch]]  # (B, 3)
            x = ex["features"][idx.reshape(-1)]
            y = ex["target"][idx.reshape(-1)]
            r = rel[order[a:a + batch]]
            m = rng.random(batch) < 0.5
            if m.any():
                mm = np.repeat(m, 3)
                x[mm] = mirror_features(x[mm], window)
                y[mm] = (y[mm] * FLIP)[:, LEFT_RIGHT_SWAP]
                r[m] = flip @ r[m] @ flip
            pred = model(torch.from_numpy(x)).reshape(batch, 3, 22, 3)
            gt = torch.from_numpy(y).reshape(batch, 3, 22, 3)
            rot = torch.from_numpy(r[:, :, :3, :3])
            tr = torch.from_numpy(r[:, :, None, :3, 3])
            # All three frames in frame k's coordinates (rigid: errors keep their size).
            p_k = torch.einsum("bfij,bfnj->bfni", rot, pred.double()) + tr
            g_k = torch.einsum("bfij,bfnj->bfni", rot, gt) + tr
            acc = (p_k[:, 2] - 2 * p_k[:, 1] + p_k[:, 0]) - (g_k[:, 2] - 2 * g_k[:, 1] + g_k[:, 0])
            loss = (pred.double() - gt).abs().mean() + acc_weight * acc.norm(dim=-1).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            running += loss.item()
            n += 1
            bar.update(1)
        log["epoch_loss"].append(round(running / max(n, 1), 6))
        if not progress:
            print(f"temporal epoch {len(log['epoch_loss'])}/{epochs}: loss {log['epoch_loss'][-1]:.5f}, "
                  f"{time.monotonic() - t0:.0f} s", flush=True)
    bar.close()
    log["seconds"] = round(time.monotonic() - t0, 1)
    log["examples"] = int(len(tri))
    return model.eval(), log


@torch.no_grad()
def refine(model: TemporalRefineNet, features: np.ndarray) -> np.ndarray:
    return np.concatenate([model(torch.from_numpy(features[a:a + 1024])).numpy()
                           for a in range(0, len(features), 1024)]).astype(np.float64)


def sequence_metrics(data: dict, world_by_method: dict[str, np.ndarray], mask: np.ndarray | None = None) -> dict:
    """MPJPE, PA-MPJPE (mm), PCK@10cm and acceleration error (mm/frame^2) of world joints
    (S, F, 22, 3) per method, on found frames (and ``mask`` (S, F) when given); acceleration
    over runs of such frames."""
    from live.core.metrics import acceleration_error, mpjpe, pa_mpjpe, pck

    out = {}
    found = data["found"] if mask is None else data["found"] & mask
    gt = data["joints"].astype(np.float64)
    for name, w in world_by_method.items():
        accs = []
        for s in range(len(found)):
            runs = np.split(np.arange(found.shape[1]), np.flatnonzero(np.diff(found[s].astype(int))) + 1)
            for r in runs:
                if found[s, r[0]] and len(r) >= 3:
                    accs.append((acceleration_error(w[s, r], gt[s, r]), len(r) - 2))
        acc = sum(a * n for a, n in accs) / max(sum(n for _, n in accs), 1)
        out[name] = {"frames": int(found.sum()), "mpjpe_mm": round(1000 * mpjpe(w[found], gt[found]), 1),
                     "pa_mpjpe_mm": round(1000 * pa_mpjpe(w[found], gt[found]), 1),
                     "pck_10cm": round(pck(w[found], gt[found], 0.1), 4),
                     "acc_mm_per_frame2": round(1000 * acc, 2)}
    return out


def one_euro(data: dict, world: np.ndarray) -> np.ndarray:
    """The stage's default One Euro filter over each sequence's found frames (the baseline)."""
    from models.skeleton.filters import OneEuroFilter
    from models.skeleton.runtime import SkeletonStage

    defaults = SkeletonStage.__init__.__kwdefaults__
    out = np.full_like(world, np.nan)
    for s in range(len(world)):
        f = OneEuroFilter(min_cutoff=defaults["min_cutoff"], beta=defaults["beta"])
        for k in np.flatnonzero(data["found"][s]):
            out[s, k] = f(world[s, k], data["t_ns"][s, k] * 1e-9)
    return out


def to_world_of(ex: dict, local: np.ndarray, shape: tuple) -> np.ndarray:
    out = np.full(shape, np.nan)
    tw = ex["to_world"]
    out[ex["seq"], ex["frame"]] = np.einsum("nij,nkj->nki", tw[:, :3, :3], local) + tw[:, None, :3, 3]
    return out


def quantized_layer(name: str) -> bool:
    """The exported layers whose weights ship in 8 bits: the MLP's (the linear filter path's
    output is added to the estimate as it is, so it stays float32)."""
    return name.startswith("/mlp/")


def export_onnx(model: TemporalRefineNet, path: Path, window: int, example: np.ndarray) -> dict:
    """Write the deployed ONNX file (input "window" (B, D), output "joints" (B, 22, 3)): the
    float32 export with the MLP's weights in 8-bit blocks (``models.train.quantize``: a quarter of
    the memory traffic per frame); the linear filter path stays float32. Returns the card's record:
    max |deployed - torch| and |float32 export - torch| (m) on ``example`` features, and how the
    weights were quantized."""
    import tempfile

    from models.train.quantize import quantize_matmuls

    want = refine(model, example)
    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / path.name
        torch.onnx.export(model.eval(), (torch.from_numpy(example[:1]),), str(fp32), input_names=["window"],
                          output_names=["joints"], dynamic_axes={"window": {0: "batch"}, "joints": {0: "batch"}},
                          opset_version=17, dynamo=False)
        fp32_diff = float(np.abs(refine_onnx(fp32, example) - want).max())
        quantization = quantize_matmuls(fp32, path, quantize=quantized_layer)
    return {"onnx_max_abs_diff_m": float(np.abs(refine_onnx(path, example) - want).max()),
            "float32_onnx_max_abs_diff_m": fp32_diff, "quantization": quantization}


def refine_onnx(path: Path, features: np.ndarray) -> np.ndarray:
    """The exported model's joints (E, 22, 3) float64 for window features (E, D)."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return np.concatenate([sess.run(None, {"window": features[a:a + 1024]})[0]
                           for a in range(0, len(features), 1024)]).astype(np.float64)


def quantization_deviation(deployed: np.ndarray, reference: np.ndarray) -> dict:
    """How far the deployed file's joints (E, 22, 3) lie from the float32 network's (m)."""
    moved = np.linalg.norm(deployed - reference, axis=-1)
    return {"mean": round(float(moved.mean()), 5), "p99": round(float(np.percentile(moved, 99)), 5),
            "max": round(float(moved.max()), 5),
            "of": "the deployed file's joints against the float32 network's, val windows"}


def validation_results(val: dict, ex: dict, raw_world: np.ndarray, methods: dict[str, np.ndarray]) -> dict:
    """The card's "val" metrics: per method on the frames where the finder found the performer
    and on all frames the model estimates (a lagging model gives none for the first of a take)."""
    estimated = np.zeros_like(val["found"])
    estimated[ex["seq"], ex["frame"]] = True
    on_performer = np.zeros_like(val["found"])
    on_performer[ex["seq"], ex["frame"]] = ex["on_performer"]
    methods = {"per_frame": raw_world, "one_euro": one_euro(val, raw_world), **methods}
    return {"on_performer": sequence_metrics(val, methods, on_performer),
            "all_found_frames": sequence_metrics(val, methods, estimated),
            "finder": {"found_frames": int(val["found"].sum()), "estimated_frames": int(estimated.sum()),
                       "on_clutter_frames": int(estimated.sum() - on_performer.sum())}}


def main(argv: list[str] | None = None) -> dict:
    from models.skeleton.runtime import DEFAULT_MODEL, SkeletonRegressor
    from models.skeleton.temporal import file_sha256, temporal_model_path
    from sim.skeleton_data import VAL_SUBJECTS
    from sim.skeleton_sequences import SEQUENCE_FPS, SEQUENCE_FRAMES, generate_sequences

    p = argparse.ArgumentParser(prog="train_skeleton_temporal", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smoke run: a few sequences, 1 epoch")
    p.add_argument("--window", type=int, default=16, help="past samples at 30 fps (16 = 0.53 s)")
    p.add_argument("--lag", type=int, default=0, help="estimate the frame this many samples back (0 = online; "
                   "2 = 67 ms later, smoother): writes skeleton_temporal_lag<L>.onnx")
    p.add_argument("--epochs", type=int, default=None)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--acc-weight", type=float, default=0.3)
    p.add_argument("--net", type=json.loads, default={}, metavar="JSON", help='e.g. \'{"width": 256}\'')
    p.add_argument("--n-train", type=int, default=None, help="presets-only training sequences (default 4000)")
    p.add_argument("--n-val", type=int, default=None, help="validation sequences (default 150)")
    p.add_argument("--anny-train", type=int, default=None, metavar="M",
                   help="M more training sequences (seed + 2) where Anny bodies join the presets "
                        "(default 3000, 0 with --quick; needs the train extra)")
    p.add_argument("--anny", type=int, default=64, metavar="N",
                   help="on-demand Anny phenotypes of those sequences (the per-frame data's; default 64)")
    p.add_argument("--anny-share", type=float, default=0.7,
                   help="share of those sequences on an Anny body (default 0.7: 30%% of 7,000)")
    # Off by default: trained on realism sequences the model was 1-3 mm worse on every held-out
    # set (docs/skeleton.md, "Measured"); the regressor it runs behind is the one trained
    # for users' sensors.
    p.add_argument("--realism", action=argparse.BooleanOptionalAction, default=False,
                   help="training sequences as users' sensors see people (sim.sensor_realism; default off)")
    # The shared clips mostly cross the room; trained on them alone, the online model was worse
    # than the regressor alone on performers moving on the spot (docs/skeleton.md).
    p.add_argument("--in-place-share", type=float, default=0.3,
                   help="share of training sequences performed in place (sim.postures in-place; default 0.3; "
                        "not with --realism, whose postures include it)")
    p.add_argument("--regressor", type=Path, default=DEFAULT_MODEL)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    n_train = args.n_train or (6 if args.quick else 4000)
    n_val = args.n_val or (3 if args.quick else 150)
    epochs = args.epochs or (1 if args.quick else 24)
    n_anny = args.anny_train if args.anny_train is not None else (0 if args.quick else 3000)
    out_dir = args.out or (assets.cache_dir("skeleton_temporal_quick") if args.quick else WEIGHTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    t0 = time.monotonic()
    # The sequences sampled as the stage samples them for this regressor (its card's depth-edge
    # test): the model learns the errors the regressor makes on what the runtime gives it.
    edges = SkeletonRegressor(args.regressor).edge_jump_share
    data = {"train": generate_sequences("train", n_train, seed=args.seed, workers=args.workers, progress=progress,
                                        realism=args.realism, edge_jump_share=edges,
                                        in_place_share=args.in_place_share),
            "val": generate_sequences("val", n_val, seed=args.seed + 1, workers=args.workers, progress=progress,
                                      edge_jump_share=edges),
            # The same held-out clips and bodies performed on the spot, as at a desk.
            "val_in_place": generate_sequences("val", n_val, seed=args.seed + 1, workers=args.workers,
                                               progress=progress, edge_jump_share=edges, in_place_share=1.0)}
    if n_anny:  # presets-only sequences, then Anny-mixed ones: the first set's cache stays valid
        from models.train.anny_bodies import ensure_built
        from sim.skeleton_data import anny_phenotypes

        ensure_built(anny_phenotypes(args.anny, args.seed + 2), progress)  # into the body cache, once
        more = generate_sequences("train", n_anny, seed=args.seed + 2, workers=args.workers, progress=progress,
                                  anny=args.anny, anny_share=args.anny_share, realism=args.realism,
                                  edge_jump_share=edges, in_place_share=args.in_place_share)
        data["train"] = {k: np.concatenate([data["train"][k], more[k]]) for k in data["train"]}
    examples, per_frame = {}, {}
    for split, d in data.items():
        per_frame[split] = regress_sequences(d, args.regressor, args.threads)
        examples[split] = build_examples(d, *per_frame[split], args.window, SEQUENCE_FPS, args.lag)
    data_seconds = round(time.monotonic() - t0, 1)
    model, log = train(examples["train"], args.window, epochs, args.lr, args.acc_weight, args.seed, args.net,
                       progress)
    val, ex = data["val"], examples["val"]
    raw_world = per_frame["val"][0]
    onnx_path = out_dir / temporal_model_path(args.lag).name
    export = export_onnx(model, onnx_path, args.window, ex["features"][:8])
    # Scored: the deployed file (quantized), and the float32 network it came from beside it.
    deployed, reference = refine_onnx(onnx_path, ex["features"]), refine(model, ex["features"])
    results = validation_results(val, ex, raw_world, {"temporal": to_world_of(ex, deployed, raw_world.shape),
                                                      "temporal_float32": to_world_of(ex, reference, raw_world.shape)})
    in_place, in_place_ex = data["val_in_place"], examples["val_in_place"]
    in_place_raw = per_frame["val_in_place"][0]
    in_place_results = validation_results(in_place, in_place_ex, in_place_raw, {"temporal": to_world_of(
        in_place_ex, refine_onnx(onnx_path, in_place_ex["features"]), in_place_raw.shape)})
    card = {
        "model": "skeleton_temporal", "file": onnx_path.name, "architecture": "TemporalRefineNet (MLP)",
        "parameters": int(sum(p.numel() for p in model.parameters())),
        "window": args.window, "fps": SEQUENCE_FPS, "lag": args.lag,
        "input": {"name": "window", "shape": ["batch", args.window * 89],
                  "layout": "models.skeleton.temporal.TemporalWindow.features: W x 22 x 3 joints in the newest "
                            "frame's person frame (newest first), W x 22 confidences, W observed flags"},
        "output": {"name": "joints", "shape": ["batch", 22, 3], "frame": "person frame of the newest frame",
                   "joints_of": "the frame lag samples before the newest one (lag 0: the newest)"},
        "regressor": args.regressor.name, "regressor_sha256": file_sha256(args.regressor),
        "onnx_opset": 17, **export, "quantization_deviation_m": quantization_deviation(deployed, reference),
        "recipe": {"epochs": epochs, "lr": args.lr, "acc_weight": args.acc_weight, "batch": 256,
                   "optimizer": "AdamW, weight decay 1e-4, one-cycle", "net": args.net,
                   "loss": "L1 joints of 3 consecutive frames + acc_weight x acceleration error",
                   "augmentation": "mirror (x -> -x, left/right swapped)",
                   # Whether the training sequences were drawn as users' sensors see people
                   # (sim.sensor_realism): models trained with and without it differ by millimetres.
                   "realism": bool(args.realism),
                   "in_place_share": 0.0 if args.realism else args.in_place_share,
                   # The finder's depth-edge test the sequences were sampled with (the regressor's).
                   "edge_jump_share": edges},
        "training": log, "data_seconds": data_seconds,
        "data": {split: {"sequences": int(len(d["found"])), "frames_per_sequence": SEQUENCE_FRAMES,
                         "found_frames": int(d["found"].sum()), "clips": int(len(np.unique(d["clip"]))),
                         "bodies": sorted(b for b in np.unique(d["body"]).tolist() if not b.startswith("anny:")),
                         "anny_sequences": int(np.char.startswith(d["body"].astype(str), "anny:").sum()),
                         "in_place_sequences": int(d["in_place"].sum()) if "in_place" in d else 0}
                 for split, d in data.items()},
        "train_sets": [{"sequences": n_train, "seed": args.seed, "bodies": "training presets"}]
        + ([{"sequences": n_anny, "seed": args.seed + 2, "anny_phenotypes": args.anny, "anny_share": args.anny_share,
             "bodies": "training presets and on-demand Anny bodies of the per-frame data "
                       "(sim.skeleton_data.anny_phenotypes, none near a held-out preset)"}] if n_anny else []),
        "split": {"val_subjects": sorted(VAL_SUBJECTS),
                  "note": "val: OAK-D 1.5-4 m, unseen CMU subjects and unseen bodies (sim.skeleton_sequences); "
                          "val_in_place: the same sequences performed in place (sim.postures in-place); "
                          "on_performer: frames where the person finder found the performer (the setting of "
                          "the per-frame card); all_found_frames: also frames where it picked clutter"},
        "metrics": {"val": results, "val_in_place": in_place_results}, "seed": args.seed, "threads": args.threads,
        "command": "python -m models.train.train_skeleton_temporal "
                   + shlex.join(argv if argv is not None else sys.argv[1:]),
        "software": {"torch": torch.__version__, "python": platform.python_version()},
    }
    onnx_path.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    for name, m in [*results["on_performer"].items(),
                    *((f"{k} in place", v) for k, v in in_place_results["on_performer"].items())]:
        print(f"{name:10s} MPJPE {m['mpjpe_mm']:5.1f}  PA-MPJPE {m['pa_mpjpe_mm']:5.1f}  "
              f"PCK {m['pck_10cm']:.3f}  Acc {m['acc_mm_per_frame2']:5.2f} mm/frame^2", flush=True)
    return card


if __name__ == "__main__":
    main()
