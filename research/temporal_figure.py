"""The skeleton stage over time, for docs/skeleton.md:
``python -m research.temporal_figure [--out docs/img/temporal_lag.png] [--clip mb_12_01.bvh]``.

A held-out CMU clip on a held-out body, seen by the virtual OAK-D, through the skeleton stage
three ways: the per-frame regressor alone, the online temporal model (the default) and the
lag-2 temporal model (``--lag 2``). Plots one joint's height and forward position against the
ground truth over a few seconds (OpenCV drawing; no plotting library needed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from live.core import assets

BVH_DIR = assets.bvh_dir()
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "temporal_lag.png"  # from the checkout root
COLOURS = {"truth": (40, 40, 40), "per-frame regressor": (80, 160, 240), "online temporal (default)": (200, 120, 40),
           "lag 2 (67 ms later)": (60, 170, 60)}


def stage_tracks(clip: Path, body_name: str, frames: int, seed: int = 0) -> tuple[dict[str, np.ndarray], float]:
    """{name: world joints (T, 22, 3), NaN where there is no skeleton} and the frame rate."""
    from live.body.library import load_body
    from live.evaluation.retarget import prepare_motion
    from models.skeleton.runtime import SkeletonStage
    from sim.synth import SyntheticScene

    motion = prepare_motion(clip, 30.0, frames)
    scene = SyntheticScene.build(motion, load_body(body_name), camera="oak-d", fps=30.0, seed=seed)
    stages = {"per-frame regressor": SkeletonStage(temporal=False, filter=False),
              "online temporal (default)": SkeletonStage(), "lag 2 (67 ms later)": SkeletonStage(lag=2)}
    n = scene.num_frames
    tracks = {"truth": np.asarray(scene.joints, np.float64)}
    tracks.update({name: np.full((n, 22, 3), np.nan) for name in stages})
    index = {}
    for i in range(n):
        t_ns = 1_000_000_000 + int(round(i * 1e9 / 30.0))
        index[t_ns] = i
        frame = scene.depth(i, t_ns)
        for name, stage in stages.items():
            sk = stage.estimate(frame)
            if sk is not None:
                tracks[name][index[sk.t_ns]] = sk.joints
    return tracks, 30.0


def _panel(tracks: dict[str, np.ndarray], joint: int, axis: int, label: str, fps: float, size=(1100, 300)) -> np.ndarray:
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 70, 20, 30, 40
    vals = np.concatenate([t[:, joint, axis] for t in tracks.values()])
    lo, hi = np.nanpercentile(vals, 0.5), np.nanpercentile(vals, 99.5)
    pad = 0.08 * (hi - lo + 1e-6)
    lo, hi = lo - pad, hi + pad
    n = len(next(iter(tracks.values())))

    def xy(i, v):  # clamped to the plot box: a wild per-frame estimate stays inside it
        y = top + (h - top - bottom) * (hi - v) / (hi - lo)
        return int(left + (w - left - right) * i / max(n - 1, 1)), int(np.clip(y, top, h - bottom))

    cv2.rectangle(img, (left, top), (w - right, h - bottom), (200, 200, 200), 1)
    for k in range(int(n / fps) + 1):
        x = xy(k * fps, lo)[0]
        cv2.line(img, (x, h - bottom), (x, h - bottom + 5), (120, 120, 120), 1)
        cv2.putText(img, f"{k} s", (x - 10, h - bottom + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (90, 90, 90), 1)
    for v in np.linspace(lo, hi, 4):
        cv2.putText(img, f"{v:.2f}", (8, xy(0, v)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (90, 90, 90), 1)
    cv2.putText(img, label, (left + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (30, 30, 30), 1, cv2.LINE_AA)
    for name, t in tracks.items():
        v = t[:, joint, axis]
        pts = [xy(i, v[i]) for i in range(n) if np.isfinite(v[i])]
        thick = 3 if name == "truth" else 1 if name.startswith("per-frame") else 2
        if len(pts) > 1:
            cv2.polylines(img, [np.array(pts, np.int32)], False, COLOURS[name], thick, cv2.LINE_AA)
    return img


def temporal_figure(clip: Path, body: str = "adult_male_average", joint: str = "left_wrist", frames: int = 150,
                    seed: int = 0, skip: int = 3) -> np.ndarray:
    """The figure (BGR image); the first ``skip`` frames are left out (CMU takes often start
    with a jump into the pose)."""
    from live.core.metrics import acceleration_error, mpjpe
    from live.core.skeleton import JOINT_NAMES

    tracks, fps = stage_tracks(clip, body, frames, seed)
    tracks = {name: t[skip:] for name, t in tracks.items()}
    j = JOINT_NAMES.index(joint)
    panels = [_panel(tracks, j, 1, f"{joint} height (m)", fps), _panel(tracks, j, 0, f"{joint} x (m)", fps)]
    legend = np.full((95, panels[0].shape[1], 3), 255, np.uint8)
    gt = tracks["truth"]
    for k, (name, colour) in enumerate(COLOURS.items()):
        x, y = 70 + 520 * (k % 2), 20 + 28 * (k // 2)
        cv2.line(legend, (x, y), (x + 30, y), colour, 3)
        text = name
        if name != "truth":
            ok = np.isfinite(tracks[name][:, 0, 0])
            run = np.flatnonzero(ok)
            acc = acceleration_error(tracks[name][run[0]:run[-1] + 1], gt[run[0]:run[-1] + 1]) \
                if ok[run[0]:run[-1] + 1].all() else float("nan")
            text += f": MPJPE {1000 * mpjpe(tracks[name][ok], gt[ok]):.0f} mm, Acc {1000 * acc:.0f} mm/frame^2"
        cv2.putText(legend, text, (x + 38, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (30, 30, 30), 1, cv2.LINE_AA)
    cv2.putText(legend, f"{clip.name} (held-out subject) on {body} (held-out body), virtual OAK-D, 30 fps; "
                "MPJPE and Acc over all 22 joints", (70, 82), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (90, 90, 90), 1,
                cv2.LINE_AA)
    return np.vstack([legend] + panels)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m research.temporal_figure", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--clip", default="mb_12_01.bvh", help="a clip of the shared CMU clips")
    p.add_argument("--body", default="adult_male_average")
    p.add_argument("--joint", default="left_wrist")
    p.add_argument("--frames", type=int, default=150)
    args = p.parse_args(argv)
    img = temporal_figure(BVH_DIR / args.clip, args.body, args.joint, args.frames)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), img)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
