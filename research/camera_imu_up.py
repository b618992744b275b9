"""How much the camera's own IMU helps when the extrinsics are withheld (docs/results.md).

Synthetic sessions of a camera pitched down and not told its pose (``--hide-extrinsics``), with
and without a floor in view, each with and without the camera IMU (``--camera-imu``), replayed
through the shipped pipeline; the up of each frame's ``camera_to_world`` in ``skeleton.npz``
against the true one (kept in the gt stream's metadata):

    python -m research.camera_imu_up [--clip mb_12_01] [--pitch -30] [--height 1.9] [--seconds 4]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np

from live.app.cli import main as livecap
from live.core import assets
from live.core.frames import DepthFrame
from live.io.session import SessionReader

UP = np.array([0.0, 1.0, 0.0])


def up_errors_deg(session: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """(up error in degrees, camera height in metres) of each skeleton of a replayed session."""
    streams = {s.name: s for s in SessionReader(session).info.streams}
    truth = np.asarray(streams["gt"].meta["camera_to_world"])[:3, :3].T @ UP
    c2w = np.load(out / "skeleton.npz")["camera_to_world"]
    ups = np.einsum("tji,j->ti", c2w[:, :3, :3], UP)  # up in camera axes: R^T e_y
    err = np.degrees(np.arccos(np.clip(ups @ truth, -1.0, 1.0)))
    return err, c2w[:, 1, 3]


def run(clip: str, pitch: float, height: float, seconds: float, seed: int, workdir: Path) -> list[dict]:
    rows = []
    motion = assets.bvh_dir() / f"{clip}.bvh"
    for floor in ("seen", "none"):
        for imu in (False, True):
            name = f"{floor}_{'imu' if imu else 'plain'}"
            session, out = workdir / f"{name}.mcap", workdir / name
            args = ["synth", "--motion", str(motion), "--out", str(session), "--seconds", str(seconds),
                    "--pitch", str(pitch), "--height", str(height), "--hide-extrinsics", "--floor", floor,
                    "--seed", str(seed), "--quiet"] + (["--camera-imu"] if imu else [])
            with contextlib.redirect_stdout(io.StringIO()):
                livecap(args)
                livecap(["replay", str(session), "--out", str(out), "--quiet"])
            err, heights = up_errors_deg(session, out)
            total = sum(1 for _, f in SessionReader(session).frames() if isinstance(f, DepthFrame))
            rows.append({"floor": floor, "camera_imu": imu, "frames": total, "skeletons": len(err),
                         "median_deg": float(np.median(err)), "max_deg": float(err.max()),
                         "height_m": float(np.median(heights))})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", default="mb_12_01")
    ap.add_argument("--pitch", type=float, default=-30.0, help="degrees, negative looks down")
    ap.add_argument("--height", type=float, default=1.9)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = run(a.clip, a.pitch, a.height, a.seconds, a.seed, Path(tmp))
    print(f"{a.clip}, {a.seconds:g} s, camera at {a.height:g} m pitched {a.pitch:g} deg, extrinsics withheld")
    print("| floor in view | camera IMU | skeletons | up error median / max | camera height |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['floor']} | {'yes' if r['camera_imu'] else 'no'} | {r['skeletons']}/{r['frames']} | "
              f"{r['median_deg']:.2f} / {r['max_deg']:.2f} deg | {r['height_m']:.2f} m |")


if __name__ == "__main__":
    main()
