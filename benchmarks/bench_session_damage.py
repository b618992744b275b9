"""Sessions under abuse: data lost to kill -9, frames kept after random bit flips, memory of the
readers on hostile and long files.

Run: .venv/bin/python benchmarks/bench_session_damage.py [--kills 5] [--trials 30] [--skip kill,flips,memory]

- kill: ``livecap record`` of a simulated suit (a pty; text lines or Xbus at several rates), and
  of the suit with the virtual camera rendering a clip live (``sim:``), is killed with SIGKILL
  at a random moment 1-3 s in; per run and stream, the seconds between the kill and the
  stream's last sample in the file, and the bytes the suit had written that the file does not
  hold (including what was still in the pty). Medians and maxima over the runs.
- flips: a 45-frame synthetic session (``livecap synth``, 1.5 s) with 1, 5 or 30 random bit
  flips anywhere in the file (seeded); depth frames read back (mean, min) and exceptions raised
  (must be 0).
- memory: peak RSS (GNU time) of ``livecap info`` / ``replay`` / ``export`` / ``export
  --foxglove`` on hostile files (a 32 KB chunk declaring a 23000 x 23000 depth image, a chunk
  declaring a 60 M-point cloud), on the largest frame the limits let through (a 4 M-point
  cloud), and of ``export`` on synthetic sessions of 2 and 8 s (memory must not grow with length).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
import zstandard

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mcap.data_stream import RecordBuilder  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mcap.records import Chunk  # noqa: E402

from live.core.errors import LivecapError  # noqa: E402
from live.io import codec  # noqa: E402
from live.io.session import SessionReader  # noqa: E402
from sim.imu_device import SimulatedSuit  # noqa: E402
from sim.imu_model import random_smooth_motion  # noqa: E402

LIVECAP = [sys.executable, "-m", "live.app.cli"]
CLIP = ROOT.parent / "shared" / "data" / "bvh" / "mb_12_01.bvh"


def _run(args: list[str]) -> tuple[int, float]:
    """Exit status and peak RSS (MB) of one livecap command, measured by GNU time (a child
    forked from this process would count this process's pages until it execs)."""
    with tempfile.NamedTemporaryFile("r") as rss:
        proc = subprocess.run(["/usr/bin/time", "-q", "-f", "%M", "-o", rss.name] + LIVECAP + args, cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        return proc.returncode, int(rss.read().split()[-1]) / 1024


# ---------------------------------------------------------------------------------------------
# kill -9


def _packets(path: Path):
    try:
        return [f for _, f in SessionReader(path).frames()]
    except LivecapError:
        return []


def kill_once(tmp: Path, protocol: str, rate_hz: float, after_s: float, depth: bool) -> dict[str, tuple]:
    """Per stream (seconds lost, bytes lost or None, byte rate) of one record killed ``after_s``
    in: a simulated suit, and with ``depth`` the virtual camera rendering a clip live."""
    out = tmp / f"k{time.monotonic_ns()}.mcap"
    motion = random_smooth_motion(240, fps=60.0, seed=1)
    with SimulatedSuit(motion, protocol=protocol, rate_hz=rate_hz, realtime=True, loop=True) as suit:
        sources = ["--source", f"serial:{suit.port}:{protocol}"] + (["--source", f"sim:{CLIP}"] if depth else [])
        proc = subprocess.Popen(LIVECAP + ["record", *sources, "--out", str(out), "--quiet"], cwd=ROOT,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while not (_packets(out) and suit.counters["bytes"] > 0):
            time.sleep(0.02)
        started, sent0 = time.monotonic(), suit.counters["bytes"]
        time.sleep(after_s)
        killed_ns, sent = time.monotonic_ns(), suit.counters["bytes"]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        rate = (sent - sent0) / (time.monotonic() - started)
    last: dict[str, int] = {}
    recorded = 0
    for stream, frame in SessionReader(out).frames():
        last[f"{stream.kind} {stream.name}"] = frame.t_ns
        recorded += len(frame.raw) if stream.kind == "serial" else 0
    return {name: ((killed_ns - t) / 1e9, sent - recorded if name.startswith("serial") else None,
                   rate if name.startswith("serial") else None) for name, t in last.items()}


def bench_kill(kills: int, rng: random.Random) -> None:
    print("\n## kill -9 during `livecap record` (simulated suit on a pty; sim: the virtual camera live)")
    print("| recording | stream | runs | seconds lost: median / max | bytes lost: median / max |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for protocol, rate_hz, depth in (("lines", 10.0, False), ("lines", 100.0, False), ("xbus", 100.0, False),
                                         ("xbus", 400.0, False), ("xbus", 100.0, True)):
            runs = [kill_once(Path(tmp), protocol, rate_hz, rng.uniform(1.0, 3.0), depth) for _ in range(kills)]
            label = f"{protocol} {rate_hz:.0f} Hz" + (" + sim depth" if depth else "")
            for stream in sorted(runs[0]):
                lost_s = np.array([r[stream][0] for r in runs if stream in r])
                cells = f"{np.median(lost_s):.2f} / {lost_s.max():.2f} s"
                if runs[0][stream][1] is not None:
                    lost_b = np.array([r[stream][1] for r in runs])
                    rate = np.median([r[stream][2] for r in runs])
                    name = f"{stream} ({rate / 1000:.1f} kB/s)"
                    print(f"| {label} | {name} | {len(lost_s)} | {cells} | {np.median(lost_b):.0f} / {lost_b.max():.0f} |")
                else:
                    print(f"| {label} | {stream} | {len(lost_s)} | {cells} | |")


# ---------------------------------------------------------------------------------------------
# random flips


def bench_flips(trials: int, rng: random.Random, tmp: Path) -> None:
    session = tmp / "s45.mcap"
    subprocess.run(LIVECAP + ["synth", "--motion", str(CLIP), "--out", str(session), "--seconds", "1.5",
                              "--seed", "1", "--quiet"], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    data = session.read_bytes()
    depth = sum(1 for s, _ in SessionReader(session).frames() if s.kind == "depth")
    print(f"\n## random bit flips in a {depth}-frame session ({len(data)} bytes), {trials} trials each")
    print("| flips | depth frames kept: mean / min | exceptions |")
    print("|---|---|---|")
    for flips in (1, 5, 30):
        kept, exceptions = [], 0
        for _ in range(trials):
            buf = bytearray(data)
            for _ in range(flips):
                buf[rng.randrange(8, len(buf))] ^= 1 << rng.randrange(8)
            path = tmp / "flipped.mcap"
            path.write_bytes(bytes(buf))
            try:
                kept.append(sum(1 for s, _ in SessionReader(path).frames() if s.kind == "depth"))
            except Exception:  # noqa: BLE001 - counted: there must be none
                exceptions += 1
        print(f"| {flips} | {np.mean(kept):.1f} / {min(kept)} of {depth} | {exceptions} |")


# ---------------------------------------------------------------------------------------------
# memory


def _hostile_chunk(payload_head: bytes, zeros: int) -> bytes:
    """A chunk record holding one message on channel 1 (the depth stream of a synthetic
    session): ``payload_head`` then ``zeros`` zero bytes, zstd-compressed as it streams."""
    msg_len = 22 + len(payload_head) + zeros
    head = struct.pack("<BQHIQQ", 0x05, msg_len, 1, 0, 10**9, 10**9) + payload_head
    cobj = zstandard.ZstdCompressor().compressobj(size=len(head) + zeros)
    parts, crc = [cobj.compress(head)], zlib.crc32(head)
    block = bytes(1 << 20)
    left = zeros
    while left:
        piece = block[: min(left, len(block))]
        parts.append(cobj.compress(piece))
        crc = zlib.crc32(piece, crc)
        left -= len(piece)
    parts.append(cobj.flush())
    rb = RecordBuilder()
    Chunk(compression="zstd", data=b"".join(parts), message_start_time=10**9, message_end_time=10**9,
          uncompressed_crc=crc, uncompressed_size=len(head) + zeros).write(rb)
    return rb.end()


def _with_chunk(session: Path, chunk: bytes, out: Path) -> Path:
    """The session's header, metadata and attachment, then ``chunk`` and the session's chunks
    (an unfinished file: the reader scans it without an index)."""
    with open(session, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    data = session.read_bytes()
    first, end = chunks[0].chunk_start_offset, chunks[-1].chunk_start_offset + chunks[-1].chunk_length
    out.write_bytes(data[:first] + chunk + data[first:end])
    return out


def bench_memory(tmp: Path) -> None:
    session = tmp / "s45.mcap"
    mats = bytes(codec._MATS.size)
    image = _with_chunk(session, _hostile_chunk(struct.pack("<BBq", codec.TAG_DEPTH_IMAGE, 1, 10**9) + mats
                                                + struct.pack("<HH", 23000, 23000), 23000 * 23000 * 2), tmp / "image.mcap")
    cloud = _with_chunk(session, _hostile_chunk(struct.pack("<BBq", codec.TAG_CLOUD, 1, 10**9) + mats
                                                + struct.pack("<I", 60_000_000), 60_000_000 * 6), tmp / "cloud.mcap")
    rng = np.random.default_rng(0)
    pts = rng.integers(-3000, 3000, size=(codec.MAX_POINTS, 3)).astype("<i2").tobytes()
    legal = _with_chunk(session, _hostile_chunk(struct.pack("<BBq", codec.TAG_CLOUD, 1, 10**9) + mats
                                                + struct.pack("<I", codec.MAX_POINTS) + pts, 0), tmp / "legal.mcap")
    print("\n## peak memory (MB, RSS) of the readers")
    print("| file | size | info | replay | export | export --foxglove |")
    print("|---|---|---|---|---|---|")
    for name, path in (("45 frames + a chunk declaring a 23000 x 23000 image", image),
                       ("45 frames + a chunk declaring a 60 M-point cloud", cloud),
                       (f"45 frames + a legal {codec.MAX_POINTS // 1_000_000} M-point cloud", legal),
                       ("45 frames, intact", session)):
        row = []
        for args in (["info", str(path)], ["replay", str(path), "--out", str(tmp / "rep"), "--quiet"],
                     ["export", str(path), "--out", str(tmp / "exp")],
                     ["export", str(path), "--foxglove", str(tmp / f"fox{time.monotonic_ns()}.mcap")]):
            rc, mb = _run(args)
            row.append(f"{mb:.0f} (exit {rc})")
        print(f"| {name} | {path.stat().st_size / 1e6:.1f} MB | " + " | ".join(row) + " |")
    print("\n| synthetic session | size | export peak RSS |")
    print("|---|---|---|")
    for seconds in (2, 8):
        path = tmp / f"long{seconds}.mcap"
        subprocess.run(LIVECAP + ["synth", "--motion", str(CLIP), "--out", str(path), "--seconds", str(seconds),
                                  "--quiet"], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        rc, mb = _run(["export", str(path), "--out", str(tmp / f"exp{seconds}")])
        print(f"| {seconds} s, 30 fps depth | {path.stat().st_size / 1e6:.1f} MB | {mb:.0f} MB (exit {rc}) |")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--kills", type=int, default=5, help="kill -9 runs per stream rate")
    p.add_argument("--trials", type=int, default=30, help="random-flip trials per flip count")
    p.add_argument("--skip", default="", help="comma-separated parts to skip: kill, flips, memory")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    rng = random.Random(args.seed)
    if "kill" not in skip:
        bench_kill(args.kills, rng)
    with tempfile.TemporaryDirectory() as tmp:
        if "flips" not in skip or "memory" not in skip:
            bench_flips(args.trials if "flips" not in skip else 1, rng, Path(tmp))
        if "memory" not in skip:
            bench_memory(Path(tmp))


if __name__ == "__main__":
    main()
