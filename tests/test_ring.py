"""Ring buffers: model-based properties, arena wrap-around, seqlock, threads, close, backpressure."""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from live.core.errors import LivecapError
from live.core.ring import CloudRing, Item, ObjectRing, Reader, Ring, RingClosedError, RingFullError

HYPO = settings(
    max_examples=150,
    stateful_step_count=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


def _cloud(seq: int, n: int) -> np.ndarray:
    """A cloud whose every coordinate encodes its seq, so a torn or misplaced copy shows."""
    return np.full((n, 3), float(seq), dtype=np.float32)


# ---- model-based tests ----------------------------------------------------------------------


class RingModel(RuleBasedStateMachine):
    """Every ring against a plain list of everything written; the stored items are the suffix
    starting at the ring's tail, which for Ring/ObjectRing must be the last `capacity` items and
    for CloudRing must respect the point budget."""

    @initialize(
        kind=st.sampled_from(["ring", "object", "cloud"]),
        capacity=st.integers(1, 6),
        arena=st.integers(1, 24),
    )
    def setup(self, kind: str, capacity: int, arena: int) -> None:
        self.kind = kind
        if kind == "ring":
            self.ring = Ring(capacity, (2,), np.int64)
        elif kind == "object":
            self.ring = ObjectRing(capacity)
        else:
            self.ring = CloudRing(capacity, arena)
        self.capacity = capacity
        self.arena = arena
        self.written: list[tuple[int, object]] = []  # (t_ns, payload) by seq
        self.readers: list[tuple[Reader, dict]] = []
        self.t = 0

    def _payload(self, seq: int, n: int) -> object:
        if self.kind == "ring":
            return np.array([seq, -seq], dtype=np.int64)
        if self.kind == "object":
            return ("frame", seq)
        return _cloud(seq, min(n, self.arena))

    def _same(self, a: object, b: object) -> bool:
        if isinstance(a, np.ndarray):
            return isinstance(b, np.ndarray) and a.shape == b.shape and bool(np.all(a == b))
        return a is b

    @property
    def tail(self) -> int:
        return self.ring.tail_seq

    @property
    def head(self) -> int:
        return len(self.written) - 1

    def _check(self, item: Item | None, seq: int | None) -> None:
        if seq is None:
            assert item is None
            return
        assert item is not None and item.seq == seq
        t, payload = self.written[seq]
        assert item.t_ns == t
        assert self._same(item.payload, payload)

    @rule(dt=st.integers(0, 3), n=st.integers(0, 30))
    def write(self, dt: int, n: int) -> None:
        self.t += dt
        payload = self._payload(len(self.written), n)
        seq = self.ring.write(payload, self.t)
        assert seq == len(self.written)
        self.written.append((self.t, payload))

    @invariant()
    def stored_suffix(self) -> None:
        if not hasattr(self, "ring"):
            return
        assert self.ring.head_seq == self.head
        stored = self.head - self.tail + 1
        assert 0 <= stored <= self.capacity
        if self.kind != "cloud":
            assert self.tail == max(0, len(self.written) - self.capacity)
        else:
            pts = sum(len(self.written[s][1]) for s in range(self.tail, self.head + 1))
            assert pts == self.ring.points_stored <= self.arena
            # Eviction is never gratuitous: the newest cloud always stays.
            if self.written:
                assert self.tail <= self.head

    @rule()
    def latest(self) -> None:
        self._check(self.ring.latest(), self.head if self.written else None)

    @rule(after=st.integers(-2, 40))
    def next_after(self, after: int) -> None:
        first = max(after + 1, self.tail)
        want = first if first <= self.head else None
        self._check(self.ring.next(after, timeout=0), want)

    @rule(q=st.integers(-2, 120))
    def nearest(self, q: int) -> None:
        item = self.ring.nearest(q)
        stored = range(self.tail, self.head + 1)
        if not stored:
            assert item is None
            return
        best = min(abs(self.written[s][0] - q) for s in stored)
        assert item is not None and abs(item.t_ns - q) == best
        self._check(item, item.seq)
        assert self.tail <= item.seq <= self.head
        if any(self.written[s][0] == q - best for s in stored):
            assert item.t_ns == q - best  # a tie goes to the older timestamp

    @rule(t0=st.integers(-2, 120), span=st.integers(-1, 30))
    def window(self, t0: int, span: int) -> None:
        t1 = t0 + span
        items = self.ring.window(t0, t1)
        want = [s for s in range(self.tail, self.head + 1) if t0 <= self.written[s][0] <= t1]
        assert [it.seq for it in items] == want
        for it in items:
            self._check(it, it.seq)

    @rule(start=st.sampled_from(["oldest", "latest", "next"]))
    def add_reader(self, start: str) -> None:
        if len(self.readers) >= 3:
            return
        r = self.ring.reader(start)
        if start == "oldest":
            pos = self.tail
        elif start == "latest":
            pos = max(self.head, 0)
        else:
            pos = self.head + 1
        assert r.start_seq == pos
        self.readers.append((r, {"pos": pos, "received": 0, "dropped": 0}))

    @precondition(lambda self: bool(getattr(self, "readers", None)))
    @rule(i=st.integers(0, 2), jump=st.booleans())
    def read(self, i: int, jump: bool) -> None:
        r, m = self.readers[i % len(self.readers)]
        if jump:
            item, want = r.latest(), (self.head if self.head >= m["pos"] else None)
            if want is not None:
                m["dropped"] += want - m["pos"]
        else:
            if m["pos"] < self.tail and m["pos"] <= self.head:
                m["dropped"] += self.tail - m["pos"]
                m["pos"] = self.tail
            item, want = r.next(timeout=0), (m["pos"] if m["pos"] <= self.head else None)
        self._check(item, want)
        if want is not None:
            m["pos"] = want + 1
            m["received"] += 1
        assert (r.received, r.dropped) == (m["received"], m["dropped"])

    def teardown(self) -> None:
        # Drain every reader: the accounting identity must hold exactly.
        for r, _ in getattr(self, "readers", []):
            while r.next(timeout=0) is not None:
                pass
            assert r.received + r.dropped == len(self.written) - r.start_seq


TestRingModel = RingModel.TestCase
TestRingModel.settings = HYPO


# ---- CloudRing arena ------------------------------------------------------------------------


def test_cloud_arena_wraps_and_evicts_oldest_first():
    ring = CloudRing(capacity=8, max_points_total=10)
    assert ring.write(_cloud(0, 4), 0) == 0  # [0, 4)
    ring.write(_cloud(1, 4), 1)  # [4, 8)
    assert ring.tail_seq == 0
    ring.write(_cloud(2, 4), 2)  # does not fit before 10: wraps to [0, 4), evicts 0
    assert (ring.tail_seq, ring.head_seq) == (1, 2)
    ring.write(_cloud(3, 2), 3)  # [4, 6) overlaps cloud 1 -> evicts 1
    assert ring.tail_seq == 2
    ring.write(_cloud(4, 4), 4)  # [6, 10) fits exactly in the end
    assert ring.tail_seq == 2 and ring.points_stored == 10
    ring.write(_cloud(5, 1), 5)  # wraps: [0, 1) overlaps 2 -> evicts 2 only
    assert ring.tail_seq == 3
    for s in range(3, 6):
        item = ring.next(s - 1, timeout=0)
        assert item.seq == s and item.payload.shape == ([2, 4, 1][s - 3], 3)
        assert np.all(item.payload == s)
    ring.write(_cloud(6, 10), 6)  # the whole arena: everything else goes
    assert (ring.tail_seq, len(ring)) == (6, 1)
    assert np.all(ring.latest().payload == 6)


def test_cloud_ring_capacity_and_empty_clouds():
    ring = CloudRing(capacity=3, max_points_total=100)
    for s in range(5):
        ring.write(_cloud(s, s % 2), s)  # empty clouds are fine
    assert (ring.tail_seq, ring.head_seq) == (2, 4)
    assert ring.latest().payload.shape == (0, 3)
    assert [it.seq for it in ring.window(0, 10)] == [2, 3, 4]


def test_cloud_too_large_or_malformed_raises():
    ring = CloudRing(capacity=4, max_points_total=10)
    with pytest.raises(ValueError, match="exceeds the arena of 10 points"):
        ring.write(np.zeros((11, 3), np.float32), 0)
    with pytest.raises(ValueError, match=r"must be \(N, 3\)"):
        ring.write(np.zeros((4, 2), np.float32), 0)
    assert ring.head_seq == -1


def test_cloud_ring_random_sizes_stay_exact():
    rng = np.random.default_rng(7)
    ring = CloudRing(capacity=16, max_points_total=5000)
    reader = ring.reader("oldest")
    sizes = rng.integers(0, 1500, size=2000)
    got = 0
    for s, n in enumerate(sizes):
        ring.write(_cloud(s, int(n)), s)
        assert ring.points_stored <= 5000
        if s % 3 == 0:
            while (item := reader.next(timeout=0)) is not None:
                assert item.payload.shape == (sizes[item.seq], 3) and np.all(item.payload == item.seq)
                got += 1
    assert reader.received == got and reader.received + reader.dropped <= len(sizes)


# ---- API details ----------------------------------------------------------------------------


def test_ring_copies_and_validates():
    ring = Ring(4, (2, 3), np.float32)
    assert ring.last_t_ns is None and ring.latest() is None and ring.nearest(0) is None
    a = np.ones((2, 3))
    ring.write(a, 10)
    assert ring.last_t_ns == 10
    a[:] = 5  # the ring kept its own copy
    item = ring.latest()
    assert item.payload.dtype == np.float32 and np.all(item.payload == 1)
    item.payload[:] = 9  # and gives out copies
    assert np.all(ring.latest().payload == 1)
    with pytest.raises(ValueError, match="payload shape"):
        ring.write(np.ones(6), 11)
    with pytest.raises(ValueError, match="must not decrease"):
        ring.write(a, 9)
    with pytest.raises(ValueError):
        Ring(0, 3)
    with pytest.raises(ValueError):
        ring.reader("middle")


def test_object_ring_keeps_references():
    ring = ObjectRing(2)
    frames = [object() for _ in range(3)]
    for i, f in enumerate(frames):
        ring.write(f, i * 1000)
    assert ring.latest().payload is frames[2]
    assert ring.nearest(0).payload is frames[1]  # frame 0 was overwritten
    assert len(ring) == 2 and ring.capacity == 2


def test_reader_latest_counts_skipped_items_as_dropped():
    ring = Ring(8, 1, np.int64)
    r = ring.reader("oldest")
    for s in range(5):
        ring.write([s], s)
    assert r.latest().seq == 4 and (r.received, r.dropped) == (1, 4)
    assert r.latest() is None  # nothing newer
    ring.write([5], 5)
    assert r.next(timeout=0).seq == 5
    assert r.received + r.dropped == ring.head_seq + 1 - r.start_seq


def test_closed_ring_refuses_writes_and_drains():
    ring = ObjectRing(4)
    r = ring.reader("next")
    ring.write("a", 0)
    ring.close()
    with pytest.raises(RingClosedError):
        ring.write("b", 1)
    assert isinstance(RingClosedError(), LivecapError)
    assert [it.payload for it in r] == ["a"]
    assert ring.next(0, timeout=None) is None


# ---- seqlock --------------------------------------------------------------------------------


class _PreemptedRing(Ring):
    """Simulates the writer running in the middle of a reader's copy (a GIL switch there)."""

    lap = 0

    def _load(self, slot: int) -> np.ndarray:
        head = self.head_seq
        for _ in range(self.lap):
            head += 1
            self.write(np.full(self.shape, head), head)
        self.lap = 0
        return super()._load(slot)


def test_seqlock_discards_copy_overwritten_during_read():
    ring = _PreemptedRing(4, (3,), np.int64)
    r = ring.reader("oldest")
    for s in range(4):
        ring.write(np.full(3, s), s)
    ring.lap = 4  # the writer laps the whole ring while the reader copies item 0
    item = r.next(timeout=0)
    # Item 0's copy could hold item 4's bytes; it must be discarded, not returned as seq 0.
    assert item.seq == 4 and np.all(item.payload == 4)
    assert (r.dropped, r.retries, r.received) == (4, 1, 1)
    ring.lap = 4
    item = ring.latest()  # same for the ring-level queries
    assert item.seq == 11 and np.all(item.payload == 11)
    ring.lap = 1
    item = ring.nearest(9)
    assert item.seq == 9 and np.all(item.payload == 9)


# ---- threads --------------------------------------------------------------------------------


@pytest.fixture
def fast_switching():
    """Switch threads every 10 us so reads and writes interleave as much as possible."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    yield
    sys.setswitchinterval(old)


def _consume(reader: Reader, log: list, slow: bool) -> None:
    work = np.arange(64.0)
    for item in reader:
        log.append((item.seq, item.payload))
        if slow:
            for _ in range(20):
                work = np.sqrt(work + 1.0)


def test_threaded_stress_no_torn_reads_exact_drops(fast_switching):
    n = 100_000
    ring = Ring(4, (8,), np.int64)  # tiny, so the writer laps readers all the time
    readers = [ring.reader("next") for _ in range(3)]
    logs: list[list] = [[], [], []]
    threads = [
        threading.Thread(target=_consume, args=(r, log, i == 2))
        for i, (r, log) in enumerate(zip(readers, logs))
    ]
    for t in threads:
        t.start()
    payload = np.empty(8, np.int64)
    for s in range(n):
        payload[:] = s * 8 + np.arange(8)  # every element encodes the seq
        ring.write(payload, s)
    ring.close()
    for t in threads:
        t.join(timeout=60)
        assert not t.is_alive()
    for r, log in zip(readers, logs):
        seqs = np.array([s for s, _ in log])
        payloads = np.array([p for _, p in log])
        assert np.all(np.diff(seqs) > 0)
        assert np.array_equal(payloads, seqs[:, None] * 8 + np.arange(8))  # no torn payload
        assert r.received == len(log)
        assert r.received + r.dropped == n  # exact: every seq either received or dropped
    assert readers[2].received > 0


def test_threaded_cloud_stress(fast_switching):
    rng = np.random.default_rng(3)
    sizes = rng.integers(1, 3000, size=3000)
    ring = CloudRing(8, 10_000)
    readers = [ring.reader("next") for _ in range(2)]
    logs: list[list] = [[], []]
    threads = [
        threading.Thread(target=_consume, args=(r, log, i == 1))
        for i, (r, log) in enumerate(zip(readers, logs))
    ]
    for t in threads:
        t.start()
    for s, n in enumerate(sizes):
        ring.write(_cloud(s, int(n)), s)
    ring.close()
    for t in threads:
        t.join(timeout=60)
        assert not t.is_alive()
    for r, log in zip(readers, logs):
        assert all(a[0] < b[0] for a, b in zip(log, log[1:]))
        for seq, cloud in log:
            assert cloud.shape == (sizes[seq], 3) and np.all(cloud == seq)
        assert r.received + r.dropped == len(sizes)


def _wait_until(cond, what: str) -> None:
    """Poll a condition that another thread will make true (bounded, no fixed sleeps)."""
    deadline = time.monotonic() + 10
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0)  # yield the GIL


def test_close_wakes_blocked_reader():
    ring = Ring(4, 1)
    reader = ring.reader("next")
    result: list = []
    t = threading.Thread(target=lambda: result.append(reader.next(timeout=None)))
    t.start()
    _wait_until(lambda: ring._waiters == 1, "the reader to block")
    ring.close()
    t.join(timeout=10)
    assert not t.is_alive() and result == [None]


def test_blocked_reader_wakes_on_write():
    ring = ObjectRing(4)
    result: list = []
    t = threading.Thread(target=lambda: result.append(ring.next(-1, timeout=None)))
    t.start()
    _wait_until(lambda: ring._waiters == 1, "the reader to block")
    ring.write("x", 5)
    t.join(timeout=10)
    assert result[0].payload == "x" and result[0].t_ns == 5


def test_next_times_out():
    ring = Ring(2, 1)
    assert ring.next(-1, timeout=0.01) is None
    assert ring.reader().next(timeout=0.01) is None


# ---- backpressure ---------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["ring", "object", "cloud"])
def test_backpressure_loses_nothing(kind, fast_switching):
    n = 5000
    if kind == "ring":
        ring, make = Ring(4, (8,), np.int64, block_when_full=True), lambda s: np.full(8, s)
    elif kind == "object":
        ring, make = ObjectRing(4, block_when_full=True), lambda s: (s,)
    else:
        ring, make = CloudRing(16, 300, block_when_full=True), lambda s: _cloud(s, 1 + s % 100)
    readers = [ring.reader("next") for _ in range(2)]
    logs: list[list] = [[], []]
    threads = [
        threading.Thread(target=_consume, args=(r, log, i == 1))
        for i, (r, log) in enumerate(zip(readers, logs))
    ]
    for t in threads:
        t.start()
    for s in range(n):
        ring.write(make(s), s, timeout=30)
    ring.close()
    for t in threads:
        t.join(timeout=60)
        assert not t.is_alive()
    for r, log in zip(readers, logs):
        assert [s for s, _ in log] == list(range(n))
        assert (r.received, r.dropped) == (n, 0)


def test_backpressure_timeout_detach_and_close():
    ring = Ring(2, 1, block_when_full=True)
    r = ring.reader("next")
    ring.write([0], 0)
    ring.write([1], 1)
    with pytest.raises(RingFullError, match="did not make room"):
        ring.write([2], 2, timeout=0.01)
    assert r.next(timeout=0).seq == 0  # room for one more
    ring.write([2], 2, timeout=0)
    r.detach()  # nobody to wait for: overwrite as usual
    ring.write([3], 3, timeout=0)
    assert ring.tail_seq == 2

    ring2 = ObjectRing(1, block_when_full=True)
    with ring2.reader("next"):
        ring2.write("a", 0)
        errors: list = []

        def blocked_write() -> None:
            try:
                ring2.write("b", 1)
            except RingClosedError as e:
                errors.append(e)

        t = threading.Thread(target=blocked_write)
        t.start()
        _wait_until(lambda: ring2._writer_waiting, "the writer to block")
        ring2.close()
        t.join(timeout=10)
        assert not t.is_alive() and len(errors) == 1


def test_backpressure_waits_for_a_reader_registered_late():
    ring = ObjectRing(2, block_when_full=True)
    for s in range(3):
        ring.write(s, s)  # no reader yet: plain overwrite
    r = ring.reader("oldest")
    assert r.start_seq == 1
    with pytest.raises(RingFullError):
        ring.write(3, 3, timeout=0)
    assert [r.next(timeout=0).payload for _ in range(2)] == [1, 2]
    ring.write(3, 3, timeout=0)
    assert (r.next(timeout=0).payload, r.dropped) == (3, 0)
