"""The skeleton stage on real depth from other sensors (docs/img/real_depth.png).

Every frame of the shared real-depth folders (Asus Xtion, Kinect v2, Kinect v1; no extrinsics,
as users have them) through the shipped skeleton stage, each skeleton drawn over its depth image
in the camera it was solved in, with the source of up and the floor in the caption:

    python -m research.real_depth_figure [--out docs/img/real_depth.png] [--model ONNX]

It also prints what can be checked without labels: the share of joints on the body (the depth
at each joint's pixel is a surface just in front of it; ``on_the_body``), upper body and all 22,
and how much the left and right bones' lengths differ (a person is nearly symmetric).
"""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.frames import FrameResult
from live.core.skeleton import JOINT_INDEX
from live.outputs.render import RenderOptions, depth_panel
from models.skeleton.runtime import SkeletonStage
from sim.depth_folder import DepthFolderSource

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "real_depth.png"


UPPER_BODY = [JOINT_INDEX[n] for n in ("spine3", "neck", "head", "left_collar", "right_collar",
                                       "left_shoulder", "right_shoulder")]
#: (left child, right child) of the limb bones compared for symmetry.
LIMB_PAIRS = [(JOINT_INDEX[f"left_{a}"], JOINT_INDEX[f"right_{a}"]) for a in ("knee", "ankle", "elbow", "wrist")]


def on_the_body(joints: np.ndarray, c2w: np.ndarray, frame, reach_m: float = 0.04) -> np.ndarray:
    """(J,) bool: within ``reach_m`` of each joint's pixel the image sees a surface 0-45 cm in
    front of the joint (a joint lies inside the body, behind its surface: up to a shoulder width
    behind it in a profile view) or up to 10 cm behind it (depth noise)."""
    cam = (joints.astype(np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    k = frame.intrinsics
    h, w = frame.depth_mm.shape
    ok = np.zeros(len(joints), bool)
    for j, (x, y, z) in enumerate(cam):
        if z <= 0:
            continue
        u, v = x / z * k[0, 0] + k[0, 2], y / z * k[1, 1] + k[1, 2]
        r = int(np.ceil(reach_m * k[0, 0] / z))
        u0, u1, v0, v1 = int(round(u)) - r, int(round(u)) + r + 1, int(round(v)) - r, int(round(v)) + r + 1
        if u1 <= 0 or v1 <= 0 or u0 >= w or v0 >= h:
            continue
        patch = frame.depth_mm[max(v0, 0):v1, max(u0, 0):u1] * 1e-3
        gap = z - patch[patch > 0]
        ok[j] = bool(np.any((gap > -0.10) & (gap < 0.45)))
    return ok


def asymmetry_mm(joints: np.ndarray) -> float:
    """Mean |left - right| length (mm) of the thigh, shin, upper arm and forearm."""
    from live.core.skeleton import PARENTS

    diffs = [abs(np.linalg.norm(joints[lc] - joints[PARENTS[lc]]) - np.linalg.norm(joints[rc] - joints[PARENTS[rc]]))
             for lc, rc in LIMB_PAIRS]
    return 1000.0 * float(np.mean(diffs))


def solve_folder(folder: Path, model: Path | None = None) -> list[tuple[FrameResult, str | None]]:
    """Each frame of a depth folder with its skeleton (or none), and where up came from."""
    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    stage = SkeletonStage(model)
    out = []
    for frame in frames:
        result = FrameResult(t_ns=frame.t_ns, depth=frame)
        stage.process(result)
        out.append((result, stage.finder.up_source))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--data", type=Path, default=assets.shared_data_dir() / "real_depth")
    ap.add_argument("--model", type=Path, default=None, help="the skeleton regressor (default: the shipped one)")
    args = ap.parse_args(argv)
    panels = []
    for folder in sorted(p for p in args.data.iterdir() if p.is_dir()):
        for result, source in solve_folder(folder, args.model):
            sk = result.skeleton
            if sk is not None:
                ok = on_the_body(sk.joints, sk.camera_to_world, result.depth)
                print(f"{folder.name} t={result.t_ns}: joints on the body {int(ok[UPPER_BODY].sum())}/"
                      f"{len(UPPER_BODY)} upper body, {int(ok.sum())}/22 all; left-right limb lengths "
                      f"differ by {asymmetry_mm(sk.joints):.0f} mm")
            panel = depth_panel(result, RenderOptions(depth_range_m=(0.5, 5.5)), (400, 320))
            found = "skeleton" if result.skeleton is not None else "nobody"
            for k, text in enumerate((folder.name, f"{found}; up from: {source}")):
                cv2.putText(panel, text, (6, 18 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
            panels.append(panel)
    rows = [np.hstack(panels[i:i + 2] + [np.zeros_like(panels[0])] * (2 - len(panels[i:i + 2])))
            for i in range(0, len(panels), 2)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack(rows))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
