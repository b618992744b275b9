"""``.npz`` files written and read with bounded memory.

``ColumnSpool`` appends the rows of one array to a temporary file as they come; ``write_npz``
assembles arrays and spools into a compressed ``.npz`` (what ``numpy.savez_compressed`` writes:
one ``.npy`` member per array, deflated), copying each spool in blocks, so an export holds one
frame at a time whatever the session's length. ``load_npz_checked`` reads an ``.npz`` from
untrusted bytes: every member's declared shape is checked against its size and a ceiling
before numpy allocates it.
"""

from __future__ import annotations

import io
import os
import tempfile
import zipfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

_BLOCK = 1 << 20
#: Largest array ``load_npz_checked`` accepts (bytes).
MAX_ARRAY_BYTES = 256 << 20


class ColumnSpool:
    """Rows of one array (dtype, each row of ``row_shape``) appended to a file in ``folder``."""

    def __init__(self, folder: Path, name: str, dtype, row_shape: tuple[int, ...] = ()):
        self.dtype = np.dtype(dtype).newbyteorder("<") if np.dtype(dtype).itemsize > 1 else np.dtype(dtype)
        self.row_shape = tuple(row_shape)
        self.rows = 0
        fd, path = tempfile.mkstemp(prefix=f"{name}-", suffix=".bin", dir=folder)
        self.path = Path(path)
        self._file = os.fdopen(fd, "wb")
        self._row_items = max(1, int(np.prod(self.row_shape, dtype=np.int64)))

    def append(self, values) -> None:
        """One or more rows: an array of shape (k, *row_shape) or (*row_shape,) or raw bytes (uint8)."""
        if isinstance(values, bytes | bytearray | memoryview):
            data = bytes(values)
            self.rows += len(data) // self.dtype.itemsize
            self._file.write(data)
            return
        arr = np.ascontiguousarray(values, dtype=self.dtype)
        self.rows += arr.size // self._row_items
        self._file.write(arr.tobytes())

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.rows, *self.row_shape)

    def close(self) -> None:
        self._file.close()

    def blocks(self) -> Iterable[bytes]:
        self._file.flush()
        with open(self.path, "rb") as f:
            while block := f.read(_BLOCK):
                yield block


def write_npz(path: Path, arrays: list[tuple[str, np.ndarray | ColumnSpool]]) -> Path:
    """A compressed .npz of the named arrays and spools, in order (numpy.load reads it)."""
    with zipfile.ZipFile(path, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for name, value in arrays:
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                if isinstance(value, ColumnSpool):
                    header = {"descr": np.lib.format.dtype_to_descr(value.dtype), "fortran_order": False,
                              "shape": value.shape}
                    _write_header(member, header)
                    for block in value.blocks():
                        member.write(block)
                else:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    return path


def _write_header(member, header: dict) -> None:
    try:
        np.lib.format.write_array_header_1_0(member, header)
    except ValueError:  # a header too long for format 1.0 (a very large shape)
        np.lib.format.write_array_header_2_0(member, header)


def load_npz_checked(data: bytes, names: Iterable[str], max_bytes: int = MAX_ARRAY_BYTES) -> dict[str, np.ndarray]:
    """The arrays ``names`` (those present) of an .npz held in ``data``. ValueError when the file
    is not an .npz, a member's header declares more than ``max_bytes`` or more than the member
    holds, or its data is not plain numbers (no pickles)."""
    out: dict[str, np.ndarray] = {}
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile as exc:
        raise ValueError(f"not an .npz ({exc})") from None
    with zf:
        for name in names:
            try:
                info = zf.getinfo(f"{name}.npy")
            except KeyError:
                continue
            with zf.open(info) as member:
                try:
                    version = np.lib.format.read_magic(member)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                                   (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                    if read_header is None:
                        raise ValueError(f"npy format {version} is not supported")
                    shape, _, dtype = read_header(member)
                except (ValueError, OSError, SyntaxError) as exc:
                    raise ValueError(f"{name}: bad .npy header ({exc})") from None
                if dtype.hasobject:
                    raise ValueError(f"{name}: holds Python objects")
                size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize if shape else dtype.itemsize
                if size > max_bytes or size > info.file_size:
                    raise ValueError(f"{name}: declares {shape} {dtype} ({size} bytes) in a member of "
                                     f"{info.file_size} bytes (limit {max_bytes})")
            with zf.open(info) as member:
                try:
                    out[name] = np.lib.format.read_array(member, allow_pickle=False)
                except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
                    raise ValueError(f"{name}: unreadable ({exc})") from None
    return out
