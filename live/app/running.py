"""Running a pipeline for a CLI command: stop on signals, a progress bar, stats.json, speed options."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
from collections.abc import Iterable
from contextlib import contextmanager
from pathlib import Path

from live.core import assets
from live.core.errors import UserInputError
from live.core.frames import FrameResult
from live.io.session import FLUSH_INTERVAL_S, FSYNC_INTERVAL_S, SessionWriter
from live.pipeline.runner import Pipeline

DEMO_SESSION = assets.demo_session()
#: Exit status of a command that finished but lost data: a damaged session read around, a
#: recording whose source died.
EXIT_DATA_LOSS = 1


def same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (symlinks resolved, hard links compared)."""
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def refuse_overwriting_inputs(out: Path, inputs: Iterable[str | Path], option: str = "--out") -> None:
    """UserInputError when ``out`` is one of the files a command reads."""
    for path in inputs:
        if path and same_file(Path(out), Path(path)):
            raise UserInputError(f"{option} {out} is an input of this command ({path}): it would be overwritten; "
                                 "write to another file")


@contextmanager
def stop_on_signals():
    """An Event set by Ctrl-C or SIGTERM; a second Ctrl-C exits at once."""
    stop = threading.Event()
    previous = {}

    def handler(signum, _frame):
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, handler)
    try:
        yield stop
    finally:
        for sig, h in previous.items():
            signal.signal(sig, h)


class Progress:
    """A tqdm progress bar on stderr for long runs (silent when not a terminal or quiet)."""

    def __init__(self, total: int | None, desc: str, enabled: bool = True):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="frame", leave=False, file=sys.stderr,
                            disable=None, dynamic_ncols=True)

    def __call__(self, result: FrameResult) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def count_trigger_frames(path: Path) -> int | None:
    """Depth frames in a session, from its summary (None when the summary is missing)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - a damaged file has no usable summary; progress goes without total
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = summary.statistics.channel_message_counts
    # A damaged summary may count channels it does not hold: only a total for progress, so skip them.
    kinds = {cid: channel.metadata.get("kind") for cid, channel in summary.channels.items()}
    return sum(n for cid, n in counts.items() if kinds.get(cid) == "depth") or None


def write_stats(out_dir: Path, stats: dict) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    p = out_dir / "stats.json"
    p.write_text(json.dumps(stats, indent=2, sort_keys=True) + "\n")
    return p


def run_pipeline(sources, stages, sinks, *, mode: str, record: Path | None = None,
                 progress_total: int | None = None, progress: bool = True,
                 seconds: float | None = None) -> dict:
    """Run a pipeline until the sources end, ``seconds`` pass, or Ctrl-C / SIGTERM.

    ``record``: also record the sources into this MCAP file, closing a chunk every
    FLUSH_INTERVAL_S (a killed run loses at most that) with gap and status records;
    ``stats["recording"]`` then says what the recording went through (live.io.recording)."""
    recorder = None
    pipeline: Pipeline | None = None
    if record is not None:
        refuse_overwriting_inputs(record, [p for src in sources for p in _paths_of(src)], "--record/--out")
        streams = [s for src in sources for s in src.streams()]
        recorder = SessionWriter(record, streams, flush_interval_s=FLUSH_INTERVAL_S, fsync_interval_s=FSYNC_INTERVAL_S,
                                 status=lambda: pipeline.source_status() if pipeline is not None else {})
    bar = Progress(progress_total, "frames", enabled=progress)
    try:
        with stop_on_signals() as stop:
            timer = None
            if seconds is not None:
                timer = threading.Timer(seconds, stop.set)
                timer.daemon = True
                timer.start()
            pipeline = Pipeline(sources, stages, sinks, mode=mode, recorder=recorder, on_result=bar)
            try:
                stats = pipeline.run(stop)
            finally:
                if timer is not None:
                    timer.cancel()
            stats["interrupted"] = bool(stop.is_set() and seconds is None and
                                        any(not getattr(s, "finished", True) for s in sources))
    finally:
        bar.close()
        if recorder is not None:
            summary = recorder.close()
    if recorder is not None:
        stats["recording"] = summary.as_dict()
    return stats


def _paths_of(source) -> list[Path]:
    """Files a source object reads (a replayed session, a folder's images)."""
    paths = [getattr(source, "path", None)] + list(getattr(source, "images", []) or [])
    return [Path(p) for p in paths if isinstance(p, str | Path)]


def parse_speed(value: str) -> float | None:
    if value in ("max", "0", "inf"):
        return None
    try:
        speed = float(value)
    except ValueError:
        raise UserInputError(f"--speed must be a positive number or 'max', not {value!r}") from None
    if speed <= 0:
        raise UserInputError("--speed must be a positive number or 'max'")
    return speed
