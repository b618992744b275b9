"""Depth from another renderer: the skeleton stage judged on depth it did not make.

    python -m research.other_renderer [--cases 32] [--frames 16] [--seed 0] [--models A.onnx ...]
        [--lag 2] [--temporal T.onnx ...] [--without-body-check] [--json FILE]
        [--figure FILE (seed 0: docs/img/other_renderer.png)]
        [--replay-check 1]

Held-out content only: CMU clips of the held-out subjects and the held-out bodies
(sim.skeleton_data's "val" split), posed with the product's own posing and skinning
(sim.skeleton_data.grounded_joints, live.body.skinning.lbs), rendered by another renderer
(research.other_renderer_scene: its own rays, rooms of open3d primitives with furniture and a
second person-sized figure, a structured-light and a time-of-flight noise model from the
literature), at 640 x 480 and 320 x 240, cameras 0.6-2.2 m high pitched -35..+15 degrees
(negative: looking down), 1.5-4 m away, any side of the performer. One case = one clip window
of ``--frames`` frames at 30 fps on one body, one sensor, one resolution, with or without its
extrinsics; the cases cycle through every (body, sensor, resolution, extrinsics) combination.

Every case is written as a depth folder (16-bit PNGs in mm + intrinsics.json, docs/conventions.md;
``camera_to_world`` left out when hidden, as a user's folder has it) under
.cache/other_renderer/, read back by the folder reader ``livecap replay`` uses
(sim.depth_folder.DepthFolderSource) and solved by the pipeline's skeleton stage
(models.skeleton.runtime.SkeletonStage, defaults: temporal model on, lag 0), one fresh stage per
case and model; ``--replay-check N`` also runs ``livecap replay FOLDER --model M`` on the first N
cases and compares its skeleton.npz with the in-process joints.

``--seed`` draws other cases from the same held-out subjects and bodies (other clips, rooms,
cameras, noise): the finder's measures were tuned on seeds 1 and 2, and the table of
docs/results.md is seed 0's.

Scores after root alignment (pelvis on pelvis; the truth moved through the camera into the world
each skeleton was solved in, so hidden extrinsics are judged in the stage's own world): MPJPE per
joint group (limbs = elbows, wrists, knees, ankles; torso; head; feet), PA-MPJPE, PCK@10cm, per
body, sensor, resolution and extrinsics. Frames where the stage found nobody are counted
("nobody"), as are skeletons whose pelvis is over 0.5 m from the performer's ("elsewhere": kept
in the scores).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import shlex
import subprocess
import sys
import tempfile
import threading
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.skeleton import BONES, JOINT_INDEX, NUM_JOINTS
from research.other_renderer_scene import RESOLUTIONS, SENSORS, Scene, make_camera, random_room, render

ROOT = Path(__file__).resolve().parents[1]
CACHE = assets.cache_dir("other_renderer")
DEFAULT_FIGURE = ROOT / "docs" / "img" / "other_renderer.png"
PREVIOUS_MODEL = ROOT / ".cache" / "skeleton_ft2_f873253.onnx"
FPS = 30.0
#: Bump when what a case renders changes (keys the cache).
VERSION = 1
GROUPS = {
    "limbs": ("left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_knee", "right_knee",
              "left_ankle", "right_ankle"),
    "torso": ("pelvis", "left_hip", "right_hip", "spine1", "spine2", "spine3", "neck", "left_collar",
              "right_collar", "left_shoulder", "right_shoulder"),
    "head": ("head",),
    "feet": ("left_foot", "right_foot"),
}
GROUP_INDEX = {g: np.array([JOINT_INDEX[n] for n in names]) for g, names in GROUPS.items()}
ELSEWHERE_M = 0.5


@dataclass(frozen=True)
class Case:
    index: int
    clip: str
    body: str
    sensor: str
    width: int
    height: int
    hide_extrinsics: bool
    seed: int

    @property
    def name(self) -> str:
        return f"case{self.index:03d}_{self.sensor[:3]}{self.width}_{self.body}"


def plan_cases(n: int, seed: int = 0) -> list[Case]:
    """``n`` cases cycling through every (held-out body, sensor, resolution, extrinsics hidden)
    combination, each with a random held-out clip and its own seed (deterministic per seed)."""
    from live.body.library import list_presets
    from sim.skeleton_data import list_clips, split_bodies, split_clips

    clips = [c.file for c in split_clips(list_clips(), "val")]
    bodies = split_bodies(list_presets(), "val")
    combos = list(itertools.product(bodies, SENSORS, RESOLUTIONS, (False, True)))
    rng = np.random.default_rng([seed, 2026])
    order = rng.permutation(len(combos))
    cases = []
    for i in range(n):
        body, sensor, (w, h), hide = combos[order[i % len(combos)]]
        cases.append(Case(i, clips[int(rng.integers(len(clips)))], body, sensor, w, h, hide,
                          int(rng.integers(2**31))))
    return cases


def joints_in_image(joints: np.ndarray, cam) -> np.ndarray:
    """(J,) bool: world joints (J, 3) in front of ``cam`` and inside its image."""
    c2w = cam.camera_to_world
    p = (np.asarray(joints, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    z = np.maximum(p[:, 2], 1e-6)
    u, v = p[:, 0] / z * cam.fx + cam.cx, p[:, 1] / z * cam.fy + cam.cy
    return (p[:, 2] > 0.3) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)


def place_camera(case: Case, joints: np.ndarray, rng: np.random.Generator):
    """(camera, height, pitch deg, distance): drawn until at least 19 of the 22 joints of the
    window's middle frame are in the image (a performer the camera frames, not always whole)."""
    mid = joints[len(joints) // 2]
    for _ in range(500):
        height, pitch = rng.uniform(0.6, 2.2), np.radians(rng.uniform(-35.0, 15.0))
        distance, around = rng.uniform(1.5, 4.0), rng.uniform(-np.pi, np.pi)
        position = np.array([np.sin(around) * distance, height, np.cos(around) * distance])
        yaw = around + np.pi + rng.uniform(-0.12, 0.12)  # toward the performer, give or take 7 deg
        cam = make_camera(case.sensor, case.width, case.height, position, yaw, pitch)
        if joints_in_image(mid, cam).sum() >= NUM_JOINTS - 3:
            return cam, height, float(np.degrees(pitch)), distance
    raise RuntimeError(f"{case.name}: no camera placement frames the performer")


def render_case(case: Case, frames: int) -> dict:
    """Render a case: depth (T, H, W) uint16 mm, truth joints (T, 22, 3) world, camera_to_world,
    intrinsics, and what the scene holds."""
    from live.body.skinning import lbs
    from live.motion.cleaning import trim_bind_pose
    from live.motion.clips import resample
    from sim.skeleton_data import body_by_name, clip_motion, grounded_joints

    rng = np.random.default_rng(case.seed)
    motion = resample(trim_bind_pose(clip_motion(case.clip)), FPS)
    body = body_by_name(case.body)
    root, joints = grounded_joints(motion, body)
    start = int(rng.integers(0, max(1, len(root) - frames + 1)))
    idx = np.arange(start, min(start + frames, len(root)))
    shift = joints[idx, 0].mean(axis=0) * [1.0, 0.0, 1.0]  # the window's centre to the origin
    root, joints = root - shift, joints - shift
    cam, height, pitch, distance = place_camera(case, joints[idx], rng)
    room = random_room(rng, cam.camera_to_world[[0, 2], 3])
    body_albedo = float(rng.uniform(0.25, 0.8))  # skin and clothes, dark to light
    faces = np.asarray(body.faces, np.int32)
    depth = []
    for i in idx:
        vertices = lbs(body.vertices, body.weights, body.rest_joints, motion.rotations[i], root[i])[0]
        scene = Scene([*room.meshes, (vertices, faces)], [*room.albedo, body_albedo])
        depth.append(render(case.sensor, scene, cam, rng))
    return {"depth": np.asarray(depth, np.uint16), "joints": joints[idx].astype(np.float64),
            "camera_to_world": cam.camera_to_world, "intrinsics": cam.intrinsics,
            "camera": {"height_m": round(height, 2), "pitch_deg": round(pitch, 1), "distance_m": round(distance, 2)},
            "room": list(room.items)}


def case_key(case: Case, frames: int) -> str:
    fields = json.dumps({**asdict(case), "frames": frames, "v": VERSION}, sort_keys=True)
    return hashlib.sha1(fields.encode()).hexdigest()[:10]


def write_folder(folder: Path, case: Case, data: dict) -> None:
    """The case as a depth folder (docs/conventions.md): PNGs and intrinsics.json, the extrinsics
    only when the case gives them."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(data["depth"]):
        cv2.imwrite(str(folder / f"{i:05d}.png"), img)
    k = data["intrinsics"]
    meta = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "width": case.width,
            "height": case.height, "fps": FPS}
    if not case.hide_extrinsics:
        meta["camera_to_world"] = np.asarray(data["camera_to_world"]).tolist()
    (folder / "intrinsics.json").write_text(json.dumps(meta, indent=1) + "\n")


def load_case(case: Case, frames: int, cache: Path = CACHE) -> tuple[dict, Path]:
    """(the rendered case, its depth folder), rendered once and cached."""
    key = case_key(case, frames)
    path, folder = cache / f"{case.name}_{key}.npz", cache / "folders" / f"{case.name}_{key}"
    if not path.is_file() or not (folder / "intrinsics.json").is_file():
        data = render_case(case, frames)
        write_folder(folder, case, data)
        cache.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, depth=data["depth"], joints=data["joints"], camera_to_world=data["camera_to_world"],
                            intrinsics=data["intrinsics"], meta=json.dumps({"camera": data["camera"], "room": data["room"]}))
        tmp.replace(path)
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data.update(json.loads(str(data.pop("meta"))))
    return data, folder


def folder_frames(folder: Path) -> list:
    """The DepthFrames ``livecap replay FOLDER`` would feed the pipeline."""
    from sim.depth_folder import DepthFolderSource

    frames: list = []
    DepthFolderSource(folder).run(frames.append, threading.Event())
    return frames


def solve(frames: list, truth: np.ndarray, true_c2w: np.ndarray, model: Path, **stage_options) -> dict:
    """One fresh skeleton stage over a case's frames: pred (T, 22, 3) (NaN where none), the
    truth in the world each skeleton was solved in (T, 22, 3), solved camera_to_world (T, 4, 4)."""
    from live.core.depth import between_worlds
    from models.skeleton.runtime import SkeletonStage

    stage = SkeletonStage(model, **stage_options)
    at = {f.t_ns: i for i, f in enumerate(frames)}
    pred = np.full((len(frames), NUM_JOINTS, 3), np.nan)
    gt = np.asarray(truth, np.float64).copy()
    solved = np.full((len(frames), 4, 4), np.nan)

    def keep(sk) -> None:
        i = at[sk.t_ns]
        c2w = true_c2w if sk.camera_to_world is None else sk.camera_to_world
        pred[i], gt[i], solved[i] = sk.joints, between_worlds(truth[i], true_c2w, c2w), c2w

    for frame in frames:
        sk = stage.estimate(frame)
        if sk is not None:
            keep(sk)
    for sk in stage.flush():  # a lagging model's last skeletons
        keep(sk)
    return {"pred": pred, "gt": gt, "solved_c2w": solved, "up_error_deg": up_error_deg(solved, true_c2w),
            "counters": stage.counters}


def up_error_deg(solved_c2w: np.ndarray, true_c2w: np.ndarray) -> np.ndarray:
    """(T,) angle (degrees) between the up each frame was solved in and the true up, both in the
    camera's axes (0 when the extrinsics were given; NaN for frames without a skeleton)."""
    true_up = np.asarray(true_c2w, np.float64)[1, :3]  # world +y in camera axes: row 1 of the rotation
    up = np.asarray(solved_c2w, np.float64)[:, 1, :3]
    cos = up @ true_up / np.maximum(np.linalg.norm(up, axis=-1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def score(pred: np.ndarray, gt: np.ndarray, up_error: np.ndarray | None = None) -> dict:
    """Metrics of frames (T, 22, 3) with NaN rows for frames without a skeleton (counted); ``up_error``
    (T,) degrees: how many frames were solved in a world tilted over 10 degrees from the true one."""
    from live.core.metrics import procrustes_align

    found = np.isfinite(pred).all(axis=(1, 2))
    out: dict = {"frames": int(len(pred)), "nobody": int((~found).sum())}
    p, g = pred[found], gt[found]
    there = np.linalg.norm(p[:, 0] - g[:, 0], axis=-1) <= ELSEWHERE_M
    out["elsewhere"] = int((~there).sum())
    if up_error is not None:
        out["up_off_10deg"] = int((np.asarray(up_error)[found] > 10.0).sum())
    if not len(p):
        return out
    err = np.linalg.norm((p - p[:, :1]) - (g - g[:, :1]), axis=-1)
    pa = np.linalg.norm(procrustes_align(p, g) - g, axis=-1)
    out["mpjpe_mm"] = round(1000 * float(err.mean()), 1)
    out.update({f"{name}_mm": round(1000 * float(err[:, j].mean()), 1) for name, j in GROUP_INDEX.items()})
    out["pa_mpjpe_mm"] = round(1000 * float(pa.mean()), 1)
    out["pa_limbs_mm"] = round(1000 * float(pa[:, GROUP_INDEX["limbs"]].mean()), 1)
    out["pck_10cm"] = round(float((err < 0.1).mean()), 3)
    if there.any():  # the regressor where the stage is on the performer
        out["on_performer_mpjpe_mm"] = round(1000 * float(err[there].mean()), 1)
        out["on_performer_limbs_mm"] = round(1000 * float(err[there][:, GROUP_INDEX["limbs"]].mean()), 1)
    right = there & (np.asarray(up_error)[found] <= 10.0) if up_error is not None else there
    if right.any():  # ... and solved in a world within 10 degrees of upright: the regressor's own share
        out["found_right_frames"] = int(right.sum())
        out["found_right_mpjpe_mm"] = round(1000 * float(err[right].mean()), 1)
        out["found_right_limbs_mm"] = round(1000 * float(err[right][:, GROUP_INDEX["limbs"]].mean()), 1)
    return out


def summarise(cases: list[Case], solved: list[dict]) -> dict:
    """{group label: score} over all cases and per body, sensor, resolution and extrinsics."""
    keys = {"all": lambda c: "all", "body": lambda c: c.body, "sensor": lambda c: c.sensor,
            "resolution": lambda c: f"{c.width}x{c.height}",
            "extrinsics": lambda c: "hidden" if c.hide_extrinsics else "given"}
    out = {}
    for kind, key in keys.items():
        for label in sorted({key(c) for c in cases}):
            sel = [s for c, s in zip(cases, solved) if key(c) == label]
            name = label if kind == "all" else f"{kind}:{label}"
            out[name] = score(*(np.concatenate([s[k] for s in sel]) for k in ("pred", "gt", "up_error_deg")))
    return out


def replay_check(folder: Path, model: Path, pred: np.ndarray, lag: int = 0) -> float:
    """Max |joint difference| (m) between ``livecap replay FOLDER --model M [--lag L]`` and the
    in-process stage on the frames both solved (the public command runs the same stage)."""
    from live.io.results import read_skeleton

    with tempfile.TemporaryDirectory() as tmp:
        cmd = [str(Path(sys.executable).with_name("livecap")), "replay", str(folder), "--out", tmp,
               "--model", str(model), "--quiet"] + (["--lag", str(lag)] if lag else [])
        subprocess.run(cmd, check=True, capture_output=True, timeout=600)
        res = read_skeleton(Path(tmp) / "skeleton.npz")
    period = 1e9 / FPS
    idx = np.rint(res.t_ns / period).astype(int)
    found = np.isfinite(pred).all(axis=(1, 2))
    if set(idx.tolist()) != set(np.flatnonzero(found).tolist()):
        return float("inf")
    return float(np.abs(res.joints - pred[idx]).max()) if len(idx) else 0.0


# ---------------------------------------------------------------------------- figure
def project(joints: np.ndarray, c2w: np.ndarray, k: np.ndarray) -> np.ndarray:
    p = (np.asarray(joints, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    z = np.maximum(p[:, 2], 1e-3)
    return np.stack([p[:, 0] / z * k[0, 0] + k[0, 2], p[:, 1] / z * k[1, 1] + k[1, 2]], axis=-1)


def figure_tile(case: Case, data: dict, result: dict, i: int, tile=(400, 300)) -> np.ndarray:
    """Frame i of a case: depth in turbo (black: no depth), the true skeleton in white and the
    stage's in colour (limbs red), captioned with the scene and the frame's limb error."""
    depth = data["depth"][i]
    img = cv2.applyColorMap(np.clip(depth / 5000.0 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[depth == 0] = 0
    s = tile[0] / case.width
    img = cv2.resize(img, tile, interpolation=cv2.INTER_NEAREST)
    k = data["intrinsics"]
    true_px = project(data["joints"][i], data["camera_to_world"], k) * s
    for a, b in BONES:
        cv2.line(img, tuple(map(int, true_px[a])), tuple(map(int, true_px[b])), (255, 255, 255), 2, cv2.LINE_AA)
    found = np.isfinite(result["pred"][i]).all()
    if found:
        px = project(result["pred"][i], result["solved_c2w"][i], k) * s
        for a, b in BONES:
            colour = (0, 0, 255) if a in GROUP_INDEX["limbs"] or b in GROUP_INDEX["limbs"] else (0, 200, 0)
            cv2.line(img, tuple(map(int, px[a])), tuple(map(int, px[b])), colour, 2, cv2.LINE_AA)
    cam = data["camera"]
    lines = [f"{case.sensor} {case.width}x{case.height} {case.body}",
             f"{cam['distance_m']} m, {cam['height_m']} m high, pitch {cam['pitch_deg']:+.0f} deg"
             + (", no extrinsics" if case.hide_extrinsics else ""),
             ", ".join(r for r in data["room"] if not r.startswith("wall")),
             "nobody found" if not found else
             f"limbs {score(result['pred'][i:i + 1], result['gt'][i:i + 1]).get('limbs_mm')} mm (root aligned)"]
    for j, text in enumerate(lines):
        cv2.putText(img, text, (5, 15 + 15 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def draw_figure(out: Path, picks: list[tuple[Case, dict, dict]]) -> None:
    tiles = [figure_tile(c, d, r, len(d["depth"]) // 2) for c, d, r in picks]
    while len(tiles) % 3:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.vstack([np.hstack(tiles[r:r + 3]) for r in range(0, len(tiles), 3)])
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), grid)


# ---------------------------------------------------------------------------- report
CELL = ("mpjpe_mm", "limbs_mm", "torso_mm", "head_mm", "pa_mpjpe_mm", "pck_10cm", "found_right_mpjpe_mm",
        "found_right_limbs_mm")


def table(results: dict, models: list[str]) -> str:
    """A markdown table: one row per group, the models side by side."""
    rows = ["| cases | frames | nobody | elsewhere | up off > 10 deg | found right | "
            + " | ".join(f"{m}: MPJPE / limbs / torso / head / PA-MPJPE / PCK@10cm; found right: MPJPE / limbs"
                         for m in models) + " |", "|" + "---|" * (6 + len(models))]
    for group, m in results[models[0]].items():
        counts = " | ".join(str(m.get(k, "-")) for k in ("frames", "nobody", "elsewhere", "up_off_10deg",
                                                          "found_right_frames"))
        cells = []
        for name in models:
            got = results[name].get(group, {})
            cells.append(" / ".join(str(got.get(k, "-")) for k in CELL[:6]) + "; "
                         + " / ".join(str(got.get(k, "-")) for k in CELL[6:]))
        rows.append(f"| {group} | {counts} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m research.other_renderer", description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=32, help="cases (32 = each combination once)")
    ap.add_argument("--frames", type=int, default=16, help="consecutive frames per case at 30 fps")
    ap.add_argument("--seed", type=int, default=0,
                    help="which cases (0: the reported ones; others for tuning: other clips, rooms, cameras)")
    ap.add_argument("--models", type=Path, nargs="+", default=None,
                    help="skeleton models (default: the shipped one and .cache/skeleton_ft2_f873253.onnx if present)")
    ap.add_argument("--lag", type=int, default=0, help="the stage's temporal model of this lag (0: online)")
    ap.add_argument("--temporal", type=Path, nargs="+", default=[],
                    help="other temporal models (.onnx) also run behind the first skeleton model, as more rows")
    ap.add_argument("--without-body-check", action="store_true",
                    help="also the first model's stage without its body check, as more rows")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--figure", type=Path, default=None,
                    help="where to draw six cases (default: the docs' figure for seed 0, the cache for tuning seeds)")
    ap.add_argument("--replay-check", type=int, default=1, help="cases also run through `livecap replay`")
    args = ap.parse_args(argv)
    models = args.models or [p for p in (assets.weight("skeleton.onnx"), PREVIOUS_MODEL) if p.is_file()]
    cases = plan_cases(args.cases, args.seed)
    rendered = []
    for case in cases:
        rendered.append(load_case(case, args.frames))
        print(f"rendered {case.name} ({rendered[-1][0]['camera']}, {', '.join(rendered[-1][0]['room'])})", flush=True)
    results: dict = {}
    solved_by: dict = {}
    per_case: dict = {}
    checks: dict = {}
    stage_labels: list[str] = []
    lag = {"lag": args.lag} if args.lag else {}
    for model in models:
        variants = [("stage", model.name, lag),
                    ("per-frame", f"{model.name} per-frame", {"temporal": False, "filter": False})]
        if model == models[0]:
            variants += [("stage", f"{model.name} + {t.parent.name}/{t.name}", {"temporal": t}) for t in args.temporal]
            if args.without_body_check:
                variants.append(("stage", f"{model.name} without the body check",
                                 {"body_check": False, **lag}))
        stage_labels += [label for variant, label, _ in variants if variant == "stage"]
        for variant, label, options in variants:
            solved = [solve(folder_frames(folder), data["joints"], data["camera_to_world"], model, **options)
                      for data, folder in rendered]
            solved_by[label] = solved
            results[label] = summarise(cases, solved) if variant == "stage" else {"all": summarise(cases, solved)["all"]}
            per_case[label] = {c.name: score(s["pred"], s["gt"], s["up_error_deg"]) for c, s in zip(cases, solved)}
        for case, (_, folder), s in list(zip(cases, rendered, solved_by[model.name]))[:args.replay_check]:
            checks[f"{model.name} {case.name}"] = replay_check(folder, model, s["pred"], args.lag)
    print(table(results, stage_labels))
    print(table({k: v for k, v in results.items() if k not in stage_labels}, [f"{m.name} per-frame" for m in models]))
    for name, diff in checks.items():
        print(f"livecap replay vs in-process stage, {name}: max |diff| {diff * 1000:.4f} mm")
    shipped = solved_by[models[0].name]
    picks = [next((i for i, c in enumerate(cases) if c.sensor == s and c.width == w), None)
             for s in SENSORS for w in (640, 320)]
    picks = [i for i in picks if i is not None]
    errors = per_case[models[0].name]
    worst = sorted((i for i in range(len(cases)) if i not in picks), key=lambda i: -errors[cases[i].name].get("mpjpe_mm", 0))
    # The worst case with frames elsewhere (or the worst), then the next worst: when there are any.
    picks += [next((i for i in worst if errors[cases[i].name]["elsewhere"]), worst[0])] if worst else []
    picks += [i for i in worst if i not in picks][:1]
    figure = args.figure or (DEFAULT_FIGURE if args.seed == 0 else CACHE / f"figure_seed{args.seed}.png")
    draw_figure(figure, [(cases[i], rendered[i][0], shipped[i]) for i in picks])
    print(f"wrote {figure}")
    report = {"command": "python -m research.other_renderer " + shlex.join(argv if argv is not None else sys.argv[1:]),
              "cases": [{**asdict(c), **d["camera"], "room": d["room"]} for c, (d, _) in zip(cases, rendered)],
              "results": results, "per_case": per_case,
              "replay_check_max_abs_m": checks}
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return report


if __name__ == "__main__":
    main()
