"""Decoder throughput: MTData2 frames/s through XbusParser (goal >= 50k frames/s), and text
lines/s through LineParser, fed in 4 KiB reads like a busy serial port. Median of 5 runs, with
the plausibility checks (drivers/plausibility.py, the default) and without them
(``plausibility=None``), and the ratio of the two medians (runs interleaved in one process).
``--baseline DIR`` adds the parsers of another checkout (e.g. ``git worktree add /tmp/old
COMMIT``), loaded under other module names into the same process. Then end to end: a
SimulatedSuit in as-fast-as-read mode on a pty -> SerialSource, records/s (both sides in one
process, so this is a lower bound; median of 3).

Usage: python benchmarks/bench_xbus.py [--frames 20000] [--baseline DIR]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.serial_source import SerialSource  # noqa: E402
from drivers.text_lines import LineParser, encode_line  # noqa: E402
from drivers.xbus import MID_MTDATA2, encode_message, encode_mtdata2  # noqa: E402
from drivers.xbus_stream import XbusParser  # noqa: E402
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


def load_baseline(root: Path) -> dict[str, type]:
    """XbusParser and LineParser of another checkout, as modules of their own names."""
    out = {}
    for module, cls in (("xbus", "XbusParser"), ("text_lines", "LineParser")):
        spec = importlib.util.spec_from_file_location(f"baseline_{module}", root / "drivers" / f"{module}.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # dataclasses look their module up there
        spec.loader.exec_module(mod)
        out[cls] = getattr(mod, cls)
    return out


def rate(parsers: dict[str, object], stream: bytes, n: int, runs: int = 5) -> dict[str, float]:
    """Records/s of each parser factory (runs interleaved, so load changes hit every one)."""
    times: dict[str, list[float]] = {name: [] for name in parsers}
    for _ in range(runs):
        for name, make in parsers.items():
            parser = make()
            t0 = time.perf_counter()
            got = 0
            for i in range(0, len(stream), CHUNK):
                got += len(parser.feed(stream[i:i + CHUNK]))
            times[name].append(time.perf_counter() - t0)
            assert got == n, (got, n, parser.counters)
    return {name: n / statistics.median(t) for name, t in times.items()}


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
    ap.add_argument("--baseline", type=Path, help="another checkout whose parsers to time alongside")
    args = ap.parse_args()
    baseline = load_baseline(args.baseline) if args.baseline else {}
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
    print(f"{'case':36s} {'bytes/rec':>9s} {'records/s, checks on':>21s} {'checks off':>11s} {'on/off':>7s}"
          + (f" {'baseline':>10s} {'on/baseline':>11s}" if baseline else ""))
    for name, (make, stream) in cases.items():
        parsers = {"on": make, "off": lambda make=make: make(plausibility=None)}
        if baseline:
            parsers["baseline"] = baseline[make.__name__]
        r = rate(parsers, stream, n)
        line = f"{name:36s} {len(stream) // n:9d} {r['on']:21,.0f} {r['off']:11,.0f} {r['on'] / r['off']:7.2f}"
        if baseline:
            line += f" {r['baseline']:10,.0f} {r['on'] / r['baseline']:11.2f}"
        print(line)
    for protocol in ("xbus", "lines"):
        print(f"{'pty end to end ' + protocol:36s} {'':9s} {end_to_end(protocol):24,.0f}")


if __name__ == "__main__":
    main()
