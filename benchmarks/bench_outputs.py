"""Speed of the outputs: rasteriser, composed video frame, VMC bundle encoding + send.

Run: .venv/bin/python benchmarks/bench_outputs.py [--repeats 30]
Prints medians in milliseconds. The avatar stand-in is a body of ellipsoids around the bones
of a posed default skeleton, about the triangle count of a body-library mesh (~20k faces).
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from live.core.depth import intrinsics_matrix  # noqa: E402
from live.core.frames import AvatarPose, DepthFrame, FrameResult, SkeletonFrame  # noqa: E402
from live.core.kinematics import forward_kinematics  # noqa: E402
from live.core.rotations import quat_from_axis_angle  # noqa: E402
from live.core.skeleton import BONES, default_rest_joints  # noqa: E402
from live.outputs.raster import look_at, orient_outward, rasterize, shade_lambert, vertex_normals, world_to_camera  # noqa: E402
from live.outputs.render import RenderOptions, avatar_camera, compose_frame  # noqa: E402
from live.outputs.vmc import VmcSink  # noqa: E402


def ellipsoid_body(joints: np.ndarray, nu: int = 24, nv: int = 22) -> tuple[np.ndarray, np.ndarray]:
    """One UV ellipsoid per bone: (V, 3) vertices and (F, 3) faces, ~21 * 2 * nu * (nv - 1) faces."""
    th = np.linspace(0, np.pi, nv)
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nv - 1), np.arange(nu), indexing="ij")
    a, b = i * nu + j, i * nu + (j + 1) % nu
    c, d = a + nu, b + nu
    grid = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    verts, faces = [], []
    for k, (pa, ch) in enumerate(BONES):
        axis = joints[ch] - joints[pa]
        length = max(np.linalg.norm(axis), 1e-3)
        y = axis / length
        x = np.cross(y, [0.0, 0.0, 1.0] if abs(y[2]) < 0.9 else [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        z = np.cross(x, y)
        r = 0.06 if length > 0.15 else 0.05
        local = unit * [r, length / 2 + 0.03, r]
        verts.append((joints[pa] + joints[ch]) / 2 + local @ np.stack([x, y, z]))
        faces.append(grid + k * len(unit))
    v, f = np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32)
    return v, orient_outward(v, f)


def median_ms(fn, repeats: int) -> str:
    """'wall W ms, cpu C ms': medians of wall-clock and of this process's CPU time (the second
    is steadier on a machine shared with other jobs)."""
    fn()  # warm-up (caches, lazy imports)
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return f"wall {np.median(wall) * 1e3:6.1f} ms, cpu {np.median(cpu) * 1e3:6.1f} ms"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    rot = quat_from_axis_angle(rng.normal(0, 0.25, (22, 3)))
    root = np.array([0.0, 0.95, 0.0])
    joints, _ = forward_kinematics(rot, root, default_rest_joints())
    verts, faces = ellipsoid_body(joints)
    print(f"avatar stand-in: {len(verts)} vertices, {len(faces)} faces")

    for size in ((640, 400), (1280, 720)):
        opts = RenderOptions(size=size)
        k, c2w = avatar_camera(root, opts, size)
        v_cam = world_to_camera(verts, c2w)
        r = rasterize(v_cam, faces, k, size, cull_backfaces=True)
        print(f"avatar panel {size[0]}x{size[1]}: {r.mask.sum()} covered pixels")
        print(f"  rasterize (culled)      {median_ms(lambda: rasterize(v_cam, faces, k, size, cull_backfaces=True), args.repeats)}")
        print(f"  rasterize (no culling)  {median_ms(lambda: rasterize(v_cam, faces, k, size), args.repeats)}")
        print(f"  normals + Lambert shade {median_ms(lambda: shade_lambert(r, vertex_normals(v_cam, faces), faces), args.repeats)}")

    kd = intrinsics_matrix(400.0, 400.0, 319.5, 199.5)
    cam = look_at([0.3, 1.3, 3.0], [0.0, 1.0, 0.0])
    depth_mm = (rng.uniform(0.5, 4.0, (400, 640)) * 1000).astype(np.uint16)
    result = FrameResult(
        t_ns=0,
        depth=DepthFrame(t_ns=0, sensor="bench", camera_to_world=cam, depth_mm=depth_mm, intrinsics=kd),
        skeleton=SkeletonFrame(t_ns=0, joints=joints, confidence=np.full(22, 0.9)),
        avatar=AvatarPose(t_ns=0, root=root, rotations=rot, joints=joints, vertices=verts),
        latency_ms={"skeleton": 5.0, "retarget": 1.0},
    )
    for size in ((640, 400), (1280, 400)):
        opts = RenderOptions(size=size, avatar_faces=faces)
        print(f"compose_frame {size[0]}x{size[1]} (depth 640x400 + avatar): "
              f"{median_ms(lambda: compose_frame(result, opts), args.repeats)}")

    # Video encoding alone: 60 composed frames (fresh depth noise each, the encoder's worst case),
    # written and closed per repeat; H.264 (PyAV libx264) against OpenCV's MPEG-4 Part 2.
    import tempfile
    from pathlib import Path

    from live.outputs import render

    opts = RenderOptions(size=(1280, 400), avatar_faces=faces)
    frames = []
    for _ in range(60):
        result.depth.depth_mm[:] = (rng.uniform(0.5, 4.0, (400, 640)) * 1000).astype(np.uint16)
        frames.append(compose_frame(result, opts))
    with tempfile.TemporaryDirectory() as tmp:
        for codec, available in (("h264", render._h264_available), ("mpeg4", lambda: False)):
            render._h264_available = available  # type: ignore[assignment]

            def encode():
                w = render._Mp4Writer(Path(tmp) / "bench.mp4", 15.0, (1280, 400))
                for f in frames:
                    w.write(f)
                w.close()
            per_frame = median_ms(encode, max(3, args.repeats // 10))
            size_kb = (Path(tmp) / "bench.mp4").stat().st_size / 1024
            print(f"video encode 1280x400, 60 frames ({codec}, {size_kb:.0f} KiB): {per_frame} per 60 frames")

    # VMC: encode one bundle and send it to a closed local port (UDP: no receiver needed).
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        sink = VmcSink("127.0.0.1", port, rate_hz=None)
        print(f"VMC bundle encode + send: {median_ms(lambda: sink.send(result), args.repeats * 10)}")
        sink.close()


if __name__ == "__main__":
    main()
