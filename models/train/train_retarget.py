"""Train the learned online retargeter, validate it on held-out motions and bodies, export ONNX.

    python -m models.train.train_retarget [--quick] [--out DIR] [--minutes M]

Data: every CMU clip of ../shared/data/bvh mapped to the canonical skeleton (live.motion.rig_mapping),
resampled to 30 fps (cached in .cache/retarget_clips.npz). A training sample is a window of the
clip's local rotations, turned by a random yaw, put on a source body A and a target body B: each a
T-pose of the body library (training presets of sim.skeleton_data.split_bodies) with random
per-bone length factors (0.85-1.15, left/right alike). Source joints = FK on A with the root
scaled by A's leg ratio (plus, in half the batches, noise shaped like the depth skeleton stage's
error: measured per-joint size and frame-to-frame correlation, ``depth_like_noise``); the exact
answer on B = the same rotations on B's T-pose with the root scaled by B's leg ratio (CONVENTIONS.md).
With ``--chain-share S`` (default 0) a share S of the batches instead takes its source joints
from the whole depth chain (virtual OAK-D -> the shipped skeleton stage, ``models.train.chain_sources``,
built once and cached), with body A the T-pose the pipeline estimates from them: the network
then learns the skeleton stage's real errors, not only a noise model of them.

Losses (see docs/learned_retargeting.md): supervised joints / rotations / root against the exact
answer; joint cycle consistency A->B->A; rotation cycle (lambda_rot = 0.01, rotations of A->B and
of B->A agree); smoothness (joint velocities match the truth's). No adversarial loss: with exact
targets it adds nothing but instability. Validation: held-out CMU subjects {7, 8, 12, 16} on
held-out bodies, whole clips run online (one step per frame, state carried), beside the analytic
retargeter. ``--quick`` trains briefly into .cache/retarget_quick unless --out is given.
Seeded; torch.set_num_threads(1) (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from live.core import assets
from live.core.heading import yaw_quat
from live.core.rotations import quat_multiply
from models.train.retarget_nets import RetargetNet, count_parameters, export_onnx, fk, leg_length

WEIGHTS = assets.weights_dir()
CACHE = assets.cache_dir()
FPS = 30.0
LAMBDA_ROT = 0.01
BATCH = 48


# ----------------------------------------------------------------------------------------- data
def load_clips(cache: Path = CACHE / "retarget_clips_v2.npz") -> dict:
    """All clips at 30 fps: rotations (N,22,4), root (N,3), offsets (C+1,), rest (C,22,3),
    subject (C,) (-1 = none), names (C,). Cached; rebuilt when the clip list changes."""
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion
    from sim.skeleton_data import BVH_DIR, list_clips

    clips = list_clips()
    names = [c.file for c in clips]
    if cache.is_file():
        data = dict(np.load(cache))
        if list(data["names"]) == names:
            return data
    rots, roots, rests, offsets = [], [], [], [0]
    from live.evaluation.retarget import grounded

    for c in clips:
        m = grounded(resample(load_motion(BVH_DIR / c.file), FPS))
        rots.append(m.rotations.astype(np.float32))
        roots.append(m.root.astype(np.float32))
        rests.append(m.rest_joints.astype(np.float32))
        offsets.append(offsets[-1] + m.num_frames)
    data = {"rotations": np.concatenate(rots), "root": np.concatenate(roots), "offsets": np.array(offsets),
            "rest": np.stack(rests), "subject": np.array([c.subject if c.subject is not None else -1 for c in clips]),
            "names": np.array(names)}
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **data)
    return data


def body_rests(split: str, source: str = "library") -> tuple[list[str], np.ndarray]:
    """Names and (K, 22, 3) T-poses of the bodies of a split (train / val).

    source "library": the body-library presets (sim.skeleton_data.split_bodies); "generic": a
    seeded set of generic T-poses (live.core.skeleton.default_rest_joints at 1.0-1.95 m, bones scaled
    by up to +-10 %), usable without the library."""
    if source == "generic":
        from live.core.skeleton import default_rest_joints

        rng = np.random.default_rng(1 if split == "train" else 2)
        heights = np.linspace(1.0, 1.95, 12 if split == "train" else 4)
        return ([f"generic-{h:.2f}" for h in heights],
                np.stack([scale_bones(default_rest_joints(h), random_factors(rng, 0.1)) for h in heights]))
    from live.body.library import list_presets, load_body
    from sim.skeleton_data import split_bodies

    names = split_bodies(list_presets(), "train" if split == "train" else "val")
    return names, np.stack([np.asarray(load_body(n).rest_joints, np.float32) for n in names])


def scale_bones(rest: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """(22,3) T-pose with bone j's offset times factors[j] (22,), rebuilt from the pelvis, lowest
    foot joint kept at its height (feet stay on the floor)."""
    from live.core.skeleton import PARENTS, rest_offsets

    off = rest_offsets(rest) * factors[:, None]
    out = np.empty_like(rest)
    out[0] = rest[0]
    for j in range(1, 22):
        out[j] = out[PARENTS[j]] + off[j]
    out[:, 1] += rest[[10, 11], 1].min() - out[[10, 11], 1].min()
    return out


def random_factors(rng: np.random.Generator, spread: float = 0.15) -> np.ndarray:
    """(22,) per-bone length factors, left and right alike."""
    from live.core.skeleton import LEFT_RIGHT_SWAP

    f = rng.uniform(1 - spread, 1 + spread, 22)
    return 0.5 * (f + f[LEFT_RIGHT_SWAP])


def quat_to_matrix_t(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).unflatten(-1, (3, 3))


class Sampler:
    """Random training windows: (rotations B x T x 22 x 3 x 3, root B x T x 3 on the clip's own
    body, clip T-pose B x 22 x 3, body A B x 22 x 3, body B B x 22 x 3); ``chain_batch`` adds
    the source joints B x T x 22 x 3 that the depth chain gave (models.train.chain_sources)."""

    def __init__(self, data: dict, clip_ids: np.ndarray, rests: np.ndarray, seed: int, chain: dict | None = None):
        self.data, self.rests, self.chain = data, rests, chain
        self.rng = np.random.default_rng(seed)
        lengths = np.diff(data["offsets"])[clip_ids]
        self.clip_ids = clip_ids
        self.p = lengths / lengths.sum()

    def body(self) -> np.ndarray:
        base = self.rests[self.rng.integers(len(self.rests))]
        return scale_bones(base, random_factors(self.rng))

    def batch(self, size: int, length: int):
        rng, d = self.rng, self.data
        rot = np.empty((size, length, 22, 4), np.float32)
        root = np.empty((size, length, 3), np.float32)
        rest = np.empty((size, 22, 3), np.float32)
        for b in range(size):
            c = self.clip_ids[rng.choice(len(self.clip_ids), p=self.p)]
            lo, hi = d["offsets"][c], d["offsets"][c + 1]
            n = min(length, hi - lo)
            s = lo + rng.integers(0, hi - lo - n + 1)
            _window(rot[b], d["rotations"][s:s + n])
            _window(root[b], d["root"][s:s + n])
            _turn(rng.uniform(-np.pi, np.pi), rot[b], root[b])
            rest[b] = d["rest"][c]
        body_a = np.stack([self.body() for _ in range(size)])
        body_b = np.stack([self.body() for _ in range(size)])
        return (quat_to_matrix_t(torch.from_numpy(rot)), torch.from_numpy(root), torch.from_numpy(rest),
                torch.from_numpy(body_a), torch.from_numpy(body_b))

    def chain_batch(self, size: int, length: int):
        """Like ``batch``, with the depth chain's own source joints appended: body A is the T-pose
        the pipeline estimated for the performer, the truth the motion on the target body B."""
        rng, d, ch = self.rng, self.data, self.chain
        rot = np.empty((size, length, 22, 4), np.float32)
        root = np.empty((size, length, 3), np.float32)
        src = np.empty((size, length, 22, 3), np.float32)
        rest = np.empty((size, 22, 3), np.float32)
        body_a = np.empty((size, 22, 3), np.float32)
        p = ch["frames"] / ch["frames"].sum()
        for b in range(size):
            r = rng.choice(len(p), p=p)
            n = min(length, int(ch["frames"][r]))
            k = int(rng.integers(0, ch["frames"][r] - n + 1))
            c = ch["clip"][r]
            s = d["offsets"][c] + ch["start"][r] + k
            _window(rot[b], d["rotations"][s:s + n])
            _window(root[b], d["root"][s:s + n])
            _window(src[b], ch["joints"][ch["offsets"][r] + k:ch["offsets"][r] + k + n])
            _turn(rng.uniform(-np.pi, np.pi), rot[b], root[b], src[b])
            rest[b], body_a[b] = d["rest"][c], ch["rest"][r]
        body_b = np.stack([self.body() for _ in range(size)])
        return (quat_to_matrix_t(torch.from_numpy(rot)), torch.from_numpy(root), torch.from_numpy(rest),
                torch.from_numpy(body_a), torch.from_numpy(body_b), torch.from_numpy(src))


def _window(out: np.ndarray, frames: np.ndarray) -> None:
    """Fill ``out`` (T, ...) with ``frames`` (n <= T, ...); a short clip holds its last pose."""
    n = len(frames)
    out[:n], out[n:] = frames, frames[n - 1]


def _turn(a: float, rot: np.ndarray, root: np.ndarray, *points: np.ndarray) -> None:
    """Turn a window by the yaw ``a`` about the world origin, in place: the same motion facing
    elsewhere. rot (T, 22, 4) local quaternions (the pelvis's turns), root (T, 3), points (T, ..., 3)."""
    rot[:, 0] = quat_multiply(yaw_quat(a).astype(np.float32), rot[:, 0])
    c_, s_ = np.cos(a), np.sin(a)
    for xyz in (root, *points):
        x, z = xyz[..., 0].copy(), xyz[..., 2].copy()
        xyz[..., 0], xyz[..., 2] = c_ * x + s_ * z, -s_ * x + c_ * z


def on_body(rot: torch.Tensor, root: torch.Tensor, clip_rest: torch.Tensor, body: torch.Tensor):
    """The motion on a body: (root B x T x 3 scaled by the leg ratio, joints B x T x 22 x 3)."""
    r = root * (leg_length(body) / leg_length(clip_rest))
    return r, fk(rot, r, body)


# ------------------------------------------------------------------------------------- training
#: Error of the depth skeleton stage per joint (std per axis, mm) and its frame-to-frame
#: correlation at 30 fps, measured on training clips (cc_002_05, mb_02_01 on heavy_male and
#: petite_female, virtual OAK-D) behind the online temporal model (skeleton_temporal.onnx), the
#: stage's default: `python -m research.measure_skeleton_noise`. (Behind the One Euro filter, the
#: stage without a temporal model, it is ~1.6x larger: 15-27 mm on the body, 46-51 on the wrists, 0.8.)
DEPTH_NOISE_MM = (9, 13, 12, 9, 11, 10, 10, 16, 15, 10, 16, 16, 9, 8, 8, 9, 13, 14, 34, 31, 37, 28)
DEPTH_NOISE_CORR = 0.87


def depth_like_noise(shape: tuple[int, int, int, int], scale: torch.Tensor) -> torch.Tensor:
    """B x T x 22 x 3 noise like the depth skeleton's error: per-joint size DEPTH_NOISE_MM times
    ``scale`` (B,), correlated in time (AR(1), DEPTH_NOISE_CORR per frame), so that the network
    learns to smooth what the regressor really gets wrong rather than white noise."""
    b, t, j, _ = shape
    sigma = torch.tensor(DEPTH_NOISE_MM, dtype=torch.float32)[None, :, None] * 1e-3 * scale[:, None, None]
    rho = DEPTH_NOISE_CORR
    steps = torch.randn(shape)
    out = torch.empty(shape)
    out[:, 0] = steps[:, 0] * sigma
    for k in range(1, t):
        out[:, k] = rho * out[:, k - 1] + (1 - rho * rho) ** 0.5 * steps[:, k] * sigma
    return out


def losses(net: RetargetNet, batch, noise: float, smooth_weight: float = 10.0) -> dict[str, torch.Tensor]:
    """``noise``: size of the depth-like source noise (0 = exact source joints). A batch with a
    sixth member (``Sampler.chain_batch``) brings its own source joints, from the depth chain."""
    rot, root, clip_rest, body_a, body_b = batch[:5]
    if len(batch) > 5:
        src = batch[5]
    else:
        _, src = on_body(rot, root, clip_rest, body_a)
        if noise > 0:
            src = src + depth_like_noise(tuple(src.shape), noise * torch.rand(src.shape[0]))
    gt_root, gt = on_body(rot, root, clip_rest, body_b)
    scale_b = leg_length(body_b)[:, None]  # B x 1 x 1 x 1: lengths in target leg lengths
    pred_rot, pred_root, pred = net.retarget(src, body_a, body_b)
    out = {
        "joints": ((pred - gt).abs() / scale_b).mean(),
        "rot": (pred_rot - rot).abs().mean(),
        "root": ((pred_root - gt_root).abs() / scale_b[..., 0]).mean(),
        "smooth": (((torch.diff(pred, dim=1) - torch.diff(gt, dim=1)).abs() / scale_b).mean()
                   + ((torch.diff(pred, 2, dim=1) - torch.diff(gt, 2, dim=1)).abs() / scale_b).mean()) * smooth_weight,
    }
    # Cycle A -> B -> A: the retargeted joints, fed back as a source on B, must give A's joints.
    # On a quarter of the batch: the second pass doubles the cost and the signal is redundant.
    k = max(1, len(rot) // 4)
    _, src_clean = on_body(rot[:k], root[:k], clip_rest[:k], body_a[:k])
    cyc_rot, _, cyc = net.retarget(pred[:k], body_b[:k], body_a[:k])
    out["cycle"] = ((cyc - src_clean).abs() / leg_length(body_a[:k])[:, None]).mean()
    out["rot_cycle"] = LAMBDA_ROT * (cyc_rot - pred_rot[:k]).abs().mean()
    out["total"] = out["joints"] + 0.5 * out["rot"] + out["root"] + out["smooth"] + 0.5 * out["cycle"] + out["rot_cycle"]
    return out


def train(net: RetargetNet, sampler: Sampler, minutes: float, max_steps: int, batch: int, lr: float,
          log, noise_scale: float = 1.2, chain_share: float = 0.0, smooth_weight: float = 10.0) -> dict:
    """``chain_share`` of the batches take their source joints from the depth chain (the sampler's
    ``chain``); the rest are split evenly between depth-like noise and exact sources."""
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-5)
    start = time.monotonic()
    step, history = 0, []
    run = {}
    while step < max_steps and time.monotonic() - start < minutes * 60:
        frac = max(step / max_steps, (time.monotonic() - start) / (minutes * 60))
        for g in opt.param_groups:
            g["lr"] = lr * 0.5 * (1 + np.cos(np.pi * min(frac, 1.0)))
        long = step % 4 == 3  # a quarter of the windows are 4 s long, against drift in long runs
        size, length = (batch // 4, 120) if long else (batch, 30)
        u = sampler.rng.random()
        if u < chain_share:
            b, noise = sampler.chain_batch(size, length), 0.0
        else:
            b = sampler.batch(size, length)
            noise = noise_scale if (u - chain_share) / (1.0 - chain_share) < 0.5 else 0.0
        out = losses(net, b, noise, smooth_weight)
        opt.zero_grad()
        out["total"].backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        run = {k: run.get(k, 0.0) * 0.98 + float(v.detach()) * 0.02 for k, v in out.items()}
        step += 1
        if step % 200 == 0:
            history.append({"step": step, "s": round(time.monotonic() - start, 1), **{k: round(v, 5) for k, v in run.items()}})
            log(f"step {step} {time.monotonic() - start:.0f}s " + " ".join(f"{k}={v:.4f}" for k, v in run.items()))
    return {"steps": step, "seconds": round(time.monotonic() - start, 1), "history": history}


# ----------------------------------------------------------------------------------- validation
def validate(onnx_path: Path, data: dict, clip_ids: np.ndarray, rests: np.ndarray, max_frames: int) -> dict:
    """Whole held-out clips on held-out body pairs, online (one ONNX step per frame), against the
    analytic retargeter: MPJPE / PA-MPJPE / Acc (m, mm/frame^2) averaged over (clip, pair)."""
    from live.core.kinematics import forward_kinematics
    from live.core.metrics import acceleration_error, mpjpe, pa_mpjpe
    from live.retarget.learned import LearnedRetargeter
    from live.retarget.retargeter import retarget_motion

    res = {"learned": [], "analytic": []}
    pairs = [(i, (i + 1) % len(rests)) for i in range(len(rests))]
    for c in clip_ids:
        lo, hi = data["offsets"][c], data["offsets"][c + 1]
        hi = min(hi, lo + max_frames)
        rot, root, clip_rest = data["rotations"][lo:hi], data["root"][lo:hi], data["rest"][c]
        for a, b in pairs:
            ra, rb = rests[a], rests[b]
            src, _ = forward_kinematics(rot, root * ra[0, 1] / clip_rest[0, 1], ra)
            gt, _ = forward_kinematics(rot, root * rb[0, 1] / clip_rest[0, 1], rb)
            learned = LearnedRetargeter(onnx_path, ra, rb)
            pred_l = np.stack([learned.step(j)[2] for j in src])
            pred_a = retarget_motion(ra, rb, joints=src, fps=FPS)[2]
            for name, pred in (("learned", pred_l), ("analytic", pred_a)):
                res[name].append((mpjpe(pred, gt), pa_mpjpe(pred, gt), 1000 * acceleration_error(pred, gt)))
    return {k: dict(zip(("mpjpe_m", "pa_mpjpe_m", "acc_mm_per_frame2"),
                        (round(float(x), 5) for x in np.mean(v, axis=0)))) for k, v in res.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a short smoke run (into .cache/retarget_quick)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--minutes", type=float, default=None, help="wall-time budget for training")
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--hidden", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", type=float, default=1.2,
                    help="depth-like source noise in half the batches: up to this x the measured skeleton error")
    ap.add_argument("--chain-share", type=float, default=0.0,
                    help="share of the batches whose source joints come from the depth chain "
                         "(models.train.chain_sources; default 0: tried at 0.5, not kept, "
                         "docs/learned_retargeting.md)")
    ap.add_argument("--chain-runs", type=int, default=2, help="depth-chain runs per training clip")
    ap.add_argument("--smooth", type=float, default=10.0, help="weight of the velocity + acceleration loss")
    ap.add_argument("--bodies", choices=("library", "generic"), default="library",
                    help="training bodies: the body library's presets or generic T-poses")
    ap.add_argument("--val-bodies", choices=("library", "generic"), default=None,
                    help="validation bodies (default: as --bodies)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    out = args.out or (CACHE / "retarget_quick" if args.quick else WEIGHTS)
    out.mkdir(parents=True, exist_ok=True)
    # A fixed number of steps decides the run (deterministic); the time limit is only a safety cap.
    minutes = args.minutes or (1.0 if args.quick else 45.0)
    steps = args.steps or (150 if args.quick else 3500)
    log = lambda msg: print(msg, flush=True)  # noqa: E731

    t0 = time.monotonic()
    data = load_clips()
    subj = data["subject"]
    train_ids = np.flatnonzero(~np.isin(subj, [7, 8, 12, 16]))
    val_ids = np.flatnonzero(np.isin(subj, [7, 8, 12, 16]))
    train_names, train_rests = body_rests("train", args.bodies)
    val_names, val_rests = body_rests("val", args.val_bodies or args.bodies)
    log(f"{len(train_ids)} training clips, {len(val_ids)} held-out; bodies {len(train_names)} / {len(val_names)}")

    chain = None
    if args.chain_share > 0:
        if args.bodies != "library":
            raise SystemExit("--chain-share needs the body library (--bodies library) or 0")
        from models.train.chain_sources import build as build_chain

        chain = build_chain(data, 1 if args.quick else args.chain_runs, 60 if args.quick else 300,
                            clip_limit=4 if args.quick else None)
        log(f"depth chain: {len(chain['clip'])} runs, {len(chain['joints'])} frames")
    net = RetargetNet(hidden=args.hidden)
    sampler = Sampler(data, train_ids, train_rests, args.seed, chain)
    run = train(net, sampler, minutes, steps, batch=BATCH, lr=2e-3, log=log, noise_scale=args.noise,
                chain_share=args.chain_share, smooth_weight=args.smooth)
    path = out / "retarget.onnx"
    export_onnx(net, str(path))
    log(f"exported {path} after {run['steps']} steps")
    metrics = validate(path, data, val_ids[:2] if args.quick else val_ids, val_rests,
                       max_frames=90 if args.quick else 900)
    log(json.dumps(metrics))
    frames = int(np.diff(data["offsets"])[train_ids].sum())
    card = {
        "model": "retarget", "file": path.name,
        "command": " ".join(["python -m models.train.train_retarget", *(argv if argv is not None else sys.argv[1:])]), "kind": "encoder GRU x2 + decoder GRU x1, 6D rotations",
        "inputs": {"source": "(1, 199) features of one frame (live/retarget/learned.py: source_features)",
                   "target": "(1, 66) target T-pose relative to the pelvis / leg length",
                   "h_enc": f"(2, 1, {args.hidden})", "h_dec": f"(1, 1, {args.hidden})"},
        "outputs": {"rot6d": "(1, 22, 6) global (world) joint rotations, 6D (first two matrix columns); local = parent^T global",
                    "root_delta": "(1, 3) root correction in target leg lengths",
                    "h_enc_out": "next h_enc", "h_dec_out": "next h_dec"},
        "hidden": args.hidden, "parameters": count_parameters(net), "fps": FPS,
        "data": {"clips": "../shared/data/bvh (CMU), 30 fps", "train_clips": len(train_ids),
                 "train_frames": frames, "val_subjects": [7, 8, 12, 16], "val_clips": len(val_ids),
                 "train_bodies": train_names, "val_bodies": val_names,
                 "augmentation": "random yaw; per-bone length x0.85-1.15; source noise like the depth skeleton's "
                                 f"(per-joint size DEPTH_NOISE_MM x U(0, {args.noise}), AR(1) {DEPTH_NOISE_CORR} per frame) in half the batches "
                                 "that do not come from the depth chain",
                 "depth_chain": None if chain is None else {
                     "share": args.chain_share, "module": "models.train.chain_sources",
                     "runs": int(len(chain["clip"])), "frames": int(len(chain["joints"])),
                     "found": round(float(chain["found"].mean()), 4),
                     "what": "training clips on training bodies seen by the virtual OAK-D (1.5-4 m, within 90 "
                             "degrees of the front), the shipped skeleton stage's online output as the source, "
                             "body A the T-pose estimated from it"}},
        "losses": {"supervised": "L1 joints + 0.5 rotation matrices + root (exact targets)",
                   "cycle": "0.5 x L1 joints A->B->A (on a quarter of each batch)", "rot_cycle": LAMBDA_ROT, "smooth": f"{args.smooth:g} x (L1 velocity + L1 acceleration) against the truth",
                   "adversarial": "not used"},
        "recipe": {"windows": "30 frames (a quarter 120)", "batch": BATCH, "optimizer": "AdamW 2e-3 cosine",
                   "steps": run["steps"], "seed": args.seed, "threads": 1},
        "validation": {"setting": "held-out clips (whole, <= 30 s) x held-out body pairs, ground-truth source skeletons, online",
                       **metrics},
        "training_seconds": run["seconds"], "total_seconds": round(time.monotonic() - t0, 1),
        "quick": args.quick, "torch": torch.__version__, "python": sys.version.split()[0],
        "machine": platform.machine(), "history": run["history"][-5:],
    }
    path.with_suffix(".json").write_text(json.dumps(card, indent=2) + "\n")
    log(f"wrote {path.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
