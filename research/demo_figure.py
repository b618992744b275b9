"""The README's demo picture: one frame of the video `livecap demo` writes.

    python -m research.demo_figure     # -> docs/img/demo_frame.png
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import cv2

OUT = Path(__file__).resolve().parent.parent / "docs" / "img" / "demo_frame.png"


def demo_frame(out: Path = OUT, frame: int = 90) -> Path:
    from live.app.cli import main

    with tempfile.TemporaryDirectory(prefix="livecap-demo-") as tmp:
        if main(["demo", "--out", tmp, "--quiet"]) != 0:
            raise SystemExit("livecap demo failed")
        cap = cv2.VideoCapture(str(Path(tmp) / "demo.mp4"))
        cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
        ok, img = cap.read()
        cap.release()
    if not ok:
        raise SystemExit(f"demo.mp4 has no frame {frame}")
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), img)
    return out


if __name__ == "__main__":
    print(demo_frame(frame=int(sys.argv[1]) if len(sys.argv) > 1 else 90))
