"""Training and validation data for the skeleton regressor, from the simulated sensors.

One sample = what the runtime sees and what it should answer: the person-frame point sample
(N x 3 float32) that ``models.skeleton.preprocess.PersonFinder`` extracts from a rendered, noisy
depth frame, and the true joints in that same person frame (22 x 3, i.e. inverse(to_world)
applied to the world ground truth), plus metadata (clip, subject, body, camera, distance,
visible-joint mask, and the view's conditions: ``VIEW_KEYS``).

Scenes: a real CMU clip (../shared/data/bvh) posed on a body of the body library, seen by a
virtual depth camera (mostly the OAK-D preset) from a random placement around the performer
(1.5-4 m, 0.6-1.9 m high, any yaw; ~10 % close-ups at 0.8-1.4 m with the legs out of frame) in a
random room with clutter, sensor noise on. Work is cut into jobs (one clip window, one body, one
camera, a few frames) run by a process pool; each job has its own seed, so the result does not
depend on the number of workers.

With ``realism`` (the training default; ``sim.sensor_realism``), a job looks more like the
depth users have: five sensor models (stereo and time of flight, 320x240 to 640x480) with
flying pixels, holes in blobs and filled silhouettes, clothes and hair on the body, a desk edge
or a chair back in front, another person behind, cameras 0.5-2.5 m high at any pitch from
looking up 20 degrees to down 45, rooms whose floor returns no depth, and 40 % of the frames
without extrinsics (the finder estimates up and the floor as it does for users).

Splits are held out twice: by CMU subject (``VAL_SUBJECTS``; clips without a subject are training
only) and by body (``VAL_BODIES``). "val" is the goal's setting (OAK-D, 1.5-4 m, no realism),
"val_upper" the close-up setting of the upper-body goal, "val_real" the held-out clips and bodies
under the realism above. numpy / open3d only (no torch).
"""

from __future__ import annotations

import csv
import hashlib
import json
import multiprocessing as mp
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import UserInputError
from live.core.skeleton import LEFT_RIGHT_SWAP, NUM_JOINTS

BVH_DIR = assets.bvh_dir()
CACHE_DIR = assets.cache_dir("skeleton_data")
VAL_SUBJECTS = frozenset({7, 8, 12, 16})
#: Body presets never seen in training (chosen to span sizes; see docs/skeleton.md).
VAL_BODY_COUNT = 4
SPLITS = ("train", "val", "val_upper", "val_real")
CAMERAS = ("oak-d", "oak-d-pro", "kinect-v1")
#: Sensors of realism jobs and how often each is drawn.
REALISM_CAMERAS = {"oak-d": 0.35, "oak-d-pro": 0.1, "kinect-v1": 0.15, "xtion": 0.2, "kinect-v2": 0.2}
STORED_POINTS = 512  # points kept per sample; training draws its N from these
FRAMES_PER_JOB = 8
#: Per-sample conditions of the view, so that errors can be reported per condition: posture,
#: extrinsics hidden, camera pitch (degrees, + up) and height (m), something between camera and
#: performer (desk edge, chair back), another person behind, clothes on the body.
VIEW_KEYS = ("posture", "hidden_extrinsics", "pitch_deg", "camera_height_m", "occluder", "bystander", "dressed")


@dataclass(frozen=True)
class Clip:
    file: str
    subject: int | None  # None: no CMU subject (training only)


def list_clips(bvh_dir: Path = BVH_DIR) -> list[Clip]:
    """Every clip of index.csv that exists on disk, in file order."""
    index = bvh_dir / "index.csv"
    if not index.is_file():
        raise UserInputError(f"no clip index at {index}")
    clips = []
    with open(index, newline="") as f:
        for row in csv.DictReader(f):
            if (bvh_dir / row["file"]).is_file():
                s = (row.get("subject") or "").strip()
                clips.append(Clip(row["file"], int(s) if s.isdigit() else None))
    return sorted(clips, key=lambda c: c.file)


def split_clips(clips: list[Clip], split: str) -> list[Clip]:
    """Training clips: every subject not held out, and clips without a subject."""
    if split == "train":
        return [c for c in clips if c.subject is None or c.subject not in VAL_SUBJECTS]
    return [c for c in clips if c.subject in VAL_SUBJECTS]


def split_bodies(presets: list[str], split: str) -> list[str]:
    """Hold out VAL_BODY_COUNT presets spread over the sorted list (deterministic)."""
    names = sorted(presets)
    if len(names) <= VAL_BODY_COUNT:
        raise UserInputError(f"need more than {VAL_BODY_COUNT} body presets, found {len(names)}")
    pick = np.linspace(1, len(names) - 1, VAL_BODY_COUNT).round().astype(int)
    val = {names[i] for i in pick}
    return [n for n in names if (n in val) == (split != "train")]


#: Anny phenotype ranges of on-demand training bodies: those the body library spans
#: (models/bodies/library.json), so that they are people, from a 4-year-old up.
ANNY_RANGES = {"gender": (0.0, 1.0), "age": (0.16, 1.0), "muscle": (0.1, 1.0), "weight": (0.0, 1.0),
               "height": (0.1, 0.7), "proportions": (0.3, 0.85)}
#: A drawn phenotype this close to a held-out preset's (in every key) is drawn again: the
#: held-out bodies stay unseen.
ANNY_HOLD_OUT_MARGIN = 0.15


def anny_phenotypes(n: int, seed: int = 0) -> list[str]:
    """``n`` random training phenotypes as ``anny:...`` body specs (deterministic per seed),
    none within ANNY_HOLD_OUT_MARGIN of a held-out preset's phenotype in all keys."""
    from live.body.library import ANNY_KEYS, format_anny_spec, list_presets, preset_phenotypes

    phenotypes = preset_phenotypes()
    held_out = [phenotypes[name] for name in split_bodies(list_presets(), "val") if name in phenotypes]
    rng = np.random.default_rng([seed, 7411])
    specs: list[str] = []
    while len(specs) < n:
        ph = {k: round(float(rng.uniform(*ANNY_RANGES[k])), 2) for k in ANNY_KEYS}
        if any(all(abs(ph[k] - h[k]) < ANNY_HOLD_OUT_MARGIN for k in ANNY_KEYS) for h in held_out):
            continue
        specs.append(format_anny_spec(ph))
    return specs


@dataclass(frozen=True)
class Job:
    clip: str
    subject: int
    body: str
    camera: str
    closeup: bool
    seed: int
    split: str = "train"
    realism: bool = False
    edge_jump_share: float | None = None  # PreprocessConfig.edge_jump_share of the finder
    hard_views: bool = False  # realism views drawn with sim.sensor_realism.HARD_VIEWS
    # A sim.postures posture the job is performed in, in place of a realism job's random one:
    # raised legs ("knee-up", "kick") in realism training, "in-place" in sequences without realism.
    posture: str = ""

    @property
    def view_odds(self):
        from sim.sensor_realism import HARD_VIEWS, USUAL_VIEWS

        return HARD_VIEWS if self.hard_views else USUAL_VIEWS


def plan_jobs(split: str, n_samples: int, seed: int, frames_per_job: int = FRAMES_PER_JOB,
              anny: list[str] | None = None, anny_share: float = 0.0, realism: bool = False,
              edge_jump_share: float | None = None, hard_share: float = 0.0,
              knee_up_share: float = 0.0, kick_share: float = 0.0) -> list[Job]:
    """The jobs that make ``n_samples`` samples (a few more are planned; failures are dropped).
    Training jobs take a body of ``anny`` (on-demand phenotypes, ``anny_phenotypes``) with
    probability ``anny_share``, else a training preset. "val_real" jobs always have realism.
    hard_share: the share of realism training jobs drawn with ``HARD_VIEWS``; knee_up_share,
    kick_share: the shares of realism training jobs whose performer raises the knees in turn
    (``knee-up``) or kicks to the front in turn (``kick``)."""
    from live.body.library import list_presets
    from sim.sensor_realism import HARD_VIEWS, USUAL_VIEWS

    if split not in SPLITS:
        raise UserInputError(f"unknown split {split!r}; choose from {', '.join(SPLITS)}")
    clips = split_clips(list_clips(), split)
    bodies = split_bodies(list_presets(), split)
    rng = np.random.default_rng([seed, SPLITS.index(split)])
    knee_rng = np.random.default_rng([seed, SPLITS.index(split), 29])
    n_jobs = -(-int(n_samples * 1.05 + 1) // frames_per_job)
    jobs = []
    realism = realism or split == "val_real"
    names, odds = list(REALISM_CAMERAS), list(REALISM_CAMERAS.values())
    for _ in range(n_jobs):
        clip = clips[int(rng.integers(len(clips)))]
        hard = bool(realism and split == "train" and hard_share > 0 and rng.random() < hard_share)
        if realism:
            camera = names[int(rng.choice(len(names), p=odds))]
            closeup = bool(rng.random() < (HARD_VIEWS if hard else USUAL_VIEWS).closeup)
        elif split == "train":
            camera = CAMERAS[int(rng.choice(3, p=[0.7, 0.15, 0.15]))]
            closeup = bool(rng.random() < 0.1)
        else:
            camera, closeup = "oak-d", split == "val_upper"
        body = bodies[int(rng.integers(len(bodies)))]
        if split == "train" and anny and anny_share > 0 and rng.random() < anny_share:
            body = anny[int(rng.integers(len(anny)))]
        # From a stream of its own: with or without raised legs, the jobs are the same.
        posture = ""
        if realism and split == "train" and knee_up_share + kick_share > 0:
            u = knee_rng.random()
            posture = "knee-up" if u < knee_up_share else "kick" if u < knee_up_share + kick_share else ""
        jobs.append(Job(clip.file, -1 if clip.subject is None else clip.subject, body, camera, closeup,
                        int(rng.integers(2**31)), split, realism, edge_jump_share, hard, posture))
    return jobs


# ---------------------------------------------------------------------------- one job
_MOTIONS: dict[str, object] = {}
_BODIES: dict[str, object] = {}


def clip_motion(file: str):
    """The Motion of a clip of BVH_DIR (cached per process)."""
    from live.motion.rig_mapping import load_motion

    if file not in _MOTIONS:
        if len(_MOTIONS) > 200:  # bound worker memory (the library has ~120 clips)
            _MOTIONS.clear()
        _MOTIONS[file] = load_motion(BVH_DIR / file)
    return _MOTIONS[file]


def body_by_name(name: str):
    """A body of the library (cached per process)."""
    from live.body.library import load_body

    if name not in _BODIES:
        _BODIES[name] = load_body(name)
    return _BODIES[name]


def grounded_joints(motion, body) -> tuple[np.ndarray, np.ndarray]:
    """(root (T,3), joints (T,22,3)) of the body performing the motion, shifted vertically so the
    clip's typical lowest joint sits where the body's does standing (some converted clips float
    or sink by up to a metre; a performer in the data must stand on the floor)."""
    from sim.synth import pose_motion_on_body

    root, joints = pose_motion_on_body(motion, body)
    lowest = np.percentile(joints[:, :, 1].min(axis=1), 5)
    dy = float(np.asarray(body.rest_joints)[:, 1].min() - lowest)
    root = root + np.array([0.0, dy, 0.0])
    return root, joints + np.array([0.0, dy, 0.0])


def visible_joints(joints_world: np.ndarray, camera) -> np.ndarray:
    """(22,) bool: joint in front of the camera (beyond its min range) and inside the image."""
    c2w = camera.camera_to_world
    cam = (joints_world - c2w[:3, 3]) @ c2w[:3, :3]
    p = camera.preset
    z = np.maximum(cam[:, 2], 1e-6)
    u = cam[:, 0] / z * p.fx + p.cx
    v = cam[:, 1] / z * p.fy + p.cy
    return (cam[:, 2] > p.min_range_m) & (u >= 0) & (u < p.width) & (v >= 0) & (v < p.height)


def random_view(job: Job, rng: np.random.Generator):
    """(VirtualDepthCamera, Room) of a job: a random placement around the performer at the
    origin (1.5-4 m, 0.6-1.9 m high, any yaw; close-ups 0.8-1.4 m aimed at the chest), random
    sensor noise, a random room cleared between the camera and the performer. Realism jobs:
    ``sim.sensor_realism.realistic_view``."""
    from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera
    from sim.room import clear_view, random_room

    if job.realism:
        from sim.sensor_realism import realistic_view

        return realistic_view(job.camera, job.closeup, job.seed, rng, job.view_odds)
    if job.closeup:
        distance, height = rng.uniform(0.8, 1.4), rng.uniform(1.2, 1.7)
        target = (0.0, float(rng.uniform(1.1, 1.4)), 0.0)
    else:
        distance, height = rng.uniform(1.5, 4.0), rng.uniform(0.6, 1.9)
        target = (0.0, 1.0, 0.0)
    c2w = look_at_camera(distance, height, rng.uniform(-np.pi, np.pi), target=target)
    noise = NoiseModel(disparity_sigma_px=None if rng.random() < 0.7 else float(rng.uniform(0.05, 0.3)),
                       dropout=float(rng.uniform(0.0, 0.03)))
    camera = VirtualDepthCamera(job.camera, c2w, noise=noise, seed=job.seed)
    return camera, clear_view(random_room(rng, keep_out_m=1.0), c2w[:3, 3])


def job_motion(job: Job, motion):
    """(the job's motion in its posture, the posture's name): the job's own posture, else a
    realism job's random one (sim.sensor_realism), else the clip as recorded."""
    if job.posture:
        from sim.postures import apply_posture

        return apply_posture(motion, job.posture), job.posture
    if job.realism:
        from sim.sensor_realism import realism_motion

        return realism_motion(motion, job.seed, job.view_odds)
    return motion, "clip"


def run_job(job: Job) -> dict[str, np.ndarray]:
    """Render one job's frames and extract its samples (arrays with a leading sample axis)."""
    from live.core.depth import between_worlds
    from live.core.frames import DepthFrame
    from models.skeleton.preprocess import PersonFinder
    from models.skeleton.preprocess_config import PreprocessConfig
    from sim.synth import SyntheticScene

    rng = np.random.default_rng(job.seed)
    motion, posture = job_motion(job, clip_motion(job.clip))
    body = body_by_name(job.body)
    root, joints = grounded_joints(motion, body)
    t = len(root)
    span = min(t, int(1.0 * motion.fps))  # a 1 s window: the performer stays near its centre
    start = int(rng.integers(0, t - span + 1))
    frames = np.sort(rng.choice(np.arange(start, start + span), min(FRAMES_PER_JOB, span), replace=False))
    # Centre the window on the origin, where the room keeps its clutter away from the subject.
    centre = joints[frames, 0].mean(axis=0)
    shift = np.array([centre[0], 0.0, centre[2]])
    root, joints = root - shift, joints - shift
    camera, room = random_view(job, rng)
    c2w = camera.camera_to_world
    scene = SyntheticScene(motion=motion, body=body, camera=camera, root=root, joints=joints)
    extras = None
    if job.realism:
        from sim.sensor_realism import random_extras

        extras = random_extras(rng, body, joints, frames, c2w, job.closeup, posture, job.view_odds)
        room = extras.room(room)
    # The runtime's finder: the same coarse-to-fine pass and evenly spread sample.
    finder = PersonFinder(PreprocessConfig(num_points=STORED_POINTS, edge_jump_share=job.edge_jump_share))
    out: dict[str, list] = {k: [] for k in ("points", "joints", "visible", "frame", "distance", "count")}
    for i in frames:
        if extras is None:
            depth_mm = camera.render(scene.vertices(int(i)), body.faces, room=room)
        else:
            depth_mm = camera.render(*extras.mesh(scene.vertices(int(i)), body, joints[i], int(i)), room=room)
        given = c2w if extras is None or not extras.hide_extrinsics else np.eye(4)
        frame = DepthFrame(t_ns=int(job.seed) * 1000 + int(i), sensor="sim", camera_to_world=given,
                           depth_mm=depth_mm, intrinsics=camera.intrinsics)
        person = finder.find(frame)
        if person is None:
            continue
        truth = joints[i]
        if person.camera_to_world is not None and given is not c2w:
            # the finder solved the frame in its own world (estimated up and floor)
            truth = between_worlds(truth, c2w, person.camera_to_world)
        inv = np.linalg.inv(person.to_world)
        local = truth @ inv[:3, :3].T + inv[:3, 3]
        # A cluster that is not the performer (clutter picked instead) is not a sample.
        if np.hypot(local[0, 0], local[0, 2]) > 0.6:
            continue
        out["points"].append(person.points)
        out["joints"].append(local.astype(np.float32))
        out["visible"].append(visible_joints(joints[i], camera))
        out["frame"].append(int(i))
        out["distance"].append(float(np.hypot(*(c2w[[0, 2], 3] - joints[i, 0, [0, 2]]))))
        out["count"].append(person.count)
    n = len(out["points"])
    view = view_conditions(c2w, posture, extras)
    arrays = {
        "points": np.asarray(out["points"], np.float32).reshape(n, STORED_POINTS, 3),
        "joints": np.asarray(out["joints"], np.float32).reshape(n, NUM_JOINTS, 3),
        "visible": np.asarray(out["visible"], bool).reshape(n, NUM_JOINTS),
        "frame": np.asarray(out["frame"], np.int32),
        "distance": np.asarray(out["distance"], np.float32),
        "count": np.asarray(out["count"], np.int32),
        "attempted": np.array([len(frames)], np.int32),
    }
    arrays.update({k: np.repeat(np.asarray(v)[None], n) for k, v in view.items()})
    return arrays


def view_conditions(camera_to_world: np.ndarray, posture: str, extras) -> dict:
    """One job's VIEW_KEYS (scalars): the camera's pitch and height from its camera_to_world
    (camera +z forward), the rest from the realism extras (None: a plain scene)."""
    c2w = np.asarray(camera_to_world, np.float64)
    pitch = float(np.degrees(np.arcsin(np.clip(c2w[1, 2], -1.0, 1.0))))
    seat = posture == "seated"
    n_boxes = 0 if extras is None else len(extras.boxes) - (2 if seat else 0)
    return {"posture": posture, "hidden_extrinsics": bool(extras is not None and extras.hide_extrinsics),
            "pitch_deg": np.float32(pitch), "camera_height_m": np.float32(c2w[1, 3]),
            "occluder": n_boxes > 0, "bystander": bool(extras is not None and extras.bystander is not None),
            "dressed": bool(extras is not None and extras.outfit is not None)}


# ---------------------------------------------------------------------------- the dataset
def _cache_path(split: str, n_samples: int, seed: int, anny: int = 0, anny_share: float = 0.0,
                realism: bool = False, edge_jump_share: float | None = None, hard_share: float = 0.0,
                knee_up_share: float = 0.0, kick_share: float = 0.0) -> Path:
    fields = {"split": split, "n": n_samples, "seed": seed, "v": 5, "val_subjects": sorted(VAL_SUBJECTS)}
    if hard_share > 0:
        fields.update(hard_share=hard_share)
    if knee_up_share > 0:
        fields.update(knee_up_share=knee_up_share)
    if kick_share > 0:
        fields.update(kick_share=kick_share)
    if edge_jump_share is not None:
        fields.update(edge_jump_share=edge_jump_share)
    if realism or split == "val_real":
        from sim.sensor_realism import REALISM_VERSION

        fields.update(realism=REALISM_VERSION)
    if anny and anny_share > 0:
        fields.update(anny=anny, anny_share=anny_share)
    key = json.dumps(fields, sort_keys=True)
    return CACHE_DIR / f"{split}_{n_samples}_{seed}_{hashlib.sha1(key.encode()).hexdigest()[:8]}.npz"


def generate(split: str, n_samples: int, seed: int = 0, workers: int = 2, cache: bool = True,
             progress: bool = False, anny: int = 0, anny_share: float = 0.0,
             realism: bool = False, edge_jump_share: float | None = None,
             hard_share: float = 0.0, knee_up_share: float = 0.0,
             kick_share: float = 0.0) -> dict[str, np.ndarray]:
    """The samples of a split (cached under .cache/skeleton_data).

    Returns points (S,512,3) float32 person frame, joints (S,22,3) float32 person frame,
    visible (S,22) bool, clip / body / camera (S,) str, subject (S,) int32 (-1 = none),
    closeup (S,) bool, frame (S,) int32, distance (S,) float32 (camera to pelvis, horizontal),
    count (S,) int32 (person points found), the view's conditions (VIEW_KEYS, (S,) each); S <= n_samples (frames where the finder failed are
    dropped; ``failed`` counts them). anny > 0: training jobs take one of ``anny`` on-demand Anny
    phenotypes (``anny_phenotypes``, the train extra) with probability ``anny_share``.
    realism: training jobs as users' sensors see people (module doc; "val_real" always).
    edge_jump_share: the finder leaves depth-edge pixels out of the sample (PreprocessConfig).
    hard_share: the share of realism training jobs weighted toward hard views (``HARD_VIEWS``).
    knee_up_share, kick_share: the shares of realism training jobs raising the knees in turn
    (``knee-up``) and kicking to the front in turn (``kick``)."""
    anny = anny if split == "train" and anny_share > 0 else 0
    realism = realism and split == "train"
    hard_share = hard_share if realism else 0.0
    knee_up_share = knee_up_share if realism else 0.0
    kick_share = kick_share if realism else 0.0
    path = _cache_path(split, n_samples, seed, anny, anny_share, realism, edge_jump_share, hard_share, knee_up_share,
                       kick_share)
    if cache and path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    phenotypes = anny_phenotypes(anny, seed) if anny else None
    jobs = plan_jobs(split, n_samples, seed, anny=phenotypes, anny_share=anny_share, realism=realism,
                     edge_jump_share=edge_jump_share, hard_share=hard_share, knee_up_share=knee_up_share,
                     kick_share=kick_share)
    if phenotypes:
        build_bodies(sorted({j.body for j in jobs if j.body.startswith("anny:")}), progress)
    data = _concat(jobs, run_jobs(run_job, jobs, workers, f"data {split}" if progress else None, chunksize=2),
                   n_samples)
    if cache:
        save_cache(path, data)
    return data


def build_bodies(specs: list[str], progress: bool) -> None:
    """Load the ``anny:`` bodies once here, before the pool forks, so the workers inherit them.
    They come from the body cache: the training commands build them there first
    (models.train.anny_bodies.ensure_built); a body not built is a one-line error."""
    it = specs
    if progress:
        from tqdm import tqdm

        it = tqdm(specs, desc="anny bodies", unit="body")
    for spec in it:
        body_by_name(spec)


def run_jobs(fn, jobs: list, workers: int, progress: str | None = None, chunksize: int = 1) -> list:
    """[fn(job) for job in jobs] on a fork pool of ``workers`` (in order: seeded jobs give the
    same result for any worker count); a progress bar labelled ``progress`` when given."""
    def bar(it):
        if progress is None:
            return it
        from tqdm import tqdm

        return tqdm(it, total=len(jobs), desc=progress, unit="job", mininterval=5.0)

    if workers <= 1:
        return [fn(j) for j in bar(jobs)]
    with mp.get_context("fork").Pool(workers) as pool:
        return list(bar(pool.imap(fn, jobs, chunksize=chunksize)))


def save_cache(path: Path, data: dict[str, np.ndarray]) -> None:
    """Write a dataset cache atomically (a killed run leaves no half-written file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **data)
    tmp.replace(path)


def _concat(jobs: list[Job], results: list[dict], n_samples: int) -> dict[str, np.ndarray]:
    meta = {"clip": [], "body": [], "camera": [], "subject": [], "closeup": []}
    for job, r in zip(jobs, results):
        n = len(r["frame"])
        for key in meta:
            meta[key] += [getattr(job, key)] * n
    data = {k: np.concatenate([r[k] for r in results])[:n_samples] for k in results[0] if k != "attempted"}
    data["clip"] = np.array(meta["clip"][:n_samples])
    data["body"] = np.array(meta["body"][:n_samples])
    data["camera"] = np.array(meta["camera"][:n_samples])
    data["subject"] = np.array(meta["subject"][:n_samples], np.int32)
    data["closeup"] = np.array(meta["closeup"][:n_samples], bool)
    data["failed"] = np.array(sum(int(r["attempted"][0]) - len(r["frame"]) for r in results), np.int64)
    return data


def mirror(points: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mirror augmentation in the person frame: x -> -x, left and right joints swapped.
    points (..., N, 3), joints (..., 22, 3). The camera stays toward +z, so it is a valid view."""
    flip = np.array([-1.0, 1.0, 1.0], np.float32)
    return points * flip, (joints * flip)[..., LEFT_RIGHT_SWAP, :]


def describe(data: dict[str, np.ndarray]) -> dict:
    """Counts for the model card."""
    bodies = np.unique(data["body"]).tolist()
    return {"samples": int(len(data["points"])), "clips": int(len(np.unique(data["clip"]))),
            "bodies": sorted(b for b in bodies if not b.startswith("anny:")),
            "anny_phenotypes": sum(b.startswith("anny:") for b in bodies),
            "anny_samples": int(np.char.startswith(data["body"].astype(str), "anny:").sum()),
            "subjects": sorted(int(s) for s in np.unique(data["subject"])),
            "cameras": {c: int((data["camera"] == c).sum()) for c in np.unique(data["camera"])},
            "closeups": int(data["closeup"].sum()), "dropped_frames": int(data.get("failed", 0)),
            "distance_m": [round(float(data["distance"].min()), 2), round(float(data["distance"].max()), 2)]}


__all__ = ["Clip", "Job", "list_clips", "clip_motion", "job_motion", "body_by_name", "split_clips", "split_bodies",
           "plan_jobs", "anny_phenotypes", "build_bodies", "run_job", "run_jobs", "save_cache", "random_view",
           "generate", "mirror", "describe", "grounded_joints", "visible_joints", "view_conditions", "VAL_SUBJECTS",
           "VIEW_KEYS",
           "SPLITS", "CAMERAS", "STORED_POINTS"]
