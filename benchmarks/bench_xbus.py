"""Decoder throughput: MTData2 frames/s through XbusParser (goal >= 50k frames/s), and text
lines/s through LineParser, fed in 4 KiB reads like a busy serial port. Median of 5 runs.
Then end to end: a SimulatedSuit in as-fast-as-read mode on a pty -> SerialSource, records/s
(both sides in one process, so this is a lower bound; median of 3).

Usage: python benchmarks/bench_xbus.py [--frames 20000]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.serial_source import SerialSource  # noqa: E402
from drivers.text_lines import LineParser, encode_line  # noqa: E402
from drivers.xbus import MID_MTDATA2, XbusParser, encode_message, encode_mtdata2  # noqa: E402
from live.core.rotations import quat_normalize  # noqa: E402
from sim.imu_device import SimulatedSuit  # noqa: E402
from sim.imu_model import random_smooth_motion  # noqa: E402

CHUNK = 4096


def xbus_stream(n: int, rng: np.random.Generator, **fields) -> bytes:
    q = quat_normalize(rng.normal(size=(n, 4)))
    extra = {k: rng.normal(size=3) for k in fields.pop("vectors", ())}
    return b"".join(encode_message(1 + i % 15, MID_MTDATA2, encode_mtdata2(
        quat=q[i], counter=i, sample_time_fine=100 * i, **extra, **fields)) for i in range(n))


def lines_stream(n: int, rng: np.random.Generator, fmt: str) -> bytes:
    q = quat_normalize(rng.normal(size=(n, 4)))
    acc = rng.normal(size=(n, 3))
    return b"".join(encode_line(1 + i % 15, 1000 * i, q[i], acc=acc[i], fmt=fmt, checksum=True)
                    for i in range(n))


def rate(make_parser, stream: bytes, n: int, runs: int = 5) -> tuple[float, int]:
    times = []
    for _ in range(runs):
        parser = make_parser()
        t0 = time.perf_counter()
        got = 0
        for i in range(0, len(stream), CHUNK):
            got += len(parser.feed(stream[i:i + CHUNK]))
        times.append(time.perf_counter() - t0)
        assert got == n, (got, n)
    return n / statistics.median(times), len(stream) // n


def end_to_end(protocol: str, runs: int = 3) -> float:
    motion = random_smooth_motion(600, fps=60.0, seed=0)
    rates = []
    for _ in range(runs):
        with SimulatedSuit(motion, protocol, rate_hz=100, realtime=False, loop=False, paused=True) as suit:
            arrived = threading.Event()
            src = SerialSource(suit.port, protocol)
            src.start(lambda p: arrived.set())
            src.connected.wait(10)
            t0 = time.perf_counter()
            suit.resume()
            suit.finished.wait(60)
            while src.counters["bytes"] < suit.counters["bytes"]:
                arrived.clear()
                arrived.wait(10)
            dt = time.perf_counter() - t0
            src.stop()
            rates.append(src.counters["records"] / dt)
    return statistics.median(rates)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.frames
    cases = {
        "xbus quat f32 + counter + STF": (XbusParser, xbus_stream(n, rng)),
        "xbus quat fp1632 + counter + STF": (XbusParser, xbus_stream(n, rng, precision="fp1632")),
        "xbus quat + acc + gyro + mag f32": (XbusParser, xbus_stream(n, rng, vectors=("acc", "gyro", "mag"))),
        "xbus rotation matrix f32": (XbusParser, xbus_stream(n, rng, orientation="matrix")),
        "lines csv + acc + checksum": (LineParser, lines_stream(n, rng, "csv")),
        "lines json + acc + checksum": (LineParser, lines_stream(n, rng, "json")),
    }
    print(f"{'case':36s} {'bytes/rec':>9s} {'records/s (median of 5)':>24s}")
    for name, (make, stream) in cases.items():
        per_s, size = rate(make, stream, n)
        print(f"{name:36s} {size:9d} {per_s:24,.0f}")
    for protocol in ("xbus", "lines"):
        print(f"{'pty end to end ' + protocol:36s} {'':9s} {end_to_end(protocol):24,.0f}")


if __name__ == "__main__":
    main()
