"""A body's surface for self-contacts: signed distance grids of its parts and probe points on its
hands and forearms, built once per body (open3d), queried per frame with numpy.

The skin is cut into regions by each vertex's heaviest joint (torso, head, each leg, each hand,
each arm: where the evaluation cuts it) and into rigid parts by the skinning weights: a face is
in a part when the part's joints weigh at least ``PART_WEIGHT`` in one of its vertices and two of
its vertices are of the part's region (neighbouring parts of one region overlap across their
seam; parts of two regions meet at it). Pelvis, the three spine segments, the collars, head and
neck, thighs, shins, upper arms, forearms, hands. Each part gets a grid of the signed distance to
its own skin, in the rest pose and relative to the joint that carries it (the part moves rigidly
with that joint's global rotation); each cell also stores the distance's gradient and the skin
vertex nearest its closest point. A query gives the distance and the direction out of the part,
both continuous (trilinear in the cell), corrected by how far skinning moves that nearest vertex
from where the rigid part puts it (near joints that bend a lot, a bent spine's belly), and
counts it for the part's region.

The sign of a part's distance: the face's normal where the closest point is inside a face, the
angle-weighted vertex normals interpolated there on an edge or a vertex; negative inside. Where
the closest point lies on the part's open edge (the cut to a neighbouring part) the distance
counts as outside: that side is the neighbour's, which covers it.

``PROBE_COUNT`` probe points are spread by farthest-point sampling over each forearm's skin and
each hand's convex hull; they are posed by skinning, like the mesh.

Queries run compiled (live/retarget/contacts_measure.py): a frame measures a few hundred probes
two to five times, and numpy's per-call overhead on arrays that small would be most of the stage.

A surface built for one rest skeleton serves a performer of another size (``BodySurface.scale``):
parts and probes are kept relative to their joints and scaled about them, so a body fitted to a
performer's estimated skeleton needs no new grids. Built models are kept in memory and in the
cache folder (``contact_surfaces``), keyed by the body's arrays.
"""

from __future__ import annotations

import hashlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import UserInputError
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES, pelvis_height
from live.retarget.contacts_measure import probe_gaps, sample_points

#: Grid cell (m) and the margin of a part's grid around its skin (m): more than every contact
#: or clearance distance in use.
GRID_CELL = 0.015
GRID_MARGIN = 0.06
#: Probes farther than this (m) outside a part's skin box are not sampled: their gap counts as
#: FAR, beyond every contact, clearance and broad-phase distance.
BAND = 0.05
FAR = 0.1
#: Weight of a part's joints from which a vertex is in the part.
PART_WEIGHT = 0.25
#: Probes per hand and per forearm (the same count: probe sets are measured as one array).
PROBE_COUNT = 48
#: How far skinning may move a probe from where its joint alone carries it (m): the first,
#: rigid broad phase allows for it.
SKIN_SLACK = 0.08
#: Where skinning moves the grid's nearest vertex more than WALK_FROM (m) from where the part's
#: joint alone carries it (a spine bent over: 5-9 cm), the grid's answer is only a start: the
#: measure walks at most WALK_STEPS edges of the skinned mesh to the nearest skinned vertex. A
#: walk ending on a vertex farther than WALK_REACH (m) from the probe stopped in a local minimum
#: far off (a hand on a child's hip read 13 cm inside its torso): the grid's answer stands.
WALK_STEPS = 32
WALK_FROM = 0.01
WALK_REACH = 0.04
#: Bumped when the grids' layout or meaning changes: older cached models are rebuilt.
MODEL_VERSION = 9


@dataclass(frozen=True)
class PartSpec:
    """A rigid part of the skin: name, the joints whose weights mark its vertices, the joint that
    carries it, and the region it belongs to."""

    name: str
    joints: tuple[str, ...]
    frame: str
    region: str


PARTS: tuple[PartSpec, ...] = (
    PartSpec("pelvis", ("pelvis",), "pelvis", "torso"),
    PartSpec("spine1", ("spine1",), "spine1", "torso"),
    PartSpec("spine2", ("spine2",), "spine2", "torso"),
    PartSpec("spine3", ("spine3",), "spine3", "torso"),
    PartSpec("left_collar", ("left_collar",), "left_collar", "torso"),
    PartSpec("right_collar", ("right_collar",), "right_collar", "torso"),
    PartSpec("head", ("neck", "head"), "neck", "head"),
    PartSpec("left_thigh", ("left_hip",), "left_hip", "left_leg"),
    PartSpec("right_thigh", ("right_hip",), "right_hip", "right_leg"),
    PartSpec("left_shin", ("left_knee",), "left_knee", "left_leg"),
    PartSpec("right_shin", ("right_knee",), "right_knee", "right_leg"),
    PartSpec("left_hand", ("left_wrist",), "left_wrist", "left_hand"),
    PartSpec("right_hand", ("right_wrist",), "right_wrist", "right_hand"),
    PartSpec("left_upper_arm", ("left_shoulder",), "left_shoulder", "left_arm"),
    PartSpec("right_upper_arm", ("right_shoulder",), "right_shoulder", "right_arm"),
    PartSpec("left_forearm", ("left_elbow",), "left_elbow", "left_arm"),
    PartSpec("right_forearm", ("right_elbow",), "right_elbow", "right_arm"),
)
#: What a hand or forearm touches: the union of its parts' skins (their distance: the smallest).
REGIONS: tuple[str, ...] = ("torso", "head", "left_leg", "right_leg", "left_hand", "right_hand", "left_arm",
                            "right_arm")


@dataclass(frozen=True)
class ProbeSpec:
    """Points that may touch or sink into the body: name, the joint carrying them (PROBE_COUNT
    of its dominant-weight vertices are sampled), side, kind (``hand`` or ``forearm``)."""

    name: str
    joint: str
    side: str
    kind: str


PROBES: tuple[ProbeSpec, ...] = (
    ProbeSpec("left_hand", "left_wrist", "left", "hand"),
    ProbeSpec("right_hand", "right_wrist", "right", "hand"),
    ProbeSpec("left_forearm", "left_elbow", "left", "forearm"),
    ProbeSpec("right_forearm", "right_elbow", "right", "forearm"),
)


@dataclass(frozen=True)
class ProbeTargets:
    """What one probe set is tested against: its regions (indices into REGIONS) and, in the same
    order, each region's parts (indices into PARTS)."""

    regions: tuple[int, ...]
    parts: tuple[tuple[int, ...], ...]

    @classmethod
    def of(cls, probe: ProbeSpec) -> ProbeTargets:
        """Every region but the probe set's own arm and hand: torso, head, legs, the other hand and
        arm (a forearm also skips its own collar, next to its elbow when the arm is raised)."""
        regions = [r for r in REGIONS if r not in (f"{probe.side}_hand", f"{probe.side}_arm")]
        skip = {f"{probe.side}_collar"} if probe.kind == "forearm" else set()
        parts = [tuple(k for k, p in enumerate(PARTS) if p.region == r and p.name not in skip) for r in regions]
        return cls(tuple(REGIONS.index(r) for r in regions), tuple(parts))


#: Every probe set, as ``measure`` takes them.
ALL_PROBES = np.arange(len(PROBES))
TARGETS: tuple[ProbeTargets, ...] = tuple(ProbeTargets.of(p) for p in PROBES)


@dataclass(frozen=True, eq=False)
class SurfaceModel:
    """The grids and probes of one body (built by ``build_surface_model``).

    data (M, 4) float32: per cell the signed distance and its gradient, all parts packed;
    nearest (M,): per cell the vertex nearest its closest skin point. Per part k: frame joint
    ``frames[k]``, grid corner ``lo[k]`` relative to that joint's rest position, ``dims[k]``
    cells per axis, ``base[k]`` first row in data, bounding sphere ``centre[k]`` / ``radius[k]``
    (relative to the joint). The skin: rest ``vertices`` (V, 3) with their four heaviest joints
    ``skin_joints`` (V, 4) and weights ``skin_weights`` (V, 4), rest unit ``normals`` (V, 3),
    each vertex's neighbours along the mesh's edges ``ring[ring_start[v]:ring_start[v + 1]]``.
    probes[i]: the vertices of probe set i. rest_joints: the rest skeleton the model was built on."""

    data: np.ndarray
    nearest: np.ndarray
    frames: np.ndarray
    lo: np.ndarray
    dims: np.ndarray
    base: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    vertices: np.ndarray
    skin_joints: np.ndarray
    skin_weights: np.ndarray
    normals: np.ndarray
    ring_start: np.ndarray
    ring: np.ndarray
    probes: tuple[np.ndarray, ...]
    rest_joints: np.ndarray
    cell: float

    def __post_init__(self) -> None:
        # The arrays the compiled queries (live/retarget/contacts_measure.py) read, in the types
        # they are compiled for: per part the strides of its grid's rows, the last cell corner.
        dims = np.asarray(self.dims, np.int64)
        sz, syz = dims[:, 2], dims[:, 1] * dims[:, 2]
        object.__setattr__(self, "_strides", np.stack([syz, sz, np.ones_like(sz)], axis=1).astype(np.float64))
        object.__setattr__(self, "_top", dims - 1.000001)
        object.__setattr__(self, "_data", np.asarray(self.data, np.float64))
        object.__setattr__(self, "_skin_joints", np.ascontiguousarray(self.skin_joints, np.int64))
        object.__setattr__(self, "_skin_weights", np.ascontiguousarray(self.skin_weights, np.float64))
        object.__setattr__(self, "_normals", np.ascontiguousarray(self.normals, np.float64))
        object.__setattr__(self, "_ring_start", np.ascontiguousarray(self.ring_start, np.int64))
        object.__setattr__(self, "_ring", np.ascontiguousarray(self.ring, np.int64))
        object.__setattr__(self, "vertex_region", JOINT_REGION_INDEX[np.asarray(self.skin_joints, np.int64)[:, 0]])
        # Each part's skin box (the grid less its margin), relative to its joint: centre, half size.
        top = self.lo + (dims - 1) * self.cell - GRID_MARGIN
        bottom = self.lo + GRID_MARGIN
        object.__setattr__(self, "box_centre", 0.5 * (top + bottom))
        object.__setattr__(self, "box_half", 0.5 * (top - bottom))
        # Each probe set's bounding sphere in its joint's frame: the broad phase's first, cheap
        # test (no skinning) of whether anything is near at all.
        joints = np.array([JOINT_INDEX[p.joint] for p in PROBES], np.int64)
        rel = [self.vertices[v] - self.rest_joints[j] for v, j in zip(self.probes, joints)]
        mid = np.array([0.5 * (r.min(0) + r.max(0)) for r in rel])
        object.__setattr__(self, "probe_vertices", np.ascontiguousarray(np.stack(self.probes), np.int64))
        object.__setattr__(self, "probe_joint", joints)
        object.__setattr__(self, "probe_centre", mid)
        object.__setattr__(self, "probe_radius", np.array([np.sqrt(((r - c) ** 2).sum(1)).max() for r, c in zip(rel, mid)]))

    def sample(self, parts: np.ndarray, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance and gradient (Q, 4) (gradient not unit) of parts[q] at local[q] (Q, 3),
        points relative to the part's joint in the model's rest units, and the vertex nearest
        each point's closest skin point (Q,). Beyond a grid's edge the distance grows by the
        distance to the edge (continuous; the margin already puts it past every contact distance)."""
        return sample_points(self._data, self.nearest, self.lo, self._top, self._strides, self.base, float(self.cell),
                             np.ascontiguousarray(parts, np.int64), np.ascontiguousarray(local, np.float64))


@dataclass(frozen=True, eq=False)
class BodySurface:
    """A SurfaceModel placed on a rest skeleton: ``scale`` times the model's size about each joint."""

    model: SurfaceModel
    scale: float = 1.0

    def fitted(self, rest_joints: np.ndarray) -> BodySurface:
        """The same body resized to another rest skeleton (by the ratio of pelvis heights)."""
        return BodySurface(self.model, pelvis_height(rest_joints) / pelvis_height(self.model.rest_joints))

    def distances(self, glob: np.ndarray, pos: np.ndarray, points: np.ndarray, parts: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distances (K, N) of world points (N, 3) to parts (K,) in a pose, with each part
        moved rigidly by its joint; the unit world directions out of each part (K, N, 3); the
        vertex nearest each closest skin point (K, N)."""
        m = self.model
        frames = np.take(m.frames, parts)
        rot = np.take(glob, frames, axis=0)  # (K, 3, 3)
        rel = points[None, :, :] - np.take(pos, frames, axis=0)[:, None, :]
        local = np.matmul(rel, rot) * (1.0 / self.scale)  # rows: R^T (p - t)
        k, n = len(parts), len(points)
        out, nearest = m.sample(np.repeat(parts, n), local.reshape(-1, 3))
        out = out.reshape(k, n, 4)
        grad = np.matmul(out[..., 1:], np.swapaxes(rot, 1, 2))
        norm = np.sqrt(np.einsum("kni,kni->kn", grad, grad))
        return out[..., 0] * self.scale, grad / np.maximum(norm, 1e-9)[..., None], nearest.reshape(k, n)


# ------------------------------------------------------------------------------------- building


def _farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` points spread by farthest-point sampling (deterministic: starts at the
    point farthest from the centroid)."""
    count = min(count, len(points))
    chosen = [int(np.argmax(((points - points.mean(0)) ** 2).sum(-1)))]
    dist = ((points - points[chosen[0]]) ** 2).sum(-1)
    while len(chosen) < count:
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, ((points - points[nxt]) ** 2).sum(-1))
    return np.array(chosen, np.int64)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Angle-weighted vertex normals (unit) of a triangle mesh: the pseudo-normals that tell
    inside from outside at a vertex (Baerentzen and Aanaes)."""
    v = vertices[faces]  # (F, 3, 3)
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    fn /= np.maximum(np.sqrt((fn * fn).sum(1)), 1e-20)[:, None]
    out = np.zeros_like(vertices)
    count = len(vertices)
    for c in range(3):
        a = v[:, (c + 1) % 3] - v[:, c]
        b = v[:, (c + 2) % 3] - v[:, c]
        cos = (a * b).sum(1) / np.maximum(np.sqrt((a * a).sum(1) * (b * b).sum(1)), 1e-20)
        weighted = fn * np.arccos(np.clip(cos, -1.0, 1.0))[:, None]
        for i in range(3):  # bincount: a scatter-add many times faster than np.add.at
            out[:, i] += np.bincount(faces[:, c], weights=weighted[:, i], minlength=count)
    return out / np.maximum(np.sqrt((out * out).sum(1)), 1e-20)[:, None]


def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(Q, 3) barycentric weights of points p on triangles (a, b, c)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-30)
    wb = (d11 * d20 - d01 * d21) / den
    wc = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - wb - wc, wb, wc], axis=1)


def border_vertices(faces: np.ndarray, count: int) -> np.ndarray:
    """(count,) bool: vertices on the open edge of a skin made of ``faces`` (edges of one face)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    border = np.zeros(count, bool)
    border[uniq[counts == 1].ravel()] = True
    return border


def signed_distances(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, points: np.ndarray,
                     border: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distances (Q,) of points (Q, 3) to the skin made of ``faces`` of a mesh (vertices,
    unit vertex normals), the unit directions out of it (Q, 3) and the vertex nearest each
    closest point (Q,). Negative inside, by the normals interpolated at the closest point; a
    closest point on the skin's open edge (where its faces end; ``border``:
    ``border_vertices(faces)``, computed when not given) counts as outside."""
    import open3d as o3d

    if border is None:
        border = border_vertices(faces, len(vertices))
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32))
    mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    hit = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, np.float32)))
    closest = hit["points"].numpy().astype(np.float64)
    tri = faces[hit["primitive_ids"].numpy().astype(np.int64)]
    bary = barycentric(closest, vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]])
    # Inside or outside: by the face's own normal where the closest point is inside a face (exact),
    # by the vertex normals interpolated there where it is on an edge or a vertex (the
    # angle-weighted normals are the pseudo-normals that decide it at a vertex).
    on_edge = bary < 1e-4
    corners = vertices[tri]
    face_n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    smooth = np.where(on_edge.any(1)[:, None], np.einsum("qc,qci->qi", bary, normals[tri]), face_n)
    gap = points - closest
    dist = np.sqrt((gap * gap).sum(1))
    sign = np.where((gap * smooth).sum(1) < 0.0, -1.0, 1.0)
    # A zero weight puts the point on the opposite edge (two: on a vertex); on the border when
    # every vertex it lies between is.
    at_border = on_edge.any(1) & np.where(on_edge, True, border[tri]).all(1)
    sign[at_border] = 1.0
    touching = dist < 1e-6
    smooth /= np.maximum(np.sqrt((smooth * smooth).sum(1)), 1e-20)[:, None]
    direction = np.where(touching[:, None], smooth, gap / np.maximum(dist, 1e-12)[:, None]) * sign[:, None]
    direction[at_border & touching] = smooth[at_border & touching]
    nearest = tri[np.arange(len(tri)), bary.argmax(1)]
    return sign * dist, direction, nearest


def winding_numbers(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, chunk: int = 200_000) -> np.ndarray:
    """Generalised winding numbers (Q,) of points (Q, 3) about a triangle skin (Jacobson, Kavan
    and Sorkine-Hornung 2013): the summed solid angles of its faces over 4 pi, about 1 inside
    and 0 outside even where the skin is open or folds over itself (as skinned meshes do at a
    deeply bent hip), where the closest face's normal can say inside 30 cm away."""
    out = np.zeros(len(points))
    corners = vertices[faces]  # (F, 3, 3)
    step = max(1, chunk // max(len(faces), 1))
    for start in range(0, len(points), step):
        p = points[start:start + step]
        rel = corners[None] - p[:, None, None, :]  # (P, F, 3, 3)
        a, b, c = rel[..., 0, :], rel[..., 1, :], rel[..., 2, :]
        la, lb, lc = (np.sqrt((x * x).sum(-1)) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la + (c * a).sum(-1) * lb
        out[start:start + step] = (2.0 * np.arctan2(det, den)).sum(1) / (4.0 * np.pi)
    return out


def _part_grid(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, origin: np.ndarray,
               cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance grid of one part's skin (its faces of the whole mesh): (lo (3,) relative to
    ``origin``, dims (3,), data (cells, 4), nearest vertex (cells,))."""
    used = np.unique(faces)
    lo = vertices[used].min(0) - GRID_MARGIN
    hi = vertices[used].max(0) + GRID_MARGIN
    dims = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    axes = [lo[i] + cell * np.arange(dims[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    dist, direction, nearest = signed_distances(vertices, normals, faces, pts)
    data = np.concatenate([dist[:, None], direction], axis=1).astype(np.float32)
    return lo - origin, dims, data, nearest.astype(np.int32)


def _probe_vertices(vertices: np.ndarray, members: np.ndarray, kind: str) -> np.ndarray:
    """PROBE_COUNT of a hand's or forearm's vertices, spread by farthest-point sampling. A
    forearm's over its whole skin: its rest pose's hull leaves the flat inner side, which a bent
    elbow and a belly press on, without probes (a forearm 12 mm inside a child's belly 37 mm from
    its nearest hull probe measured 2 mm outside). A hand's over its convex hull first (what sinks
    deepest is on the hull: sampled evenly over the whole skin, fingers and all, 32 probes missed
    a hand's deepest point by 7 mm on average); then, when the hull has too few, the other
    vertices, farthest from the hull's first."""
    from scipy.spatial import ConvexHull, QhullError

    pts = vertices[members]
    if kind == "forearm":
        return np.resize(members[_farthest_points(pts, PROBE_COUNT)], PROBE_COUNT)
    try:
        hull = np.unique(ConvexHull(pts).vertices)
    except (QhullError, ValueError):
        hull = np.arange(len(pts))
    chosen = list(hull[_farthest_points(pts[hull], min(PROBE_COUNT, len(hull)))])
    rest = np.setdiff1d(np.arange(len(pts)), chosen)
    while len(chosen) < PROBE_COUNT and len(rest):
        d = np.min(((pts[rest][:, None] - pts[chosen][None]) ** 2).sum(-1), axis=1)
        chosen.append(int(rest[np.argmax(d)]))
        rest = np.setdiff1d(rest, chosen)
    return np.resize(members[np.asarray(chosen, np.int64)], PROBE_COUNT)  # a coarse mesh repeats some


def build_surface_model(body, cell: float = GRID_CELL) -> SurfaceModel:
    """Grids and probes of a body (vertices, faces, weights, rest_joints as live.body.Body)."""
    vertices = np.asarray(body.vertices, np.float64)
    faces = np.asarray(body.faces, np.int64)
    weights = np.asarray(body.weights, np.float64)
    rest = np.asarray(body.rest_joints, np.float64)
    if len(faces) == 0:
        raise UserInputError("self-contacts need an avatar mesh (faces); a point cloud has none")
    normals = vertex_normals(vertices, faces)
    blocks, nearest, frames, los, dims, bases, centres, radii = [], [], [], [], [], [], [], []
    row = 0
    region_of = JOINT_REGION_INDEX[weights.argmax(1)]
    for spec in PARTS:
        cols = [JOINT_INDEX[n] for n in spec.joints]
        member = weights[:, cols].sum(1) >= PART_WEIGHT
        # Cut at the region's seam, as the evaluation cuts the skin: overlapping the hand's skin,
        # a forearm's grid counted its samples by the wrist for the hand, and a hand holding that
        # forearm there read far from it.
        part_faces = faces[member[faces].any(1) & skin_faces(faces, region_of == REGIONS.index(spec.region))]
        frame = JOINT_INDEX[spec.frame]
        if len(part_faces) == 0:
            # No skin on this joint (a VRM's spine often skips a segment): a part never near.
            lo, dim = np.zeros(3), np.full(3, 2, np.int64)
            data = np.tile(np.array([[FAR, 0.0, 0.0, 0.0]], np.float32), (8, 1))
            near, mid, radius = np.zeros(8, np.int32), np.zeros(3), -1e9
        else:
            lo, dim, data, near = _part_grid(vertices, normals, part_faces, rest[frame], cell)
            used = vertices[np.unique(part_faces)] - rest[frame]
            mid = 0.5 * (used.min(0) + used.max(0))
            radius = float(np.sqrt(((used - mid) ** 2).sum(1)).max())
        blocks.append(data)
        nearest.append(near)
        frames.append(frame)
        los.append(lo)
        dims.append(dim)
        bases.append(row)
        centres.append(mid)
        radii.append(radius)
        row += len(data)
    dominant = weights.argmax(1)
    probes = []
    for spec in PROBES:
        members = np.flatnonzero(dominant == JOINT_INDEX[spec.joint])
        if len(members) < 4:
            raise UserInputError(f"the avatar mesh has no skin weighted to its {spec.joint}")
        probes.append(_probe_vertices(vertices, members, spec.kind))
    # Each vertex's four heaviest joints, renormalised: skinning a few vertices per frame.
    heavy = np.argsort(-weights, axis=1, kind="stable")[:, :4]
    heavy_w = np.take_along_axis(weights, heavy, axis=1)
    heavy_w /= np.maximum(heavy_w.sum(1, keepdims=True), 1e-12)
    ring_start, ring = vertex_rings(faces, len(vertices))
    return SurfaceModel(data=np.concatenate(blocks), nearest=np.concatenate(nearest), frames=np.array(frames, np.int64),
                        lo=np.array(los), dims=np.array(dims, np.int64), base=np.array(bases, np.int64),
                        centre=np.array(centres), radius=np.array(radii), vertices=vertices.copy(),
                        skin_joints=heavy.astype(np.int64), skin_weights=heavy_w, normals=normals,
                        ring_start=ring_start, ring=ring, probes=tuple(probes), rest_joints=rest.copy(), cell=float(cell))


def skin_faces(faces: np.ndarray, member: np.ndarray) -> np.ndarray:
    """(F,) whether each face is in the skin of the vertices ``member`` (V,) marks: two or more of
    its vertices are (the cut of the parts' grids, of the evaluation's regions and of the contact
    clips' targets)."""
    return member[faces].sum(1) >= 2


def vertex_rings(faces: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's neighbours along the mesh's edges, packed: (start (count + 1,), neighbours):
    vertex v's are neighbours[start[v]:start[v + 1]], sorted."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.unique(np.concatenate([edges, edges[:, ::-1]]), axis=0)  # both ways, sorted by vertex
    start = np.zeros(count + 1, np.int64)
    np.cumsum(np.bincount(edges[:, 0], minlength=count), out=start[1:])
    return start, edges[:, 1].astype(np.int64)


# -------------------------------------------------------------------------------------- caching

_MEMO_LOCK = threading.Lock()
_MEMO: dict[str, SurfaceModel] = {}
_ARRAYS = ("data", "nearest", "frames", "lo", "dims", "base", "centre", "radius", "vertices", "skin_joints",
           "skin_weights", "normals", "ring_start", "ring", "rest_joints")


def _key(body) -> str:
    h = hashlib.sha1(f"v{MODEL_VERSION} {GRID_CELL} {GRID_MARGIN} {PART_WEIGHT} {PROBE_COUNT}".encode())
    for a in (body.vertices, body.faces, body.weights, body.rest_joints):
        arr = np.ascontiguousarray(a)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()[:20]


def _save(path: Path, model: SurfaceModel) -> None:
    arrays = {k: getattr(model, k) for k in _ARRAYS}
    arrays.update({f"probe{i}": p for i, p in enumerate(model.probes)}, cell=np.array(model.cell))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _load(path: Path) -> SurfaceModel | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            fields = {k: z[k] for k in _ARRAYS}
            probes = tuple(z[f"probe{i}"] for i in range(len(PROBES)))
            cell = float(z["cell"])
    except (OSError, KeyError, ValueError, EOFError):
        return None  # a damaged or older cache file: built again
    if len(fields["frames"]) != len(PARTS):
        return None
    return SurfaceModel(probes=probes, cell=cell, **fields)


def surface_model(body) -> SurfaceModel:
    """The body's SurfaceModel: from memory, from the cache folder, or built (about a second)."""
    key = _key(body)
    with _MEMO_LOCK:
        hit = _MEMO.get(key)
    if hit is not None:
        return hit
    path = assets.cache_dir("contact_surfaces") / f"{key}.npz"
    model = _load(path) if path.is_file() else None
    if model is None:
        model = build_surface_model(body)
        try:
            _save(path, model)
        except OSError:
            pass  # a read-only cache: built again next time
    with _MEMO_LOCK:
        if len(_MEMO) >= 16:
            _MEMO.pop(next(iter(_MEMO)))
        _MEMO[key] = model
    return model


def warm_up(surface: BodySurface) -> None:
    """Compile ``measure``'s kernel, or read it from numba's cache: a few seconds the first time on
    a machine, then a fraction of one per process; better spent before a stream than on its
    first frame with a hand near the body."""
    m = surface.model
    measure(surface, np.broadcast_to(np.eye(3), (len(m.rest_joints), 3, 3)), m.rest_joints, ALL_PROBES, 0.0, 0.003)


def body_surface(body) -> BodySurface:
    """The surface of a body (a live.body.Body with a mesh) on its own rest skeleton."""
    return BodySurface(surface_model(body))



#: ALLOWED[i, k]: probe set i is tested against part k (TARGETS as a table).
ALLOWED = np.zeros((len(PROBES), len(PARTS)), bool)
for _i, _t in enumerate(TARGETS):
    for _parts in _t.parts:
        ALLOWED[_i, list(_parts)] = True
#: The region of each part (index into REGIONS).
PART_REGION = np.array([REGIONS.index(p.region) for p in PARTS], np.int64)
assert set(PART_REGION.tolist()) == set(range(len(REGIONS))), "every region needs a part"
#: The region of a vertex by its heaviest joint (feet with their legs; -1: none).
JOINT_REGION = {"pelvis": "torso", "spine1": "torso", "spine2": "torso", "spine3": "torso", "left_collar": "torso",
                "right_collar": "torso", "neck": "head", "head": "head", "left_hip": "left_leg",
                "left_knee": "left_leg", "left_ankle": "left_leg", "left_foot": "left_leg", "right_hip": "right_leg",
                "right_knee": "right_leg", "right_ankle": "right_leg", "right_foot": "right_leg",
                "left_wrist": "left_hand", "right_wrist": "right_hand", "left_shoulder": "left_arm",
                "left_elbow": "left_arm", "right_shoulder": "right_arm", "right_elbow": "right_arm"}
#: JOINT_REGION as indices into REGIONS, per joint.
JOINT_REGION_INDEX = np.array([REGIONS.index(JOINT_REGION[n]) for n in JOINT_NAMES], np.int64)


@dataclass(frozen=True)
class Gaps:
    """Gaps of probe sets to regions in one pose, one row per (probe set, region) near enough to
    be measured: probe (G,) and region (G,) indices, gap (G,) signed metres, direction (G, 3)
    unit, out of the region, point (G, 3) on the probe set where it is closest."""

    probe: np.ndarray
    region: np.ndarray
    gap: np.ndarray
    direction: np.ndarray
    point: np.ndarray

    @classmethod
    def empty(cls) -> Gaps:
        none = np.zeros(0, np.int64)
        return cls(none, none, np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))


def measure(surface: BodySurface, glob: np.ndarray, pos: np.ndarray, probes: np.ndarray, reach: np.ndarray | float,
            tau: float, band: np.ndarray | float = BAND) -> Gaps:
    """Gaps of probe sets (indices into PROBES) to the regions they are tested against, in a pose
    (glob (22, 3, 3), pos (22, 3)), in one compiled pass (live/retarget/contacts_measure.py).

    Broad phase: a part is measured when its bounding sphere comes within ``reach`` (per probe
    set or one value) of the probe set's, and then only at the probes within ``band`` (per probe
    set or one value; default BAND) of its skin's
    box. Each distance counts for its part's region. A region's gap is the least of its probes'
    distances, each part moved rigidly by its joint and then corrected by how far skinning moves
    the nearest skin vertex out of that rigid place (a bent spine's belly), or, where skinning
    moved it more than WALK_FROM, measured on the skinned mesh from there: the nearest probe's;
    its direction and point are softmin-weighted (length ``tau``), so that they change
    continuously as the closest probe or part changes. Regions with no probe that near are left out."""
    m = surface.model
    probes = np.ascontiguousarray(probes, np.int64)
    reach_of, band_of = (np.full(len(probes), float(v)) if np.ndim(v) == 0 else np.ascontiguousarray(v, np.float64)
                         for v in (reach, band))
    return Gaps(*probe_gaps(np.ascontiguousarray(glob, np.float64), np.ascontiguousarray(pos, np.float64),
                            float(surface.scale), probes, reach_of, band_of, float(SKIN_SLACK), float(tau),
                            m.probe_vertices, m.probe_joint, m.probe_centre, m.probe_radius, ALLOWED,
                            m.frames, m.centre, m.radius, m.box_centre, m.box_half, m._data, m.nearest, m.lo,
                            m._top, m._strides, m.base, float(m.cell), m.vertex_region, m.vertices, m.rest_joints,
                            m._skin_joints, m._skin_weights, m._normals, m._ring_start, m._ring, int(WALK_STEPS), float(WALK_FROM), float(WALK_REACH),
                            PART_REGION))
