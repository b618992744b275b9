"""Checks of command-line values: number types for argparse (range, finite, ceilings) and the
rules for output paths, the same for every command.

Output rules (docs/reliability.md, "User mistakes"):
- a results folder (``--out`` of demo, replay, run, export) may exist and is reused; a file in its
  place is an error;
- an output file (``--out`` of record, synth, render, calibrate; ``--foxglove``, ``--record``,
  ``--video``, ``--viewer save:F.rrd``) that exists is refused unless ``--force``; a folder in its
  place is an error;
- an output file is never one of the command's inputs, ``--force`` or not;
- the nearest existing parent of every output must be a folder.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from live.core.errors import UserInputError

#: Ceilings of numeric options (docs/reliability.md): beyond them a value is a typo, and
#: following it would allocate or wait without bound.
MAX_SECONDS = 1_000_000.0   # --seconds, --start, --timeout: 11.6 days
MAX_FPS = 1000.0            # synth --fps
MAX_THREADS = 64            # --threads (onnxruntime pool)
MAX_SPEED = 1_000_000.0     # --speed (beyond: use max)
MIN_SPEED = 0.001           # --speed (below: hours per recorded second)
MAX_LAG = 1000              # --lag frames
MAX_VMC_RATE = 10_000.0     # --vmc-rate Hz
MAX_POINTS = 100_000_000    # export --max-points
MAX_FRAMES = 100_000_000    # eval --max-frames


def _fmt(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def number(kind: type = float, *, low: float | None = None, high: float | None = None,
           low_open: bool = False) -> Callable[[str], float | int]:
    """An argparse type: ``kind`` (float or int) parsed from the text, finite, in [low, high]
    (``low_open``: low excluded). Its error names the accepted range."""
    lo = "" if low is None else (f"> {_fmt(low)}" if low_open else f">= {_fmt(low)}")
    hi = "" if high is None else f"<= {_fmt(high)}"
    rule = " and ".join(p for p in (lo, hi) if p)
    noun = "an integer" if kind is int else "a number"
    expected = f"{noun} {rule}".strip()

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, not {text!r}") from None
        bad = (isinstance(value, float) and not math.isfinite(value)) \
            or (low is not None and (value <= low if low_open else value < low)) \
            or (high is not None and value > high)
        if bad:
            raise argparse.ArgumentTypeError(f"expected {expected}, not {text!r}")
        return value

    parse.__name__ = f"{kind.__name__} {rule}".strip()  # argparse names the type in some errors
    return parse


positive_seconds = number(float, low=0.0, high=MAX_SECONDS, low_open=True)
start_seconds = number(float, low=0.0, high=MAX_SECONDS)
fps = number(float, low=0.0, high=MAX_FPS, low_open=True)
threads = number(int, low=1, high=MAX_THREADS)
lag = number(int, low=0, high=MAX_LAG)
vmc_rate = number(float, low=0.0, high=MAX_VMC_RATE)
seed = number(int, low=0, high=2**63 - 1)
max_points = number(int, low=1, high=MAX_POINTS)
max_frames = number(int, low=1, high=MAX_FRAMES)
camera_distance = number(float, low=0.0, high=50.0, low_open=True)   # metres: farther sees nothing
camera_height = number(float, low=0.0, high=20.0)                     # metres above the floor
angle_degrees = number(float, low=-3600.0, high=3600.0)
depth_range = number(float, low=0.0, high=100.0, low_open=True)      # metres
performer_height = number(float, low=0.5, high=3.0)                  # metres


def speed(text: str) -> str:
    """``--speed``: ``max`` (also ``inf`` or ``0``) or a finite factor in [MIN_SPEED, MAX_SPEED]
    (the text is kept: the commands parse it with live.app.running.parse_speed)."""
    if text in ("max", "inf", "0"):
        return text
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and MIN_SPEED <= value <= MAX_SPEED):
        raise argparse.ArgumentTypeError(f"expected 'max' or a factor in [{_fmt(MIN_SPEED)}, {_fmt(MAX_SPEED)}] "
                                         f"(1.0 = recorded timing), not {text!r}")
    return text


# --- output paths -----------------------------------------------------------------------------------

#: Per command: options naming a results folder, and options naming an output file.
OUTPUT_FOLDERS = {"demo": ("out",), "replay": ("out",), "run": ("out",), "export": ("out",)}
OUTPUT_FILES = {"record": ("out",), "synth": ("out",), "render": ("out", "video"), "calibrate": ("out",), "import": ("out",),
                "export": ("foxglove",), "run": ("record", "video"), "replay": ("video",), "demo": ("video",)}
#: Options naming files a command reads (besides --source strings and the session argument).
INPUT_OPTIONS = ("session", "motion", "calibration", "results", "model", "body", "avatar", "layout", "sessions", "path")
#: Source kinds whose target is a file or folder the command reads.
_PATH_SOURCES = ("replay:", "folder:", "sim:", "realsense-bag:")


def _flag(name: str) -> str:
    return "--out" if name == "out" else f"--{name.replace('_', '-')}"


def _nearest_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_parent(path: Path, flag: str) -> None:
    above = _nearest_existing(path.parent if path.parent != Path("") else Path("."))
    if not above.is_dir():
        raise UserInputError(f"{flag} {path}: {above} is a file, not a folder")


def check_output_folder(path: Path, flag: str = "--out") -> None:
    """A results folder: it may exist (and is reused); a file in its place is an error."""
    if path.exists() and not path.is_dir():
        raise UserInputError(f"{flag} {path} is a file; give a folder for the results")
    _check_parent(path, flag)


def check_output_file(path: Path, flag: str = "--out", *, force: bool = False,
                      inputs: Iterable[Path] = ()) -> None:
    """An output file: not a folder, not an input; an existing one only with ``force``."""
    if path.is_dir():
        raise UserInputError(f"{flag} {path} is a folder; give a file name")
    if path.exists():
        for src in inputs:
            if _same_file(path, src):
                raise UserInputError(f"{flag} {path} is also an input of this command: it would be overwritten "
                                     "while being read")
        if not force:
            raise UserInputError(f"{flag} {path} exists (add --force to overwrite it)")
    _check_parent(path, flag)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def input_paths(args: argparse.Namespace) -> list[Path]:
    """Files and folders a parsed command reads (those that exist)."""
    found: list[Path] = []
    for name in INPUT_OPTIONS:
        value = getattr(args, name, None)
        for v in value if isinstance(value, list) else [value]:
            if v is not None and str(v) and not str(v).startswith("anny:"):
                found.append(Path(v))
    sources = getattr(args, "source", None)
    for text in sources if isinstance(sources, list) else [sources]:
        if isinstance(text, str):
            for prefix in _PATH_SOURCES:
                if text.startswith(prefix):
                    found.append(Path(text[len(prefix):].split("?", 1)[0]))
    return [p for p in found if p.exists()]


def viewer_save_path(args: argparse.Namespace) -> Path | None:
    viewer = getattr(args, "viewer", None)
    if isinstance(viewer, str) and viewer.startswith("save:") and len(viewer) > len("save:"):
        return Path(viewer[len("save:"):])
    return None


def check_outputs(command: str, args: argparse.Namespace) -> None:
    """Apply the output rules above to a parsed command (UserInputError on the first broken one)."""
    for name in OUTPUT_FOLDERS.get(command, ()):
        value = getattr(args, name, None)
        if value is not None:
            check_output_folder(Path(value), _flag(name))
    inputs = input_paths(args)
    force = bool(getattr(args, "force", False))
    outputs = [(Path(getattr(args, n)), _flag(n)) for n in OUTPUT_FILES.get(command, ())
               if getattr(args, n, None) is not None]
    rrd = viewer_save_path(args)
    if rrd is not None:
        outputs.append((rrd, "--viewer save:"))
    for path, flag in outputs:
        check_output_file(path, flag, force=force, inputs=inputs)
