"""One item of a batch, run in whichever worker gets it: a `livecap replay` or `livecap synth`
command line, through the command's own code (so its outputs are byte for byte the command's),
into a scratch folder whose files then go into place.

Everything here is picklable and imports nothing heavy at module level: process-pool and Ray
workers import this module and call ``run_item``. A worker process lives for many items, so what
a command loads once per process (the avatar and body library, through ``load_body``'s cache;
the modules; the digest of the shipped models) is loaded once per worker."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import io
import json
import os
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from live import __version__
from live.app import batch_storage as storage
from live.core.errors import LivecapError

REPLAY = "replay"
SYNTH = "synth"


@dataclass(frozen=True)
class BatchItem:
    """One unit of work. ``source``: the session or depth folder (replay) or the motion clip
    (synth), a path or URL. Outputs: ``out_dir/name/`` (replay) or ``out_dir/name.mcap`` (synth)."""

    name: str
    kind: str
    source: str
    out_dir: str
    #: The command's other options, as on its command line (``--avatar default``, ``--seed 3``).
    options: tuple[str, ...] = ()
    #: Other files the outputs depend on (``--model``, an avatar or body file, ``--calibration``):
    #: their content goes into the item's key.
    depends_on: tuple[str, ...] = ()
    #: This name's record from an earlier run into the same folder (key and outputs), if any.
    previous: dict | None = None

    def destination(self) -> str:
        """The folder this item's files go into."""
        return storage.join(self.out_dir, self.name) if self.kind == REPLAY else self.out_dir

    def command_line(self, source: Path | str, out: Path | str) -> list[str]:
        """The `livecap` arguments that make this item (with ``source`` read and ``out`` written)."""
        if self.kind == REPLAY:
            return [REPLAY, str(source), "--out", str(out), "--speed", "max", "--quiet", *self.options]
        return [SYNTH, "--motion", str(source), "--out", str(out), "--quiet", *self.options]


@dataclass
class ItemResult:
    """What became of an item: ``status`` done, skipped (done before with the same key) or failed."""

    name: str
    status: str
    source: str
    key: str | None = None
    #: file name -> {"sha256", "bytes"} of what the item wrote.
    outputs: dict = field(default_factory=dict)
    frames: int | None = None
    fps: float | None = None
    accuracy: dict | None = None
    error: str | None = None
    #: Finished but with data lost (a damaged session read around): what the command said.
    warning: str | None = None
    #: Wall time of the item in its worker, and of the command alone.
    seconds: float = 0.0
    command_seconds: float = 0.0
    worker: str = ""

    def record(self) -> dict:
        return asdict(self)


@functools.lru_cache(maxsize=1)
def shipped_models_digest() -> str:
    """sha256 of the shipped models and the body library, hashed once per worker process (the
    worker's own install: what it replays with)."""
    from live.core import assets

    parts = {"weights": storage.sha256_tree(assets.weights_dir()), "bodies": storage.sha256_tree(assets.bodies_dir())}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


@functools.lru_cache(maxsize=64)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:
    return storage.sha256_tree(Path(path))


def _digest(path: str) -> str:
    """sha256 of a file or folder a command depends on, cached per worker while it is unchanged."""
    p = Path(path)
    stat = p.stat()
    return _file_digest(str(p.resolve()), stat.st_mtime_ns, stat.st_size) if p.is_file() else storage.sha256_tree(p)


def item_key(item: BatchItem, local_source: Path) -> str:
    """The item's identity: livecap's version, the command, its input's content, the files it
    depends on, the shipped models and the options. Same key -> same outputs."""
    parts = {"livecap": __version__, "command": item.kind, "input": storage.sha256_tree(local_source),
             "options": list(item.options), "depends_on": {p: _digest(p) for p in item.depends_on},
             "models": shipped_models_digest()}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def _still_done(item: BatchItem, key: str) -> bool:
    """Done before with the same key, and every output it wrote is still there at its size."""
    prev = item.previous or {}
    if prev.get("status") not in ("done", "skipped") or prev.get("key") != key or not prev.get("outputs"):
        return False
    dest = item.destination()
    return all(storage.size(storage.join(dest, name)) == meta.get("bytes") for name, meta in prev["outputs"].items())


def describe_error(exc: BaseException) -> str:
    """One line for a failed item, as ``livecap`` itself would say it."""
    if isinstance(exc, LivecapError):
        return str(exc)
    if isinstance(exc, FileNotFoundError):
        return f"no such file: {exc.filename}"
    if isinstance(exc, OSError) and exc.filename:
        return f"cannot use {exc.filename}: {exc.strerror}"
    if isinstance(exc, MemoryError):
        return f"out of memory ({exc or 'allocation failed'})"
    return f"{type(exc).__name__}: {exc}"


def _run_command(argv: list[str]) -> tuple[int, str]:
    """Run one `livecap` command in this process: (its exit code, what it said on stderr)."""
    from live.app.cli import build_parser

    args = build_parser().parse_args(argv)
    if args.command == REPLAY:
        from live.app.commands import cmd_replay as command
    else:
        from live.app.tool_commands import cmd_synth as command
    said = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(said):
        code = int(command(args) or 0)
    return code, said.getvalue().strip()


def _replay_summary(result: ItemResult, out: Path) -> None:
    stats = json.loads((out / "stats.json").read_text())
    if stats.get("interrupted"):
        raise LivecapError("interrupted (Ctrl-C or SIGTERM) before the session's end")
    result.frames, result.fps = stats.get("frames"), stats.get("fps")
    acc = stats.get("accuracy") or {}
    if acc.get("frames_scored"):
        result.accuracy = {k: acc.get(k) for k in ("mpjpe_mm", "pa_mpjpe_mm", "pck_10cm", "frames_scored")}


def run_item(item: BatchItem) -> ItemResult:
    """Make one item (or find it already made); never raises for the item's own failures: they
    are the result's ``error``, and the batch goes on."""
    start = time.perf_counter()
    result = ItemResult(name=item.name, status="failed", source=item.source,
                        worker=f"{socket.gethostname()}:{os.getpid()}")
    scratch = None
    try:
        scratch = storage.scratch_for(storage.join(item.out_dir, item.name))
        local_source = storage.stage_input(item.source, scratch)
        if not local_source.exists():
            raise FileNotFoundError(2, "no such file", item.source)
        result.key = item_key(item, local_source)
        if _still_done(item, result.key):
            prev = item.previous or {}
            result.status = "skipped"
            for name in ("outputs", "frames", "fps", "accuracy", "warning"):
                setattr(result, name, prev.get(name))
            return result
        out = scratch / "out"
        target = out if item.kind == REPLAY else out / f"{item.name}.mcap"
        out.mkdir()
        t0 = time.perf_counter()
        code, said = _run_command(item.command_line(local_source, target))
        result.command_seconds = time.perf_counter() - t0
        if item.kind == REPLAY:
            _replay_summary(result, out)
            if code:  # EXIT_DATA_LOSS: damaged regions read around, outputs of what was readable
                result.warning = said.removeprefix("livecap: ") or "the session is damaged: parts of it were skipped"
        else:
            from live.app.running import count_trigger_frames

            result.frames = count_trigger_frames(target)
        files = sorted(p for p in out.iterdir() if p.is_file())
        result.outputs = {f.name: {"sha256": storage.sha256_file(f), "bytes": f.stat().st_size} for f in files}
        storage.publish(files, item.destination())
        result.status = "done"
    except SystemExit as exc:  # an option the command's parser refused (checked before the batch starts)
        result.error = f"the command line was refused (exit {exc.code})"
    except Exception as exc:  # noqa: BLE001 - one item's failure is recorded; the batch goes on
        result.error = describe_error(exc)
    finally:
        if scratch is not None:
            storage.discard_scratch(scratch)
        result.seconds = time.perf_counter() - start
    return result
