"""Avatars: ``load_avatar(spec) -> Body`` for a body preset, a body file, or any T-pose mesh / cloud.

A preset name, a body ``.npz`` or an ``anny:...`` phenotype goes to live.body.library.load_body. A VRM,
or a glTF / GLB with a skin, brings its own skeleton and skin (live/body/gltf_avatar.py). Any other
file that open3d reads (OBJ, PLY, glTF/GLB, OFF, STL as meshes; PLY/PCD/XYZ/PTS as point clouds)
is taken as a humanoid in the T-pose (y up, arms along x), in metres (a figure taller than 3 units
is read as centimetres, taller than 300 as millimetres). Which way it faces, +z or -z, is told by
its feet (``facing_sign``: toes reach further ahead of the shins than heels behind them); a figure
facing -z is turned half about y. It is put on the floor (feet at y = 0) and centred, and gets:

- a T-pose skeleton by fitting the canonical skeleton template to the figure (``fit_skeleton``):
  each joint keeps its position relative to the figure's extent, averaged over the body library
  (x in half arm spans, y in heights, z in heights from the hip centre), then the arm chain is put
  at the arm's height and the knees and ankles at the centres of the legs. We chose this over running the
  skeleton regressor on a virtual depth render because the regressor is trained on people seen in
  rooms at 1.5-4 m, not on turntable renders of arbitrary characters; the template fit is exact in
  its assumptions (a T-pose) and measured in docs/learned_retargeting.md;
- skinning weights from the skinning field (live/body/skinning_field.py).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import sys
from pathlib import Path

import numpy as np

from live.body.gltf_avatar import gltf_is_rigged, is_gltf_file, load_gltf_avatar, read_gltf_mesh
from live.core.errors import FormatError, UserInputError
from live.core.skeleton import JOINT_INDEX, NUM_JOINTS, PARENTS

MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb", ".off", ".stl", ".fbx")
CLOUD_SUFFIXES = (".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
_ARM = tuple(JOINT_INDEX[n] for n in ("left_collar", "left_shoulder", "left_elbow", "left_wrist",
                                      "right_collar", "right_shoulder", "right_elbow", "right_wrist"))
_LEGS = tuple(JOINT_INDEX[n] for n in ("left_knee", "left_ankle", "right_knee", "right_ankle"))
#: |facing_measure| below this (in heights) does not tell the facing: measured +0.071 (a stylised
#: VRM, Godette) and +0.085 to +0.105 (the 21 library bodies) on figures facing +z.
FACING_MIN = 0.035

log = logging.getLogger(__name__)


def is_geometry_file(spec: str | Path) -> bool:
    """True for a path whose suffix is a mesh or point-cloud format (not a body .npz)."""
    return Path(str(spec)).suffix.lower() in MESH_SUFFIXES + CLOUD_SUFFIXES


#: Ceilings of an avatar mesh or cloud (docs/reliability.md). Counts declared in a PLY, OFF or
#: binary STL header are checked against them and against the file's size before open3d reads
#: it (open3d would reserve what the header says: 2e9 vertices are 24 GB).
MAX_AVATAR_FILE_BYTES = 256 * 1024 * 1024
MAX_AVATAR_VERTICES = 2_000_000
MAX_AVATAR_FACES = 4_000_000
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _declared(kind: str, count: int, minimum_bytes: int, room: int, where: str) -> None:
    ceiling = MAX_AVATAR_VERTICES if kind == "vertex" else MAX_AVATAR_FACES
    if count > ceiling and kind in ("vertex", "face"):
        raise FormatError(f"declares {count} {kind} elements, more than the {ceiling} an avatar may have", path=where)
    if count * minimum_bytes > room:
        raise FormatError(f"declares {count} {kind} elements, more than its {room} bytes can hold", path=where)


def _check_ply(data: bytes, size: int, where: str) -> None:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise FormatError("not a PLY file (no 'ply' ... 'end_header' header)", path=where)
    lines = data[:end].decode("ascii", "replace").splitlines()
    binary = any(ln.split()[:2] in (["format", "binary_little_endian"], ["format", "binary_big_endian"])
                 for ln in lines if ln.strip())
    elements: list[list] = []  # [name, count, bytes per element at least]
    for ln in lines:
        tok = ln.split()
        if tok[:1] == ["element"] and len(tok) == 3:
            if not tok[2].isdigit():
                raise FormatError(f"bad element count {tok[2]!r}", path=where)
            elements.append([tok[1], int(tok[2]), 0])
        elif tok[:1] == ["property"] and elements and len(tok) >= 3:
            # A list property holds at least its count; text needs at least 2 bytes a value.
            elements[-1][2] += (_PLY_SIZES.get(tok[2], 1) if tok[1] == "list" else _PLY_SIZES.get(tok[1], 1)) \
                if binary else 2
    room = size - end
    for name, count, least in elements:
        _declared(name, count, max(least, 1), room, where)


def _check_off(data: bytes, size: int, where: str) -> None:
    tok = data[:4096].decode("ascii", "replace").split()
    if not tok or not tok[0].endswith("OFF"):
        raise FormatError("not an OFF file", path=where)
    counts = tok[1:4]
    if len(counts) < 2 or not all(t.isdigit() for t in counts[:2]):
        raise FormatError("an OFF file needs vertex and face counts after 'OFF'", path=where)
    _declared("vertex", int(counts[0]), 6, size, where)   # "0 0 0\n"
    _declared("face", int(counts[1]), 8, size, where)     # "3 0 1 2\n"


def _check_stl(data: bytes, size: int, where: str) -> None:
    if data[:5].lower() == b"solid" and b"facet" in data[:4096]:
        return  # text STL: read line by line, bounded by the file size
    if len(data) < 84:
        raise FormatError("not an STL file (shorter than a binary STL header)", path=where)
    _declared("face", int.from_bytes(data[80:84], "little"), 50, size - 84, where)


def check_geometry_file(path: Path) -> None:
    """Refuse, before open3d reads it, a mesh or cloud larger than the ceilings above or whose
    header declares more elements than the ceilings or than the file can hold."""
    size = path.stat().st_size
    where = str(path)
    if size > MAX_AVATAR_FILE_BYTES:
        raise FormatError(f"{size / 2**20:.0f} MiB: larger than the {MAX_AVATAR_FILE_BYTES >> 20} MiB an avatar file "
                          "may be", path=where)
    with open(path, "rb") as f:
        head = f.read(65536)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        _check_ply(head, size, where)
    elif suffix == ".off":
        _check_off(head, size, where)
    elif suffix == ".stl":
        _check_stl(head, size, where)


def read_geometry(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int32; F = 0 for a point cloud) read by open3d,
    after ``check_geometry_file``; open3d's own warnings are silenced (the error says what failed)."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"no avatar file {path}")
    check_geometry_file(path)
    verts, faces = np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        if path.suffix.lower() in MESH_SUFFIXES:
            mesh = o3d.io.read_triangle_mesh(str(path))
            verts, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int32)
        if len(faces) == 0 and path.suffix.lower() in (".ply",) + CLOUD_SUFFIXES:
            cloud = o3d.io.read_point_cloud(str(path))
            verts = np.asarray(cloud.points, np.float64)
    if len(verts) < 100:
        raise FormatError(f"open3d read {len(verts)} points; an avatar needs at least 100", path=str(path))
    if len(verts) > MAX_AVATAR_VERTICES or len(faces) > MAX_AVATAR_FACES:
        raise FormatError(f"{len(verts)} vertices and {len(faces)} faces: more than an avatar may have "
                          f"({MAX_AVATAR_VERTICES}, {MAX_AVATAR_FACES})", path=str(path))
    if not np.isfinite(verts).all():
        raise FormatError("vertices hold NaN or infinite values", path=str(path))
    if len(faces) and (faces.min() < 0 or faces.max() >= len(verts)):
        raise FormatError("faces index vertices that do not exist", path=str(path))
    return verts, faces


def facing_measure(vertices: np.ndarray) -> float:
    """How far (in heights) the feet reach ahead (+z) of the shins more than behind them: the 98th
    and 2nd z percentiles of the vertices in the lowest 4 % of the figure against the median z of
    those between 12 % and 22 % (the shins). Positive for a figure facing +z (toes ahead), negative facing -z. Needs y up."""
    v = np.asarray(vertices, np.float64)
    y0, h = float(v[:, 1].min()), float(np.ptp(v[:, 1]))
    if not h > 0:
        return 0.0
    feet = v[v[:, 1] < y0 + 0.04 * h, 2]
    shins = v[(v[:, 1] > y0 + 0.12 * h) & (v[:, 1] < y0 + 0.22 * h), 2]
    if len(feet) < 3 or len(shins) < 3:
        return 0.0
    c = float(np.median(shins))
    ahead, behind = np.percentile(feet, [98.0, 2.0])  # percentiles: a stray vertex does not decide
    return float((ahead - c) - (c - behind)) / h


def face_plus_z(vertices: np.ndarray, where: str = "avatar") -> np.ndarray:
    """The figure turned half about y when its feet say it faces -z (``facing_measure``); when they do
    not tell, one stderr line says +z is assumed (glTF's convention, and the canonical T-pose's)."""
    m = facing_measure(vertices)
    if m <= -FACING_MIN:
        log.info("%s faces -z (its toes point that way): turned to face +z", where)
        return np.asarray(vertices, np.float64) * np.array([-1.0, 1.0, -1.0])
    if m < FACING_MIN:
        print(f"livecap: {where}: its feet do not tell which way it faces; taking +z as its front",
              file=sys.stderr, flush=True)
    return np.asarray(vertices, np.float64)


def normalise_figure(vertices: np.ndarray) -> np.ndarray:
    """Vertices in metres, feet on y = 0, x centred on the bounding box, z on the hip band's centre."""
    v = np.asarray(vertices, np.float64).copy()
    height = np.ptp(v[:, 1])
    if not height > 0:
        raise UserInputError("the avatar has no height")
    if height > 300.0:
        v *= 0.001
    elif height > 3.0:
        v *= 0.01
    v[:, 1] -= v[:, 1].min()
    v[:, 0] -= 0.5 * (v[:, 0].min() + v[:, 0].max())
    h = v[:, 1].max()
    band = (v[:, 1] > 0.45 * h) & (v[:, 1] < 0.6 * h) & (np.abs(v[:, 0]) < 0.2 * h)
    v[:, 2] -= np.median(v[band, 2]) if band.any() else np.median(v[:, 2])
    return v


def _extent(v: np.ndarray) -> tuple[float, float, float]:
    """(height, half arm span, hip-band z centre) of a figure already on the floor, x-centred."""
    h = float(v[:, 1].max() - v[:, 1].min())
    span = 0.5 * float(v[:, 0].max() - v[:, 0].min())
    band = (v[:, 1] > 0.45 * h) & (v[:, 1] < 0.6 * h) & (np.abs(v[:, 0]) < 0.2 * h)
    zc = float(np.median(v[band, 2])) if band.any() else float(np.median(v[:, 2]))
    return h, span, zc


def normalised_joints(vertices: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
    """(22, 3) joints in figure units: x / half span, y / height, (z - hip z) / height."""
    h, span, zc = _extent(np.asarray(vertices, np.float64))
    j = np.asarray(rest_joints, np.float64)
    return np.stack([j[:, 0] / span, j[:, 1] / h, (j[:, 2] - zc) / h], axis=1)


@functools.lru_cache(maxsize=1)
def skeleton_template(exclude: tuple[str, ...] = ()) -> np.ndarray:
    """(22, 3) mean normalised T-pose joints over the body-library presets (minus ``exclude``)."""
    from live.body.library import list_presets, load_body

    rows = []
    for name in list_presets():
        if name in exclude:
            continue
        b = load_body(name)
        rows.append(normalised_joints(b.vertices, b.rest_joints))
    if not rows:
        raise UserInputError("the body library is empty: no skeleton template")
    tpl = np.mean(rows, axis=0)
    tpl[:, 0] -= tpl[0, 0]  # a symmetric template: the pelvis on x = 0
    return tpl


def fit_skeleton(vertices: np.ndarray, template: np.ndarray | None = None) -> np.ndarray:
    """T-pose joints (22, 3) of a normalised figure (see ``normalise_figure``) from the template,
    with the arm chain moved to the arm's own height and the knees / ankles to the legs' x centres."""
    v = np.asarray(vertices, np.float64)
    tpl = skeleton_template() if template is None else np.asarray(template, np.float64)
    h, span, zc = _extent(v)
    j = np.stack([tpl[:, 0] * span, tpl[:, 1] * h, tpl[:, 2] * h + zc], axis=1)
    # Arms: horizontal in the T-pose; their height is the median height of the points beyond the
    # elbow (what is there is arm), corrected by the template's own shoulder-to-arm offset.
    for side, sign in ((0, 1.0), (4, -1.0)):
        elbow = j[_ARM[side + 2]]
        arm = sign * v[:, 0] > sign * elbow[0]
        if arm.sum() > 10:
            dy = float(np.median(v[arm, 1])) - elbow[1]
            for k in _ARM[side + 1:side + 4]:
                j[k, 1] += dy
    # Knees and ankles: the x centre of the leg's points at the joint's height (not the hips: at
    # their height the slab holds the pelvis too, which made them worse).
    for k in _LEGS:
        slab = (np.abs(v[:, 1] - j[k, 1]) < 0.02 * h) & (np.sign(v[:, 0]) == np.sign(j[k, 0]))
        slab &= np.abs(v[:, 0]) < 0.25 * h
        if slab.sum() > 10:
            j[k, 0] = 0.5 * (v[slab, 0].min() + v[slab, 0].max())
    return j.astype(np.float32)


def avatar_from_points(vertices: np.ndarray, faces: np.ndarray | None = None, *, name: str = "avatar",
                       field_model: str | Path | None = None, rest_joints: np.ndarray | None = None):
    """A Body from T-pose geometry: normalised, skeleton fitted (unless given), weights from the field."""
    from live.body.library import Body
    from live.body.skinning_field import SkinningFieldModel

    v = normalise_figure(vertices)
    joints = fit_skeleton(v) if rest_joints is None else np.asarray(rest_joints, np.float32)
    weights = SkinningFieldModel(field_model).weights(v, joints)
    f = np.zeros((0, 3), np.int32) if faces is None else np.asarray(faces, np.int32)
    return Body(vertices=v.astype(np.float32), faces=f, rest_joints=joints, weights=weights,
                parents=PARENTS.copy(), name=name, phenotype=None)


def load_avatar(spec: str | Path, *, field_model: str | Path | None = None):
    """A Body for ``--avatar``: a preset name, a body .npz, ``anny:...``, a VRM or rigged glTF (its own
    skeleton and skin), or a T-pose mesh / point cloud file (skeleton fitted, weights from the
    skinning field)."""
    from live.body.library import load_body

    if is_gltf_file(spec) and gltf_is_rigged(spec):
        # A VRM, or a glTF with a skin: its own skeleton, weights and facing (live/body/gltf_avatar.py).
        return load_gltf_avatar(spec)
    if is_gltf_file(spec):
        # A glTF mesh without a skeleton: read by pygltflib with its nodes and materials.
        verts, faces, look = read_gltf_mesh(spec)
        body = avatar_from_points(face_plus_z(verts, str(spec)), faces, name=Path(str(spec)).stem,
                                  field_model=field_model)
        return dataclasses.replace(body, look=look)
    if is_geometry_file(spec):
        verts, faces = read_geometry(spec)
        return avatar_from_points(face_plus_z(verts, str(spec)), faces, name=Path(str(spec)).stem,
                                  field_model=field_model)
    return load_body(spec)


__all__ = ["load_avatar", "avatar_from_points", "face_plus_z", "facing_measure", "fit_skeleton", "normalise_figure",
           "read_geometry",
           "skeleton_template", "is_geometry_file", "NUM_JOINTS"]
