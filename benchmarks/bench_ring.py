"""Ring throughput: one writer thread -> one reader thread, small items and 10k-point clouds.

Run: python benchmarks/bench_ring.py [--reps 5] [--small N] [--clouds N]

For each case and mode it prints the median over the repetitions of
- write/s: items written per second by the writer thread,
- recv/s: items the reader received per second (run time = first write to reader done),
- dropped: fraction of items the reader lost to overwrite (always 0 with block_when_full),
then one JSON line with all medians.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from live.core.ring import CloudRing, ObjectRing, Ring  # noqa: E402


def run_once(make_ring, payloads: list, n: int) -> dict:
    """Write n items (cycling through payloads) from a thread while another thread reads them."""
    ring = make_ring()
    reader = ring.reader("next")
    done = threading.Event()
    times: dict[str, float] = {}

    def read() -> None:
        for _ in reader:
            pass
        times["read_end"] = time.perf_counter()
        done.set()

    def write() -> None:
        k = len(payloads)
        t0 = time.perf_counter()
        for i in range(n):
            ring.write(payloads[i % k], i)
        times["write"] = time.perf_counter() - t0
        times["start"] = t0
        ring.close()

    threads = [threading.Thread(target=read), threading.Thread(target=write)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    total = times["read_end"] - times["start"]
    assert reader.received + reader.dropped == n
    return {
        "write_per_s": n / times["write"],
        "recv_per_s": reader.received / total,
        "dropped": reader.dropped / n,
    }


def bench(name: str, make_ring, payloads: list, n: int, reps: int) -> dict:
    runs = [run_once(make_ring, payloads, n) for _ in range(reps)]
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    print(
        f"{name:<28} write/s {med['write_per_s']:>11,.0f}   recv/s {med['recv_per_s']:>11,.0f}"
        f"   dropped {100 * med['dropped']:5.1f} %"
    )
    return med


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--small", type=int, default=200_000, help="small items per run")
    ap.add_argument("--clouds", type=int, default=5_000, help="clouds per run")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    small = [rng.standard_normal(8) for _ in range(64)]
    clouds = [rng.standard_normal((10_000, 3)).astype(np.float32) for _ in range(8)]
    cloud_arena = 32 * 10_000  # 32 clouds of 10k points: 3.8 MB
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {args.reps} reps, medians")
    out = {}
    for block in (False, True):
        mode = "block" if block else "overwrite"
        out[f"small_{mode}"] = bench(
            f"Ring (8,) f64 {mode}",
            lambda: Ring(4096, (8,), np.float64, block_when_full=block),
            small,
            args.small,
            args.reps,
        )
        out[f"object_{mode}"] = bench(
            f"ObjectRing {mode}",
            lambda: ObjectRing(4096, block_when_full=block),
            small,
            args.small,
            args.reps,
        )
        out[f"cloud10k_{mode}"] = bench(
            f"CloudRing 10k pts {mode}",
            lambda: CloudRing(64, cloud_arena, block_when_full=block),
            clouds,
            args.clouds,
            args.reps,
        )
    summary = {k: {m: round(v, 4 if m == "dropped" else 0) for m, v in d.items()} for k, d in out.items()}
    print(json.dumps({"bench": "ring", "reps": args.reps, **summary}))


if __name__ == "__main__":
    main()
