"""Another renderer for the held-out depth test (research.other_renderer): cameras, rooms, sensors.

Independent of the product's virtual camera (sim.depth_camera, sim.sensor_realism, sim.room):
its own pinhole rays cast with open3d's RaycastingScene, rooms built from open3d primitive meshes
(walls at random distances, a floor that may return nothing, a sofa, a table, shelves, a second
person-sized figure), and two sensor models taken from the literature rather than ours:

* ``structured-light`` (Kinect v1 / PrimeSense): lateral noise of Nguyen, Izadi & Lovell (3DIMPVT
  2012), sigma_L = 0.8 + 0.035 theta / (pi/2 - theta) px at 640 px, cast as jittered rays so edges
  wander; their axial noise sigma_z = 1.2 mm + 1.9 mm (z - 0.4)^2 + 0.1 mm / sqrt(z) theta^2 /
  (pi/2 - theta)^2, applied in disparity; disparity quantised to 1/8 px at 640 px (f b / d,
  Khoshelham & Elberink, Sensors 2012); no depth where the projector's light cannot reach (its
  7.5 cm offset, a second ray cast) and at grazing incidence beyond 78 degrees.
* ``time-of-flight`` (Kinect v2 / Azure Kinect style, Sarbolandi, Lefloch & Kolb, CVIU 2015): every
  pixel integrates four sub-rays spread by the lens (Gaussian, 0.6 px) and the sensor measures the
  phase of the sum of their returns (amplitude albedo cos(theta) / r^2) at 16, 80 and 120 MHz, the
  lowest unwrapping the others: at depth edges the mixed range lies between foreground and
  background or a little beyond (flying pixels) and weak mixed returns
  are discarded (amplitude threshold, as the sensors' invalidation does); shot-noise-limited
  depth noise sigma_r = 1.5 mm r / sqrt(albedo cos(theta)) (sigma ~ 1 / sqrt(amplitude)); 1 mm
  steps.

Meshes are (vertices (V, 3) float32, faces (F, 3) int32) in the world (+y up, metres, the floor
at y = 0); cameras follow docs/conventions.md (OpenCV axes; pixel (u, v) looks along K^-1 (u, v, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

_o3c = o3d.core
Mesh = tuple[np.ndarray, np.ndarray]
SENSORS = ("structured-light", "time-of-flight")
RESOLUTIONS = ((640, 480), (320, 240))
#: Focal length (px at 640 x 480) per sensor: a 58 deg and a 65 deg horizontal field of view.
FOCAL_640 = {"structured-light": 580.0, "time-of-flight": 502.0}
KINECT_BASELINE_M = 0.075
SUBPIXEL = 8  # disparity steps per pixel at 640 px
TOF_MOD_HZ = (16e6, 80e6, 120e6)  # Kinect v2's three modulation frequencies
LIGHT_MPS = 299_792_458.0
RANGE_M = {"structured-light": (0.5, 5.0), "time-of-flight": (0.5, 5.0)}


@dataclass(frozen=True)
class Camera:
    """A pinhole depth camera: image size, intrinsics (px) and camera_to_world (4, 4)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    camera_to_world: np.ndarray

    @property
    def intrinsics(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def scale_to_640(self) -> float:
        return 640.0 / self.width


def make_camera(sensor: str, width: int, height: int, position: np.ndarray, yaw: float, pitch: float) -> Camera:
    """A camera at ``position`` (world), facing the horizontal direction (sin yaw, 0, cos yaw)
    tilted up by ``pitch`` (radians; negative looks down), image x to the right of the view, y down."""
    f = FOCAL_640[sensor] * width / 640.0
    forward = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, position
    return Camera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, c2w)


def camera_rays(cam: Camera, du: np.ndarray | float = 0.0, dv: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 6) float32 world rays [origin, direction] and (H, W, 3) camera-frame directions with
    z = 1 (so a hit distance along them is the depth), pixel centres moved by (du, dv) px."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    d_cam = np.stack([(u + du - cam.cx) / cam.fx, (v + dv - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    rot, origin = cam.camera_to_world[:3, :3], cam.camera_to_world[:3, 3]
    rays = np.concatenate([np.broadcast_to(origin, d_cam.shape), d_cam @ rot.T], axis=-1)
    return rays.astype(np.float32), d_cam


class Scene:
    """Meshes in one open3d RaycastingScene; each mesh keeps an albedo (for time of flight)."""

    def __init__(self, meshes: list[Mesh], albedo: list[float]):
        self.raycaster = o3d.t.geometry.RaycastingScene()
        ids = [self.raycaster.add_triangles(_o3c.Tensor(np.ascontiguousarray(v, np.float32)),
                                            _o3c.Tensor(np.ascontiguousarray(f, np.uint32))) for v, f in meshes]
        self.albedo = np.zeros(max(ids) + 2 if ids else 1)
        self.albedo[ids] = albedo

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_hit (inf: none), geometry id (-1: none), unit normal) per ray of (..., 6) rays."""
        out = self.raycaster.cast_rays(_o3c.Tensor(np.ascontiguousarray(rays, np.float32)))
        t = out["t_hit"].numpy().astype(np.float64)
        gid = out["geometry_ids"].numpy().astype(np.int64)
        gid[~np.isfinite(t)] = -1
        return t, gid, out["primitive_normals"].numpy().astype(np.float64)


def incidence(directions_world: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Angle (radians, 0 = head on) between each ray and the surface it hits (either side)."""
    d = directions_world / np.linalg.norm(directions_world, axis=-1, keepdims=True)
    return np.arccos(np.clip(np.abs(np.sum(d * normals, axis=-1)), 0.0, 1.0))


def ideal_depth(scene: Scene, cam: Camera) -> np.ndarray:
    """(H, W) float64 noise-free depth (m), 0 where nothing is hit."""
    rays, _ = camera_rays(cam)
    t, _, _ = scene.cast(rays)
    return np.where(np.isfinite(t), t, 0.0)


# ---------------------------------------------------------------------------- structured light
def nguyen_lateral_px(theta: np.ndarray) -> np.ndarray:
    """Lateral noise sd (px at 640 px) against incidence angle (Nguyen et al. 2012)."""
    theta = np.minimum(theta, np.radians(85.0))
    return 0.8 + 0.035 * theta / (np.pi / 2 - theta)


def nguyen_axial_m(z: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Axial noise sd (m) against depth (m) and incidence angle (Nguyen et al. 2012)."""
    theta = np.minimum(theta, np.radians(85.0))
    return 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / np.sqrt(np.maximum(z, 0.1)) * theta**2 / (np.pi / 2 - theta) ** 2


def quantise_disparity(z: np.ndarray, focal_640: float, baseline: float = KINECT_BASELINE_M) -> np.ndarray:
    """Depth (m) read back from a disparity f b / z rounded to 1/SUBPIXEL px (f at 640 px)."""
    fb = focal_640 * baseline
    d = np.round(fb / np.maximum(z, 1e-6) * SUBPIXEL) / SUBPIXEL
    return np.where(d > 0, fb / np.maximum(d, 1e-9), 0.0)


def structured_light(scene: Scene, cam: Camera, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float64 depth (m, 0 = none) of a Kinect-v1-like sensor (module doc)."""
    k = cam.scale_to_640
    rays0, _ = camera_rays(cam)
    _, gid0, n0 = scene.cast(rays0)
    theta0 = np.where(gid0 >= 0, incidence(rays0[..., 3:], n0), 0.0)
    # Lateral noise: each pixel samples the scene off its centre (in px of this resolution).
    sd = nguyen_lateral_px(theta0) / k
    du, dv = rng.normal(size=sd.shape) * sd, rng.normal(size=sd.shape) * sd
    rays, _ = camera_rays(cam, du, dv)
    t, gid, normals = scene.cast(rays)
    hit = gid >= 0
    z = np.where(hit, t, 0.0)
    theta = np.where(hit, incidence(rays[..., 3:], normals), 0.0)
    # The projector's shadow: the point must be seen from the projector too.
    c2w = cam.camera_to_world
    projector = c2w[:3, 3] - KINECT_BASELINE_M * c2w[:3, 0]
    points = rays[..., :3].astype(np.float64) + t[..., None] * rays[..., 3:]
    to_point = np.where(hit[..., None], points - projector, np.array([0.0, 0.0, 1.0]))
    dist = np.linalg.norm(to_point, axis=-1)
    shadow_rays = np.concatenate([np.broadcast_to(projector, to_point.shape), to_point / dist[..., None]], axis=-1)
    t_proj, _, _ = scene.cast(shadow_rays)
    lit = t_proj > dist - 0.01
    # Axial noise in disparity (it is what the sensor measures), then 1/8 px steps.
    fb = FOCAL_640["structured-light"] * KINECT_BASELINE_M
    zs = np.maximum(z, 1e-3)
    d = fb / zs + rng.normal(size=z.shape) * nguyen_axial_m(zs, theta) * fb / zs**2
    z = quantise_disparity(fb / np.maximum(d, 1e-6), FOCAL_640["structured-light"])
    near, far = RANGE_M["structured-light"]
    valid = hit & lit & (theta < np.radians(78.0)) & (z >= near) & (z <= far)
    return np.where(valid, z, 0.0)


# ---------------------------------------------------------------------------- time of flight
def phasor_mix(r: np.ndarray, amplitude: np.ndarray, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """(range, amplitude) a continuous-wave ToF pixel measures from several returns (r metres,
    amplitudes) along ``axis``, Kinect v2 style: the phase of the summed phasors at each of
    TOF_MOD_HZ, the lowest frequency's range (unambiguous to its half wavelength) unwrapping the
    others, and the ranges averaged with weights f^2 (a phase error costs less range at a higher
    frequency); the amplitude is the summed phasor's at the middle frequency."""
    r, amplitude = np.moveaxis(np.asarray(r, np.float64), axis, -1), np.moveaxis(np.asarray(amplitude), axis, -1)
    ranges, weights, amp = [], [], None
    coarse = None
    for f in TOF_MOD_HZ:
        k = 4.0 * np.pi * f / LIGHT_MPS  # rad per metre of range
        s = np.sum(amplitude * np.exp(1j * k * r), axis=-1)
        wrap = 2.0 * np.pi / k
        rf = np.mod(np.angle(s), 2.0 * np.pi) / k
        if coarse is None:
            coarse = rf
        else:
            rf = rf + wrap * np.round((coarse - rf) / wrap)
        ranges.append(rf)
        weights.append(f * f)
        if f == TOF_MOD_HZ[1]:
            amp = np.abs(s)
    measured = np.average(np.stack(ranges, -1), axis=-1, weights=weights)
    return measured, amp
def time_of_flight(scene: Scene, cam: Camera, rng: np.random.Generator, spread_px: float = 0.6,
                   min_amplitude: float = 0.008) -> np.ndarray:
    """(H, W) float64 depth (m, 0 = none) of a ToF sensor (module doc)."""
    returns, amps = [], []
    for _ in range(4):
        du = rng.normal(size=(cam.height, cam.width)) * spread_px
        dv = rng.normal(size=(cam.height, cam.width)) * spread_px
        rays, d_cam = camera_rays(cam, du, dv)
        t, gid, normals = scene.cast(rays)
        hit = gid >= 0
        r = np.where(hit, t * np.linalg.norm(d_cam, axis=-1), 0.0)
        cos = np.cos(np.where(hit, incidence(rays[..., 3:], normals), np.pi / 2))
        amp = np.where(hit, scene.albedo[np.maximum(gid, 0)] * cos / np.maximum(r, 0.1) ** 2, 0.0)
        returns.append(r)
        amps.append(amp)
    r_mix, a_mix = phasor_mix(np.stack(returns, -1), np.stack(amps, -1))
    a_mix = a_mix / 4.0
    # Shot noise: sd ~ 1 / sqrt(amplitude); 1.5 mm at 1 m head on with albedo 1.
    sd = 0.0015 / np.sqrt(np.maximum(a_mix, 1e-6))
    r_noisy = r_mix + rng.normal(size=r_mix.shape) * sd
    _, d_centre = camera_rays(cam)
    z = np.round(r_noisy / np.linalg.norm(d_centre, axis=-1) * 1000.0) / 1000.0
    near, far = RANGE_M["time-of-flight"]
    valid = (a_mix >= min_amplitude) & (z >= near) & (z <= far)
    return np.where(valid, z, 0.0)


def render(sensor: str, scene: Scene, cam: Camera, rng: np.random.Generator) -> np.ndarray:
    """(H, W) uint16 depth in millimetres (0 = no data) of ``sensor`` (SENSORS)."""
    z = structured_light(scene, cam, rng) if sensor == "structured-light" else time_of_flight(scene, cam, rng)
    return np.clip(np.round(z * 1000.0), 0, 65535).astype(np.uint16)


# ---------------------------------------------------------------------------- rooms
def _mesh(m: o3d.geometry.TriangleMesh) -> Mesh:
    return np.asarray(m.vertices, np.float32), np.asarray(m.triangles, np.int32)


def box(size: tuple[float, float, float], centre: np.ndarray, yaw: float = 0.0) -> Mesh:
    """An open3d box of ``size`` (x, y, z) centred at ``centre``, turned by ``yaw`` about +y."""
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size) / 2.0)
    m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.0, yaw, 0.0)), center=(0.0, 0.0, 0.0))
    m.translate(np.asarray(centre, np.float64))
    return _mesh(m)


def cylinder(radius: float, height: float, base: np.ndarray) -> Mesh:
    """An upright open3d cylinder standing on ``base``."""
    m = o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution=16, split=1)
    m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((np.pi / 2, 0.0, 0.0)), center=(0.0, 0.0, 0.0))
    m.translate(np.asarray(base, np.float64) + [0.0, height / 2, 0.0])
    return _mesh(m)


def sphere(radius: float, centre: np.ndarray) -> Mesh:
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=12)
    m.translate(np.asarray(centre, np.float64))
    return _mesh(m)


def _local(origin: np.ndarray, yaw: float, x: float, y: float, z: float) -> np.ndarray:
    """A point x right, y up, z forward of ``origin`` in a frame turned by ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return origin + np.array([c * x + s * z, y, -s * x + c * z])


def sofa(at: np.ndarray, yaw: float, rng: np.random.Generator) -> list[Mesh]:
    w = rng.uniform(1.5, 2.2)
    return [box((w, 0.42, 0.85), _local(at, yaw, 0, 0.21, 0), yaw),
            box((w, 0.45, 0.2), _local(at, yaw, 0, 0.62, -0.33), yaw),
            box((0.18, 0.6, 0.85), _local(at, yaw, -w / 2 + 0.09, 0.3, 0), yaw),
            box((0.18, 0.6, 0.85), _local(at, yaw, w / 2 - 0.09, 0.3, 0), yaw)]


def table(at: np.ndarray, yaw: float, rng: np.random.Generator) -> list[Mesh]:
    w, d, h = rng.uniform(0.8, 1.6), rng.uniform(0.6, 0.9), rng.uniform(0.7, 0.78)
    parts = [box((w, 0.04, d), _local(at, yaw, 0, h - 0.02, 0), yaw)]
    for sx in (-1, 1):
        for sz in (-1, 1):
            parts.append(cylinder(0.025, h - 0.04, _local(at, yaw, sx * (w / 2 - 0.06), 0, sz * (d / 2 - 0.06))))
    return parts


def shelves(at: np.ndarray, yaw: float, rng: np.random.Generator) -> list[Mesh]:
    w, h, d = rng.uniform(0.6, 1.2), rng.uniform(1.4, 2.1), 0.35
    parts = [box((w, h, 0.02), _local(at, yaw, 0, h / 2, -d / 2), yaw)]
    parts += [box((0.02, h, d), _local(at, yaw, sx * w / 2, h / 2, 0), yaw) for sx in (-1, 1)]
    parts += [box((w, 0.025, d), _local(at, yaw, 0, y, 0), yaw) for y in np.linspace(0.05, h - 0.02, 5)]
    return parts


def figure(at: np.ndarray, yaw: float, rng: np.random.Generator) -> list[Mesh]:
    """A second person-sized thing: a box or a cylinder-and-sphere figure, 1.5-1.9 m tall."""
    h = rng.uniform(1.5, 1.9)
    if rng.random() < 0.5:
        return [box((rng.uniform(0.4, 0.55), h, rng.uniform(0.25, 0.35)), at + [0.0, h / 2, 0.0], yaw)]
    torso = h - 0.25
    return [cylinder(rng.uniform(0.14, 0.2), torso, at), sphere(0.11, at + [0.0, torso + 0.12, 0.0])]


FURNITURE = {"sofa": sofa, "table": table, "shelves": shelves, "figure": figure}
#: How far each piece reaches from where it stands (half its largest extent, m).
FURNITURE_REACH_M = {"sofa": 1.1, "table": 0.8, "shelves": 0.6, "figure": 0.3}


@dataclass(frozen=True)
class Room:
    """The static meshes around the performer, their albedos, and what they are."""

    meshes: tuple[Mesh, ...]
    albedo: tuple[float, ...]
    items: tuple[str, ...]


def random_room(rng: np.random.Generator, camera_xz: np.ndarray, keep_clear_m: float = 0.9) -> Room:
    """A room around a performer at the origin seen from ``camera_xz``: a floor (one in five
    returns no depth: dark carpet), a wall behind the performer 0.6-3 m away and turned up to 25
    degrees, a side wall with probability 0.6, and one to three of a sofa, a table, shelves and a
    second person-sized figure, placed at least ``keep_clear_m`` from the performer and off the
    line of sight."""
    meshes: list[Mesh] = []
    albedo: list[float] = []
    items: list[str] = []
    cam = np.asarray(camera_xz, np.float64)
    dist = float(np.linalg.norm(cam))
    toward = cam / dist  # performer -> camera, horizontal
    side = np.array([toward[1], -toward[0]])
    view_yaw = float(np.arctan2(toward[0], toward[1]))
    if rng.random() < 0.8:
        meshes.append(box((14.0, 0.02, 14.0), np.array([0.0, -0.01, 0.0])))
        albedo.append(rng.uniform(0.3, 0.8))
        items.append("floor")
    back = rng.uniform(0.6, 3.0)
    c = -toward * back
    meshes.append(box((10.0, 3.0, 0.1), np.array([c[0], 1.5, c[1]]), view_yaw + rng.uniform(-0.45, 0.45)))
    albedo.append(rng.uniform(0.5, 0.9))
    items.append(f"wall {back:.1f} m behind")
    if rng.random() < 0.6:
        off = rng.choice([-1.0, 1.0]) * rng.uniform(1.2, 3.0)
        c = side * off
        meshes.append(box((0.1, 3.0, 10.0), np.array([c[0], 1.5, c[1]]), view_yaw))
        albedo.append(rng.uniform(0.5, 0.9))
        items.append("side wall")
    for name in rng.choice(list(FURNITURE), size=int(rng.integers(1, 4)), replace=False):
        reach = FURNITURE_REACH_M[name]
        for _ in range(30):  # somewhere clear of the performer and of the line of sight
            spot = side * rng.uniform(-2.5, 2.5) + toward * rng.uniform(-back + 0.3, 1.2)
            along, off_line = float(spot @ toward), abs(float(spot @ side))
            if (np.linalg.norm(spot) >= keep_clear_m + reach and along > -back + 0.3
                    and (along < 0.2 or off_line > 0.8 + reach)):
                break
        else:
            continue
        parts = FURNITURE[name](np.array([spot[0], 0.0, spot[1]]), view_yaw + rng.uniform(-0.6, 0.6), rng)
        meshes += parts
        albedo += [float(rng.uniform(0.1, 0.9))] * len(parts)
        items.append(str(name))
    return Room(tuple(meshes), tuple(albedo), tuple(items))


__all__ = ["SENSORS", "RESOLUTIONS", "Camera", "Scene", "Room", "make_camera", "camera_rays", "ideal_depth",
           "render", "structured_light", "time_of_flight", "phasor_mix", "quantise_disparity", "nguyen_axial_m",
           "nguyen_lateral_px", "random_room", "box"]
