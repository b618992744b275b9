"""Many small sessions: a shell loop of `livecap replay` against `livecap batch replay` (in one
process, a local process pool, a local Ray), and what Ray costs per session beyond the replay.

Run: .venv/bin/python benchmarks/bench_batch.py [--sessions 40] [--seconds 1] [--runs 3]
The sessions (``--seconds`` each: clips of ../shared/data/bvh x seeds, made once with
`livecap batch synth` and kept in the cache) are replayed at --speed max onto the default avatar
by every mode in turn, each mode a whole command as a user runs it (Python start, imports, a
Ray started and stopped), alternating over the runs. Prints per mode the median wall time,
sessions/s and throughput relative to the shell loop; checks that every mode wrote the shell
loop's skeleton.npz, avatar.npz and avatar.bvh byte for byte. Overhead per session, from the
batch's own records: (dispatch wall time - startup) / sessions - the replay command's own time
in its worker, measured with one worker (``--workers 1``: nothing runs alongside), and the
startup (a local Ray started, or joined) apart.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from live.core import assets  # noqa: E402

LIVECAP = [sys.executable, "-m", "live.app.cli"]
REPLAY_OPTIONS = ["--avatar", "default"]
RESULT_FILES = ("skeleton.npz", "avatar.npz", "avatar.bvh")


def make_sessions(count: int, seconds: float) -> list[Path]:
    """``count`` sessions: the first clips of the shared BVH folder x 4 seeds (cached)."""
    clips = sorted(assets.bvh_dir().glob("cc_*.bvh"))[: (count + 3) // 4]
    folder = assets.cache_dir("bench_batch", f"sessions-{seconds:g}s")
    subprocess.run([*LIVECAP, "batch", "synth", "--motion", *map(str, clips), "--seeds", "4", "--seconds", str(seconds),
                    "--out", str(folder), "--workers", "2", "--quiet"], check=True)
    return sorted(folder.glob("*.mcap"))[:count]


def shell_loop(sessions: list[Path], out: Path) -> None:
    for s in sessions:
        subprocess.run([*LIVECAP, "replay", str(s), "--out", str(out / s.stem), "--speed", "max", "--quiet",
                        *REPLAY_OPTIONS], check=True)


def batch(sessions: list[Path], out: Path, *execution: str) -> dict:
    subprocess.run([*LIVECAP, "batch", "replay", *map(str, sessions), "--out", str(out), "--quiet", *REPLAY_OPTIONS,
                    *execution], check=True)
    return json.loads((out / "batch.json").read_text())


def overhead_per_session(record: dict) -> float:
    """Seconds per session beyond the replay command itself (one worker: nothing alongside)."""
    totals, sessions = record["totals"], record["sessions"].values()
    dispatch = totals["wall_s"] - totals["startup_s"]
    return dispatch / len(sessions) - median(s["command_seconds"] for s in sessions)


def same_outputs(reference: Path, out: Path, names: list[str]) -> bool:
    return all(filecmp.cmp(reference / n / f, out / n / f, shallow=False) for n in names for f in RESULT_FILES)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sessions", type=int, default=40)
    p.add_argument("--seconds", type=float, default=1.0)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args(argv)
    sessions = make_sessions(args.sessions, args.seconds)
    names = [s.stem for s in sessions]
    modes = {
        "shell loop of `livecap replay`": None,
        "batch, one process (--workers 1)": ["--workers", "1"],
        "batch, process pool (--workers 2)": ["--workers", "2"],
        "batch, local Ray (2 CPUs)": ["--ray", "local"],
        "batch, local Ray (1 CPU)": ["--ray", "local", "--workers", "1"],
    }
    walls: dict[str, list[float]] = {m: [] for m in modes}
    records: dict[str, list[dict]] = {m: [] for m in modes}
    identical = True
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        for run in range(args.runs):
            reference = Path(tmp) / f"shell{run}"
            for mode, execution in modes.items():
                out = Path(tmp) / f"{run}-{len(walls[mode])}-{mode.split()[0]}"
                t0 = time.perf_counter()
                if execution is None:
                    shell_loop(sessions, reference)
                    out = reference
                else:
                    records[mode].append(batch(sessions, out, *execution))
                walls[mode].append(time.perf_counter() - t0)
                identical &= same_outputs(reference, out, names)
                if out != reference:
                    shutil.rmtree(out)
            shutil.rmtree(reference)
    base = median(walls["shell loop of `livecap replay`"])
    print(f"{len(sessions)} sessions of {args.seconds:g} s ({sessions[0].parent}), replayed onto the default avatar; "
          f"{args.runs} runs per mode, alternating; medians")
    print(f"{'mode':<36}{'wall s':>9}{'sessions/s':>12}{'x shell loop':>14}")
    for mode, w in walls.items():
        wall = median(w)
        print(f"{mode:<36}{wall:>9.2f}{len(sessions) / wall:>12.2f}{base / wall:>14.2f}")
    inline = median(walls["batch, one process (--workers 1)"])
    for mode in ("batch, process pool (--workers 2)", "batch, local Ray (2 CPUs)"):
        print(f"{mode}: {inline / median(walls[mode]):.2f}x the one-process batch")
    for mode in ("batch, one process (--workers 1)", "batch, local Ray (1 CPU)"):
        recs = records[mode]
        print(f"{mode}: overhead per session beyond the replay itself {median(map(overhead_per_session, recs)):.3f} s "
              f"(replay itself {median(median(s['command_seconds'] for s in r['sessions'].values()) for r in recs):.3f} s); "
              f"startup {median(r['totals']['startup_s'] for r in recs):.2f} s")
    print(f"outputs identical to the shell loop's in every mode and run: {'yes' if identical else 'NO'}")


if __name__ == "__main__":
    main()
