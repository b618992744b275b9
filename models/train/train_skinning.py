"""Train the skinning field (distances to the T-pose joints -> skinning weights), export ONNX.

    python -m models.train.train_skinning [--quick] [--out DIR] [--minutes M]

Data: the body library's training presets (sim.skeleton_data.split_bodies), their vertices,
T-pose joints and true weights, and random poses (frames of the training CMU clips, 30 fps, as
for the retargeter). Loss per step, on one body, 2048 random vertices and 8 random poses:
cross-entropy against the true weights + 20 x the L1 linear-blend-skinning reconstruction error
in leg lengths (vertices posed with predicted vs true weights, the reference's posed/T-pose
pairs of the same body). Validation on the held-out presets: mean |w - w_true| per weight, mean
per-vertex L1 of the weight rows, and MPVD of LBS with predicted vs true weights over 64 poses of
the held-out CMU subjects. Seeded; torch.set_num_threads(1).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from models.train.retarget_nets import PARENTS, SkinningField, count_parameters, export_skinning_onnx
from models.train.train_retarget import CACHE, WEIGHTS, load_clips, quat_to_matrix_t

VAL_SUBJECTS = (7, 8, 12, 16)


def lbs_torch(vertices: torch.Tensor, weights: torch.Tensor, rest: torch.Tensor, local: torch.Tensor) -> torch.Tensor:
    """Vertices N x 3 (T-pose), weights N x 22, T-pose joints 22 x 3, local rotations P x 22 x 3 x 3
    -> posed vertices P x N x 3 (root at the rest pelvis; as live.body.skinning.lbs)."""
    glob, pos = [local[:, 0]], [rest[0].expand(local.shape[0], 3)]
    for j in range(1, 22):
        p = PARENTS[j]
        pos.append(pos[p] + glob[p] @ (rest[j] - rest[p]))
        glob.append(glob[p] @ local[:, j])
    g = torch.stack(glob, 1)  # P x 22 x 3 x 3
    t = torch.stack(pos, 1) - torch.einsum("pjab,jb->pja", g, rest)
    m = torch.einsum("nj,pjab->pnab", weights, g)
    return torch.einsum("pnab,nb->pna", m, vertices) + torch.einsum("nj,pja->pna", weights, t)


def library(split: str) -> list:
    from live.body.library import list_presets, load_body
    from sim.skeleton_data import split_bodies

    return [load_body(n) for n in split_bodies(list_presets(), split)]


def pose_pool(data: dict, val: bool) -> np.ndarray:
    """(K, 22, 4) frames of the training (or held-out) clips, every 5th frame."""
    keep = np.isin(data["subject"], VAL_SUBJECTS)
    keep = keep if val else ~keep
    idx = np.concatenate([np.arange(data["offsets"][c], data["offsets"][c + 1], 5) for c in np.flatnonzero(keep)])
    return data["rotations"][idx]


def train(field: SkinningField, bodies: list, poses: np.ndarray, minutes: float, steps: int, seed: int, log) -> dict:
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(field.parameters(), lr=3e-3)
    tensors = [(torch.from_numpy(np.asarray(b.vertices, np.float32)), torch.from_numpy(np.asarray(b.weights, np.float32)),
                torch.from_numpy(np.asarray(b.rest_joints, np.float32))) for b in bodies]
    start, step, run = time.monotonic(), 0, {}
    while step < steps and time.monotonic() - start < minutes * 60:
        frac = max(step / steps, (time.monotonic() - start) / (minutes * 60))
        for g in opt.param_groups:
            g["lr"] = 3e-3 * 0.5 * (1 + np.cos(np.pi * min(frac, 1.0)))
        v, w, j = tensors[rng.integers(len(tensors))]
        pick = torch.from_numpy(rng.choice(len(v), size=min(2048, len(v)), replace=False))
        v, w = v[pick], w[pick]
        local = quat_to_matrix_t(torch.from_numpy(poses[rng.choice(len(poses), 8)]))
        logits = field.logits(v, j)
        pred = torch.softmax(logits, -1)
        ce = -(w * torch.log_softmax(logits, -1)).sum(-1).mean()
        recon = (lbs_torch(v, pred, j, local) - lbs_torch(v, w, j, local)).abs().sum(-1).mean() / j[0, 1]
        loss = ce + 20.0 * recon
        opt.zero_grad()
        loss.backward()
        opt.step()
        run = {k: run.get(k, float(x.detach())) * 0.98 + float(x.detach()) * 0.02 for k, x in (("ce", ce), ("recon", recon))}
        step += 1
        if step % 200 == 0:
            log(f"step {step} {time.monotonic() - start:.0f}s " + " ".join(f"{k}={x:.4f}" for k, x in run.items()))
    return {"steps": step, "seconds": round(time.monotonic() - start, 1)}


def validate(onnx_path: Path, bodies: list, poses: np.ndarray, seed: int) -> dict:
    """Held-out bodies: weight errors and MPVD of LBS with predicted vs true weights (metres)."""
    from live.body.skinning import lbs
    from live.body.skinning_field import SkinningFieldModel
    from live.core.metrics import mpvd

    model = SkinningFieldModel(onnx_path)
    rng = np.random.default_rng(seed)
    sel = poses[rng.choice(len(poses), 64, replace=False)]
    root = np.zeros((len(sel), 3))
    per = []
    for b in bodies:
        w = model.weights(b.vertices, b.rest_joints)
        true = np.asarray(b.weights, np.float64)
        root[:] = np.asarray(b.rest_joints)[0]
        err = mpvd(lbs(b.vertices, w, b.rest_joints, sel, root), lbs(b.vertices, true, b.rest_joints, sel, root))
        per.append({"body": b.name, "weight_mae": float(np.abs(w - true).mean()),
                    "row_l1": float(np.abs(w - true).sum(1).mean()), "mpvd_m": float(err),
                    "argmax_agreement": float((w.argmax(1) == true.argmax(1)).mean())})
    mean = {k: round(float(np.mean([p[k] for p in per])), 6) for k in ("weight_mae", "row_l1", "mpvd_m", "argmax_agreement")}
    return {"mean": mean, "bodies": per}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--hidden", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    out = args.out or (CACHE / "skinning_quick" if args.quick else WEIGHTS)
    out.mkdir(parents=True, exist_ok=True)
    minutes = args.minutes or (0.5 if args.quick else 30.0)  # safety cap; the steps decide
    steps = args.steps or (60 if args.quick else 8000)
    log = lambda msg: print(msg, flush=True)  # noqa: E731
    t0 = time.monotonic()
    data = load_clips()
    train_bodies, val_bodies = library("train"), library("val")
    field = SkinningField(args.hidden)
    run = train(field, train_bodies, pose_pool(data, False), minutes, steps, args.seed, log)
    path = out / "skinning_field.onnx"
    export_skinning_onnx(field, str(path))
    metrics = validate(path, val_bodies, pose_pool(data, True), args.seed)
    log(json.dumps(metrics["mean"]))
    card = {
        "model": "skinning_field", "file": path.name,
        "command": " ".join(["python -m models.train.train_skinning", *(argv if argv is not None else sys.argv[1:])]),
        "kind": "3-layer MLP: distances to the 22 T-pose joints / leg length -> softmax weights",
        "inputs": {"points": "(N, 3) float32 T-pose points, metres", "joints": "(22, 3) float32 T-pose joints"},
        "outputs": {"weights": "(N, 22) float32, rows sum to 1"},
        "hidden": args.hidden, "parameters": count_parameters(field),
        "data": {"train_bodies": [b.name for b in train_bodies], "val_bodies": [b.name for b in val_bodies],
                 "poses": "frames of the training CMU clips (every 5th at 30 fps); validation poses from subjects 7, 8, 12, 16"},
        "losses": {"cross_entropy": 1.0, "lbs_reconstruction_l1_in_leg_lengths": 20.0},
        "recipe": {"points_per_step": 2048, "poses_per_step": 8, "optimizer": "Adam 3e-3 cosine",
                   "steps": run["steps"], "seed": args.seed, "threads": 1},
        "validation": metrics, "training_seconds": run["seconds"], "total_seconds": round(time.monotonic() - t0, 1),
        "quick": args.quick, "torch": torch.__version__, "python": sys.version.split()[0],
    }
    path.with_suffix(".json").write_text(json.dumps(card, indent=2) + "\n")
    log(f"wrote {path} and {path.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
