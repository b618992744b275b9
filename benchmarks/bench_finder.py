"""Frames with the performer in view and no skeleton, over camera heights, pitches and floors.

Run: .venv/bin/python benchmarks/bench_finder.py [--quick] [--json FILE] [--workers 2]

A held-out test set of synthetic sessions (held-out CMU subjects on held-out bodies, as
``sim.skeleton_data`` splits them), cached under ``.cache/finder_bench``: the OAK-D at heights
{0.5, 0.9, 1.3, 1.8, 2.5} m and pitches {-45, -25, -10, 0, +20} degrees (negative looks down),
with the floor seen and with a floor the sensor does not return (``--floor none``), the performer
moving on the spot, seated on a chair, crouching, or walking across the view, from the front,
back, side or at an angle; plus upper-body close-ups (0.8-1.1 m, seated or standing). The
distance of each view is the one (0.8-3.5 m) that shows the most joints; a view that shows
fewer than 8 of the 22 joints is left out (the performer cannot be in view). ~2 s at 15 fps
each.

Every session hides its extrinsics (``--hide-extrinsics``: identity camera_to_world, as a real
user's camera) and is replayed through the shipped skeleton stage (a fresh
``models.skeleton.runtime.SkeletonStage`` per session). Per frame: the performer is in view when
>= 8 true joints project into the image in front of the camera (beyond the sensor's minimum
range); a miss is a frame in view without a skeleton. Where a skeleton comes out: PA-MPJPE
(frame-invariant) and, when the skeleton says which camera_to_world it was solved in, MPJPE after
root alignment with the truth moved into that frame through the camera, and "elsewhere": frames
whose skeleton's pelvis is over 0.5 m from the performer's there (on something else). Timing: the finder
(``PersonFinder.find``) and the whole stage (``SkeletonStage.estimate``), median and p95 per frame.

Prints tables per height, pitch, floor condition, posture and framing, and a height x pitch
grid of misses; ``--json FILE`` writes everything (per session too).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from live.core import assets  # noqa: E402
from live.core.depth import between_worlds  # noqa: E402
from live.core.report import percentiles  # noqa: E402

HEIGHTS = (0.5, 0.9, 1.3, 1.8, 2.5)
PITCHES = (-45, -25, -10, 0, 20)  # degrees, negative looks down
FLOORS = ("seen", "none")
DISTANCES = (0.8, 1.0, 1.3, 1.7, 2.2, 2.8, 3.5)
CLOSE_DISTANCES = (0.8, 1.1)
CLOSE_HEIGHTS = (0.9, 1.3)
CLOSE_PITCHES = (-25, -10, 0, 20)
#: Held-out clips (subjects 7, 8, 12, 16; checked against sim.skeleton_data's split).
CLIPS = ("mb_08_07.bvh", "mb_12_03.bvh", "cc_007_04.bvh", "mb_16_31.bvh", "mb_08_11.bvh", "mb_16_58.bvh")
FPS = 15.0
SECONDS = 2.0
START_S = 0.3
IN_VIEW_JOINTS = 8
#: A skeleton whose pelvis is farther than this from the performer's is on something else.
ELSEWHERE_M = 0.5
FLOOR_IN_VIEW_SHARE = 0.05  # of the image: below it the floor is out of frame
CAMERA = "oak-d"
BENCH_VERSION = 1  # bump to regenerate the cached sessions
CACHE = assets.cache_dir("finder_bench")


@dataclass(frozen=True)
class Spec:
    """One session of the test set (both floor conditions share everything else)."""

    clip: str
    body: str
    posture: str  # sim.postures: in-place, seated, crouching, clip (walking across)
    framing: str  # full, close-up, walking
    height: float
    pitch: int  # degrees, negative looks down
    yaw: float  # degrees around the performer, 0 = in front
    distance: float
    floor: str
    seed: int
    start_s: float = START_S
    seconds: float = SECONDS
    fps: float = FPS

    @property
    def key(self) -> str:
        text = json.dumps({**asdict(self), "v": BENCH_VERSION, "camera": CAMERA}, sort_keys=True)
        return hashlib.sha1(text.encode()).hexdigest()[:16]

    @property
    def path(self) -> Path:
        return CACHE / f"{self.key}.mcap"


# ------------------------------------------------------------------------- the test set
def held_out() -> tuple[list[str], list[str]]:
    """(clips, bodies) of the held-out split, checked: a training clip here would be an error."""
    from live.body.library import list_presets
    from sim.skeleton_data import list_clips, split_bodies, split_clips

    val = {c.file for c in split_clips(list_clips(), "val")}
    clips = [c for c in CLIPS if c in val]
    if len(clips) != len(CLIPS):
        raise SystemExit(f"bench_finder: not held out (or missing): {sorted(set(CLIPS) - val)}")
    return clips, split_bodies(list_presets(), "val")


def _project(joints: np.ndarray, c2w: np.ndarray, preset) -> np.ndarray:
    """(..., 22) bool: joints (..., 22, 3) world in front (beyond min range) and in the image."""
    cam = (joints - c2w[:3, 3]) @ c2w[:3, :3]
    z = np.maximum(cam[..., 2], 1e-6)
    u = cam[..., 0] / z * preset.fx + preset.cx
    v = cam[..., 1] / z * preset.fy + preset.cy
    return (cam[..., 2] > preset.min_range_m) & (u >= 0) & (u < preset.width) & (v >= 0) & (v < preset.height)


def _camera(distance: float, height: float, yaw_deg: float, pitch_deg: float) -> np.ndarray:
    from sim.depth_camera import look_at_camera

    return look_at_camera(distance, height, np.radians(yaw_deg), -np.radians(pitch_deg), target=(0.0, 1.0, 0.0))


def _window_joints(clip: str, body: str, posture: str) -> np.ndarray:
    """The true joints (T, 22, 3) of the rendered window, as ``livecap synth`` poses them."""
    from live.motion.cleaning import trim_bind_pose
    from sim.skeleton_data import body_by_name, clip_motion
    from sim.synth import SyntheticScene

    scene = SyntheticScene.build(trim_bind_pose(clip_motion(clip)), body_by_name(body), camera=CAMERA, fps=FPS,
                                 posture=posture)
    first = int(round(START_S * FPS))
    return scene.joints[first:first + int(round(SECONDS * FPS))]


def best_distance(joints: np.ndarray, height: float, pitch: int, yaw: float,
                  distances: tuple[float, ...]) -> tuple[float, float]:
    """(distance, median joints in view) of the candidate showing the most joints (median over
    the window; ties go to the distance nearest 2.2 m, a living room's)."""
    from sim.depth_camera import get_preset

    preset = get_preset(CAMERA)
    best = None
    for d in distances:
        seen = float(np.median(_project(joints, _camera(d, height, yaw, pitch), preset).sum(axis=1)))
        score = (seen, -abs(d - 2.2))
        if best is None or score > best[0]:
            best = (score, d)
    return best[1], best[0][0]


def plan(quick: bool = False) -> tuple[list[Spec], list[tuple[float, int]]]:
    """The sessions of the test set (both floors), deterministic, and the (height, pitch) views
    left out because the performer cannot be in view from there."""
    clips, bodies = held_out()
    cells = [(h, p) for h in HEIGHTS for p in PITCHES]
    kinds = [("in-place", "full"), ("seated|crouching", "full"), ("clip", "walking")]
    if quick:
        cells = [(0.9, -10), (1.3, 0), (2.5, -45), (0.5, 20)]
        kinds = [("in-place", "full")]
    yaws = {"full": (0.0, 180.0, 90.0, -45.0, 135.0, -90.0), "walking": (90.0, -90.0, 60.0),
            "close-up": (0.0, -30.0, 30.0, 180.0)}
    joints_cache: dict[tuple[str, str, str], np.ndarray] = {}

    def joints_of(clip: str, body: str, posture: str) -> np.ndarray:
        if (clip, body, posture) not in joints_cache:
            joints_cache[(clip, body, posture)] = _window_joints(clip, body, posture)
        return joints_cache[(clip, body, posture)]

    # Clip, body, yaw and seated/crouching rotate per kind of view and per cell, so that every
    # kind meets every clip, body and viewing direction.
    views: list[tuple[str, str, str, str, float, int, float, tuple[float, ...]]] = []
    for c, (h, p) in enumerate(cells):
        for k, (posture, framing) in enumerate(kinds):
            if posture == "seated|crouching":
                posture = ("seated", "crouching")[c % 2]
            views.append((clips[(c + 2 * k) % len(clips)], bodies[(c + k) % len(bodies)], posture, framing, h, p,
                          yaws[framing][(c + k) % len(yaws[framing])], DISTANCES))
    close = [(h, p) for h in CLOSE_HEIGHTS for p in CLOSE_PITCHES]
    for c, (h, p) in enumerate(close[:1] if quick else close):
        views.append((clips[(c + 1) % len(clips)], bodies[(c + 2) % len(bodies)], ("seated", "in-place")[c % 2],
                      "close-up", h, p, yaws["close-up"][(c // 2) % len(yaws["close-up"])], CLOSE_DISTANCES))
    specs, skipped = [], []
    for i, (clip, body, posture, framing, h, p, yaw, distances) in enumerate(views):
        d, seen = best_distance(joints_of(clip, body, posture), h, p, yaw, distances)
        if seen < IN_VIEW_JOINTS:
            skipped.append((h, p))  # the performer cannot be in view from there
            continue
        for floor in FLOORS:
            specs.append(Spec(clip, body, posture, framing, h, p, yaw, d, floor, seed=i,
                              seconds=1.0 if quick else SECONDS))
    return specs, skipped


def _generate(spec: Spec) -> str:
    """Write one session (atomically) unless cached; returns its path."""
    from sim.skeleton_data import BVH_DIR
    from sim.synth import CameraPlacement, SynthOptions, synthesize

    if not spec.path.is_file():
        spec.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = spec.path.with_suffix(".tmp.mcap")
        placement = CameraPlacement(spec.distance, spec.height, np.radians(spec.yaw), -np.radians(spec.pitch))
        synthesize(SynthOptions(motion=str(BVH_DIR / spec.clip), body=spec.body, camera=CAMERA, fps=spec.fps,
                                seconds=spec.seconds, start_s=spec.start_s, seed=spec.seed, placement=placement,
                                posture=spec.posture, floor=spec.floor == "seen", hide_extrinsics=True), tmp)
        tmp.replace(spec.path)
    return str(spec.path)


def generate(specs: list[Spec], workers: int) -> None:
    from sim.skeleton_data import run_jobs

    todo = [s for s in specs if not s.path.is_file()]
    if todo:
        print(f"generating {len(todo)} of {len(specs)} sessions into {CACHE} ...", file=sys.stderr)
        run_jobs(_generate, todo, workers, progress="sessions")


# ------------------------------------------------------------------------- replay and score
def floor_share(depth_mm: np.ndarray, intrinsics: np.ndarray, c2w: np.ndarray) -> float:
    """Share of the image that the sensor returns from the floor (world y within 3 cm of 0,
    away from the walls of the room the synthetic session builds around the camera): the floor
    in view or not, occlusion by the performer and the sensor's invalid pixels counted."""
    from live.core.depth import depth_to_points, points_to_world

    pts = points_to_world(depth_to_points(depth_mm, intrinsics), c2w)
    half = max(4.0, float(np.abs(c2w[[0, 2], 3]).max()) + 0.5) - 0.1
    floor = (np.abs(pts[:, 1]) < 0.03) & (np.abs(pts[:, 0]) < half) & (np.abs(pts[:, 2]) < half)
    return float(floor.sum()) / depth_mm.size


def _root_aligned_error(pred: np.ndarray, truth_world: np.ndarray, solved_c2w: np.ndarray,
                        true_c2w: np.ndarray) -> float:
    """MPJPE (m) after root alignment, the truth moved into the frame the skeleton was solved in
    (through the camera: solved_c2w @ inverse(true_c2w))."""
    truth = between_worlds(truth_world, true_c2w, solved_c2w)
    return float(np.linalg.norm((pred - pred[0]) - (truth - truth[0]), axis=-1).mean())


def replay(spec: Spec, stage_factory) -> dict:
    """One session through a fresh stage: per-frame records and the session's summary."""
    from live.core.metrics import pa_mpjpe
    from live.evaluation.skeleton import session_frames
    from live.io.session import SessionReader
    from sim.depth_camera import get_preset

    streams = {s.kind: s for s in SessionReader(spec.path).info.streams}
    true_c2w = np.asarray(streams["gt"].meta["camera_to_world"], np.float64)
    preset = get_preset(streams["depth"].meta.get("camera", CAMERA))
    pairs = session_frames(spec.path)
    share = floor_share(pairs[0][0].depth_mm, pairs[0][0].intrinsics, true_c2w)
    stage = stage_factory()
    find = stage.finder.find
    finder_ms: list[float] = []

    def timed_find(frame, **kwargs):
        # (before the performer has moved, the stage's body check regresses inside the finder)
        t0 = time.perf_counter()
        try:
            return find(frame, **kwargs)
        finally:
            finder_ms.append((time.perf_counter() - t0) * 1e3)

    stage.finder.find = timed_find
    frames = []
    for depth, truth in pairs:
        t0 = time.perf_counter()
        skel = stage.estimate(depth)
        stage_ms = (time.perf_counter() - t0) * 1e3
        gt = np.asarray(truth.joints, np.float64)
        n_view = int(_project(gt, true_c2w, preset).sum())
        rec = {"in_view": n_view >= IN_VIEW_JOINTS, "joints_in_view": n_view, "found": skel is not None,
               "stage_ms": stage_ms, "finder_ms": finder_ms[-1] if finder_ms else None, "first": not frames}
        if skel is not None:
            pred = np.asarray(skel.joints, np.float64)
            if skel.t_ns != depth.t_ns:  # a lagging model: score against the frame it estimates
                gt = np.asarray(next(t for d, t in pairs if d.t_ns == skel.t_ns).joints, np.float64)
            rec["pa_mpjpe_m"] = float(pa_mpjpe(pred, gt))
            solved = getattr(skel, "camera_to_world", None)
            if solved is not None:
                rec["mpjpe_m"] = _root_aligned_error(pred, gt, np.asarray(solved, np.float64), true_c2w)
                truth = between_worlds(gt[0], true_c2w, np.asarray(solved, np.float64))
                rec["pelvis_off_m"] = float(np.linalg.norm(pred[0] - truth))
        frames.append(rec)
    details = getattr(stage, "details", None)  # which up source the finder used (when it says)
    details = (details() if callable(details) else details) or {}
    return {"spec": asdict(spec), "floor_share": round(share, 4),
            "up_source": details.get("up_source"), "frames": frames}


def summarize(frames: list[dict]) -> dict:
    in_view = [f for f in frames if f["in_view"]]
    missed = sum(not f["found"] for f in in_view)
    found = [f for f in frames if f["found"]]
    out = {"frames": len(frames), "in_view": len(in_view), "missed": missed,
           "missed_pct": round(100.0 * missed / len(in_view), 2) if in_view else None,
           "found_out_of_view": sum(f["found"] and not f["in_view"] for f in frames)}
    pa = [f["pa_mpjpe_m"] for f in found if f["in_view"]]
    if pa:
        out["pa_mpjpe_mm"] = round(1000 * float(np.mean(pa)), 1)
    off = [f["pelvis_off_m"] for f in found if f["in_view"] and "pelvis_off_m" in f]
    if off:
        out["elsewhere"] = sum(d > ELSEWHERE_M for d in off)
    mp = [f["mpjpe_m"] for f in found if f["in_view"] and "mpjpe_m" in f]
    if mp:
        out["mpjpe_mm"] = round(1000 * float(np.mean(mp)), 1)
    return out


def floor_condition(session: dict) -> str:
    if session["spec"]["floor"] == "none":
        return "none (sensor)"
    return "seen, in view" if session["floor_share"] >= FLOOR_IN_VIEW_SHARE else "seen, out of frame"


GROUPS = {
    "height (m)": lambda s: s["spec"]["height"],
    "pitch (deg)": lambda s: s["spec"]["pitch"],
    "floor": lambda s: s["spec"]["floor"],
    "floor condition": floor_condition,
    "posture": lambda s: s["spec"]["posture"],
    "framing": lambda s: s["spec"]["framing"],
}


def _timing(frames: list[dict]) -> dict:
    finder = [f["finder_ms"] for f in frames if f["finder_ms"] is not None]
    stage = [f["stage_ms"] for f in frames]
    return {"finder": percentiles(finder, (50, 95), digits=3), "stage": percentiles(stage, (50, 95), digits=3),
            "frames": len(stage)}


def report(sessions: list[dict], skipped: list[tuple[float, int]] = ()) -> dict:
    all_frames = [f for s in sessions for f in s["frames"]]
    groups = {}
    for name, key in GROUPS.items():
        values = sorted({key(s) for s in sessions}, key=lambda v: (isinstance(v, str), v))
        groups[name] = {str(v): summarize([f for s in sessions if key(s) == v for f in s["frames"]])
                        for v in values}
    grid: dict[str, dict | str] = {}
    for h, p in skipped:
        for floor in FLOORS:
            grid.setdefault(f"{floor} {h:g} {p:+d}", "skip")
    for floor in FLOORS:
        for h in HEIGHTS:
            for p in PITCHES:
                frames = [f for s in sessions if s["spec"]["floor"] == floor and s["spec"]["height"] == h
                          and s["spec"]["pitch"] == p for f in s["frames"]]
                if frames:
                    grid[f"{floor} {h:g} {p:+d}"] = summarize(frames)
    sources: dict[str, int] = {}
    for s in sessions:
        sources[str(s["up_source"])] = sources.get(str(s["up_source"]), 0) + 1
    return {"overall": summarize(all_frames), "groups": groups, "grid": grid, "up_sources": sources,
            # A session's first frame sets up what later frames reuse (the floor, caches): apart.
            "timing_ms": {"all": _timing(all_frames), "after_first": _timing([f for f in all_frames if not f["first"]]),
                          "first": _timing([f for f in all_frames if f["first"]])}}


# ------------------------------------------------------------------------- output
def _fmt(v) -> str:
    return "-" if v is None else f"{v:g}" if isinstance(v, float) else str(v)


def format_tables(rep: dict) -> str:
    cols = ("frames", "in_view", "missed", "missed_pct", "elsewhere", "found_out_of_view", "pa_mpjpe_mm", "mpjpe_mm")
    heads = ("frames", "in view", "missed", "missed %", "elsewhere", "found, out of view", "PA-MPJPE mm", "MPJPE mm")
    lines = []

    def table(title: str, rows: dict) -> None:
        lines.append(f"\n| {title} | " + " | ".join(heads) + " |")
        lines.append("|---" * (len(heads) + 1) + "|")
        for label, row in rows.items():
            lines.append(f"| {label} | " + " | ".join(_fmt(row.get(c)) for c in cols) + " |")

    table("all", {"all": rep["overall"]})
    for name, rows in rep["groups"].items():
        table(name, rows)
    lines.append("\nmissed % of frames in view (in view / frames), height x pitch")
    for floor in FLOORS:
        lines.append(f"\n| floor {floor}: height \\ pitch | " + " | ".join(f"{p:+d}" for p in PITCHES) + " |")
        lines.append("|---" * (len(PITCHES) + 1) + "|")
        for h in HEIGHTS:
            cells = []
            for p in PITCHES:
                row = rep["grid"].get(f"{floor} {h:g} {p:+d}")
                cells.append("" if row is None else row if isinstance(row, str)
                             else f"{_fmt(row['missed_pct'])} ({row['in_view']}/{row['frames']})")
            lines.append(f"| {h:g} m | " + " | ".join(cells) + " |")
    lines.append("(skip: the performer cannot be in view from there; empty: not in this run)")
    lines.append(f"\nup source per session: {rep['up_sources']}")
    lines.append("\n| time per frame (ms) | frames | finder p50 | finder p95 | stage p50 | stage p95 |")
    lines.append("|---|---|---|---|---|---|")
    for label, key in (("all frames", "all"), ("after each session's first", "after_first"),
                       ("first frames", "first")):
        t = rep["timing_ms"][key]
        lines.append(f"| {label} | {t['frames']} | {t['finder']['p50']:.2f} | {t['finder']['p95']:.2f} | "
                     f"{t['stage']['p50']:.2f} | {t['stage']['p95']:.2f} |")
    return "\n".join(lines)


def _revision() -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def make_stage(args: argparse.Namespace):
    """The stage under test. ``--temporal`` attaches that temporal model whatever regressor it was
    trained behind: the measurement that decides whether it may run behind this one."""
    from models.skeleton.runtime import SkeletonStage
    from models.skeleton.temporal import TemporalRefiner

    if args.temporal is None:
        return SkeletonStage(args.model, threads=args.threads)
    stage = SkeletonStage(args.model, threads=args.threads, temporal=False, filter=False)
    stage.temporal = TemporalRefiner(args.temporal, args.threads)
    stage.lag_s = stage.temporal.lag_s
    return stage


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="a small subset (4 views, 1 s each, and one close-up)")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the results as JSON")
    p.add_argument("--workers", type=int, default=2, help="processes generating the sessions (default 2)")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads of the stage (default 1)")
    p.add_argument("--model", type=Path, default=None, metavar="ONNX",
                   help="the skeleton regressor (default: the shipped one)")
    p.add_argument("--temporal", type=Path, default=None, metavar="ONNX",
                   help="the temporal model behind it, even one trained behind another regressor "
                        "(default: the shipped one when it matches the regressor)")
    p.add_argument("--label", default=None, help="a name for this run in the output (default: the git revision)")
    args = p.parse_args(argv)
    if args.workers < 1 or args.threads < 1:
        p.error("--workers and --threads are >= 1")
    specs, skipped = plan(args.quick)
    generate(specs, args.workers)
    # Warm-up (ONNX sessions, caches): not timed.
    replay(specs[0], lambda: make_stage(args))
    sessions = []
    for i, spec in enumerate(specs):
        sessions.append(replay(spec, lambda: make_stage(args)))
        print(f"\rreplayed {i + 1}/{len(specs)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    rep = report(sessions, skipped)
    rev = args.label or _revision()
    print(f"{len(specs)} sessions, held-out clips and bodies, extrinsics hidden, {CAMERA} at {FPS:g} fps "
          f"(revision {rev})")
    print(format_tables(rep))
    if args.json is not None:
        args.json.write_text(json.dumps({"revision": rev, "quick": args.quick, "in_view_joints": IN_VIEW_JOINTS,
                                         "skipped_views": skipped,
                                         **rep, "sessions": [{k: v for k, v in s.items() if k != "frames"}
                                                             | {"summary": summarize(s["frames"])}
                                                             for s in sessions]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
