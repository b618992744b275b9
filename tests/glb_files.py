"""Reading and writing GLB files by hand in tests that edit a file's JSON (the product reads them
with pygltflib; these build the test inputs)."""

from __future__ import annotations

import json
import struct
from pathlib import Path


def glb_chunks(path: Path) -> tuple[dict, bytes]:
    """(JSON chunk, BIN chunk) of a GLB."""
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    jlen = struct.unpack_from("<I", data, 12)[0]
    blen = struct.unpack_from("<I", data, 20 + jlen)[0]
    return json.loads(data[20:20 + jlen]), data[28 + jlen:28 + jlen + blen]


def write_glb(path: Path, doc: dict, blob: bytes) -> Path:
    """A GLB of this JSON and BIN chunk (each padded to 4 bytes)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
    return path
