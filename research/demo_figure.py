"""The README's demo picture: one frame of the video `livecap demo` writes.

    python -m research.demo_figure [--frame 90] [--out docs/img/demo_frame.png]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2

OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "demo_frame.png"  # research/ is in the checkout root


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


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m research.demo_figure", description=__doc__.splitlines()[0])
    p.add_argument("--frame", type=int, default=90, help="frame of demo.mp4 (default 90)")
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args(argv)
    print(demo_frame(args.out, args.frame))


if __name__ == "__main__":
    main()
