"""Fuzzing livecap through its commands: seeded mutations of every format it reads (sessions,
BVH clips, depth folders, body .npz files, serial byte streams; research/fuzz_mutations.py), each
run in-process through the commands that read it (live.app.cli.main) and judged:

- ok:        exit 0 and the output complete (the same frames as the intact input, every image,
             an avatar for every frame...): the mutation left the input valid;
- refused:   exit 2 and one line on stderr (a user mistake or a file livecap cannot read);
- data-loss: exit 1 and a line saying what was skipped (a damaged session or folder read around);
- failures:  crash (an exception escaped the command: a traceback), silent (exit 0 with an
             incomplete output), unclear (another status, or no single line explaining it),
             memory (out of memory: a declared size got past the ceilings), hang (over the
             per-command time limit).

    python -m research.fuzz_inputs [--cases 300] [--formats session,bvh,folder,npz,serial] [--seed 0] [--json F]
    python -m research.fuzz_inputs --memory     # peak RSS on small files declaring huge sizes

The tests (tests/test_fuzz_inputs.py, tests/test_fuzz_sessions.py) run a few dozen cases per
format; this script runs as many as asked and prints, per format, the cases tried, the outcomes
and the slowest command, and the process's peak memory. Needs the shared BVH clips.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import functools
import io
import json
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from research import fuzz_mutations as mut

FORMATS = ("session", "bvh", "folder", "npz", "serial")
FAILURES = ("crash", "silent", "unclear", "memory", "hang")
#: Wall-clock limit of one command, seconds (a hang is a failure, not a wait).
COMMAND_TIMEOUT_S = 60.0
EXIT_USER_ERROR, EXIT_DATA_LOSS = 2, 1


class CaseTimeout(BaseException):
    """Raised in the main thread when a command runs past COMMAND_TIMEOUT_S (a BaseException, so
    no ``except Exception`` in the code under test swallows it)."""


@dataclass
class Run:
    """One command on one input: exit status (None when an exception escaped), stderr lines, the
    escaped exception's traceback, seconds."""

    argv: list[str]
    status: int | None
    stderr: list[str]
    stdout: str
    exception: str | None
    seconds: float


@dataclass
class CaseResult:
    format: str
    case: int
    mutation: str
    command: str
    status: int | None
    outcome: str
    detail: str = ""
    seconds: float = 0.0


def run_command(argv: list[str], timeout_s: float = COMMAND_TIMEOUT_S) -> Run:
    """live.app.cli.main(argv) in this process, its output captured, bounded in time."""
    from live.app.cli import main

    out, err = io.StringIO(), io.StringIO()

    def expire(_signum, _frame):
        raise CaseTimeout

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    t0 = time.perf_counter()
    status, exc = None, None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main([str(a) for a in argv])
    except CaseTimeout:
        exc = "CaseTimeout"
    except SystemExit as e:  # main returns its status; an exit from deeper down is a finding too
        exc = f"SystemExit({e.code}) escaped main"
    except BaseException:  # noqa: BLE001 - any escaped exception is what a fuzzer looks for
        exc = traceback.format_exc()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    return Run([str(a) for a in argv], status, lines, out.getvalue(), exc, time.perf_counter() - t0)


def _json_error(stdout: str) -> str:
    try:
        doc = json.loads(stdout)
    except ValueError:
        return ""
    return str(doc.get("error") or "") if isinstance(doc, dict) else ""


def judge(run: Run, complete: Callable[[Run], bool | str]) -> tuple[str, str]:
    """(outcome, detail) of a run; ``complete(run)`` is asked only after exit 0: True, or False /
    a reason when the output is incomplete."""
    if run.exception is not None:
        return ("hang" if run.exception == "CaseTimeout" else "crash"), run.exception.strip().splitlines()[-1]
    last = run.stderr[-1] if run.stderr else ""
    if run.status == 0:
        verdict = complete(run)
        return ("ok", "") if verdict is True else ("silent", str(verdict or "incomplete output"))
    if "out of memory" in last:
        return "memory", last
    if run.status == EXIT_USER_ERROR and len(run.stderr) == 1 and "error:" in last:
        return "refused", last
    if run.status == EXIT_DATA_LOSS and run.stderr:
        return "data-loss", last
    if run.status == EXIT_DATA_LOSS and _json_error(run.stdout):  # --json: the document says what was lost
        return "data-loss", _json_error(run.stdout)
    return "unclear", f"exit {run.status}, stderr {run.stderr[-3:]}"


# --- the intact inputs --------------------------------------------------------------------------

@dataclass
class Bases:
    """The intact inputs and what the commands make of them."""

    work: Path
    session: Path
    lines_session: Path
    bvh_text: str
    folder_meta: dict
    folder_images: list[bytes]
    body_npz: bytes
    session_counts: dict[str, int] = field(default_factory=dict)
    session_frames: int = 0
    serial_streams: dict[str, tuple] = field(default_factory=dict)


def build_bases(work: Path, clip: Path) -> Bases:
    """Write the intact inputs into ``work``: a 1 s synthetic session with an Xbus suit (and one
    with a text-line suit), a 30-frame cut of ``clip``, a 4-image depth folder, the performer body."""
    import cv2

    from live.core import assets
    from live.io.session import SessionReader

    work.mkdir(parents=True, exist_ok=True)
    session, lines_session = work / "base.mcap", work / "base_lines.mcap"
    for path, imu in ((session, "xbus"), (lines_session, "lines")):
        run = run_command(["synth", "--motion", clip, "--seconds", "1", "--imu", imu, "--out", path, "--quiet", "--force"])
        if run.status != 0:
            raise RuntimeError(f"cannot write the base session: {run.stderr} {run.exception}")
    text = clip.read_text()
    head, _, motion = text.partition("MOTION")
    rows = motion.strip().splitlines()
    bvh_text = head + "MOTION\nFrames: 30\n" + rows[1] + "\n" + "\n".join(rows[2:32]) + "\n"
    rng = np.random.default_rng(0)
    images = []
    for _ in range(4):
        img = rng.integers(800, 3000, size=(40, 64)).astype(np.uint16)
        images.append(cv2.imencode(".png", img)[1].tobytes())
    body = (assets.bodies_dir() / "adult_male_average.npz").read_bytes()
    bases = Bases(work, session, lines_session, bvh_text,
                  {"fx": 200.0, "fy": 200.0, "cx": 32.0, "cy": 20.0, "width": 64, "height": 40, "fps": 15},
                  images, body)
    info = json.loads(run_command(["info", session, "--json"]).stdout)
    bases.session_counts = {s["name"]: s["messages"] for s in info["streams"]}
    replay = run_command(["replay", session, "--out", work / "base_replay", "--quiet"])
    bases.session_frames = json.loads((work / "base_replay" / "stats.json").read_text())["frames"]
    assert replay.status == 0
    for path in (session, lines_session):
        reader = SessionReader(path)
        suit = next(s for s in reader.info.streams if s.kind == "serial")
        reads = [(f.t_ns, f.raw) for st, f in reader.frames() if st.name == suit.name]
        bases.serial_streams[path.name] = (suit, reads)
    return bases


# --- one format each ----------------------------------------------------------------------------

def _fresh(bases: Bases, name: str) -> Path:
    p = bases.work / "cases" / name
    if p.exists():
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def _stats(folder: Path) -> dict | None:
    try:
        return json.loads((folder / "stats.json").read_text())
    except (OSError, ValueError):
        return None


def session_cases(bases: Bases, rng: random.Random, case: int, export_every: int = 25) -> Iterator[CaseResult]:
    """A mutated session through info --json, replay --speed max and (every ``export_every``-th
    case) export: exit 0 only with every message / frame of the intact session."""
    label, data = mut.mutate_session(bases.session.read_bytes(), rng)
    path = _fresh(bases, f"session_{case}.mcap")
    path.write_bytes(data)

    def same_counts(run: Run) -> bool | str:
        counts = {s["name"]: s["messages"] for s in json.loads(run.stdout)["streams"]}
        return counts == bases.session_counts or f"messages {counts} of {bases.session_counts}"

    def all_frames(out: Path) -> Callable[[Run], bool | str]:
        def check(run: Run) -> bool | str:
            stats = _stats(out)
            return stats is not None and stats["frames"] == bases.session_frames or \
                f"{stats and stats['frames']} of {bases.session_frames} frames"
        return check

    def all_files(out: Path) -> Callable[[Run], bool | str]:
        def check(run: Run) -> bool | str:
            written = sorted(p.name for p in out.glob("*.npz"))
            return written == ["depth_cam.npz", "gt.npz", "imu_suit.npz", "serial_suit.npz"] or f"wrote {written}"
        return check

    commands: list[tuple[list, Callable[[Run], bool | str]]] = [
        (["info", path, "--json"], same_counts),
        (["replay", path, "--out", _fresh(bases, f"replay_{case}"), "--quiet"], all_frames(bases.work / "cases" / f"replay_{case}")),
    ]
    if export_every and case % export_every == 0:
        out = _fresh(bases, f"export_{case}")
        commands.append((["export", path, "--out", out], all_files(out)))
    for argv, check in commands:
        run = run_command(argv)
        outcome, detail = judge(run, check)
        yield CaseResult("session", case, label, argv[0], run.status, outcome, detail, run.seconds)


def bvh_cases(bases: Bases, rng: random.Random, case: int) -> Iterator[CaseResult]:
    """A mutated BVH through synth --motion: exit 0 only with a readable session holding a depth
    frame for every ground-truth frame."""
    from live.io.session import SessionReader

    label, data = mut.mutate_bvh(bases.bvh_text, rng)
    clip = _fresh(bases, f"clip_{case}.bvh")
    clip.write_bytes(data)
    out = _fresh(bases, f"synth_{case}.mcap")

    def complete(run: Run) -> bool | str:
        reader = SessionReader(out)
        kinds = Counter(st.kind for st, _ in reader.frames())
        if reader.error or not kinds["depth"] or kinds["depth"] != kinds["gt"]:
            return f"session {dict(kinds)}, {reader.error}"
        return True

    # At most half a second rendered: a mutated Frame Time can make the clip a minute long.
    run = run_command(["synth", "--motion", clip, "--out", out, "--quiet", "--no-noise", "--seconds", "0.5"])
    outcome, detail = judge(run, complete)
    yield CaseResult("bvh", case, label, "synth", run.status, outcome, detail, run.seconds)


def folder_cases(bases: Bases, rng: random.Random, case: int) -> Iterator[CaseResult]:
    """A depth folder with a mutated intrinsics.json or image through replay: exit 0 only with a
    frame for every image; exit 1 only with fewer."""
    folder = _fresh(bases, f"folder_{case}")
    folder.mkdir()
    images = list(bases.folder_images)
    meta = json.dumps(bases.folder_meta).encode()
    if rng.random() < 0.5:
        label, meta = mut.mutate_intrinsics(bases.folder_meta, rng, len(images))
    else:
        i = rng.randrange(len(images))
        label, images[i] = mut.mutate_png(images[i], rng)
        label = f"image {i}: {label}"
    (folder / "intrinsics.json").write_bytes(meta)
    for i, img in enumerate(images):
        (folder / f"{i:04d}.png").write_bytes(img)
    out = _fresh(bases, f"folder_replay_{case}")

    def complete(run: Run) -> bool | str:
        stats = _stats(out)
        return stats is not None and stats["frames"] == len(images) or f"{stats and stats['frames']} of {len(images)} frames"

    run = run_command(["replay", folder, "--out", out, "--quiet"])
    outcome, detail = judge(run, complete)
    if outcome == "data-loss" and (_stats(out) or {}).get("frames", len(images)) >= len(images):
        outcome, detail = "unclear", "exit 1 though every image was replayed"
    yield CaseResult("folder", case, label, "replay", run.status, outcome, detail, run.seconds)


def npz_cases(bases: Bases, rng: random.Random, case: int) -> Iterator[CaseResult]:
    """A mutated body .npz as replay --avatar: exit 0 only with an avatar pose for every frame."""
    label, data = mut.mutate_npz(bases.body_npz, rng)
    body = _fresh(bases, f"body_{case}.npz")  # a new name per case: load_body caches by path
    body.write_bytes(data)
    out = _fresh(bases, f"avatar_{case}")

    def complete(run: Run) -> bool | str:
        from live.io.results import read_avatar

        poses = len(read_avatar(out / "avatar.npz").t_ns) if (out / "avatar.npz").is_file() else 0
        return poses == bases.session_frames or f"{poses} avatar poses for {bases.session_frames} frames"

    run = run_command(["replay", bases.session, "--out", out, "--avatar", body, "--quiet"])
    outcome, detail = judge(run, complete)
    yield CaseResult("npz", case, label, "replay --avatar", run.status, outcome, detail, run.seconds)


def serial_cases(bases: Bases, rng: random.Random, case: int) -> Iterator[CaseResult]:
    """A session whose suit stream (Xbus or text lines) holds mutated serial reads, through
    replay --only imu and info: the parsers count what they drop; exit 0 with stats.json."""
    from live.core.frames import MocapPacket
    from live.io.session import SessionWriter

    name = rng.choice(sorted(bases.serial_streams))
    suit, reads = bases.serial_streams[name]
    label, raws = mut.mutate_serial([raw for _, raw in reads], rng)
    stamps = [t for t, _ in reads]
    stamps += [stamps[-1] + 1_000_000 * (k + 1) for k in range(max(0, len(raws) - len(stamps)))]
    path = _fresh(bases, f"serial_{case}.mcap")
    with SessionWriter(path, [suit]) as w:
        for t, raw in zip(stamps, raws):
            if raw:
                w.write(MocapPacket(t_ns=t, device=suit.name, raw=raw))
    label = f"{suit.meta.get('protocol')}: {label}"
    out = _fresh(bases, f"serial_replay_{case}")
    for argv, check in ((["replay", path, "--out", out, "--only", "imu", "--quiet"],
                         lambda run: _stats(out) is not None or "no stats.json"),
                        (["info", path, "--json"], lambda run: bool(json.loads(run.stdout)["streams"]))):
        run = run_command(argv)
        outcome, detail = judge(run, check)
        yield CaseResult("serial", case, label, argv[0], run.status, outcome, detail, run.seconds)


CASES: dict[str, Callable[..., Iterator[CaseResult]]] = {
    "session": session_cases, "bvh": bvh_cases, "folder": folder_cases, "npz": npz_cases, "serial": serial_cases}


def fuzz_case(bases: Bases, fmt: str, case: int, seed: int = 0) -> list[CaseResult]:
    """Mutated input number ``case`` of one format (Random(seed * 1000003 + case): the same case
    is the same input on every run) through its commands; its files are removed after."""
    try:
        return list(CASES[fmt](bases, random.Random(seed * 1_000_003 + case), case))
    finally:
        shutil.rmtree(bases.work / "cases", ignore_errors=True)


def fuzz(bases: Bases, fmt: str, cases: int, seed: int = 0) -> list[CaseResult]:
    """``cases`` mutated inputs of one format, each through its commands."""
    return [r for k in range(cases) for r in fuzz_case(bases, fmt, k, seed)]


@functools.lru_cache(maxsize=2)
def shared_bases(clip: Path) -> Bases:
    """The intact inputs, built once per process in a temporary folder removed at exit (the tests
    of several formats share them)."""
    work = Path(tempfile.mkdtemp(prefix="livecap-fuzz-"))
    atexit.register(shutil.rmtree, work, True)
    return build_bases(work, clip)


def summarise(results: list[CaseResult]) -> dict:
    by_format: dict[str, dict] = {}
    for r in results:
        d = by_format.setdefault(r.format, {"cases": set(), "runs": 0, "outcomes": Counter(), "slowest_s": 0.0})
        d["cases"].add(r.case)
        d["runs"] += 1
        d["outcomes"][r.outcome] += 1
        d["slowest_s"] = max(d["slowest_s"], r.seconds)
    return {fmt: {"cases": len(d["cases"]), "runs": d["runs"], "outcomes": dict(d["outcomes"]),
                  "failures": sum(d["outcomes"][f] for f in FAILURES), "slowest_s": round(d["slowest_s"], 2)}
            for fmt, d in by_format.items()}


def hostile_files(bases: Bases) -> dict[str, list]:
    """Small files declaring huge sizes, and the intact inputs, as (label -> livecap arguments)."""
    w = bases.work / "hostile"
    w.mkdir(exist_ok=True)
    bomb = w / "bomb.npz"
    with zipfile.ZipFile(bomb, "w") as z:
        z.writestr("vertices.npy", mut.npy_header("<f4", (1 << 40, 3)))
    ply = w / "bomb.ply"
    ply.write_text("ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
                   "property float y\nproperty float z\nend_header\n")
    head, _, _ = bases.bvh_text.partition("MOTION")
    row = bases.bvh_text.strip().splitlines()[-1]
    long_clip = w / "frame_time.bvh"
    long_clip.write_text(head + "MOTION\nFrames: 10\nFrame Time: 1000000\n" + "\n".join([row] * 10) + "\n")
    many = w / "frames.bvh"
    many.write_text(head + "MOTION\nFrames: 100000000000\nFrame Time: 0.0083333\n" + "\n".join([row] * 10) + "\n")
    wide = w / "wide"
    wide.mkdir(exist_ok=True)
    (wide / "intrinsics.json").write_text(json.dumps(dict(bases.folder_meta, width=10**9, height=10**9)))
    (wide / "0000.png").write_bytes(bases.folder_images[0])
    png = w / "png_bomb"
    png.mkdir(exist_ok=True)
    (png / "intrinsics.json").write_text(json.dumps(dict(bases.folder_meta, width=8192, height=4096)))
    (png / "0000.png").write_bytes(mut.png_ihdr(8192, 4096, 16, 0) + bases.folder_images[0][33:])
    folder = w / "folder"
    folder.mkdir(exist_ok=True)
    (folder / "intrinsics.json").write_text(json.dumps(bases.folder_meta))
    for i, img in enumerate(bases.folder_images):
        (folder / f"{i:04d}.png").write_bytes(img)
    out = w / "out"
    return {
        "session, intact (replay)": ["replay", bases.session, "--out", out, "--quiet"],
        "body .npz declaring (2^40, 3) float32, 12 TiB (replay --avatar)":
            ["replay", bases.session, "--out", out, "--quiet", "--avatar", bomb],
        "PLY declaring 2e9 vertices (replay --avatar)": ["replay", bases.session, "--out", out, "--quiet", "--avatar", ply],
        "body preset (replay --avatar)": ["replay", bases.session, "--out", out, "--quiet", "--avatar", "default"],
        "BVH, Frame Time 1000000 (synth)": ["synth", "--motion", long_clip, "--out", w / "a.mcap", "--force", "--quiet"],
        "BVH, Frames 1e11 (synth)": ["synth", "--motion", many, "--out", w / "a.mcap", "--force", "--quiet"],
        "BVH, 30 frames intact (synth)": ["synth", "--motion", bases.work / "clip.bvh", "--out", w / "a.mcap", "--force",
                                          "--quiet"],
        "depth folder, intrinsics 1e9 x 1e9 (replay)": ["replay", wide, "--out", out, "--quiet"],
        "depth folder, a PNG declaring 8192 x 4096 (replay)": ["replay", png, "--out", out, "--quiet"],
        "depth folder, 4 images intact (replay)": ["replay", folder, "--out", out, "--quiet"],
    }


def measure_memory(bases: Bases) -> list[dict]:
    """Peak RSS (GNU time) and exit status of the CLI, in its own process, on hostile_files."""
    (bases.work / "clip.bvh").write_text(bases.bvh_text)
    rows = []
    for label, args in hostile_files(bases).items():
        cmd = ["/usr/bin/time", "-f", "%M", sys.executable, "-m", "live.app.cli", *map(str, args)]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        lines = [ln for ln in proc.stderr.strip().splitlines() if not ln.startswith("Command exited")]
        rss = int(lines[-1]) / 1024 if lines and lines[-1].isdigit() else float("nan")
        rows.append({"input": label, "status": proc.returncode, "peak_rss_mb": round(rss),
                     "stderr": lines[:-1]})
        message = " | ".join(lines[:-1])
        print(f"{label:65s} exit {proc.returncode}  {rss:5.0f} MB  {message[:150]}", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    from live.core import assets

    p = argparse.ArgumentParser(prog="python -m research.fuzz_inputs", description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=300, help="mutated inputs per format (default 300)")
    p.add_argument("--formats", default=",".join(FORMATS), help=f"comma-separated, of {', '.join(FORMATS)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clip", type=Path, default=assets.shared_data_dir() / "bvh" / "mb_12_01.bvh")
    p.add_argument("--json", type=Path, default=None, help="also write every case's result here")
    p.add_argument("--memory", action="store_true", help="instead: peak memory of the CLI on small files "
                   "declaring huge sizes, each in its own process (GNU time)")
    args = p.parse_args(argv)
    formats = [f for f in args.formats.split(",") if f]
    unknown = set(formats) - set(FORMATS)
    if unknown or not args.clip.is_file():
        p.error(f"unknown formats {sorted(unknown)}" if unknown else f"no clip {args.clip}")
    results: list[CaseResult] = []
    with tempfile.TemporaryDirectory(prefix="livecap-fuzz-") as tmp:
        t0 = time.perf_counter()
        bases = build_bases(Path(tmp), args.clip)
        if args.memory:
            rows = measure_memory(bases)
            if args.json is not None:
                args.json.write_text(json.dumps(rows, indent=1))
            return 0
        for fmt in formats:
            t = time.perf_counter()
            found = fuzz(bases, fmt, args.cases, args.seed)
            results.extend(found)
            failed = [r for r in found if r.outcome in FAILURES]
            print(f"{fmt:8s} {args.cases} cases, {len(found)} runs in {time.perf_counter() - t:.0f} s: "
                  f"{dict(Counter(r.outcome for r in found))}", flush=True)
            for r in failed[:20]:
                print(f"  FAIL case {r.case} {r.command}: {r.mutation}: {r.outcome}: {r.detail[:200]}")
        total_s = time.perf_counter() - t0
    summary = summarise(results)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"total {sum(s['cases'] for s in summary.values())} cases, {len(results)} runs, "
          f"{sum(s['failures'] for s in summary.values())} failures, {total_s:.0f} s, peak RSS {peak_mb:.0f} MB")
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": summary, "peak_rss_mb": round(peak_mb),
                                         "results": [asdict(r) for r in results]}, indent=1))
    return 1 if any(s["failures"] for s in summary.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
