"""The glTF container of an avatar file, read with pygltflib: ``open_gltf`` (the document and its
buffers' bytes, after the size and magic checks), ``read_accessor`` (an accessor as numpy, checked
against the bytes its buffer holds) and ``world_matrices`` (the node tree at rest).

pygltflib parses the GLB container and the JSON (extensions stay plain dicts); it does not decode
accessors, which is done here with bounds checks, so a file declaring more than it holds is a
one-line FormatError and never a large allocation.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from live.core.errors import FormatError, UserInputError

MAX_FILE_BYTES = 256 * 1024 * 1024
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}


def open_gltf(path: Path):
    """The pygltflib document with every buffer as bytes (list), after the size and magic checks."""
    import pygltflib

    if not path.is_file():
        raise UserInputError(f"no avatar file {path}")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise FormatError(f"{size / 2**20:.0f} MiB: larger than the {MAX_FILE_BYTES >> 20} MiB an avatar file may be",
                          path=str(path))
    with open(path, "rb") as f:
        head = f.read(4)
    try:
        if head == b"glTF":
            doc = pygltflib.GLTF2.load_binary(str(path))
        elif head[:1] in (b"{", b" ", b"\n", b"\r", b"\t"):
            doc = pygltflib.GLTF2.load_json(str(path))
        else:
            raise FormatError("not a glTF file (neither a binary glTF 'glTF' header nor glTF JSON)", path=str(path))
    except FormatError:
        raise
    except Exception as e:  # pygltflib raises whatever its JSON and struct parsing meet
        raise FormatError(f"not a readable glTF file ({type(e).__name__}: {e})", path=str(path)) from None
    if doc is None or not doc.nodes:
        raise FormatError("not a readable glTF file (no nodes)", path=str(path))
    buffers = []
    for i, buf in enumerate(doc.buffers or []):
        buffers.append(_buffer_bytes(doc, i, buf, path))
    return doc, buffers


def _buffer_bytes(doc, i: int, buf, path: Path) -> bytes:
    uri = buf.uri
    if uri is None:
        blob = doc.binary_blob() if i == 0 else None
        if blob is None:
            raise FormatError(f"buffer {i} has no data (no uri and no GLB binary chunk)", path=str(path))
        data = bytes(blob)
    elif uri.startswith("data:"):
        try:
            data = base64.b64decode(uri.split(",", 1)[1], validate=False)
        except Exception as e:
            raise FormatError(f"buffer {i}: a data URI that does not decode ({e})", path=str(path)) from None
    else:
        # An external file beside the glTF, never a path that leaves its folder (names are not trusted).
        target = (path.parent / uri).resolve()
        if target.parent != path.parent.resolve() or not target.is_file():
            raise FormatError(f"buffer {i}: {uri!r} is not a file beside the glTF", path=str(path))
        data = target.read_bytes()
    if len(data) < (buf.byteLength or 0):
        raise FormatError(f"buffer {i} holds {len(data)} bytes, fewer than the {buf.byteLength} it declares",
                          path=str(path))
    return data


def read_accessor(doc, buffers: list[bytes], index: int, where: str) -> np.ndarray:
    """Accessor ``index`` as a float64 (count, components) array (normalized integers scaled)."""
    if not 0 <= index < len(doc.accessors or []):
        raise FormatError(f"accessor {index} does not exist", path=where)
    acc = doc.accessors[index]
    if acc.sparse is not None:
        raise FormatError(f"accessor {index} is sparse, which avatars do not use", path=where)
    if acc.componentType not in _DTYPES or acc.type not in _COMPONENTS:
        raise FormatError(f"accessor {index}: unknown component type {acc.componentType} / {acc.type}", path=where)
    dtype = np.dtype(_DTYPES[acc.componentType]).newbyteorder("<")
    ncomp, count = _COMPONENTS[acc.type], int(acc.count)
    if acc.bufferView is None:
        return np.zeros((count, ncomp))
    if not 0 <= acc.bufferView < len(doc.bufferViews or []):
        raise FormatError(f"accessor {index}: buffer view {acc.bufferView} does not exist", path=where)
    view = doc.bufferViews[acc.bufferView]
    if not 0 <= view.buffer < len(buffers):
        raise FormatError(f"buffer view {acc.bufferView}: buffer {view.buffer} does not exist", path=where)
    data = buffers[view.buffer]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    elem = dtype.itemsize * ncomp
    stride = view.byteStride or elem
    end_view = (view.byteOffset or 0) + view.byteLength
    need = start + (stride * (count - 1) + elem if count else 0)
    if stride < elem or need > min(end_view, len(data)) or start < 0:
        raise FormatError(f"accessor {index} reads past its buffer ({need} > {min(end_view, len(data))} bytes)",
                          path=where)
    raw = np.lib.stride_tricks.as_strided(
        np.frombuffer(data, np.uint8, count=need - start if count else 0, offset=start),
        shape=(count, elem), strides=(stride, 1)) if count else np.zeros((0, elem), np.uint8)
    out = np.ascontiguousarray(raw).view(dtype).reshape(count, ncomp).astype(np.float64)
    if acc.normalized and dtype.kind in "iu":
        out /= float(np.iinfo(dtype).max)
    if not np.isfinite(out).all():
        raise FormatError(f"accessor {index} holds NaN or infinite values", path=where)
    return out


def _local_matrix(node) -> np.ndarray:
    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T  # glTF matrices are column-major
    m = np.eye(4)
    if node.scale is not None:
        m[:3, :3] = np.diag(np.asarray(node.scale, np.float64))
    if node.rotation is not None:
        x, y, z, w = (float(c) for c in node.rotation)  # glTF quaternions are (x, y, z, w)
        n = np.sqrt(x * x + y * y + z * z + w * w) or 1.0
        x, y, z, w = x / n, y / n, z / n, w / n
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m[:3, :3] = r @ m[:3, :3]
    if node.translation is not None:
        m[:3, 3] = np.asarray(node.translation, np.float64)
    return m


def world_matrices(doc, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 4) world matrices of the nodes at rest and (N,) parents (-1 for roots)."""
    n = len(doc.nodes)
    parents = np.full(n, -1, np.int64)
    for i, node in enumerate(doc.nodes):
        for c in node.children or []:
            if not 0 <= c < n or parents[c] >= 0 or c == i:
                raise FormatError(f"node {i} has a bad child {c} (missing, shared or itself)", path=where)
            parents[c] = i
    world = np.full((n, 4, 4), np.nan)
    for i in range(n):
        chain, j = [], i
        while j >= 0 and np.isnan(world[j, 0, 0]):
            chain.append(j)
            j = int(parents[j])
            if len(chain) > n:
                raise FormatError("the node tree has a cycle", path=where)
        m = np.eye(4) if j < 0 else world[j]
        for k in reversed(chain):
            m = m @ _local_matrix(doc.nodes[k])
            world[k] = m
    if not np.isfinite(world).all():
        raise FormatError("a node transform holds NaN or infinite values", path=where)
    return world, parents
