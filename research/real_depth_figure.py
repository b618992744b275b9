"""The skeleton stage on real depth from other sensors (docs/img/real_depth.png).

Every frame of the shared real-depth folders (Asus Xtion, Kinect v2, Kinect v1; no extrinsics,
as users have them) through the shipped skeleton stage, each skeleton drawn over its depth image
in the camera it was solved in, with the source of up and the floor in the caption:

    python -m research.real_depth_figure [--out docs/img/real_depth.png]
"""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

import cv2
import numpy as np

from live.core import assets
from live.core.frames import FrameResult
from live.outputs.render import RenderOptions, depth_panel
from models.skeleton.runtime import SkeletonStage
from sim.depth_folder import DepthFolderSource

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "real_depth.png"


def solve_folder(folder: Path) -> list[tuple[FrameResult, str | None]]:
    """Each frame of a depth folder with its skeleton (or none), and where up came from."""
    frames: list = []
    DepthFolderSource(folder, speed=None).run(frames.append, threading.Event())
    stage = SkeletonStage()
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
    args = ap.parse_args(argv)
    panels = []
    for folder in sorted(p for p in args.data.iterdir() if p.is_dir()):
        for result, source in solve_folder(folder):
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
