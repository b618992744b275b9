"""Damaged serial frames that decode to wrong values: how many get through the parsers.

A 15-sensor suit turning smoothly (up to 8 rad/s per sensor) streams at 100 Hz; a fraction of
its frames (Xbus) or lines (text, with and without the ``*HH`` checksum) get 1, 2 or 3 random
bits flipped. Every decoded sample is compared with what was sent: a sample that matches no
sent sample exactly (orientation within 1e-5 rad, counter, clock, sensor id, acc/gyro) is
damage that got through ("wrong out"). Columns: how many of those have a wrong orientation
(against the sent sample they came from), how many by more than 5 degrees and the largest
error; samples missing their orientation or acc (an item id damaged into an unknown one:
"partial", not counted as wrong); samples whose id, counter or clock is damaged ("bad key");
intact records not decoded ("intact lost"). Printed per case and per number of flipped bits, with the parser's
plausibility checks on (the default) and off (``plausibility=None``: the bare protocol decoder,
what the checksum and framing alone let through), and the rejection counters. Seeded.

Usage: python benchmarks/bench_serial_corruption.py [--steps 4000] [--fraction 0.1]
"""

from __future__ import annotations

import argparse
import inspect
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.text_lines import LineParser, encode_line  # noqa: E402
from drivers.xbus import MID_MTDATA2, encode_message, encode_mtdata2  # noqa: E402
from drivers.xbus_stream import XbusParser  # noqa: E402
from live.core.rotations import quat_from_axis_angle, quat_multiply, quat_normalize  # noqa: E402

SENSORS = 15
RATE_HZ = 100
REASONS = ("non_finite", "implausible_norm", "implausible_rate", "counter_jump")


def smooth_orientations(steps: int, rng: np.random.Generator) -> np.ndarray:
    """(steps, SENSORS, 4) world quaternions: each sensor turns about a slowly wandering axis
    at 1-8 rad/s."""
    q0 = quat_normalize(rng.normal(size=(SENSORS, 4)))
    axis = rng.normal(size=(SENSORS, 3))
    speed = rng.uniform(1.0, 8.0, size=SENSORS)
    out = np.empty((steps, SENSORS, 4))
    q = q0
    for t in range(steps):
        axis += 0.05 * rng.normal(size=axis.shape)
        unit = axis / np.linalg.norm(axis, axis=1, keepdims=True)
        q = quat_normalize(quat_multiply(q, quat_from_axis_angle(unit * (speed / RATE_HZ)[:, None])))
        out[t] = q
    return out


def flip_bits(record: bytes, k: int, rng: np.random.Generator, keep_newline: bool) -> bytes:
    buf = bytearray(record)
    n_bits = 8 * (len(buf) - (1 if keep_newline else 0))
    for bit in rng.choice(n_bits, size=k, replace=False):
        buf[bit // 8] ^= 1 << (bit % 8)
    return bytes(buf)


def angle(a, b) -> float:
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(a, b)))))


def _sources(smp, line: tuple[int, int] | None) -> tuple[list[tuple[int, int]], bool]:
    """The (sensor, step) of the sent samples a decoded one may come from, and whether its own
    id, counter and clock are intact. line: the (sensor, step) of the line it came out of.

    Text lines are fed one line at a time, so a sample's source is the line it came out of.
    Xbus frames may be decoded out of step with the feeding (a damaged length field makes the
    parser wait), so a sample whose id, counter and clock agree with a sent frame came from it;
    otherwise the candidates are the frames its counter and its clock point to (of its id, or of
    any id when that is unknown): the nearest in orientation is taken (a lower bound of the error).
    """
    if line is not None:
        return [line], (smp.sensor, smp.t_us) == (line[0], line[1] * (1_000_000 // RATE_HZ))
    step_c = smp.counter
    step_t = smp.sample_time_fine // (10_000 // RATE_HZ) if smp.sample_time_fine is not None else None
    if step_c is not None and step_c == step_t and 1 <= smp.sensor <= SENSORS:
        return [(smp.sensor, step_c)], True
    sensors = [smp.sensor] if 1 <= smp.sensor <= SENSORS else range(1, SENSORS + 1)
    return [(s, t) for t in {step_c, step_t} if t is not None for s in sensors], False


def run_case(protocol: str, make_parser: Callable, quats: np.ndarray, flips: int, fraction: float,
             seed: int) -> dict:
    """Stream every sample once, damage ``fraction`` of them with ``flips`` bits, decode, compare."""
    rng = np.random.default_rng(seed)
    acc = rng.normal(size=quats.shape[:2] + (3,))
    records: list[tuple[tuple, bytes]] = []
    damaged = 0
    intact: set[tuple] = set()
    steps = len(quats)
    for t in range(steps):
        for s in range(SENSORS):
            sensor = s + 1
            if protocol == "xbus":
                rec = encode_message(sensor, MID_MTDATA2, encode_mtdata2(
                    quat=quats[t, s], counter=t, sample_time_fine=t * (10_000 // RATE_HZ), acc=acc[t, s]))
            else:
                rec = encode_line(sensor, t * (1_000_000 // RATE_HZ), quats[t, s], acc=acc[t, s],
                                  checksum=protocol == "lines+cs")
            if rng.random() < fraction:
                rec = flip_bits(rec, flips, rng, keep_newline=protocol != "xbus")
                damaged += 1
            else:
                intact.add((sensor, t))
            records.append(((sensor, t), rec))
    parser = make_parser()
    decoded: list[tuple] = []  # (sample, (sensor, step) of the line it came out of, or None)
    if protocol == "xbus":
        stream = b"".join(rec for _, rec in records)
        for i in range(0, len(stream), 4096):
            decoded += [(smp, None) for smp in parser.feed(stream[i:i + 4096])]
    else:
        for (sensor, t), rec in records:
            decoded += [(smp, (sensor, t)) for smp in parser.feed(rec)]
    out = {"wrong": 0, "orient": 0, "orient_5deg": 0, "partial": 0, "bad_key": 0}
    errors = [0.0]
    found = set()
    for smp, line in decoded:
        if smp.quat is None or smp.acc is None:  # an item id damaged into an unknown one
            out["partial"] += 1
            continue
        candidates, key_ok = _sources(smp, line)
        candidates = [(s, t) for s, t in candidates if 0 <= t < steps]
        if not candidates:
            out["bad_key"] += 1
            out["wrong"] += 1
            continue
        err, (s, t) = min((angle(smp.quat, quats[t, s - 1]), (s, t)) for s, t in candidates)
        out["bad_key"] += not key_ok
        if err > 1e-5:
            out["orient"] += 1
            out["orient_5deg"] += err > math.radians(5.0)
            errors.append(err)
        if not key_ok or err > 1e-5 or not np.allclose(smp.acc, acc[t, s - 1], atol=1e-5):
            out["wrong"] += 1
        else:
            found.add((s, t))
    counters = parser.counters
    return {"damaged": damaged, **out, "lost_intact": len(intact - found),
            "max_err_deg": math.degrees(max(errors)),
            "rejected": {r: counters.get(r, 0) for r in REASONS}}


def parsers(protocol: str) -> dict[str, Callable]:
    cls = XbusParser if protocol == "xbus" else LineParser
    out = {"checks on": cls}
    if "plausibility" in inspect.signature(cls).parameters:
        out["checks off"] = lambda: cls(plausibility=None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=4000, help="samples per sensor (100 Hz)")
    ap.add_argument("--fraction", type=float, default=0.1, help="share of records damaged")
    args = ap.parse_args()
    quats = smooth_orientations(args.steps, np.random.default_rng(0))
    print(f"{SENSORS} sensors x {args.steps} samples at {RATE_HZ} Hz, {args.fraction:.0%} of records damaged")
    print(f"{'case':9s} {'bits':>4s} {'checks':10s} {'damaged':>7s} {'wrong out':>9s} {'share':>6s} "
          f"{'orient.':>7s} {'> 5 deg':>7s} {'max err':>8s} {'partial':>7s} {'bad key':>7s} "
          f"{'intact lost':>11s}  rejected")
    for protocol in ("xbus", "lines+cs", "lines"):
        for flips in (1, 2, 3):
            for label, make in parsers(protocol).items():
                r = run_case(protocol, make, quats, flips, args.fraction, seed=flips)
                rej = " ".join(f"{k}={v}" for k, v in r["rejected"].items() if v)
                print(f"{protocol:9s} {flips:4d} {label:10s} {r['damaged']:7d} {r['wrong']:9d} "
                      f"{r['wrong'] / max(r['damaged'], 1):6.2%} {r['orient']:7d} {r['orient_5deg']:7d} "
                      f"{r['max_err_deg']:7.1f}° {r['partial']:7d} {r['bad_key']:7d} {r['lost_intact']:11d}  {rej}")


if __name__ == "__main__":
    main()
