"""Consecutive-frame training and validation data for the temporal skeleton model.

One sequence = what the live skeleton stage sees over ``SEQUENCE_FRAMES`` consecutive 30 fps
frames: a real CMU clip window on a body of the library, seen by the same random virtual camera,
room and sensor noise as the per-frame data (``sim.skeleton_data.random_view``), with one
``PersonFinder`` kept across the frames as the runtime keeps it. Stored per frame: the person
sample (512 points, person frame), the person frame (``to_world``), whether the finder found the
performer, and the true world joints. The regressor is not run here: the temporal trainer runs
the current skeleton model on the stored samples, so the data outlives any one model.

Splits and held-out subjects / bodies are those of ``sim.skeleton_data``; "val" is the goal's
setting (OAK-D, 1.5-4 m). With ``realism`` (training only), sequences are seen as users' sensors
see people (``sim.sensor_realism``); a sequence without extrinsics stores each frame's truth in
the world the finder estimated for it. Without it, ``in_place_share`` of the sequences are
performed in place (``sim.postures`` ``in-place``): the shared clips mostly cross the room,
and a performer in front of a desk or a monitor moves on the spot. Jobs are seeded, so the result
does not depend on the worker count.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import numpy as np

from live.core.errors import UserInputError
from live.core.skeleton import NUM_JOINTS
from live.core.timing import frame_offset_ns
from sim.skeleton_data import (
    CACHE_DIR,
    STORED_POINTS,
    VAL_SUBJECTS,
    Job,
    anny_phenotypes,
    body_by_name,
    build_bodies,
    clip_motion,
    grounded_joints,
    job_motion,
    plan_jobs,
    random_view,
    run_jobs,
    save_cache,
    visible_joints,
)

SEQUENCE_FPS = 30.0
SEQUENCE_FRAMES = 48  # 1.6 s: the performer stays near the centre of the cleared room


def _motion_at_fps(file: str):
    from live.motion.clips import resample

    return resample(clip_motion(file), SEQUENCE_FPS)


def run_sequence_job(job: Job) -> dict[str, np.ndarray]:
    """Render one job's consecutive frames; arrays with a leading frame axis (F = SEQUENCE_FRAMES,
    frames past the end of a short clip are marked not found)."""
    from live.core.depth import between_worlds
    from live.core.frames import DepthFrame
    from models.skeleton.preprocess import PersonFinder
    from models.skeleton.preprocess_config import PreprocessConfig
    from sim.synth import SyntheticScene

    rng = np.random.default_rng(job.seed)
    motion, posture = job_motion(job, _motion_at_fps(job.clip))
    body = body_by_name(job.body)
    root, joints = grounded_joints(motion, body)
    span = min(len(root), SEQUENCE_FRAMES)
    start = int(rng.integers(0, len(root) - span + 1))
    window = np.arange(start, start + span)
    centre = joints[window, 0].mean(axis=0)
    shift = np.array([centre[0], 0.0, centre[2]])
    root, joints = root - shift, joints - shift
    camera, room = random_view(job, rng)
    c2w = camera.camera_to_world
    scene = SyntheticScene(motion=motion, body=body, camera=camera, root=root, joints=joints)
    extras = None
    if job.realism:
        from sim.sensor_realism import random_extras

        extras = random_extras(rng, body, joints, window, c2w, job.closeup, posture)
        room = extras.room(room)
    given = np.eye(4) if extras is not None and extras.hide_extrinsics else c2w
    finder = PersonFinder(PreprocessConfig(num_points=STORED_POINTS, edge_jump_share=job.edge_jump_share))
    f = SEQUENCE_FRAMES
    out = {"points": np.zeros((f, STORED_POINTS, 3), np.float32),
           "to_world": np.tile(np.eye(4), (f, 1, 1)), "found": np.zeros(f, bool),
           "joints": np.zeros((f, NUM_JOINTS, 3), np.float32), "visible": np.zeros((f, NUM_JOINTS), bool),
           "t_ns": np.zeros(f, np.int64)}
    for k, i in enumerate(window):
        t_ns = 1_000_000_000 + frame_offset_ns(k, SEQUENCE_FPS)
        if extras is None:
            depth_mm = camera.render(scene.vertices(int(i)), body.faces, room=room)
        else:
            depth_mm = camera.render(*extras.mesh(scene.vertices(int(i)), body, joints[i], int(i)), room=room)
        person = finder.find(DepthFrame(t_ns=t_ns, sensor="sim", camera_to_world=given,
                                        depth_mm=depth_mm, intrinsics=camera.intrinsics))
        truth = joints[i]
        if person is not None and given is not c2w and person.camera_to_world is not None:
            truth = between_worlds(truth, c2w, person.camera_to_world)  # the finder's own world
        out["joints"][k] = truth
        out["visible"][k] = visible_joints(joints[i], camera)
        out["t_ns"][k] = t_ns
        if person is not None:
            out["points"][k] = person.points
            out["to_world"][k] = person.to_world
            out["found"][k] = True
    return out


def _cache_path(split: str, n_sequences: int, seed: int, anny: int = 0, anny_share: float = 0.0,
                realism: bool = False, edge_jump_share: float | None = None, in_place_share: float = 0.0):
    fields = {"split": split, "n": n_sequences, "seed": seed, "frames": SEQUENCE_FRAMES,
              "fps": SEQUENCE_FPS, "v": 1, "val_subjects": sorted(VAL_SUBJECTS)}
    if edge_jump_share is not None:
        fields.update(edge_jump_share=edge_jump_share)
    if in_place_share > 0:  # without it, the key (and the caches) of the clips as recorded
        fields.update(in_place_share=in_place_share)
    if realism:
        from sim.sensor_realism import REALISM_VERSION

        fields.update(realism=REALISM_VERSION)
    if anny and anny_share > 0:  # without them, the key (and the caches) of the presets-only data
        fields.update(anny=anny, anny_share=anny_share)
    key = json.dumps(fields, sort_keys=True)
    return CACHE_DIR / f"seq_{split}_{n_sequences}_{seed}_{hashlib.sha1(key.encode()).hexdigest()[:8]}.npz"


def _load(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _largest_cached_prefix(split: str, n_sequences: int, seed: int, anny: int, anny_share: float,
                           realism: bool = False, edge_jump_share: float | None = None,
                           in_place_share: float = 0.0) -> dict[str, np.ndarray] | None:
    """The cached sequences of the same split, seed and bodies with the most sequences below n, if any."""
    def path(n: int):
        return _cache_path(split, n, seed, anny, anny_share, realism, edge_jump_share, in_place_share)

    best = max((n for n in range(1, n_sequences) if path(n).is_file()), default=None)
    return None if best is None else _load(path(best))


def generate_sequences(split: str, n_sequences: int, seed: int = 0, workers: int = 2, cache: bool = True,
                       progress: bool = False, anny: int = 0, anny_share: float = 0.0,
                       realism: bool = False, edge_jump_share: float | None = None,
                       in_place_share: float = 0.0) -> dict[str, np.ndarray]:
    """The sequences of a split (cached under .cache/skeleton_data). anny > 0: training
    sequences take one of ``anny`` on-demand Anny phenotypes (the per-frame data's,
    ``sim.skeleton_data.anny_phenotypes``; the train extra) with probability ``anny_share``.

    Returns points (S, F, 512, 3) float32 person frame, to_world (S, F, 4, 4), found (S, F) bool,
    joints (S, F, 22, 3) float32 world, visible (S, F, 22) bool, t_ns (S, F) int64, and per
    sequence clip / body / camera (S,) str, subject (S,) int32, closeup / in_place (S,) bool. realism:
    training sequences as users' sensors see people (module doc). edge_jump_share: the finder's
    (PreprocessConfig), as the regressor the sequences are for was trained with. in_place_share:
    the share of sequences without realism performed in place (drawn from a stream of
    its own: the other sequences are those of the plan without it)."""
    if split not in ("train", "val"):
        raise UserInputError(f"sequence data has splits train and val, not {split!r}")
    anny = anny if split == "train" and anny_share > 0 else 0
    realism = realism and split == "train"
    in_place_share = 0.0 if realism else in_place_share
    path = _cache_path(split, n_sequences, seed, anny, anny_share, realism, edge_jump_share, in_place_share)
    if cache and path.is_file():
        return _load(path)
    # plan_jobs plans ~5 % spare jobs for the per-frame data; sequences keep exactly n. Its plan
    # for n jobs starts with its plan for fewer, so a cached smaller set is this one's prefix.
    phenotypes = anny_phenotypes(anny, seed) if anny else None  # the per-frame data's, same seed
    jobs = plan_jobs(split, n_sequences, seed + 1000, frames_per_job=1, anny=phenotypes,
                     anny_share=anny_share, realism=realism, edge_jump_share=edge_jump_share)[:n_sequences]
    if in_place_share > 0:
        draws = np.random.default_rng([seed, 31]).random(len(jobs))
        jobs = [replace(j, posture="in-place") if u < in_place_share else j for j, u in zip(jobs, draws)]
    prefix = _largest_cached_prefix(split, n_sequences, seed, anny, anny_share, realism,
                                    edge_jump_share, in_place_share) if cache else None
    done = len(prefix["found"]) if prefix else 0
    if phenotypes:
        build_bodies(sorted({j.body for j in jobs[done:] if j.body.startswith("anny:")}), progress)
    results = run_jobs(run_sequence_job, jobs[done:], workers, f"sequences {split}" if progress else None)
    data = {k: np.stack([r[k] for r in results]) for k in results[0]}
    if prefix:
        data = {k: np.concatenate([prefix[k], data[k]]) for k in data}
    for key in ("clip", "body", "camera"):
        data[key] = np.array([getattr(j, key) for j in jobs])
    data["subject"] = np.array([j.subject for j in jobs], np.int32)
    data["closeup"] = np.array([j.closeup for j in jobs], bool)
    data["in_place"] = np.array([j.posture == "in-place" for j in jobs], bool)
    if cache:
        save_cache(path, data)
    return data


__all__ = ["SEQUENCE_FPS", "SEQUENCE_FRAMES", "generate_sequences", "run_sequence_job"]
