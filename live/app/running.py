"""Running a pipeline for a CLI command: stop on signals, a progress bar, stats.json, speed options."""

from __future__ import annotations

import json
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from live.core import assets
from live.core.errors import UserInputError
from live.core.frames import FrameResult
from live.io.session import SessionWriter
from live.pipeline.runner import Pipeline

DEMO_SESSION = assets.demo_session()


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
    return sum(n for cid, n in counts.items() if summary.channels[cid].metadata.get("kind") == "depth") or None


def write_stats(out_dir: Path, stats: dict) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    p = out_dir / "stats.json"
    p.write_text(json.dumps(stats, indent=2, sort_keys=True) + "\n")
    return p


def run_pipeline(sources, stages, sinks, *, mode: str, record: Path | None = None,
                 progress_total: int | None = None, progress: bool = True,
                 seconds: float | None = None) -> dict:
    """Run a pipeline until the sources end, ``seconds`` pass, or Ctrl-C / SIGTERM."""
    recorder = None
    if record is not None:
        streams = [s for src in sources for s in src.streams()]
        recorder = SessionWriter(record, streams)
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
            recorder.close()
    return stats


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
