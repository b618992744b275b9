"""Static scene geometry for the virtual depth camera: a room, clutter boxes, a stand-in person.

Meshes are ``(vertices (V, 3) float32, faces (F, 3) int32)`` in world coordinates (+Y up,
metres, floor at y = 0). The subject stands at the origin facing +z, so the room is centred on
the origin and whatever wall lies opposite the camera is "behind the subject".
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from live.core.errors import UserInputError
from live.core.heading import yaw_matrix
from live.core.skeleton import BONES, JOINT_INDEX, NUM_JOINTS

Mesh = tuple[np.ndarray, np.ndarray]

# The 12 triangles of a unit cube [-0.5, 0.5]^3, outward winding.
_CUBE_V = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float32
)
_CUBE_F = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
    dtype=np.int32,
)


@dataclass(frozen=True)
class Box:
    """An axis-aligned (up to a yaw about +Y) box: centre (x, y, z), size (sx, sy, sz), metres."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0

    def mesh(self) -> Mesh:
        v = (_CUBE_V * np.asarray(self.size)) @ yaw_matrix(self.yaw).T + np.asarray(self.center)
        return v.astype(np.float32), _CUBE_F.copy()


@dataclass(frozen=True)
class Room:
    """A rectangular room centred on the subject: floor (y = 0), optional walls and ceiling.

    width along x, depth along z, height along y (metres); boxes are clutter (furniture).
    floor False: a floor the sensor returns nothing from (dark or shiny: no depth there), left
    out of the mesh (nothing lies under it, so it hides nothing either).
    Frozen and hashable so that a camera can cache what it sees of it.
    """

    width: float = 8.0
    depth: float = 8.0
    height: float = 3.0
    walls: bool = True
    ceiling: bool = False
    boxes: tuple[Box, ...] = field(default_factory=tuple)
    floor: bool = True

    def mesh(self) -> Mesh:
        """The room as one triangle mesh (a few dozen triangles)."""
        hx, hz, h = self.width / 2, self.depth / 2, self.height
        quads = [[(-hx, 0, -hz), (hx, 0, -hz), (hx, 0, hz), (-hx, 0, hz)]] if self.floor else []
        if self.walls:
            quads += [
                [(-hx, 0, -hz), (hx, 0, -hz), (hx, h, -hz), (-hx, h, -hz)],
                [(-hx, 0, hz), (hx, 0, hz), (hx, h, hz), (-hx, h, hz)],
                [(-hx, 0, -hz), (-hx, 0, hz), (-hx, h, hz), (-hx, h, -hz)],
                [(hx, 0, -hz), (hx, 0, hz), (hx, h, hz), (hx, h, -hz)],
            ]
        if self.ceiling:
            quads.append([(-hx, h, -hz), (hx, h, -hz), (hx, h, hz), (-hx, h, hz)])
        verts = np.asarray(quads, dtype=np.float32).reshape(-1, 3)
        base = np.arange(len(quads), dtype=np.int32)[:, None] * 4
        faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
        return merge_meshes([(verts, faces)] + [b.mesh() for b in self.boxes])


def merge_meshes(meshes: list[Mesh]) -> Mesh:
    """Concatenate meshes into one (faces re-indexed)."""
    verts, faces, n = [], [], 0
    for v, f in meshes:
        verts.append(np.asarray(v, dtype=np.float32))
        faces.append(np.asarray(f, dtype=np.int32) + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def random_room(
    rng: np.random.Generator, n_boxes: tuple[int, int] = (0, 4), keep_out_m: float = 1.0
) -> Room:
    """A room of random size with random clutter boxes standing on the floor, none closer
    than keep_out_m (horizontally) to the subject at the origin, for training-data variety."""
    width, depth = rng.uniform(5.0, 10.0, size=2)
    boxes = []
    for _ in range(int(rng.integers(n_boxes[0], n_boxes[1] + 1))):
        size = rng.uniform((0.3, 0.3, 0.3), (1.5, 1.5, 1.2))
        # Rejection sampling of the position: the keep-out disc is small next to the room.
        while True:
            x = rng.uniform(-width / 2 + 0.5, width / 2 - 0.5)
            z = rng.uniform(-depth / 2 + 0.5, depth / 2 - 0.5)
            if np.hypot(x, z) - np.hypot(size[0], size[2]) / 2 > keep_out_m:
                break
        boxes.append(Box((float(x), float(size[1] / 2), float(z)),
                         tuple(float(s) for s in size), float(rng.uniform(-np.pi, np.pi))))
    return Room(width=float(width), depth=float(depth), height=float(rng.uniform(2.4, 3.5)),
                boxes=tuple(boxes))


def clear_view(room: Room, eye: np.ndarray, margin_m: float = 0.4) -> Room:
    """The room grown to hold the camera, without the clutter boxes that stand between the
    camera at ``eye`` (3,) and the performer at the origin (we train on people in clear view)."""
    cam = np.asarray(eye, np.float64)[[0, 2]]
    keep = []
    for box in room.boxes:
        c = np.asarray(box.center)[[0, 2]]
        r = 0.5 * np.hypot(box.size[0], box.size[2]) + margin_m
        t = np.clip(c @ cam / max(cam @ cam, 1e-9), 0.0, 1.0)  # closest point of the sight line
        if np.linalg.norm(c - t * cam) > r:
            keep.append(box)
    reach = 2.0 * float(np.abs(cam).max()) + 1.5
    return replace(room, width=max(room.width, reach), depth=max(room.depth, reach), boxes=tuple(keep))


def capsule_mesh(a: np.ndarray, b: np.ndarray, radius: float, n_lon: int = 16, n_lat: int = 10) -> Mesh:
    """A closed capsule from point a to point b (3,), radius metres; (V, 3), (F, 3).

    Built as a UV sphere whose upper hemisphere is moved to b and lower one to a, so the
    cylinder between them comes from the equator band for free."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    axis = b - a
    length = float(np.linalg.norm(axis))
    w = axis / length if length > 1e-9 else np.array([0.0, 1.0, 0.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    # n_lat even so that the equator falls between two rings: rings [0, n_lat/2) go to b.
    theta = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]  # polar angle of each ring, from +w
    phi = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    st, ct = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    ring = (np.cos(phi)[None, :, None] * u + np.sin(phi)[None, :, None] * v) * st + ct * w
    centre = np.where((theta < np.pi / 2)[:, None, None], b, a)
    pts = (radius * ring + centre).reshape(-1, 3)
    verts = np.concatenate([pts, [b + radius * w, a - radius * w]])
    n_ring = len(theta)
    top, bottom = n_ring * n_lon, n_ring * n_lon + 1
    faces = []
    j = np.arange(n_lon)
    jn = (j + 1) % n_lon
    for i in range(n_ring - 1):
        r0, r1 = i * n_lon, (i + 1) * n_lon
        faces.append(np.stack([r0 + j, r1 + j, r1 + jn], 1))
        faces.append(np.stack([r0 + j, r1 + jn, r0 + jn], 1))
    faces.append(np.stack([np.full(n_lon, top), j, jn], 1))
    last = (n_ring - 1) * n_lon
    faces.append(np.stack([np.full(n_lon, bottom), last + jn, last + j], 1))
    return verts.astype(np.float32), np.concatenate(faces).astype(np.int32)


# Radius (metres, for a 1.75 m adult) of the capsule ending at each joint (bone parent -> joint).
_BONE_RADIUS = {
    "left_hip": 0.09, "right_hip": 0.09, "spine1": 0.13, "left_knee": 0.075, "right_knee": 0.075,
    "spine2": 0.14, "left_ankle": 0.055, "right_ankle": 0.055, "spine3": 0.15, "left_foot": 0.045,
    "right_foot": 0.045, "neck": 0.055, "left_collar": 0.07, "right_collar": 0.07, "head": 0.1,
    "left_shoulder": 0.07, "right_shoulder": 0.07, "left_elbow": 0.05, "right_elbow": 0.05,
    "left_wrist": 0.04, "right_wrist": 0.04,
}


def capsule_body(joints: np.ndarray, scale: float = 1.0, n_lon: int = 24, n_lat: int = 14) -> Mesh:
    """A stand-in person: one capsule per bone of a posed 22-joint skeleton (22, 3) world,
    plus a head. About 7k vertices at the default resolution; radii scale with ``scale``.

    Used where no body from the body library is at hand (tests, benchmarks, figures)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (NUM_JOINTS, 3):
        raise UserInputError(f"capsule_body needs (22, 3) joints, got {joints.shape}")
    parts = []
    for parent, child in BONES:
        name = next(k for k, i in JOINT_INDEX.items() if i == child)
        parts.append(capsule_mesh(joints[parent], joints[child], _BONE_RADIUS[name] * scale,
                                  n_lon, n_lat))
    head, neck = joints[JOINT_INDEX["head"]], joints[JOINT_INDEX["neck"]]
    up = head - neck
    up /= max(np.linalg.norm(up), 1e-9)
    parts.append(capsule_mesh(head, head + 0.08 * scale * up, 0.1 * scale, n_lon, n_lat))
    return merge_meshes(parts)
