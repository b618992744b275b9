"""Where a batch reads and writes: local paths, or fsspec URLs (``s3://``, ``gs://``, ``file://``, ...)
that every worker can reach. A URL input is copied to a local temporary file (or folder) before
the pipeline reads it; outputs are written locally and then moved (local) or uploaded (URL) into
place, so a destination only ever holds the complete files of a finished item."""

from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from pathlib import Path

from live.core.errors import UserInputError

#: Read size for hashing: large enough for throughput, small enough to stay out of memory's way.
_HASH_BLOCK = 1 << 20


def is_url(location: str | Path) -> bool:
    """Whether a location names a file through fsspec (``proto://...``) rather than a local path."""
    return "://" in str(location)


def _filesystem(url: str):
    """(fsspec filesystem, path inside it) for a URL; a one-line error without fsspec."""
    try:
        import fsspec
    except ImportError:
        raise UserInputError(f"{url}: URLs need fsspec (pip install fsspec, plus the protocol's package, e.g. "
                             "s3fs or gcsfs); or give a local path on storage every worker shares") from None
    try:
        return fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as exc:  # an unknown protocol, or its package missing
        raise UserInputError(f"{url}: {exc}") from None


def check_protocol(url: str) -> None:
    """UserInputError when the URL's protocol cannot be used here (fsspec or its package missing)."""
    _filesystem(url)


def absolute(location: str | Path) -> str:
    """A local path made absolute (workers may run in another folder; symlinks are kept, their
    names name the outputs); a URL as it is."""
    return str(location) if is_url(location) else os.path.abspath(location)


def join(base: str, *parts: str) -> str:
    """``base/part/...`` for a local path or a URL."""
    if is_url(base):
        return "/".join([base.rstrip("/"), *parts])
    return str(Path(base, *parts))


def exists(location: str) -> bool:
    if is_url(location):
        fs, path = _filesystem(location)
        return bool(fs.exists(path))
    return Path(location).exists()


def is_dir(location: str) -> bool:
    if is_url(location):
        fs, path = _filesystem(location)
        return bool(fs.isdir(path))
    return Path(location).is_dir()


def size(location: str) -> int | None:
    """Bytes of a file, None when it is not there."""
    try:
        if is_url(location):
            fs, path = _filesystem(location)
            return int(fs.size(path)) if fs.isfile(path) else None
        return Path(location).stat().st_size if Path(location).is_file() else None
    except OSError:
        return None


def read_text(location: str) -> str | None:
    """A small text file's content, None when it is not there."""
    if is_url(location):
        fs, path = _filesystem(location)
        if not fs.exists(path):
            return None
        with fs.open(path, "r") as f:
            return f.read()
    p = Path(location)
    return p.read_text() if p.is_file() else None


def write_text(location: str, text: str) -> None:
    """Write a small text file whole: a local one through a temporary file and a rename, so a
    reader (or a killed batch) never sees half of it."""
    if is_url(location):
        fs, path = _filesystem(location)
        fs.makedirs(fs._parent(path), exist_ok=True)
        with fs.open(path, "w") as f:
            f.write(text)
        return
    p = Path(location)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, p)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_HASH_BLOCK):
            h.update(block)
    return h.hexdigest()


def sha256_tree(path: Path) -> str:
    """A file's sha256, or a folder's: of its files' relative names and contents, in name order."""
    path = Path(path)
    if path.is_file():
        return sha256_file(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(f.relative_to(path).as_posix().encode() + b"\0" + sha256_file(f).encode() + b"\n")
    return h.hexdigest()


def stage_input(location: str, scratch: Path) -> Path:
    """A local path to read ``location`` from: the path itself, or a copy of the URL's file or
    folder in ``scratch`` (under the same base name, which commands may show)."""
    if not is_url(location):
        return Path(location)
    fs, path = _filesystem(location)
    if not fs.exists(path):
        raise FileNotFoundError(2, "no such file", location)
    local = scratch / "input" / Path(path.rstrip("/")).name
    local.parent.mkdir(parents=True, exist_ok=True)
    if fs.isdir(path):
        fs.get(path.rstrip("/") + "/", str(local), recursive=True)
    else:
        fs.get_file(path, str(local))
    return local


def scratch_for(destination: str) -> Path:
    """A fresh local folder to write an item's outputs in before they go to ``destination``: beside
    it for a local destination (a rename moves them), in the temporary folder for a URL."""
    if is_url(destination):
        import tempfile

        return Path(tempfile.mkdtemp(prefix="livecap-batch-"))
    base = Path(destination).parent / ".partial"
    scratch = base / f"{Path(destination).name}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
    scratch.mkdir(parents=True)
    return scratch


def discard_scratch(scratch: Path) -> None:
    shutil.rmtree(scratch, ignore_errors=True)


def remove_empty_scratch_folder(out_dir: str) -> None:
    """The driver's tidying at the end: ``DIR/.partial`` goes when no item is in it (a worker
    removing it could race another worker making its scratch folder there)."""
    if not is_url(out_dir):
        try:
            (Path(out_dir) / ".partial").rmdir()
        except OSError:
            pass


def publish(files: list[Path], destination: str) -> None:
    """Put ``files`` into the folder ``destination`` (created when missing), each replacing the
    file of its name there; other files there are left alone, as a replay into an existing
    folder leaves them."""
    if is_url(destination):
        fs, path = _filesystem(destination)
        fs.makedirs(path, exist_ok=True)
        for f in files:
            fs.put_file(str(f), f"{path.rstrip('/')}/{f.name}")
        return
    Path(destination).mkdir(parents=True, exist_ok=True)
    for f in files:
        os.replace(f, Path(destination) / f.name)
