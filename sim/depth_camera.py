"""A virtual depth camera: ray-casts a posed body mesh in a room and adds stereo sensor noise.

Rays are cast with open3d's ``RaycastingScene`` (Embree). The camera does not move, so its rays
are built once, and the static room is cast once per room and cached; each frame only builds a
scene of the body (its camera-facing triangles when the mesh is closed) and casts the rays of the
image tiles the body projects onto, then keeps the nearer of body and room per pixel (the first
hit over a union is the nearest of the hits).

Output follows the DepthFrame convention: (H, W) uint16 millimetres, 0 = no data, OpenCV camera
frame, pixel (u, v) looks along K^-1 (u, v, 1) as ``live.core.depth.depth_to_points`` assumes.

Noise model (a stereo or structured-light sensor measures disparity d = f b / z, in pixels):
Gaussian disparity noise (so depth error grows as z^2 / (f b)), disparity quantisation to
1 / 2^subpixel_bits px, invalid pixels at depth edges, in the occlusion shadow that the second
view cannot see, at grazing angles, random dropouts, and outside [min_range, max_range].
A time-of-flight sensor (``kind="tof"``) measures depth itself: Gaussian depth noise growing
linearly with range, 1 mm steps, no occlusion shadow. Both can add flying pixels (edge pixels
whose depth lies between the foreground and the background, as mixed returns give) and holes in
blobs (dark, shiny or thin material: a few places lose depth, not a scatter of single pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from live.core.depth import intrinsics_matrix
from live.core.errors import UserInputError
from sim.room import Room

_o3c = o3d.core
_TILE = 8  # pixels per side of the tiles used to pick which rays may hit the body


@dataclass(frozen=True)
class CameraPreset:
    """A depth sensor's image size, pinhole intrinsics (pixels), stereo baseline and range.

    disparity_sigma_px is the sensor's typical random disparity error (1 sigma, pixels at this
    resolution); subpixel_bits the fractional bits of its disparity output."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    min_range_m: float
    max_range_m: float
    fps: float
    subpixel_bits: int
    disparity_sigma_px: float = 0.1
    kind: str = "stereo"  # "stereo" (disparity noise) or "tof" (depth noise, no shadow)
    tof_sigma_m_per_m: float = 0.0  # time of flight: depth noise sd per metre of range

    @property
    def intrinsics(self) -> np.ndarray:
        return intrinsics_matrix(self.fx, self.fy, self.cx, self.cy)


# Where the numbers come from (see docs/virtual_camera.md):
# - oak-d: OV9282 stereo pair, 7.5 cm baseline; fx = 441.25 px is Luxonis's own 400P example
#   (rectified, HFOV ~72 deg). Min range: RVC2 searches disparities 0..95 px -> f b / 95 = 0.35 m.
#   Subpixel default 3 fractional bits. sigma ~0.15 px matches "< 2 % error below 4 m".
# - oak-d-pro: same OV9282 pair and baseline; fx from the spec-sheet HFOV of 80 deg at 640 px
#   (320 / tan 40 deg = 381.4 px); the IR dot projector makes matching easier -> lower sigma.
# - kinect-v1: 640x480 IR camera, fx = fy = 580 px and 7.5 cm projector-camera baseline,
#   disparity in 1/8 px, 0.5-5 m range, error ~4 cm at 5 m (Khoshelham & Elberink 2012).
# - xtion: Asus Xtion PRO, the same PrimeSense design at 320x240 (fx = fy = 285.71 px, as the
#   shared ITOP frames' intrinsics), disparity still resolved at 640 px (one more fractional bit);
#   sigma fitted to the real frames' plane-fit noise on the body (docs/depth_realism.md: about
#   10 mm at 2.75-3.25 m), 0.55x the kinect-v1 sigma scaled to this focal length.
# - kinect-v2: time of flight, 512x424, fx = fy = 364.85 px (the shared Panoptic frame's
#   intrinsics), 0.5-4.5 m; depth noise about 2.5 mm per metre of range, fitted to the real
#   frame's plane-fit noise on the body (docs/depth_realism.md: 6-7 mm at 2.25-2.75 m).
PRESETS: dict[str, CameraPreset] = {
    p.name: p
    for p in (
        CameraPreset("oak-d", 640, 400, 441.25, 441.25, 319.5, 199.5, 0.075, 0.35, 10.0, 30.0, 3,
                     0.15),
        CameraPreset("oak-d-pro", 640, 400, 381.4, 381.4, 319.5, 199.5, 0.075, 0.30, 10.0, 30.0,
                     3, 0.1),
        CameraPreset("kinect-v1", 640, 480, 580.0, 580.0, 319.5, 239.5, 0.075, 0.5, 5.0, 30.0, 3,
                     0.07),
        CameraPreset("xtion", 320, 240, 285.7143, 285.7143, 159.5, 119.5, 0.075, 0.8, 4.5, 30.0, 4,
                     0.019),
        CameraPreset("kinect-v2", 512, 424, 364.85, 364.85, 255.5, 211.5, 0.0, 0.5, 4.5, 30.0, 0,
                     0.0, kind="tof", tof_sigma_m_per_m=0.0025),
    )
}


def get_preset(name: str | CameraPreset) -> CameraPreset:
    """A preset by name (or the preset itself)."""
    if isinstance(name, CameraPreset):
        return name
    if name not in PRESETS:
        raise UserInputError(f"unknown camera preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]


@dataclass(frozen=True)
class NoiseModel:
    """What makes a rendered depth image look measured. ``NoiseModel()`` is a realistic default;
    ``NoiseModel.none()`` gives ideal depth (only millimetre rounding and the range limits).

    disparity_sigma_px: Gaussian disparity noise, None = the preset's typical value.
    subpixel: quantise disparity to 1 / 2^subpixel_bits px (else to whole pixels).
    edge_jump_px: a neighbour whose disparity differs by more than this marks a depth edge;
      edge_width_px pixels around it become 0 (stereo matching fails across edges). 0 = off.
    occlusion: drop pixels the second view (other camera / projector) cannot see.
    grazing_deg: drop pixels whose surface normal is more than this from the ray. None = off.
    dropout: probability that a pixel drops out at random.
    range_limits: drop depths outside [min_range_m, max_range_m] of the preset.
    noise_block_px: disparity noise is shared over square patches of this size (1 = per pixel).
    flying_pixels: share of the pixels beside a depth edge (foreground side and background side)
      that report a depth between the two surfaces instead of their own or none.
    hole_blobs: share of the image lost in blobs of about hole_blob_px pixels (material the
      sensor cannot measure), on top of the single-pixel ``dropout``.
    """

    disparity_sigma_px: float | None = None
    quantize: bool = True
    subpixel: bool = True
    edge_jump_px: float = 1.0
    edge_width_px: int = 1
    occlusion: bool = True
    grazing_deg: float | None = 80.0
    dropout: float = 0.01
    range_limits: bool = True
    noise_block_px: int = 2
    flying_pixels: float = 0.0
    hole_blobs: float = 0.0
    hole_blob_px: int = 12

    def __post_init__(self) -> None:
        for name in ("dropout", "flying_pixels", "hole_blobs"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise UserInputError(f"{name} must be in [0, 1), got {getattr(self, name)}")
        if self.hole_blob_px < 1:
            raise UserInputError(f"hole_blob_px must be >= 1, got {self.hole_blob_px}")
        if (self.disparity_sigma_px or 0.0) < 0 or self.edge_jump_px < 0 or self.noise_block_px < 1:
            raise UserInputError("noise sigma and edge jump must be >= 0, noise_block_px >= 1")
        if self.grazing_deg is not None and not 0.0 < self.grazing_deg <= 90.0:
            raise UserInputError(f"grazing_deg must be in (0, 90], got {self.grazing_deg}")

    @classmethod
    def none(cls) -> NoiseModel:
        return cls(disparity_sigma_px=0.0, quantize=False, edge_jump_px=0.0, occlusion=False,
                   grazing_deg=None, dropout=0.0)


@dataclass
class _StaticView:
    """What the camera sees of the room: camera z (inf = nothing), |cos| of the incidence angle."""

    z: np.ndarray
    cos: np.ndarray


class VirtualDepthCamera:
    """A fixed depth camera in the world. camera_to_world (4, 4) maps OpenCV camera coordinates
    (+X right, +Y down, +Z forward) to world coordinates (+Y up), metres."""

    def __init__(self, preset: str | CameraPreset, camera_to_world: np.ndarray,
                 noise: NoiseModel | None = None, seed: int = 0):
        self.preset = get_preset(preset)
        m = np.asarray(camera_to_world, dtype=np.float64)
        if m.shape != (4, 4):
            raise UserInputError(f"camera_to_world must be 4x4, got {m.shape}")
        if not np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-5) or np.linalg.det(m[:3, :3]) < 0:
            raise UserInputError("camera_to_world must be a rigid transform (a rotation, no scale)")
        self._c2w = m.copy()
        self._c2w.setflags(write=False)
        self.noise = NoiseModel() if noise is None else noise
        self.rng = np.random.default_rng(seed)
        p = self.preset
        u, v = np.meshgrid(np.arange(p.width, dtype=np.float64), np.arange(p.height, dtype=np.float64))
        # Direction with camera-frame z = 1, so t_hit is directly the depth z.
        d_cam = np.stack([(u - p.cx) / p.fx, (v - p.cy) / p.fy, np.ones_like(u)], axis=-1)
        d_world = d_cam @ m[:3, :3].T
        self._rays = np.concatenate(
            [np.broadcast_to(m[:3, 3], d_world.shape), d_world], axis=-1
        ).astype(np.float32)
        self._inv_len = (1.0 / np.linalg.norm(d_world, axis=-1)).astype(np.float32)
        self._static: dict[Room, _StaticView] = {}
        self._winding: dict[tuple, int] = {}
        # Flat pixel indices of each _TILE x _TILE tile, (gh, gw, _TILE^2), -1 beyond the image.
        gh, gw = -(-p.height // _TILE), -(-p.width // _TILE)
        pad = np.full((gh * _TILE, gw * _TILE), -1, dtype=np.int64)
        pad[: p.height, : p.width] = np.arange(p.height * p.width).reshape(p.height, p.width)
        self._tile_pixels = pad.reshape(gh, _TILE, gw, _TILE).transpose(0, 2, 1, 3).reshape(gh, gw, -1)

    @property
    def intrinsics(self) -> np.ndarray:
        """(3, 3) float64 pinhole matrix."""
        return self.preset.intrinsics

    @property
    def camera_to_world(self) -> np.ndarray:
        """(4, 4) float64, read-only."""
        return self._c2w

    # ---------------------------------------------------------------- rendering
    def render(self, vertices: np.ndarray, faces: np.ndarray, room: bool | Room = True) -> np.ndarray:
        """Posed mesh (V, 3) float32 world + faces (F, 3) int32 -> depth (H, W) uint16 mm."""
        return self.render_with_labels(vertices, faces, room)[0]

    def render_with_labels(self, vertices: np.ndarray, faces: np.ndarray,
                           room: bool | Room = True) -> tuple[np.ndarray, np.ndarray]:
        """Like render, plus body_mask (H, W) bool: pixels whose ray first hits the body (before
        any invalidation; valid body pixels are ``body_mask & (depth > 0)``)."""
        z, cos, body = self.render_ideal(vertices, faces, room)
        return self._measure(z, cos), body

    def render_ideal(self, vertices: np.ndarray, faces: np.ndarray,
                     room: bool | Room = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free ray casting: z (H, W) float32 metres (inf = no hit), |cos| (H, W) float32
        of the angle between ray and surface normal, body_mask (H, W) bool."""
        vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        faces = np.asarray(faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise UserInputError(f"need vertices (V, 3) and faces (F, 3), got {vertices.shape} "
                                 f"and {faces.shape}")
        if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise UserInputError(f"faces index vertices outside 0..{len(vertices) - 1}")
        static = self._static_view(room)
        z, cos = static.z.copy(), static.cos.copy()
        body = np.zeros(z.shape, dtype=bool)
        pix = self._candidate_pixels(vertices, faces) if len(faces) else None
        if pix is not None and len(pix):
            scene = o3d.t.geometry.RaycastingScene()
            visible = self._front_faces(vertices, faces)
            scene.add_triangles(_o3c.Tensor.from_numpy(vertices),
                                _o3c.Tensor.from_numpy(visible.astype(np.uint32)))
            rays = self._rays.reshape(-1, 6)[pix]
            hit = scene.cast_rays(_o3c.Tensor.from_numpy(rays))
            bz = hit["t_hit"].numpy()
            zf, cf, bf = z.reshape(-1), cos.reshape(-1), body.reshape(-1)
            nearer = bz < zf[pix]
            sel = pix[nearer]
            zf[sel] = bz[nearer]
            n = hit["primitive_normals"].numpy()[nearer]
            cf[sel] = np.abs(np.einsum("nc,nc->n", n, rays[nearer, 3:])) * self._inv_len.reshape(-1)[sel]
            bf[sel] = True
        return z, cos, body

    def _front_faces(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """The faces that can be a first hit. On a closed, consistently wound mesh a ray from
        outside always enters through a face turned towards the camera, so the others are left
        out of the scene: the BVH build dominates the frame time and this halves it. Open meshes
        (a plane, a mesh with holes) keep all their faces, and so does a camera inside the
        mesh's bounding box."""
        faces = np.asarray(faces)
        key = (faces.shape, hash(faces.tobytes()))
        sign = self._winding.get(key)
        if sign is None:
            sign = closed_mesh_winding(vertices, faces)
            if len(self._winding) > 16:
                self._winding.clear()
            self._winding[key] = sign
        eye = self._c2w[:3, 3].astype(np.float32)
        # From inside a closed mesh the first hit faces away; outside its box we are outside it.
        if sign == 0 or ((eye >= vertices.min(0)) & (eye <= vertices.max(0))).all():
            return faces
        a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
        n = np.cross(b - a, c - a)
        return faces[np.einsum("fc,fc->f", n, a - eye) * sign <= 0]

    def _candidate_pixels(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
        """Flat indices of the pixels whose rays may hit the mesh: the union of the image tiles
        covered by each triangle's projected bounding box (so a body covering a tenth of the
        image costs about a tenth of the rays). None when no pixel can see the mesh."""
        m, pr, t = self._c2w, self.preset, _TILE
        p = (vertices - m[:3, 3].astype(np.float32)) @ m[:3, :3].astype(np.float32)
        if not np.isfinite(p).all():
            raise UserInputError("mesh vertices must be finite")
        if (p[:, 2] <= 1e-3).all():
            return None
        if (p[:, 2] <= 1e-3).any():
            # Part of the mesh is beside or behind the camera: its projection is unbounded.
            return np.arange(pr.width * pr.height)
        gh, gw = -(-pr.height // t), -(-pr.width // t)
        u = p[:, 0] / p[:, 2] * pr.fx + pr.cx
        v = p[:, 1] / p[:, 2] * pr.fy + pr.cy
        fa, fb, fc = faces[:, 0], faces[:, 1], faces[:, 2]
        # Column-wise min/max: numpy reduces a length-3 axis slowly.
        ua, ub, uc, va, vb, vc = u[fa], u[fb], u[fc], v[fa], v[fb], v[fc]
        umin, umax = np.minimum(np.minimum(ua, ub), uc), np.maximum(np.maximum(ua, ub), uc)
        vmin, vmax = np.minimum(np.minimum(va, vb), vc), np.maximum(np.maximum(va, vb), vc)
        # One pixel of margin: a pixel's ray can hit a triangle whose box ends just before it.
        tu0 = np.floor((umin - 1.0) / t).clip(0, gw)
        tu1 = np.floor((umax + 1.0) / t).clip(-1, gw - 1)
        tv0 = np.floor((vmin - 1.0) / t).clip(0, gh)
        tv1 = np.floor((vmax + 1.0) / t).clip(-1, gh - 1)
        keep = (tu0 <= tu1) & (tv0 <= tv1)
        tu0, tu1, tv0, tv1 = (a[keep].astype(np.int64) for a in (tu0, tu1, tv0, tv1))
        if len(tu0) == 0:
            return None
        # Mark every rectangle at once: +1/-1 at its corners, then a 2-D prefix sum.
        stride = gw + 1
        idx = np.concatenate([tv0 * stride + tu0, tv0 * stride + tu1 + 1,
                              (tv1 + 1) * stride + tu0, (tv1 + 1) * stride + tu1 + 1])
        w = np.repeat(np.array([1.0, -1.0, -1.0, 1.0]), len(tu0))
        cover = np.bincount(idx, w, minlength=(gh + 1) * stride).reshape(gh + 1, stride)
        tiles = cover.cumsum(0).cumsum(1)[:gh, :gw] > 0.5
        pix = self._tile_pixels[tiles].reshape(-1)
        return pix[pix >= 0] if pr.height % t or pr.width % t else pix

    def _static_view(self, room: bool | Room) -> _StaticView:
        if room is True:
            room = Room()
        if room is False or room is None:
            shape = (self.preset.height, self.preset.width)
            return _StaticView(np.full(shape, np.inf, np.float32), np.ones(shape, np.float32))
        if not isinstance(room, Room):
            raise UserInputError(f"room must be True, False or a sim.room.Room, got {type(room)}")
        if room not in self._static:
            v, f = room.mesh()
            if len(f) == 0:  # no floor, walls, ceiling or clutter: nothing to see
                return self._static_view(False)
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(_o3c.Tensor.from_numpy(v),
                                _o3c.Tensor.from_numpy(f.astype(np.uint32)))
            hit = scene.cast_rays(_o3c.Tensor.from_numpy(self._rays))
            normals = hit["primitive_normals"].numpy()
            cos = np.abs(np.einsum("hwc,hwc->hw", normals, self._rays[..., 3:])) * self._inv_len
            if len(self._static) > 8:  # a handful of rooms per camera at most; bound the cache
                self._static.clear()
            self._static[room] = _StaticView(hit["t_hit"].numpy().astype(np.float32), cos)
        return self._static[room]

    # ---------------------------------------------------------------- sensor model
    def _measure(self, z: np.ndarray, cos: np.ndarray) -> np.ndarray:
        """Ideal z (H, W) metres -> measured depth (H, W) uint16 mm under self.noise."""
        return measure_depth(z, cos, self.preset, self.noise, self.rng)


def measure_depth(z: np.ndarray, cos: np.ndarray, preset: CameraPreset, noise: NoiseModel,
                  rng: np.random.Generator) -> np.ndarray:
    """Ideal depth z (H, W) float32 metres (inf = no hit) and |cos| incidence (H, W) -> (H, W)
    uint16 mm as the sensor would report it. Draws from rng only for the noise terms that are on."""
    z = np.asarray(z, dtype=np.float32)
    flying = None
    if noise.flying_pixels > 0:
        z, flying = _flying_pixels(z, noise.flying_pixels, rng)
    if preset.kind == "tof":
        valid, depth_mm = _tof_depth(z, preset, noise, rng)
    else:
        valid, depth_mm = _stereo_depth(z, preset, noise, rng)
    if flying is not None:  # a mixed return is a measurement, not an edge the matcher drops
        valid |= flying & np.isfinite(z)
    if noise.grazing_deg is not None:
        valid &= cos >= np.float32(np.cos(np.radians(noise.grazing_deg)))
    if noise.dropout > 0:
        valid &= rng.random(z.shape, dtype=np.float32) >= np.float32(noise.dropout)
    if noise.hole_blobs > 0:
        valid &= ~_hole_blobs(rng, z.shape, noise.hole_blobs, noise.hole_blob_px)
    lo, hi = 0.0, 65535.0  # what fits in uint16 millimetres
    if noise.range_limits:
        lo, hi = preset.min_range_m * 1000.0, min(preset.max_range_m * 1000.0, hi)
    valid &= np.isfinite(depth_mm) & (depth_mm >= np.float32(lo)) & (depth_mm <= np.float32(hi))
    return np.rint(np.where(valid, depth_mm, np.float32(0.0))).astype(np.uint16)


def _stereo_depth(z: np.ndarray, preset: CameraPreset, noise: NoiseModel,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(valid, depth mm) of a disparity sensor: noise and quantisation act on disparity."""
    fb = np.float32(preset.fx * preset.baseline_m)
    disp = fb / z  # disparity in px; inf (no hit) gives 0
    valid = disp > 0
    if noise.edge_jump_px > 0:
        valid &= ~_edges(disp, noise.edge_jump_px, noise.edge_width_px)
    if noise.occlusion:
        valid &= ~_occluded(disp)
    sigma = preset.disparity_sigma_px if noise.disparity_sigma_px is None else noise.disparity_sigma_px
    measured = disp
    if sigma > 0:
        measured = disp + _block_noise(rng, z.shape, noise.noise_block_px, np.float32(sigma))
    if noise.quantize:
        step = np.float32(0.5 ** preset.subpixel_bits if noise.subpixel else 1.0)
        measured = np.rint(measured * (1 / step)) * step
    valid &= measured > 0
    return valid, np.float32(1000.0) * fb / np.where(valid, measured, np.float32(1.0))


def _tof_depth(z: np.ndarray, preset: CameraPreset, noise: NoiseModel,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(valid, depth mm) of a time-of-flight sensor: depth noise growing with range, per pixel
    (no matching window), no second view. ``disparity_sigma_px`` of the noise model, when set,
    scales the preset's noise (sigma / 0.1 px, so the training range 0.05-0.3 spans 0.5-3x)."""
    valid = np.isfinite(z)
    zf = np.where(valid, z, np.float32(0.0))
    if noise.edge_jump_px > 0:  # the same relative jump as a stereo edge of that many px at 1 m
        inv = np.where(valid, 1.0 / np.maximum(zf, 1e-3), 0.0).astype(np.float32)
        valid &= ~_edges(inv, noise.edge_jump_px * 0.05, noise.edge_width_px)
    scale = 1.0 if noise.disparity_sigma_px is None else noise.disparity_sigma_px / 0.1
    sigma = np.float32(preset.tof_sigma_m_per_m * scale * 1000.0) * zf
    depth_mm = zf * np.float32(1000.0)
    if scale > 0 and preset.tof_sigma_m_per_m > 0:
        depth_mm = depth_mm + sigma * rng.standard_normal(z.shape, dtype=np.float32)
    return valid & (depth_mm > 0), depth_mm


def _flying_pixels(z: np.ndarray, share: float, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Mixed returns at depth edges: of the pixels next to a neighbour more than 5 % deeper or
    shallower (4-neighbourhood), ``share`` take a depth drawn uniformly between their own and that
    neighbour's. Returns (new z, flying mask)."""
    finite = np.isfinite(z)
    zz = np.where(finite, z, np.float32(0.0))
    other = np.zeros_like(zz)  # the most different neighbour's depth (0 = none)
    gap = np.zeros_like(zz)
    for axis, shift in ((1, 1), (1, -1), (0, 1), (0, -1)):
        nb = np.roll(zz, shift, axis=axis)
        nf = np.roll(finite, shift, axis=axis)
        if axis == 1:
            (nf[:, 0] if shift == 1 else nf[:, -1])[...] = False
        else:
            (nf[0] if shift == 1 else nf[-1])[...] = False
        d = np.where(nf & finite, np.abs(nb - zz), 0.0)
        take = d > gap
        gap = np.where(take, d, gap)
        other = np.where(take, nb, other)
    edge = finite & (gap > np.float32(0.05) * np.maximum(zz, other))
    flying = edge & (rng.random(z.shape, dtype=np.float32) < np.float32(share))
    a = rng.random(z.shape, dtype=np.float32)
    mixed = np.where(flying, zz + a * (other - zz), z).astype(np.float32)
    return mixed, flying


def _hole_blobs(rng: np.random.Generator, shape: tuple[int, int], share: float, blob_px: int) -> np.ndarray:
    """(H, W) bool: about ``share`` of the image in smooth blobs about blob_px across (a coarse
    random field, upsampled bilinearly, thresholded at its 1 - share quantile)."""
    import cv2

    h, w = shape
    small = rng.random((max(h // blob_px, 1) + 1, max(w // blob_px, 1) + 1), dtype=np.float32)
    field = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return field > np.quantile(field, 1.0 - share)


def _block_noise(rng: np.random.Generator, shape: tuple[int, int], block: int,
                 sigma: np.float32) -> np.ndarray:
    """(H, W) float32 Gaussian noise, constant over block x block patches: stereo matching
    aggregates a window, so the errors of neighbouring pixels are correlated."""
    h, w = shape
    b = max(int(block), 1)
    small = rng.standard_normal((-(-h // b), -(-w // b)), dtype=np.float32) * sigma
    if b == 1:
        return small
    return np.repeat(np.repeat(small, b, axis=0), b, axis=1)[:h, :w]


def _edges(disp: np.ndarray, jump_px: float, width_px: int) -> np.ndarray:
    """(H, W) bool: pixels within width_px of a disparity jump larger than jump_px (depth edge)."""
    edge = np.zeros(disp.shape, dtype=bool)
    dx = np.abs(np.diff(disp, axis=1)) > jump_px
    dy = np.abs(np.diff(disp, axis=0)) > jump_px
    edge[:, :-1] |= dx
    edge[:, 1:] |= dx
    edge[:-1, :] |= dy
    edge[1:, :] |= dy
    for _ in range(max(width_px - 1, 0)):  # grow by one pixel per step (4-neighbourhood)
        grown = edge.copy()
        grown[:, 1:] |= edge[:, :-1]
        grown[:, :-1] |= edge[:, 1:]
        grown[1:, :] |= edge[:-1, :]
        grown[:-1, :] |= edge[1:, :]
        edge = grown
    return edge


def _occluded(disp: np.ndarray, tol_px: float = 0.5) -> np.ndarray:
    """(H, W) bool: pixels the second view cannot see (the stereo "shadow" beside foreground).

    The depth image is referenced to the right camera (as depthai does by default); the other
    view sits at -baseline along camera X, where pixel u appears at u + d(u). A pixel is hidden
    there when some pixel to its left lands at or beyond it: max_{u' < u}(u' + d(u')) > u + d(u).
    """
    s = disp + np.arange(disp.shape[1], dtype=np.float32)
    prev = np.maximum.accumulate(s, axis=1)
    hidden = np.zeros(disp.shape, dtype=bool)
    hidden[:, 1:] = prev[:, :-1] > s[:, 1:] + np.float32(tol_px)
    return hidden


def closed_mesh_winding(vertices: np.ndarray, faces: np.ndarray) -> int:
    """+1 if the mesh (V, 3), (F, 3) is closed with faces wound counter-clockwise seen from
    outside, -1 if closed and wound the other way, 0 if not closed or not consistently wound
    (every directed edge must occur exactly once and be matched by its reverse)."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 0
    src = f.reshape(-1)
    dst = f[:, [1, 2, 0]].reshape(-1)
    n = int(f.max()) + 1
    directed = np.sort(src * n + dst)
    if (directed[1:] == directed[:-1]).any():
        return 0
    reverse = np.sort(dst * n + src)
    if not np.array_equal(directed, reverse):
        return 0
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volume = np.einsum("fc,fc->f", a, np.cross(b, c)).sum() / 6.0
    return 1 if volume > 0 else -1 if volume < 0 else 0


# -------------------------------------------------------------------- camera placement
def look_at_camera(distance: float, height: float, yaw: float, pitch: float | None = None,
                   target: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> np.ndarray:
    """camera_to_world (4, 4) for a camera ``distance`` metres from target horizontally, at
    ``height`` metres above the floor, around the subject by ``yaw`` radians (0 = in front of a
    subject facing +z, i.e. at +z looking toward -z; pi/2 = on the subject's left, +x).

    pitch None: look straight at target. Else: face target horizontally, tilted down by pitch
    radians (negative looks up)."""
    t = np.asarray(target, dtype=np.float64)
    eye = t + np.array([distance * np.sin(yaw), 0.0, distance * np.cos(yaw)])
    eye[1] = height
    up = np.array([0.0, 1.0, 0.0])
    if pitch is None:
        fwd = t - eye
    else:
        horiz = np.array([-np.sin(yaw), 0.0, -np.cos(yaw)])
        fwd = np.cos(pitch) * horiz - np.sin(pitch) * up
    n = np.linalg.norm(fwd)
    if n < 1e-9:
        raise UserInputError("look_at_camera: the camera sits on its target")
    fwd /= n
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-6:
        raise UserInputError("look_at_camera: looking straight up or down leaves the roll undefined")
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, fwd, eye
    return m


def random_camera_pose(rng: np.random.Generator, distance: tuple[float, float] = (1.5, 4.0),
                       height: tuple[float, float] = (0.5, 2.0),
                       yaw: tuple[float, float] = (-np.pi, np.pi), pitch_jitter: float = 0.1,
                       target: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> np.ndarray:
    """A random camera_to_world (4, 4) around the subject for training data: uniform distance,
    height and yaw, aimed at target with the pitch jittered uniformly by +-pitch_jitter rad."""
    d = rng.uniform(*distance)
    h = rng.uniform(*height)
    y = rng.uniform(*yaw)
    pitch = np.arctan2(h - target[1], d) + rng.uniform(-pitch_jitter, pitch_jitter)
    return look_at_camera(d, h, y, pitch, target)


__all__ = [
    "CameraPreset", "PRESETS", "get_preset", "NoiseModel", "VirtualDepthCamera", "measure_depth",
    "closed_mesh_winding",
    "look_at_camera", "random_camera_pose",
]
