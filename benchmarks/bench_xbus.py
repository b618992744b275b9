"""Decoder throughput: MTData2 frames/s through XbusParser (goal >= 50k frames/s), and text
lines/s through LineParser, fed in 4 KiB reads like a busy serial port. Median of 5 runs, with
the plausibility checks (drivers/plausibility.py, the default) and without them
(``plausibility=None``), and the ratio of the two medians. Then end to end: a SimulatedSuit in as-fast-as-read mode on a pty -> SerialSource, records/s
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
from live.core.rotations import quat_from_axis_angle, quat_multiply, quat_normalize  # noqa: E402
from sim.imu_device import SimulatedSuit  # noqa: E402
from sim.imu_model import random_smooth_motion  # noqa: E402

CHUNK = 4096


SENSORS = 15


def suit_orientations(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4): sample i is sensor 1 + i % 15 at step i // 15 (100 Hz), each sensor turning at
    5 rad/s about its own axis, so every sample passes the plausibility checks."""
    axis = rng.normal(size=(SENSORS, 3))
    axis *= (5.0 / np.linalg.norm(axis, axis=1))[:, None]
    step = np.arange(n) // SENSORS
    turn = quat_from_axis_angle(axis[np.arange(n) % SENSORS] * (step / 100.0)[:, None])
    return quat_multiply(quat_normalize(rng.normal(size=(SENSORS, 4)))[np.arange(n) % SENSORS], turn)


def xbus_stream(n: int, rng: np.random.Generator, **fields) -> bytes:
    q = suit_orientations(n, rng)
    extra = {k: rng.normal(size=3) for k in fields.pop("vectors", ())}
    return b"".join(encode_message(1 + i % SENSORS, MID_MTDATA2, encode_mtdata2(
        quat=q[i], counter=i // SENSORS, sample_time_fine=100 * (i // SENSORS), **extra, **fields))
        for i in range(n))


def lines_stream(n: int, rng: np.random.Generator, fmt: str) -> bytes:
    q = suit_orientations(n, rng)
    acc = rng.normal(size=(n, 3))
    return b"".join(encode_line(1 + i % SENSORS, 10_000 * (i // SENSORS), q[i], acc=acc[i], fmt=fmt,
                                checksum=True) for i in range(n))


def rate(make_parser, stream: bytes, n: int, runs: int = 5) -> tuple[float, float, int]:
    """Records/s with the checks on and off (runs interleaved, so load changes hit both)."""
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(runs):
        for checks in (True, False):
            parser = make_parser() if checks else make_parser(plausibility=None)
            t0 = time.perf_counter()
            got = 0
            for i in range(0, len(stream), CHUNK):
                got += len(parser.feed(stream[i:i + CHUNK]))
            times[checks].append(time.perf_counter() - t0)
            assert got == n, (got, n, parser.counters)
    return n / statistics.median(times[True]), n / statistics.median(times[False]), len(stream) // n


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
    print(f"{'case':36s} {'bytes/rec':>9s} {'records/s, checks on':>21s} {'checks off':>11s} {'on/off':>7s}")
    for name, (make, stream) in cases.items():
        on, off, size = rate(make, stream, n)
        print(f"{name:36s} {size:9d} {on:21,.0f} {off:11,.0f} {on / off:7.2f}")
    for protocol in ("xbus", "lines"):
        print(f"{'pty end to end ' + protocol:36s} {'':9s} {end_to_end(protocol):24,.0f}")


if __name__ == "__main__":
    main()
