"""Rendered video output: the depth view with the performer's skeleton beside the shaded avatar.

``compose_frame`` is pure (one FrameResult -> one BGR image); ``VideoSink`` writes those images
to an .mp4 (H.264 through PyAV, else OpenCV's MPEG-4 Part 2); ``frames_to_video`` does the same for a finished run
(``livecap render``). Layout, left to right: depth panel (colour-mapped depth image, or the
points splatted through the intrinsics; skeleton projected world -> camera -> pixels), avatar
panel (posed mesh rasterised by live/outputs/raster.py from a fixed virtual camera in front of
the avatar, or prisms around its bones when there is no mesh). Captions: time, per-stage latency and
skeleton confidence.
"""

from __future__ import annotations

import logging
import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from live.body.body import AvatarLook
from live.core.errors import UserInputError
from live.core.frames import FrameResult
from live.core.skeleton import BONES, JOINT_NAMES
from live.outputs.raster import (
    look_at,
    orient_outward,
    project,
    rasterize,
    shade_lambert,
    vertex_normals,
    world_to_camera,
)
from live.outputs.texture import surface_albedo

log = logging.getLogger(__name__)

# BGR colours: the performer's left side warm, right side cool, centre white.
_SIDE_COLOURS = {"left": (60, 160, 255), "right": (255, 160, 60), "centre": (235, 235, 235)}
_BONE_COLOURS = tuple(
    _SIDE_COLOURS["left" if JOINT_NAMES[c].startswith("left") else "right" if JOINT_NAMES[c].startswith("right") else "centre"]
    for _, c in BONES
)
_BACKGROUND = (40, 40, 40)
_AVATAR_BGR = (0.62, 0.72, 0.85)  # skin-like tone, BGR


@dataclass(frozen=True, slots=True)
class RenderOptions:
    """How frames are drawn. size (W, H) of the whole output; the depth panel takes the left half.

    intrinsics / camera_to_world: used when the frame's depth carries none (points-only frames,
    or no depth at all); a 60-degree pinhole on a 640 x 400 image when absent everywhere.
    depth_range_m: the colour map's near and far limits. avatar_height: metres framed by the
    avatar camera (feet on y = 0). avatar_faces (F, 3): the avatar mesh's triangles.
    """

    size: tuple[int, int] = (1280, 400)
    intrinsics: np.ndarray | None = None
    camera_to_world: np.ndarray | None = None
    depth_range_m: tuple[float, float] = (0.3, 5.0)
    avatar_faces: np.ndarray | None = None
    avatar_height: float = 1.9
    avatar_fov_deg: float = 40.0
    avatar_look: AvatarLook | None = None


def bone_mesh(joints: np.ndarray, radius: float = 0.045, sides: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A closed prism around every bone of (22, 3) joints, wound outwards: vertices
    (21 * (2 * sides + 2), 3) float32 and faces (21 * 4 * sides, 3) int32. Stands in for the
    avatar mesh when only joints are known."""
    j = np.asarray(joints, dtype=np.float64)
    theta = 2 * np.pi * np.arange(sides) / sides
    verts, faces = [], []
    i = np.arange(sides)
    n = (i + 1) % sides
    for p, c in BONES:
        a, b = j[p], j[c]
        d = b - a
        d = d / max(np.linalg.norm(d), 1e-9)
        u = np.cross(d, (1.0, 0.0, 0.0) if abs(d[0]) < 0.9 else (0.0, 1.0, 0.0))
        u /= np.linalg.norm(u)
        v = np.cross(d, u)  # (u, v, d) right-handed: increasing theta turns u towards v
        ring = radius * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)
        base = sum(len(x) for x in verts)
        verts.append(np.concatenate([a + ring, b + ring, [a, b]]))
        ra, rb, ca, cb = base + i, base + sides + i, base + 2 * sides, base + 2 * sides + 1
        ra_n, rb_n = base + n, base + sides + n
        faces += [np.stack([ra, ra_n, rb_n], 1), np.stack([ra, rb_n, rb], 1),
                  np.stack([np.full(sides, cb), rb, rb_n], 1), np.stack([np.full(sides, ca), ra_n, ra], 1)]
    return np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32)


def default_intrinsics(width: int = 640, height: int = 400, hfov_deg: float = 60.0) -> np.ndarray:
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


@lru_cache(maxsize=8)
def _depth_lut(near_mm: int, far_mm: int) -> np.ndarray:
    """(65536,) uint8 colour-map index of every millimetre value: 255 at near, 1 at far and
    beyond, 0 only for no data (0 mm)."""
    mm = np.arange(65536, dtype=np.float32)
    t = np.clip((far_mm - mm) / max(far_mm - near_mm, 1), 0.0, 1.0)
    lut = (1 + t * 254).astype(np.uint8)
    lut[0] = 0
    return lut


def depth_colormap(depth_mm: np.ndarray, near: float, far: float) -> np.ndarray:
    """(H, W) uint16 millimetres (0 = no data) -> (H, W, 3) uint8 BGR; near and far in metres.
    One byte-table lookup per pixel, then OpenCV's colour map (a float pipeline costs more)."""
    index = _depth_lut(int(near * 1000), int(far * 1000))[np.asarray(depth_mm, dtype=np.uint16)]
    img = cv2.applyColorMap(index, cv2.COLORMAP_TURBO)
    img[index == 0] = 0
    return img


def splat_points(points_cam: np.ndarray, intrinsics: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(N, 3) camera-frame points -> (H, W) uint16 depth image in millimetres (nearest point per
    pixel, 0 = no point); size is (W, H)."""
    w, h = size
    p = np.asarray(points_cam, dtype=np.float64)
    p = p[(p[:, 2] > 1e-3) & (p[:, 2] < 65.0)]
    depth = np.full(h * w, 65535, dtype=np.uint16)
    if len(p):
        uv = np.rint(project(p, intrinsics)).astype(np.int64)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        mm = np.maximum(np.rint(p[ok, 2] * 1000.0), 1).astype(np.uint16)
        np.minimum.at(depth, uv[ok, 1] * w + uv[ok, 0], mm)
    depth[depth == 65535] = 0
    return depth.reshape(h, w)


def _fit(src_wh: tuple[int, int], dst_wh: tuple[int, int]) -> tuple[float, int, int]:
    """Scale and offsets that letterbox an image of src size into dst size."""
    s = min(dst_wh[0] / src_wh[0], dst_wh[1] / src_wh[1])
    return s, int((dst_wh[0] - src_wh[0] * s) // 2), int((dst_wh[1] - src_wh[1] * s) // 2)


def draw_skeleton(
    img: np.ndarray,
    joints_px: np.ndarray,
    visible: np.ndarray,
    confidence: np.ndarray | None = None,
    thickness: int = 2,
) -> None:
    """Draw bones and joints (22, 2) pixel positions on img in place; confidence colours the
    joint dots from red (0) to green (1)."""
    pts = np.rint(joints_px).astype(np.int64)
    for (p, c), colour in zip(BONES, _BONE_COLOURS):
        if visible[p] and visible[c]:
            cv2.line(img, tuple(map(int, pts[p])), tuple(map(int, pts[c])), colour, thickness, cv2.LINE_AA)
    for j in np.flatnonzero(visible):
        k = 1.0 if confidence is None else float(np.clip(confidence[j], 0.0, 1.0))
        cv2.circle(img, tuple(map(int, pts[j])), thickness + 2, (0, int(255 * k), int(255 * (1 - k))), -1, cv2.LINE_AA)


def _project_joints(joints_world, camera_to_world, intrinsics, scale=1.0, ox=0, oy=0, wh=None):
    cam = world_to_camera(joints_world, camera_to_world)
    visible = cam[:, 2] > 1e-3
    px = np.zeros((len(cam), 2))
    px[visible] = project(cam[visible], intrinsics) * scale + (ox, oy)
    if wh is not None:  # cv2 drawing overflows on huge coordinates from points near z = 0
        visible &= np.all(np.abs(px) < 4 * max(wh), axis=1)
    return px, visible


def depth_panel(result: FrameResult, opts: RenderOptions, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 BGR: the frame's depth, colour-mapped, with the performer's skeleton."""
    pw, ph = size
    panel = np.zeros((ph, pw, 3), dtype=np.uint8)
    depth = result.depth
    k = opts.intrinsics if depth is None or depth.intrinsics is None else depth.intrinsics
    k = default_intrinsics() if k is None else np.asarray(k, dtype=np.float64)
    # The skeleton is drawn in the camera it was solved in: the stage's own estimate for a camera
    # without extrinsics (a depth folder), else the frame's.
    solved_in = result.skeleton.camera_to_world if result.skeleton is not None else None
    c2w = solved_in if solved_in is not None else depth.camera_to_world if depth is not None else opts.camera_to_world
    c2w = np.eye(4) if c2w is None else np.asarray(c2w, dtype=np.float64)
    if depth is not None and depth.depth_mm is not None:
        img_mm = depth.depth_mm
    else:
        img_wh = (max(1, int(round(2 * (k[0, 2] + 0.5)))), max(1, int(round(2 * (k[1, 2] + 0.5)))))
        img_mm = splat_points(depth.points, k, img_wh) if depth is not None else np.zeros(img_wh[::-1], np.uint16)
    ih, iw = img_mm.shape
    s, ox, oy = _fit((iw, ih), (pw, ph))
    colour = depth_colormap(img_mm, *opts.depth_range_m)
    tw, th = max(1, int(round(iw * s))), max(1, int(round(ih * s)))
    panel[oy:oy + th, ox:ox + tw] = cv2.resize(colour, (tw, th), interpolation=cv2.INTER_NEAREST)[: ph - oy, : pw - ox]
    if result.skeleton is not None:
        # Pixel centres map by (u + 0.5) * s - 0.5 under a resize; close enough at panel scale.
        px, vis = _project_joints(result.skeleton.joints, c2w, k, s, ox, oy, (pw, ph))
        draw_skeleton(panel, px, vis, result.skeleton.confidence)
    return panel


def avatar_camera(root: np.ndarray, opts: RenderOptions, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics (3, 3) and camera_to_world (4, 4) of the virtual camera framing the avatar:
    in front of it (+z, the T-pose's facing), level, following the root horizontally."""
    pw, ph = size
    half = math.tan(math.radians(opts.avatar_fov_deg) / 2)
    f = 0.5 * ph / half
    k = np.array([[f, 0.0, (pw - 1) / 2], [0.0, f, (ph - 1) / 2], [0.0, 0.0, 1.0]])
    target = np.array([root[0], opts.avatar_height / 2, root[2]], dtype=np.float64)
    distance = 1.1 * (opts.avatar_height / 2) / half  # 10 % margin above and below
    return k, look_at(target + (0.0, 0.0, distance), target)


def avatar_panel(result: FrameResult, opts: RenderOptions, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 BGR: the shaded posed avatar mesh (or its bones) from the avatar camera."""
    pw, ph = size
    avatar = result.avatar
    if avatar is None:
        panel = np.empty((ph, pw, 3), dtype=np.uint8)
        panel[:] = _BACKGROUND
        return panel
    k, c2w = avatar_camera(np.asarray(avatar.root, dtype=np.float64), opts, size)
    if avatar.vertices is not None and opts.avatar_faces is not None:
        v_cam = world_to_camera(avatar.vertices, c2w)
        # Back-face culling halves the raster work but needs outward winding; the signed
        # volume tells (about 1 ms for 20k faces).
        faces = orient_outward(v_cam, opts.avatar_faces)
        raster = rasterize(v_cam, faces, k, size, cull_backfaces=True)
        albedo = None if opts.avatar_look is None else surface_albedo(raster, faces, opts.avatar_look, _AVATAR_BGR)
        panel = shade_lambert(raster, vertex_normals(v_cam, faces), faces, color=_AVATAR_BGR, background=_BACKGROUND,
                              albedo=albedo)
    else:
        if avatar.joints is not None:
            v, f = bone_mesh(avatar.joints)
            v_cam = world_to_camera(v, c2w)
            raster = rasterize(v_cam, f, k, size, cull_backfaces=True)
            panel = shade_lambert(raster, vertex_normals(v_cam, f), f, color=_AVATAR_BGR, background=_BACKGROUND)
        else:
            panel = np.empty((ph, pw, 3), dtype=np.uint8)
            panel[:] = _BACKGROUND
    # The floor line, for a sense of contact.
    floor = _project_joints(np.array([[avatar.root[0] - 2.0, 0.0, avatar.root[2]], [avatar.root[0] + 2.0, 0.0, avatar.root[2]]]), c2w, k)[0]
    cv2.line(panel, tuple(map(int, np.rint(floor[0]))), tuple(map(int, np.rint(floor[1]))), (90, 90, 90), 1)
    return panel


def _captions(result: FrameResult, t0_ns: int | None) -> tuple[list[str], list[str]]:
    left = []
    t = (result.t_ns - (result.t_ns if t0_ns is None else t0_ns)) * 1e-9
    left.append(f"t {t:7.3f} s")
    if result.skeleton is not None:
        c = np.asarray(result.skeleton.confidence, dtype=np.float64)
        left.append(f"confidence mean {c.mean():.2f} min {c.min():.2f}")
    else:
        left.append("no skeleton")
    right = [f"{name} {ms:6.1f} ms" for name, ms in result.latency_ms.items()]
    if result.latency_ms:
        right.append(f"total {sum(result.latency_ms.values()):6.1f} ms")
    if result.points is not None:
        right.append(f"points {result.points}")
    return left, right


def _put_lines(img: np.ndarray, lines: list[str], x: int, y: int) -> None:
    for i, text in enumerate(lines):
        org = (x, y + 18 * i)
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)


def compose_frame(result: FrameResult, opts: RenderOptions | None = None, t0_ns: int | None = None) -> np.ndarray:
    """One FrameResult -> (H, W, 3) uint8 BGR image of opts.size (depth panel | avatar panel),
    captioned with time since t0_ns, per-stage latency and confidence."""
    opts = RenderOptions() if opts is None else opts
    w, h = opts.size
    left_w = w // 2
    out = np.empty((h, w, 3), dtype=np.uint8)
    out[:, :left_w] = depth_panel(result, opts, (left_w, h))
    out[:, left_w:] = avatar_panel(result, opts, (w - left_w, h))
    out[:, left_w - 1 : left_w + 1] = (128, 128, 128)
    left, right = _captions(result, t0_ns)
    _put_lines(out, left, 8, 18)
    _put_lines(out, right, left_w + 8, 18)
    return out


def _check_options(path: str | Path, fps: float, opts: RenderOptions) -> Path:
    path = Path(path)
    if fps <= 0:
        raise UserInputError(f"video fps must be > 0, got {fps}")
    w, h = opts.size
    if w < 16 or h < 16:
        raise UserInputError(f"video size must be at least 16 x 16, got {w} x {h}")
    if opts.avatar_faces is not None:
        f = np.asarray(opts.avatar_faces)
        if f.ndim != 2 or f.shape[1] != 3:
            raise UserInputError(f"avatar faces must be (F, 3), got {f.shape}")
        if opts.avatar_look is not None and len(opts.avatar_look.face_material) != len(f):
            raise UserInputError(f"the avatar's look has {len(opts.avatar_look.face_material)} triangles, its mesh {len(f)}")
    if not path.parent.exists():
        raise UserInputError(f"folder {path.parent} does not exist")
    return path


class _Mp4Writer:
    """BGR frames -> .mp4 at a constant rate. H.264 (libx264 through PyAV, yuv420p, faststart: what
    browsers play) when PyAV is installed, else OpenCV's MPEG-4 Part 2 ('mp4v', which browsers do
    not play) after one line on stderr saying so. Frame i is shown at i / fps, so N frames last
    N / fps seconds."""

    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        self.path, self.size = path, size
        self.codec = "h264" if _h264_available() else "mpeg4"
        if self.codec == "h264":
            self._open_h264(fps)
        else:
            _warn_no_h264()
            self._cv = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
            if not self._cv.isOpened():
                raise UserInputError(f"cannot write video {path} (OpenCV's mp4v encoder refused it)")

    def _open_h264(self, fps: float) -> None:
        import av

        try:
            self._container = av.open(str(self.path), "w", options={"movflags": "+faststart"})
        except (OSError, av.FFmpegError) as e:
            raise UserInputError(f"cannot write video {self.path} ({e})") from None
        # yuv420p needs even sides: an odd width or height gets one repeated edge column / row.
        w, h = self.size
        self._pad = (h % 2, w % 2)
        stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1_000_000))
        stream.width, stream.height, stream.pix_fmt = w + w % 2, h + h % 2, "yuv420p"
        stream.options = {"crf": "23", "preset": "veryfast"}
        self._stream = stream

    def write(self, bgr: np.ndarray) -> None:
        if self.codec != "h264":
            self._cv.write(bgr)
            return
        import av

        if any(self._pad):
            bgr = np.pad(bgr, ((0, self._pad[0]), (0, self._pad[1]), (0, 0)), mode="edge")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(bgr), format="bgr24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def close(self) -> None:
        if self.codec != "h264":
            self._cv.release()
            return
        try:
            for packet in self._stream.encode():  # the frames the encoder still holds
                self._container.mux(packet)
        finally:
            self._container.close()


@lru_cache(maxsize=1)
def _h264_available() -> bool:
    try:
        import av

        av.codec.Codec("libx264", "w")
    except Exception:  # not installed, or a build without libx264
        return False
    return True


@lru_cache(maxsize=1)
def _warn_no_h264() -> None:
    # print, not log: the CLI shows only errors unless -v, and this decides whether the file plays.
    print("livecap: no H.264 encoder (PyAV with libx264): writing MPEG-4 Part 2 video, which browsers do not "
          "play; `pip install av` for H.264", file=sys.stderr, flush=True)


def _open_writer(path: Path, fps: float, size: tuple[int, int]) -> _Mp4Writer:
    return _Mp4Writer(path, fps, size)


class VideoSink:
    """Writes one composed frame per FrameResult to an .mp4 (H.264, see _Mp4Writer) at fps: the
    take's frame rate, so the video lasts as long as the take.

    Never raises from send(); errors are counted in ``errors`` and logged.
    """

    def __init__(
        self,
        path: str | Path,
        fps: float = 30.0,
        size: tuple[int, int] = (1280, 400),
        avatar_faces: np.ndarray | None = None,
        intrinsics: np.ndarray | None = None,
        camera_to_world: np.ndarray | None = None,
        **options: object,
    ) -> None:
        self.opts = RenderOptions(
            size=(int(size[0]), int(size[1])),
            intrinsics=intrinsics,
            camera_to_world=camera_to_world,
            avatar_faces=None if avatar_faces is None else np.asarray(avatar_faces, dtype=np.int32),
            **options,
        )
        self.path = _check_options(path, fps, self.opts)
        self.fps = float(fps)
        self._writer: _Mp4Writer | None = _open_writer(self.path, fps, self.opts.size)
        self.codec = self._writer.codec  # "h264", or "mpeg4" without PyAV
        self._t0_ns: int | None = None
        self.frames = 0
        self.errors = 0

    name = "video"

    @property
    def counters(self) -> dict[str, int]:
        return {"frames": self.frames, "errors": self.errors}

    @property
    def details(self) -> dict[str, object]:
        return {"codec": self.codec, "fps": self.fps, "path": str(self.path)}

    def send(self, result: FrameResult) -> None:
        if self._writer is None:
            return
        try:
            if self._t0_ns is None:
                self._t0_ns = result.t_ns
            self._writer.write(compose_frame(result, self.opts, self._t0_ns))
            self.frames += 1
        except Exception as e:  # a sink must never take the pipeline down
            self.errors += 1
            if self.errors == 1 or self.errors % 100 == 0:
                log.warning("video sink %s: %s (%d errors so far)", self.path, e, self.errors)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> VideoSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def frames_to_video(
    results: Iterable[FrameResult],
    path: str | Path,
    fps: float = 30.0,
    size: tuple[int, int] = (1280, 400),
    avatar_faces: np.ndarray | None = None,
    intrinsics: np.ndarray | None = None,
    camera_to_world: np.ndarray | None = None,
    **options: object,
) -> int:
    """Render every result into an .mp4 at path; returns the number of frames written.
    Unlike the sink, errors propagate (a batch render should fail loudly)."""
    opts = RenderOptions(
        size=(int(size[0]), int(size[1])),
        intrinsics=intrinsics,
        camera_to_world=camera_to_world,
        avatar_faces=None if avatar_faces is None else np.asarray(avatar_faces, dtype=np.int32),
        **options,
    )
    path = _check_options(path, fps, opts)
    writer = _open_writer(path, fps, opts.size)
    n, t0 = 0, None
    try:
        for result in results:
            t0 = result.t_ns if t0 is None else t0
            writer.write(compose_frame(result, opts, t0))
            n += 1
    finally:
        writer.close()
    return n
