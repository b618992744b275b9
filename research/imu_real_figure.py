"""A real suit recording solved to a skeleton (docs/imu.md, docs/img/imu_real_gait.png):

    python -m research.imu_real_figure [--recording ../shared/data/real_imu/ximu3_lower_body] [--out PATH]

The x-IMU3 lower-body take (seven sensors: pelvis, thighs, shanks, feet; it starts standing still,
then walks, turns and walks back) goes through ``livecap import ximu3`` (live.imu.importing: the
calibration from the take's hold and its walking) and the suit-only stage
(live.imu.stage.ImuSkeletonStage: feet on the floor by foot contacts), exactly as ``livecap
replay`` runs it. Drawn: side views of the legs through a stretch of walking (the pelvis's
facing to the right, the floor at y = 0) and both feet's heights and knee angles over the take.
Printed: the plausibility checks ``gait_checks`` makes (feet alternate, no foot below the floor,
knees bend forward), which tests/test_imu_import.py asserts too.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.skeleton import BONES
from live.core.skeleton import JOINT_INDEX as J

DEFAULT_RECORDING = assets.shared_data_dir() / "real_imu" / "ximu3_lower_body"
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "imu_real_gait.png"
LEGS = [(p, c) for p, c in BONES if c in {J[f"{s}_{n}"] for s in ("left", "right")
                                           for n in ("hip", "knee", "ankle", "foot")}]
SIDE_COLOURS = {"left": (200, 110, 30), "right": (40, 60, 210)}


def solve_recording(recording: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t (T,) seconds, joints (T, 22, 3)) of the take through import + replay (IMU only)."""
    from live.imu.importing import import_session
    from live.imu.stage import build_stages
    from live.pipeline.runner import Pipeline
    from sim.replay import ReplaySource

    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "take.mcap"
        import_session("ximu3", [recording], session)
        source = ReplaySource(session)
        stages = build_stages("imu", stream_meta=source.streams()[0].meta)
        rows: list[tuple[int, np.ndarray]] = []
        Pipeline([source], stages, mode="every",
                 on_result=lambda r: rows.append((r.t_ns, np.asarray(r.skeleton.joints, np.float64)))
                 if r.skeleton is not None else None).run(threading.Event())
    t = np.array([a for a, _ in rows], np.float64) / 1e9
    return t - t[0], np.stack([b for _, b in rows])


def _facing(joints: np.ndarray) -> np.ndarray:
    """(T, 3) the pelvis's forward direction (horizontal): up x (left hip - right hip)."""
    lateral = joints[:, J["left_hip"]] - joints[:, J["right_hip"]]
    fwd = np.cross(lateral, [0.0, 1.0, 0.0])
    fwd[:, 1] = 0.0
    return fwd / np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-9)


def knee_angles(joints: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(flexion degrees (T,), how far the knee is in front of the hip-ankle line (T,) metres)."""
    h, k, a = (J[f"{side}_{n}"] for n in ("hip", "knee", "ankle"))
    thigh, shank = joints[:, k] - joints[:, h], joints[:, a] - joints[:, k]
    cos = np.sum(thigh * shank, -1) / np.maximum(np.linalg.norm(thigh, axis=-1) * np.linalg.norm(shank, axis=-1), 1e-9)
    front = np.sum((joints[:, k] - 0.5 * (joints[:, h] + joints[:, a])) * _facing(joints), -1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), front


def foot_heights(joints: np.ndarray) -> dict[str, np.ndarray]:
    """{side: (T,) height of that foot's lowest joint (ankle or toes)}."""
    return {s: joints[:, [J[f"{s}_ankle"], J[f"{s}_foot"]], 1].min(axis=1) for s in ("left", "right")}


def gait_checks(t: np.ndarray, joints: np.ndarray, *, lift_m: float = 0.05, bent_deg: float = 15.0) -> dict:
    """Plausibility of a solved walk: steps (a foot lifted above ``lift_m``, its highest point)
    and whether consecutive steps change feet; the lowest foot joint over the take (the floor
    is y = 0); among frames with a knee bent beyond ``bent_deg``, the share whose knee is in
    front of its hip-ankle line (a knee bends forward)."""
    feet = foot_heights(joints)
    steps: list[tuple[float, str]] = []
    for side, h in feet.items():
        up = h > lift_m
        edges = np.flatnonzero(np.diff(up.astype(int)))
        bounds = np.concatenate([[0], edges + 1, [len(h)]])
        for a, b in zip(bounds[:-1], bounds[1:]):
            if up[a]:
                steps.append((float(t[a + int(np.argmax(h[a:b]))]), side))
    steps.sort()
    changes = [steps[k][1] != steps[k - 1][1] for k in range(1, len(steps))]
    bent, forward = 0, 0
    for side in ("left", "right"):
        angle, front = knee_angles(joints, side)
        sel = angle > bent_deg
        bent += int(sel.sum())
        forward += int((front[sel] > 0).sum())
    lowest = min(float(h.min()) for h in feet.values())
    return {"steps": len(steps), "alternating_share": float(np.mean(changes)) if changes else 0.0,
            "lowest_foot_m": lowest, "knee_bent_frames": bent,
            "knee_forward_share": forward / bent if bent else 0.0}


def _side_view(joints: np.ndarray, frames: list[int], size=(1300, 330)) -> np.ndarray:
    """Stick legs of ``frames`` side by side, each seen from its pelvis's right (forward = right)."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    scale = 260.0
    floor_y = h - 30
    cv2.line(img, (0, floor_y), (w, floor_y), (150, 150, 150), 1)
    fwd = _facing(joints)
    def px(p: np.ndarray, f: int, cx: int) -> tuple[int, int]:
        return int(cx + scale * float((p - joints[f, 0]) @ fwd[f])), int(floor_y - scale * float(p[1]))

    for n, f in enumerate(frames):
        cx = int(60 + n * (w - 120) / max(len(frames) - 1, 1))
        for side in ("right", "left"):  # the far leg first
            for p, c in LEGS:
                if JOINT_INDEX_SIDE.get(c) == side:
                    cv2.line(img, px(joints[f, p], f, cx), px(joints[f, c], f, cx), SIDE_COLOURS[side], 4, cv2.LINE_AA)
        cv2.circle(img, px(joints[f, 0], f, cx), 5, (40, 40, 40), -1, cv2.LINE_AA)
    cv2.putText(img, "walking, seen from the side (forward = right); blue: left leg, red: right leg",
                (10, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (30, 30, 30), 1, cv2.LINE_AA)
    return img


JOINT_INDEX_SIDE = {J[f"{s}_{n}"]: s for s in ("left", "right") for n in ("hip", "knee", "ankle", "foot")}


def _plot(t: np.ndarray, series: dict[str, tuple[np.ndarray, tuple[int, int, int]]], label: str, lo: float,
          hi: float, size=(1300, 220)) -> np.ndarray:
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 60, 20, 28, 30
    cv2.rectangle(img, (left, top), (w - right, h - bottom), (200, 200, 200), 1)

    def xy(x: float, v: float) -> tuple[int, int]:
        return (int(left + (w - left - right) * x / max(t[-1], 1e-9)),
                int(np.clip(top + (h - top - bottom) * (hi - v) / (hi - lo), top, h - bottom)))

    for s in range(int(t[-1]) + 1):
        x = xy(s, lo)[0]
        cv2.putText(img, f"{s}", (x - 4, h - bottom + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (90, 90, 90), 1)
    for v in np.linspace(lo, hi, 3):
        cv2.putText(img, f"{v:g}", (6, xy(0, v)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (90, 90, 90), 1)
    cv2.putText(img, label, (left + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (30, 30, 30), 1, cv2.LINE_AA)
    for values, colour in series.values():
        pts = np.array([xy(a, b) for a, b in zip(t, values)], np.int32)
        cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
    return img


def figure(t: np.ndarray, joints: np.ndarray, out: Path) -> None:
    # A stretch of walking: two seconds from the first step.
    feet = foot_heights(joints)
    moving = np.flatnonzero(np.maximum(feet["left"], feet["right"]) > 0.05)
    start = int(moving[0]) if len(moving) else 0
    frames = [int(i) for i in np.linspace(start, min(start + int(2.0 / np.median(np.diff(t))), len(t) - 1), 12)]
    knees = {s: knee_angles(joints, s)[0] for s in ("left", "right")}
    panels = [_side_view(joints, frames),
              _plot(t, {s: (feet[s], SIDE_COLOURS[s]) for s in feet}, "foot height (m) over the take (s)", 0.0, 0.5),
              _plot(t, {s: (knees[s], SIDE_COLOURS[s]) for s in knees}, "knee flexion (deg)", 0.0, 140.0)]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(panels, axis=0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--recording", type=Path, default=DEFAULT_RECORDING)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    t, joints = solve_recording(args.recording)
    figure(t, joints, args.out)
    print(json.dumps(gait_checks(t, joints), indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
