"""Depth on the body, real sensors beside our virtual ones (docs/depth_realism.md).

    python -m research.depth_realism [--out docs/img/depth_realism.png] [--json FILE] [--frames 4]

Real: every frame of ../shared/data/real_depth (Asus Xtion 320x240 structured light, Kinect v2
512x424 time of flight, Kinect v1 640x480 structured light; no labels). The body is the person the
shipped skeleton stage finds: the pixels whose world point falls in the occupancy cells of the
person's sample (``person_mask``). Synthetic: a held-out clip on held-out bodies rendered by
``sim.depth_camera`` with the current noise model through a camera matched to each real one (its
resolution, focal length and range) plus the oak-d preset; the body is found the same way (with
the camera's extrinsics; the renderer's own body mask only checks that derivation).

Statistics per sensor (``body_statistics``): hole ratio on the body, on the inner and outer
silhouette band; |dz| between neighbouring body pixels (mm); the edge profile across the left and
right silhouette edges (holes and flying pixels, those between body and background); the residual
of a local plane fit (5x5 body pixels) against range; the depth quantisation step at range.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import threading
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.frames import DepthFrame
from sim.depth_camera import PRESETS, CameraPreset, NoiseModel, VirtualDepthCamera, look_at_camera

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "depth_realism.png"
GRAD_EDGES_MM = (0, 1, 2, 4, 8, 16, 32, 64, 128, np.inf)  # |dz| histogram bins (mm)
PROFILE_REACH = 8  # edge-profile offsets -REACH..REACH-1 px, 0 = first pixel outside the silhouette
RANGE_BIN_M = 0.5


# ------------------------------------------------------------------ statistics (pure functions)
def silhouette(person: np.ndarray, close_px: int = 2) -> np.ndarray:
    """(H, W) bool: the person's pixels (H, W bool) closed by a disc of close_px and with interior
    holes filled: the body's outline including its pixels without depth."""
    m = person.astype(np.uint8)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * close_px + 1,) * 2)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(m)
    if contours:
        big = max(cv2.contourArea(c) for c in contours)
        keep = [c for c in contours if cv2.contourArea(c) >= 0.02 * big]
        cv2.drawContours(filled, keep, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool)


def _erode(mask: np.ndarray, px: int) -> np.ndarray:
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * px + 1,) * 2)
    return cv2.erode(mask.astype(np.uint8), k, borderValue=0).astype(bool)


def _dilate(mask: np.ndarray, px: int) -> np.ndarray:
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * px + 1,) * 2)
    return cv2.dilate(mask.astype(np.uint8), k).astype(bool)


def hole_ratios(depth: np.ndarray, person: np.ndarray, sil: np.ndarray, band_px: int = 2) -> dict[str, float]:
    """Share of pixels without depth: on the body (the silhouette's person pixels and holes; the
    background seen through it, between arm and trunk, left out), on its inner band (band_px
    inside the outline) and on its outer band (band_px outside)."""
    hole = depth == 0
    body = sil & (person | hole)
    inner = body & ~_erode(sil, band_px)
    outer = _dilate(sil, band_px) & ~sil
    return {"body": _share(hole, body), "inner_band": _share(hole, inner), "outer_band": _share(hole, outer)}


def _share(flag: np.ndarray, where: np.ndarray) -> float:
    n = int(where.sum())
    return float((flag & where).sum() / n) if n else float("nan")


def neighbour_gradients(depth: np.ndarray, body: np.ndarray) -> np.ndarray:
    """|dz| (mm, float64) of every horizontal and vertical pair of body pixels with depth."""
    z = depth.astype(np.float64)
    ok = body & (depth > 0)
    dx = np.abs(np.diff(z, axis=1))[ok[:, 1:] & ok[:, :-1]]
    dy = np.abs(np.diff(z, axis=0))[ok[1:, :] & ok[:-1, :]]
    return np.concatenate([dx, dy])


def gradient_summary(grads: np.ndarray) -> dict:
    """Histogram over GRAD_EDGES_MM (shares), median, p90, share of zeros and of jumps > 50 mm."""
    if len(grads) == 0:
        return {"hist": [float("nan")] * (len(GRAD_EDGES_MM) - 1), "median": float("nan"),
                "p90": float("nan"), "zero": float("nan"), "over_50": float("nan")}
    hist = np.histogram(grads, np.asarray(GRAD_EDGES_MM, np.float64))[0] / len(grads)
    return {"hist": hist.round(4).tolist(), "median": float(np.median(grads)),
            "p90": float(np.percentile(grads, 90)), "zero": float((grads == 0).mean()),
            "over_50": float((grads > 50).mean())}


def edge_profiles(depth: np.ndarray, sil: np.ndarray, min_jump_mm: float = 300.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Depth along rows across the silhouette's left and right edges where the background lies
    at least min_jump_mm behind the body: (P, 2 * PROFILE_REACH) float64, normalised so the body
    is 0 and the background 1, NaN where there is no depth. Offset index PROFILE_REACH is the
    first pixel outside the silhouette; the body level is the median of offsets -6..-3, the
    background's that of +4..+7 (beyond a stereo shadow or a band of flying pixels). Also
    (P,) int: +1 for a right edge (outward = +u), -1 for a left one."""
    h, w = depth.shape
    z = depth.astype(np.float64)
    z[depth == 0] = np.nan
    r = PROFILE_REACH
    out, sides = [], []
    rows, cols = np.nonzero(sil[:, 1:] != sil[:, :-1])
    for y, x in zip(rows, cols, strict=True):
        step = 1 if sil[y, x] else -1  # walking outward: right edge (+1) or left edge (-1)
        first_out = x + 1 if step == 1 else x
        idx = first_out + step * np.arange(-r, r)
        if idx.min() < 0 or idx.max() >= w:
            continue
        line = z[y, idx]
        inside, beyond = line[r - 6:r - 2], line[r + 4:r + 8]
        if np.isnan(inside).all() or np.isnan(beyond).all():
            continue
        zb, zg = np.nanmedian(inside), np.nanmedian(beyond)
        if zg - zb < min_jump_mm or not sil[y, idx[:r]].all() or sil[y, idx[r:]].any():
            continue
        out.append((line - zb) / (zg - zb))
        sides.append(step)
    return np.asarray(out, np.float64).reshape(-1, 2 * r), np.asarray(sides, np.int64)


def profile_summary(profiles: np.ndarray, sides: np.ndarray | None = None) -> dict:
    """Per offset: share of holes, of flying pixels (depth 10-90 % of the way from body to
    background), median normalised depth; and per edge crossing (offsets -2..+2) the mean
    number of flying pixels and of holes, also per side (left / right edges) when given."""
    nan = float("nan")
    if len(profiles) == 0:
        nans = [nan] * (2 * PROFILE_REACH)
        return {"count": 0, "hole": nans, "flying": nans, "median": nans, "flying_per_edge": nan,
                "holes_per_edge": nan, "holes_per_left_edge": nan, "holes_per_right_edge": nan}
    hole = np.isnan(profiles)
    with np.errstate(invalid="ignore"):
        flying = (profiles > 0.1) & (profiles < 0.9)
    med = [float(np.nanmedian(c)) if not np.isnan(c).all() else float("nan") for c in profiles.T]
    near = slice(PROFILE_REACH - 2, PROFILE_REACH + 3)
    per_edge = hole[:, near].sum(1)
    sides = np.zeros(len(profiles), np.int64) if sides is None else np.asarray(sides)

    def side(k: int) -> float:
        return float(per_edge[sides == k].mean()) if (sides == k).any() else nan

    return {"count": len(profiles), "hole": hole.mean(0).round(4).tolist(),
            "flying": flying.mean(0).round(4).tolist(), "median": med,
            "flying_per_edge": float(flying[:, near].sum(1).mean()),
            "holes_per_edge": float(per_edge.mean()), "holes_per_left_edge": side(-1),
            "holes_per_right_edge": side(1)}


def plane_residuals(depth: np.ndarray, body: np.ndarray, win: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(depth of each window (m), residual std (mm)) of a least-squares plane z = a u + b v + c
    over every win x win window whose pixels are all body pixels with depth. On the centred grid
    the plane's terms are orthogonal, so the fit is a few box filters."""
    ok = (body & (depth > 0)).astype(np.float32)
    z = depth.astype(np.float64) * ok
    n = win * win
    c = np.arange(win, dtype=np.float64) - (win - 1) / 2
    ku, kv = np.tile(c, (win, 1)), np.tile(c[:, None], (1, win))
    box = np.ones((win, win), np.float64)

    def corr(img: np.ndarray, k: np.ndarray) -> np.ndarray:
        return cv2.filter2D(img, cv2.CV_64F, k, borderType=cv2.BORDER_CONSTANT)

    full = corr(ok.astype(np.float64), box) > n - 0.5
    s, s2 = corr(z, box), corr(z * z, box)
    su, sv = corr(z, ku), corr(z, kv)
    suu = float((ku * ku).sum())
    ss = s2 - s * s / n - su * su / suu - sv * sv / suu
    ss = np.maximum(ss[full], 0.0)
    return s[full] / n / 1000.0, np.sqrt(ss / (n - 3))


def noise_by_range(zm: np.ndarray, resid: np.ndarray, bin_m: float = RANGE_BIN_M, min_windows: int = 20
                   ) -> list[tuple[float, float, int]]:
    """(bin centre m, median residual std mm, windows) per range bin with enough windows."""
    out = []
    if len(zm) == 0:
        return out
    bins = np.floor(zm / bin_m).astype(int)
    for b in np.unique(bins):
        sel = bins == b
        if sel.sum() >= min_windows:
            out.append(((b + 0.5) * bin_m, float(np.median(resid[sel])), int(sel.sum())))
    return out


def quantisation_step(values_mm: np.ndarray) -> float:
    """The depth step (mm) between the distinct values of a set of pixels at one range: the
    median gap between consecutive distinct values (a quantised sensor leaves most of the
    values in between unused; 1 = millimetre resolution)."""
    u = np.unique(values_mm[values_mm > 0])
    return float(np.median(np.diff(u))) if len(u) > 2 else float("nan")


# ------------------------------------------------------------------ the body of a frame
def person_mask(frame: DepthFrame, cloud, cell_m: float = 0.05, floor_margin_m: float = 0.03) -> np.ndarray:
    """(H, W) bool: pixels with depth whose world point lies in the floor-plane occupancy cells
    (cell_m, grown by one cell) of the person's sample that the skeleton stage found
    (``PersonCloud``: the sample in the person frame, ``to_world``, the ``camera_to_world`` it was
    solved in), between the floor and 10 cm above their top; only the image component holding
    most of them."""
    depth, k = frame.depth_mm, frame.intrinsics
    c2w = np.asarray(cloud.camera_to_world, np.float64)
    sample = cloud.points.astype(np.float64) @ cloud.to_world[:3, :3].T + cloud.to_world[:3, 3]
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    zc = depth.astype(np.float64) / 1000.0
    cam = np.stack([(u - k[0, 2]) / k[0, 0] * zc, (v - k[1, 2]) / k[1, 1] * zc, zc], -1)
    world = cam @ c2w[:3, :3].T + c2w[:3, 3]
    lo = sample[:, [0, 2]].min(0) - 2 * cell_m
    grid = np.zeros(tuple(np.ceil((sample[:, [0, 2]].max(0) + 2 * cell_m - lo) / cell_m).astype(int) + 1), np.uint8)
    ij = np.floor((sample[:, [0, 2]] - lo) / cell_m).astype(int)
    grid[ij[:, 0], ij[:, 1]] = 1
    grid = cv2.dilate(grid, np.ones((3, 3), np.uint8)).astype(bool)
    cij = np.floor((world[..., [0, 2]] - lo) / cell_m).astype(int)
    inside = (cij >= 0).all(-1) & (cij[..., 0] < grid.shape[0]) & (cij[..., 1] < grid.shape[1])
    cell = np.zeros((h, w), bool)
    cell[inside] = grid[cij[inside][:, 0], cij[inside][:, 1]]
    mask = cell & (depth > 0) & (world[..., 1] > floor_margin_m) & (world[..., 1] < sample[:, 1].max() + 0.1)
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if n <= 2:
        return mask
    counts = np.bincount(labels[mask], minlength=n)
    return labels == int(np.argmax(counts))


@dataclass
class SensorStats:
    """Everything measured over one sensor's frames (pooled)."""

    name: str
    kind: str  # "real" or "synthetic"
    resolution: str
    frames: int = 0
    body_pixels: int = 0
    holes: dict = field(default_factory=dict)
    gradients: dict = field(default_factory=dict)
    profile: dict = field(default_factory=dict)
    noise: list = field(default_factory=list)
    median_depth_m: float = float("nan")
    quant_step_mm: float = float("nan")
    mask_iou: float | None = None  # synthetic only: derived body mask against the renderer's

    def row(self) -> dict:
        noise = {f"{c:.2f}": round(s, 1) for c, s, _ in self.noise}
        return {"sensor": self.name, "kind": self.kind, "resolution": self.resolution, "frames": self.frames,
                "body_px": self.body_pixels, "median_depth_m": round(self.median_depth_m, 2),
                **{f"holes_{k}": round(v, 3) for k, v in self.holes.items()},
                "grad_median_mm": self.gradients.get("median"), "grad_p90_mm": self.gradients.get("p90"),
                "grad_zero": round(self.gradients.get("zero", float("nan")), 3),
                "grad_over_50": round(self.gradients.get("over_50", float("nan")), 3),
                "edges": self.profile.get("count"),
                "flying_per_edge": round(self.profile.get("flying_per_edge", float("nan")), 2),
                "holes_per_edge": round(self.profile.get("holes_per_edge", float("nan")), 2),
                "holes_per_left_edge": round(self.profile.get("holes_per_left_edge", float("nan")), 2),
                "holes_per_right_edge": round(self.profile.get("holes_per_right_edge", float("nan")), 2),
                "plane_resid_mm_by_range": noise, "quant_step_mm": self.quant_step_mm,
                "mask_iou": None if self.mask_iou is None else round(self.mask_iou, 3)}


def body_statistics(name: str, kind: str, frames: list[tuple[np.ndarray, np.ndarray]],
                    true_masks: list[np.ndarray] | None = None) -> SensorStats:
    """Pool the statistics of (depth (H, W) uint16 mm, person mask (H, W) bool) frames."""
    h, w = frames[0][0].shape
    st = SensorStats(name, kind, f"{w}x{h}", frames=len(frames))
    holes, grads, profiles, zs, rs, body_z = [], [], [], [], [], []
    ious = []
    for i, (depth, person) in enumerate(frames):
        sil = silhouette(person)
        body = sil & person
        holes.append((hole_ratios(depth, person, sil), int((sil & (person | (depth == 0))).sum())))
        grads.append(neighbour_gradients(depth, body))
        profiles.append(edge_profiles(depth, sil))
        zm, res = plane_residuals(depth, body)
        zs.append(zm)
        rs.append(res)
        body_z.append(depth[body & (depth > 0)])
        if true_masks is not None:
            t = true_masks[i]
            ious.append((t & sil).sum() / max((t | sil).sum(), 1))
    weights = np.array([n for _, n in holes], np.float64)
    st.holes = {k: float(np.average([d[k] for d, _ in holes], weights=weights)) for k in holes[0][0]}
    st.body_pixels = int(sum(len(z) for z in body_z))
    st.gradients = gradient_summary(np.concatenate(grads))
    st.profile = profile_summary(np.concatenate([p for p, _ in profiles]),
                                 np.concatenate([sd for _, sd in profiles]))
    st.noise = noise_by_range(np.concatenate(zs), np.concatenate(rs))
    allz = np.concatenate(body_z)
    st.median_depth_m = float(np.median(allz)) / 1000.0
    near = allz[np.abs(allz.astype(np.float64) - np.median(allz)) < 150]
    st.quant_step_mm = quantisation_step(near)
    st.mask_iou = float(np.mean(ious)) if ious else None
    return st


# ------------------------------------------------------------------ frames: real and synthetic
def real_frames(folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """(depth, person mask) of each frame of a depth folder in which the skeleton stage finds
    someone (the stage runs over the frames in order, as a replay would)."""
    from models.skeleton.runtime import SkeletonStage
    from sim.depth_folder import DepthFolderSource

    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    stage = SkeletonStage()
    out = []
    for frame in frames:
        stage.estimate(frame)
        if stage.last_cloud is not None:
            out.append((frame.depth_mm, person_mask(frame, stage.last_cloud)))
    return out


@dataclass(frozen=True)
class SimScene:
    """Where a virtual camera sees the held-out performer from: horizontal distance range (m)
    to the pelvis, camera height (m), pitch down (rad; None = aimed at a point aim_up metres
    above the pelvis)."""

    preset: CameraPreset
    distance: tuple[float, float]
    height: float
    pitch: float | None = 0.0
    aim_up: float = 0.0


def _scaled(base: str, name: str, width: int, height: int, f: float, **kw) -> CameraPreset:
    """A preset with another image size and focal length; disparity sigma scaled with f (it is
    in pixels of this image)."""
    p = PRESETS[base]
    return dataclasses.replace(p, name=name, width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2,
                               cy=(height - 1) / 2, disparity_sigma_px=p.disparity_sigma_px * f / p.fx, **kw)


#: The virtual sensor closest to each real one that the current noise model can express, posed
#: like the real frames (docs/depth_realism.md): the Xtion is the Kinect v1's PrimeSense design
#: with its image halved (disparity still resolved at 640 px: one more fractional bit at 320);
#: the Kinect v2 is the time-of-flight preset.
SCENES: dict[str, SimScene] = {
    "xtion": SimScene(PRESETS["xtion"], (2.6, 3.4), 1.2),
    "kinect-v2": SimScene(PRESETS["kinect-v2"], (2.2, 2.8), 1.8, None),
    "kinect-v1": SimScene(PRESETS["kinect-v1"], (0.75, 0.95), 1.45, None, 0.55),
    "oak-d": SimScene(PRESETS["oak-d"], (1.5, 4.0), 1.3, None),
}
ROOM_HALF_DEPTH = 4.5
#: Noise models to compare: the default, and one typical of the training scenes' draws
#: (sim.sensor_realism.random_noise): mixed returns at edges, holes in blobs, fewer single holes.
NOISES: dict[str, NoiseModel | None] = {
    "default": None,
    "realism": NoiseModel(dropout=0.003, flying_pixels=0.3, hole_blobs=0.01, hole_blob_px=10),
}
REAL_FOLDERS = {"xtion": "itop_xtion_2frames", "kinect-v2": "panoptic_kinect2_3people",
                "kinect-v1": "pcl_kinect1_upper_body"}


def synthetic_frames(scene: SimScene, count: int, noise: NoiseModel | None = None, seed: int = 0
                     ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """``count`` frames of a held-out clip on the held-out bodies (cycled), camera distance and
    yaw drawn per frame (seeded): ([(depth, person mask from the skeleton stage)], [renderer's
    body masks])."""
    from live.body.library import list_presets, load_body
    from live.body.skinning import lbs
    from live.core.skeleton import pelvis_height
    from live.motion.rig_mapping import load_motion
    from models.skeleton.runtime import SkeletonStage
    from sim.room import Room
    from sim.skeleton_data import list_clips, split_bodies, split_clips

    rng = np.random.default_rng([seed, 26])
    bodies = split_bodies(list_presets(), "val")
    clips = split_clips(list_clips(), "val")
    out, truth = [], []
    for i in range(count):
        clip = clips[int(rng.integers(len(clips)))]
        motion = load_motion(assets.bvh_dir() / clip.file)
        f = int(rng.integers(motion.num_frames))
        body = load_body(bodies[i % len(bodies)])
        root = motion.root[f:f + 1] * (pelvis_height(body.rest_joints) / pelvis_height(motion.rest_joints))
        verts = np.asarray(lbs(body.vertices, body.weights, body.rest_joints, motion.rotations[f:f + 1], root)[0],
                           np.float32)
        # The performer faces a random way near the room's back wall (0.8-2 m in front of it, as
        # in the real frames), the camera in front of them looking at the wall.
        turn = rng.uniform(-np.pi, np.pi)
        c, sn = np.cos(turn), np.sin(turn)
        xz = verts[:, [0, 2]] - root[0, [0, 2]].astype(np.float32)
        behind = float(rng.uniform(0.8, 2.0))
        verts[:, 0] = c * xz[:, 0] + sn * xz[:, 1]
        verts[:, 2] = -sn * xz[:, 0] + c * xz[:, 1] - ROOM_HALF_DEPTH + behind
        target = (0.0, float(root[0, 1]) + scene.aim_up, -ROOM_HALF_DEPTH + behind)
        pose = look_at_camera(float(rng.uniform(*scene.distance)), scene.height, 0.0, scene.pitch, target)
        cam = VirtualDepthCamera(scene.preset, pose, noise=noise, seed=seed * 1000 + i)
        room = Room(width=6.0, depth=2 * ROOM_HALF_DEPTH)
        depth, body_mask = cam.render_with_labels(verts, np.asarray(body.faces, np.int32), room)
        # With its extrinsics: the floor search (open3d RANSAC, threaded) is not bit-repeatable.
        frame = DepthFrame(t_ns=0, sensor=scene.preset.name, depth_mm=depth, intrinsics=cam.intrinsics,
                           camera_to_world=cam.camera_to_world)
        stage = SkeletonStage()  # a fresh stage per frame: frames are unrelated, as the real ones
        stage.estimate(frame)
        if stage.last_cloud is None:
            continue
        person, true_sil = person_mask(frame, stage.last_cloud), silhouette(body_mask)
        if (person & true_sil).sum() < 0.5 * true_sil.sum():
            continue  # the stage took something else for the performer: not a statistic of depth
        out.append((depth, person))
        truth.append(true_sil)
    return out, truth


# ------------------------------------------------------------------ table, figure, command
def markdown_table(stats: list[SensorStats]) -> str:
    """The side-by-side table of docs/depth_realism.md."""
    head = ("| sensor | kind | size | frames | median depth | holes body / inner band / outer band | "
            "\\|dz\\| median / p90 / > 50 mm | flying px per edge | holes per edge (left / right) | "
            "plane residual (mm) by range | step at range |")
    lines = [head, "|" + "---|" * 11]
    for s in stats:
        h, g, p = s.holes, s.gradients, s.profile
        noise = ", ".join(f"{c:.2f} m: {r:.1f}" for c, r, _ in s.noise) or "-"
        lines.append(
            f"| {s.name} | {s.kind} | {s.resolution} | {s.frames} | {s.median_depth_m:.2f} m | "
            f"{h['body']:.1%} / {h['inner_band']:.1%} / {h['outer_band']:.1%} | "
            f"{g['median']:.0f} / {g['p90']:.0f} / {g['over_50']:.1%} | {p['flying_per_edge']:.2f} | "
            f"{p['holes_per_edge']:.1f} ({p['holes_per_left_edge']:.1f} / {p['holes_per_right_edge']:.1f}) | "
            f"{noise} | {s.quant_step_mm:.1f} mm |")
    return "\n".join(lines)


def _colour(depth: np.ndarray, mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The body's bounding box (grown by 15 %) of a depth image, colour-mapped over the body's
    own depth range, holes black, letterboxed into size (w, h)."""
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    gy, gx = int(0.15 * (y1 - y0)) + 2, int(0.15 * (x1 - x0)) + 2
    y0, y1, x0, x1 = max(y0 - gy, 0), min(y1 + gy, depth.shape[0]), max(x0 - gx, 0), min(x1 + gx, depth.shape[1])
    crop = depth[y0:y1, x0:x1].astype(np.float32)
    lo, hi = np.percentile(depth[mask & (depth > 0)], (2, 98))
    t = np.clip((crop - lo + 100) / (hi - lo + 600), 0, 1)
    img = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[crop == 0] = 0
    w, h = size
    k = min(w / img.shape[1], h / img.shape[0])
    img = cv2.resize(img, (max(int(img.shape[1] * k), 1), max(int(img.shape[0] * k), 1)), interpolation=cv2.INTER_NEAREST)
    out = np.full((h, w, 3), 40, np.uint8)
    oy, ox = (h - img.shape[0]) // 2, (w - img.shape[1]) // 2
    out[oy:oy + img.shape[0], ox:ox + img.shape[1]] = img
    return out


_REAL, _SIM = (60, 60, 230), (230, 160, 40)  # BGR: real red, synthetic blue
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _axes(w: int, h: int, title: str) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    img = np.full((h, w, 3), 255, np.uint8)
    box = (40, 24, w - 10, h - 28)
    cv2.rectangle(img, box[:2], box[2:], (0, 0, 0), 1)
    cv2.putText(img, title, (40, 16), _FONT, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return img, box


def _hist_panel(real: SensorStats | None, sim: SensorStats, size: tuple[int, int]) -> np.ndarray:
    img, (x0, y0, x1, y1) = _axes(*size, "|dz| between body neighbours (share per bin)")
    labels = [f"{int(a)}" for a in GRAD_EDGES_MM[:-1]]
    nb = len(labels)
    bw = (x1 - x0) / nb
    for i, lab in enumerate(labels):
        cv2.putText(img, lab, (int(x0 + i * bw + 2), y1 + 14), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        for j, (st, col) in enumerate(((real, _REAL), (sim, _SIM))):
            if st is None:
                continue
            v = st.gradients["hist"][i]
            top = int(y1 - (y1 - y0) * min(v, 1.0))
            xa = int(x0 + i * bw + 2 + j * (bw - 4) / 2)
            cv2.rectangle(img, (xa, top), (int(xa + (bw - 4) / 2) - 1, y1), col, -1)
    cv2.putText(img, "mm >=", (2, y1 + 14), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "1", (x0 - 14, y0 + 10), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _profile_panel(real: SensorStats | None, sim: SensorStats, size: tuple[int, int]) -> np.ndarray:
    img, (x0, y0, x1, y1) = _axes(*size, "edge: holes (thick), flying (thin)")
    n = 2 * PROFILE_REACH
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
    xb = int(x0 + PROFILE_REACH * (x1 - x0) / n)
    cv2.line(img, (xb, y0), (xb, y1), (150, 150, 150), 1)
    cv2.putText(img, "body | outside", (xb - 48, y1 + 14), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    for st, col in ((real, _REAL), (sim, _SIM)):
        if st is None or not st.profile.get("count"):
            continue
        for key, thick in (("hole", 2), ("flying", 1)):
            v = np.nan_to_num(np.asarray(st.profile[key], np.float64))
            pts = np.stack([xs, y1 - (y1 - y0) * v], 1).astype(np.int32)
            cv2.polylines(img, [pts], False, col, thick, cv2.LINE_AA)
    return img


def _noise_panel(real: SensorStats | None, sim: SensorStats, size: tuple[int, int]) -> np.ndarray:
    top = max([r for s in (real, sim) if s is not None for _, r, _ in s.noise] + [1.0]) * 1.15
    img, (x0, y0, x1, y1) = _axes(*size, f"residual 0-{top:.0f} mm, range 0.5-4.5 m")
    for st, col in ((real, _REAL), (sim, _SIM)):
        if st is None:
            continue
        for c, r, _ in st.noise:
            x = int(x0 + (c - 0.5) / 4.0 * (x1 - x0))
            cv2.circle(img, (x, int(y1 - (y1 - y0) * r / top)), 4, col, -1, cv2.LINE_AA)
    return img


def figure(pairs: list[tuple[SensorStats | None, SensorStats, tuple | None, tuple]], out: Path) -> Path:
    """One row per sensor: real body, synthetic body, |dz| histogram, edge profile, noise."""
    tile = (200, 170)
    rows = []
    for real, sim, real_frame, sim_frame in pairs:
        cells = []
        for fr, label in ((real_frame, f"real {real.name if real else ''}"), (sim_frame, f"synthetic {sim.name}")):
            if fr is None:
                cell = np.full((tile[1], tile[0], 3), 40, np.uint8)
                cv2.putText(cell, "no real frames", (40, 90), _FONT, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            else:
                cell = _colour(fr[0], fr[1], tile)
            cv2.putText(cell, label, (4, 14), _FONT, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
            cells.append(cell)
        cells += [_hist_panel(real, sim, (300, tile[1])), _profile_panel(real, sim, (260, tile[1])),
                  _noise_panel(real, sim, (240, tile[1]))]
        rows.append(np.hstack([np.pad(c, ((2, 2), (2, 2), (0, 0)), constant_values=255) for c in cells]))
    legend = np.full((22, rows[0].shape[1], 3), 255, np.uint8)
    cv2.putText(legend, "red: real sensor   blue: our virtual sensor (current noise model); body crops: "
                "turbo over the body's depth, black = no depth", (6, 15), _FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.vstack([legend] + rows))
    return out


def measure(frames: int = 6, seed: int = 0, noise: NoiseModel | None = None, data: Path | None = None
            ) -> list[tuple[SensorStats | None, SensorStats, tuple | None, tuple]]:
    """(real stats or None, synthetic stats, a real frame, a synthetic frame) per sensor."""
    data = assets.shared_data_dir() / "real_depth" if data is None else data
    pairs = []
    for name, scene in SCENES.items():
        real = real_frame = None
        folder = REAL_FOLDERS.get(name)
        if folder is not None and (data / folder).is_dir():
            got = real_frames(data / folder)
            if got:
                real, real_frame = body_statistics(name, "real", got), got[0]
        sim_frames, truth = synthetic_frames(scene, frames, noise, seed)
        if not sim_frames:
            raise RuntimeError(f"the skeleton stage found the performer in none of the {name} frames")
        pairs.append((real, body_statistics(name, "synthetic", sim_frames, truth), real_frame, sim_frames[0]))
    return pairs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.depth_realism", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the figure (PNG)")
    ap.add_argument("--json", type=Path, default=None, help="also write every statistic here")
    ap.add_argument("--frames", type=int, default=6, help="synthetic frames per sensor")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", choices=tuple(NOISES), default="default",
                    help="the virtual sensors' noise: the default model, or with the terms the training "
                         "scenes add (flying pixels, holes in blobs, fewer single-pixel holes)")
    ap.add_argument("--data", type=Path, default=None, help="the real depth folders (default: shared data)")
    args = ap.parse_args(argv)
    if args.frames < 1:
        ap.error("--frames must be >= 1")
    pairs = measure(args.frames, args.seed, noise=NOISES[args.noise], data=args.data)
    stats = [s for real, sim, _, _ in pairs for s in (real, sim) if s is not None]
    print(markdown_table(stats))
    print(f"wrote {figure(pairs, args.out)}")
    if args.json is not None:
        rows = [{**s.row(), "gradient_hist": s.gradients["hist"], "gradient_bins_mm": list(GRAD_EDGES_MM[:-1]),
                 "edge_hole_share": s.profile["hole"], "edge_flying_share": s.profile["flying"]} for s in stats]
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
