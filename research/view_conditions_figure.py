"""Skeleton regressors side by side per sensor, body and view condition, as one bar chart.

    python -m research.view_conditions_figure RESULTS.json [--split val_real] [--key root_aligned_pck_10cm]
        [--names NAME ...] [--out docs/img/view_conditions.png]

RESULTS.json is what ``python -m research.compare_skeleton --json`` writes. One row per group of
the split (all, each sensor, body and view condition), one bar per model, the goal as a line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "view_conditions.png"
#: Bar colours (BGR) of the models, in order.
COLOURS = ((150, 150, 150), (40, 140, 240), (200, 120, 40), (60, 170, 60))
ROW_PX, LABEL_PX, PLOT_PX = 22, 230, 520


def bar_chart(rows: list[tuple[str, list[float], int]], names: list[str], title: str,
              goal: float | None = None, lo: float = 0.4, hi: float = 1.0) -> np.ndarray:
    """A white BGR image: per row (label, one value per model, frames) a bar per model from lo to
    hi, the value written at its end; a legend of ``names`` on top, ``goal`` as a dashed line."""
    top = 30 + 18 * len(names)
    row_px = max(ROW_PX, 10 * len(names) + 4)  # room for each bar's value
    img = np.full((top + row_px * len(rows) + 25, LABEL_PX + PLOT_PX + 60, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(img, title, (8, 18), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for k, name in enumerate(names):
        y = 34 + 18 * k
        cv2.rectangle(img, (8, y - 9), (26, y), COLOURS[k % len(COLOURS)], -1)
        cv2.putText(img, name, (32, y), font, 0.42, (0, 0, 0), 1, cv2.LINE_AA)

    def x_of(v: float) -> int:
        return LABEL_PX + int(round(PLOT_PX * (min(max(v, lo), hi) - lo) / (hi - lo)))

    for r, (label, values, frames) in enumerate(rows):
        y0 = top + row_px * r
        cv2.putText(img, f"{label} ({frames})", (8, y0 + 14), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        for k, v in enumerate(values):
            y = y0 + 2 + k * (row_px - 4) // len(values)
            cv2.rectangle(img, (LABEL_PX, y), (x_of(v), y + (row_px - 4) // len(values) - 1),
                          COLOURS[k % len(COLOURS)], -1)
            cv2.putText(img, f"{v:.2f}", (x_of(v) + 3, y + 7), font, 0.3, (0, 0, 0), 1, cv2.LINE_AA)
    bottom = top + row_px * len(rows)
    for v in np.arange(lo, hi + 1e-9, 0.1):
        cv2.line(img, (x_of(v), top - 4), (x_of(v), bottom), (225, 225, 225), 1)
        cv2.putText(img, f"{v:.1f}", (x_of(v) - 9, bottom + 15), font, 0.35, (90, 90, 90), 1, cv2.LINE_AA)
    if goal is not None:
        for y in range(top - 4, bottom, 8):
            cv2.line(img, (x_of(goal), y), (x_of(goal), y + 4), (0, 0, 200), 1)
    return img


def rows_of(results: dict, split: str, key: str) -> tuple[list[tuple[str, list[float], int]], list[str]]:
    by_model = results[split]
    models = list(by_model)
    groups = list(by_model[models[0]])
    rows = [(g, [float(by_model[m][g][key]) for m in models], int(by_model[models[0]][g]["frames"]))
            for g in groups]
    return rows, models


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m research.view_conditions_figure", description=__doc__.split("\n\n")[0])
    ap.add_argument("results", type=Path, help="research.compare_skeleton --json output")
    ap.add_argument("--split", default="val_real")
    ap.add_argument("--key", default="root_aligned_pck_10cm",
                    help="root_aligned_pck_10cm (default), pck_10cm, or an error in mm with --range")
    ap.add_argument("--range", type=float, nargs=2, default=(0.4, 1.0), metavar=("LO", "HI"))
    ap.add_argument("--goal", type=float, default=0.85)
    ap.add_argument("--names", nargs="+", default=None, help="legend names of the models, in order")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    if not args.results.is_file():
        ap.error(f"no results file {args.results}")
    results = json.loads(args.results.read_text())
    if args.split not in results:
        ap.error(f"{args.results} has no split {args.split!r} (it has {', '.join(results)})")
    rows, models = rows_of(results, args.split, args.key)
    names = args.names or models
    if len(names) != len(models):
        ap.error(f"{len(names)} names for {len(models)} models")
    title = f"{args.split}: {args.key} per group (frames); dashed: goal {args.goal:g}"
    img = bar_chart(rows, names, title, args.goal, *args.range)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), img)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
