"""Picture of the body library, side by side in the T-pose (docs/img/bodies.png).

    python -m research.body_figure [--out docs/img/bodies.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from live.body.library import list_presets, load_body
from live.outputs.raster import rasterize, shade_lambert, vertex_normals

OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "bodies.png"  # research/ is in the checkout root


def bodies_figure(out: Path = OUT, names: list[str] | None = None, cell: tuple[int, int] = (260, 300)) -> Path:
    names = names or list_presets()
    w, h = cell
    distance = 12.0  # a long lens from far away: nearly orthographic, every body at one scale
    f = (h - 40) * distance / 2.1
    k = np.array([[f, 0, w / 2], [0, f, h - 12], [0, 0, 1.0]])
    tiles = []
    for name in names:
        b = load_body(name)
        v = b.vertices.astype(np.float64)
        # A camera in front of the body (at +z, looking toward -z): OpenCV x right, y down.
        cam_scaled = np.stack([v[:, 0], -v[:, 1], distance - v[:, 2]], axis=1)
        raster = rasterize(cam_scaled.astype(np.float32), b.faces, k, (w, h))
        normals = vertex_normals(cam_scaled, b.faces)
        img = shade_lambert(raster, normals, b.faces, background=(255, 255, 255))
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
        cv2.putText(img, name.replace("_", " "), (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (30, 30, 30), 1, cv2.LINE_AA)
        cv2.putText(img, f"{b.height:.2f} m", (6, 32), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (30, 30, 30), 1, cv2.LINE_AA)
        tiles.append(img)
    cols = 7
    rows = [np.hstack(tiles[i:i + cols] + [np.full_like(tiles[0], 255)] * (cols - len(tiles[i:i + cols])))
            for i in range(0, len(tiles), cols)]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.vstack(rows))
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m research.body_figure", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    print(bodies_figure(p.parse_args(argv).out))


if __name__ == "__main__":
    main()
