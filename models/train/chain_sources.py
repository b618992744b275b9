"""What the learned retargeter really sees live: source skeletons from the whole depth chain.

Used by ``train_retarget --chain-share``; ``python -m research.chain_sources`` runs it alone.

Why: the depth skeleton stage's error is not the AR(1) noise of ``train_retarget.depth_like_noise``;
it depends on the pose and the view (a wrist behind the body, a foot at the image edge) and has
its own spectrum behind the temporal model. Training on the chain's own output teaches the
retargeter to smooth exactly that error. Each run: a window of a training clip (CMU subjects other
than 7, 8, 12, 16) on a training body (never a held-out preset), seen by the virtual OAK-D from a
random placement (1.5-4 m, within 90 degrees of the performer's front) and put through the shipped
skeleton stage online (temporal model included), as ``live.evaluation.retarget.depth_skeletons``
runs it. Kept per run: the stage's joints in the clip's coordinates (frames where nobody was found
hold the last skeleton, as the live avatar does), the found mask, and the performer's T-pose
estimated from those joints as the pipeline estimates it. Cached in .cache/ under the hashes of
the skeleton files and the person finder, so a new skeleton stage makes a new set. The default
set (96 clips x 2 runs of up to 300 frames: 192 runs, 35,424 frames) takes ~8 min on 2 cores.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from live.core import assets

CACHE = assets.cache_dir()
FPS = 30.0


def skeleton_files_key() -> str:
    """Short hash of the shipped skeleton regressor, online temporal model and person finder."""
    from models.skeleton import background, floor, person_clusters, point_sample, preprocess, preprocess_config
    from models.skeleton.runtime import DEFAULT_MODEL
    from models.skeleton.temporal import DEFAULT_TEMPORAL_MODEL

    finder = (preprocess, preprocess_config, background, floor, person_clusters, point_sample)
    h = hashlib.sha256()
    for p in (DEFAULT_MODEL, DEFAULT_TEMPORAL_MODEL, *(Path(m.__file__) for m in finder)):
        h.update(Path(p).read_bytes())
    return h.hexdigest()[:12]


def plan_runs(data: dict, clip_ids: np.ndarray, body_names: list[str], runs_per_clip: int, frames: int,
              seed: int) -> list[dict]:
    """One dict per run: clip index, window start and length, body name, placement, noise seed."""
    rng = np.random.default_rng(seed)
    runs = []
    for c in clip_ids:
        n_clip = int(data["offsets"][c + 1] - data["offsets"][c])
        for _ in range(runs_per_clip):
            n = min(frames, n_clip)
            runs.append({"clip": int(c), "start": int(rng.integers(0, n_clip - n + 1)), "frames": int(n),
                         "body": body_names[int(rng.integers(len(body_names)))],
                         "distance": float(rng.uniform(1.5, 4.0)), "height": float(rng.uniform(0.6, 1.9)),
                         "yaw": float(rng.uniform(-np.pi / 2, np.pi / 2)), "seed": int(rng.integers(1 << 30))})
    return runs


def run_chain(run: dict, data: dict, template: np.ndarray) -> dict:
    """The skeleton stage's output for one planned run (see the module docstring)."""
    from live.body.library import load_body
    from live.core.kinematics import forward_kinematics
    from live.evaluation.retarget import depth_skeletons
    from live.motion.clips import Motion
    from live.retarget.analytic import estimate_rest_joints
    from sim.synth import CameraPlacement

    c = run["clip"]
    lo = int(data["offsets"][c]) + run["start"]
    rot, root, rest = data["rotations"][lo:lo + run["frames"]], data["root"][lo:lo + run["frames"]], data["rest"][c]
    motion = Motion(name=str(data["names"][c]), fps=FPS, joints=forward_kinematics(rot, root, rest)[0],
                    rotations=rot, root=root, rest_joints=rest, source_rig="cmu")
    placement = CameraPlacement(distance=run["distance"], height=run["height"], yaw=run["yaw"])
    joints, found = depth_skeletons(motion, load_body(run["body"]), seed=run["seed"], placement=placement)
    return {"joints": joints.astype(np.float32), "found": found,
            "rest": estimate_rest_joints(joints[found], template).astype(np.float32)}


def _work(args):
    run, data, template = args
    return run_chain(run, data, template)


def build(data: dict, runs_per_clip: int = 2, frames: int = 300, workers: int = 2, seed: int = 0,
          clip_limit: int | None = None, progress: bool = True) -> dict:
    """Run (or load from the cache) the chain over the training clips of ``data``
    (models.train.train_retarget.load_clips); returns a dict of arrays: clip, start, frames (R,),
    body (R,) names, joints (sum frames, 22, 3), found (sum frames,), rest (R, 22, 3), offsets
    (R + 1,) into joints."""
    from multiprocessing import get_context

    from tqdm import tqdm

    from live.body.library import list_presets, load_body, mean_rest_template
    from sim.skeleton_data import VAL_SUBJECTS, split_bodies

    clip_ids = np.flatnonzero(~np.isin(data["subject"], sorted(VAL_SUBJECTS)))[:clip_limit]
    bodies = split_bodies(list_presets(), "train")
    template = mean_rest_template(tuple(bodies))
    path = CACHE / f"retarget_chain_{skeleton_files_key()}_{runs_per_clip}x{frames}_s{seed}_{len(clip_ids)}.npz"
    if path.is_file():
        return dict(np.load(path))
    runs = plan_runs(data, clip_ids, bodies, runs_per_clip, frames, seed)
    for b in set(r["body"] for r in runs):
        load_body(b)  # build any missing body cache once, not in every worker
    jobs = [(r, data, template) for r in runs]
    with get_context("fork").Pool(workers) as pool:
        outs = list(tqdm(pool.imap(_work, jobs), total=len(jobs), desc="chain runs", disable=not progress))
    result = {"clip": np.array([r["clip"] for r in runs]), "start": np.array([r["start"] for r in runs]),
              "frames": np.array([r["frames"] for r in runs]), "body": np.array([r["body"] for r in runs]),
              "joints": np.concatenate([o["joints"] for o in outs]), "found": np.concatenate([o["found"] for o in outs]),
              "rest": np.stack([o["rest"] for o in outs]),
              "offsets": np.concatenate([[0], np.cumsum([r["frames"] for r in runs])])}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **result)
    return result

