"""Fixed-capacity ring buffers between one writer thread and any number of reader threads.

Three rings share one query API and one reader type:

- ``Ring(capacity, shape, dtype)``: fixed-shape numpy payloads in a preallocated (capacity, *shape)
  array; readers get copies.
- ``CloudRing(capacity, max_points_total)``: variable-size (N, 3) float32 clouds in one
  preallocated point arena (circular, each cloud contiguous); readers get copies.
- ``ObjectRing(capacity)``: any Python object, stored by reference (frames from live/core/frames.py).

Every item has an int sequence number (0, 1, 2, ... per ring) and an int64 host timestamp in ns
(nondecreasing). By default the writer never waits: it overwrites the oldest item, and each
``Reader`` counts exactly how many items it lost that way (``dropped``). With
``block_when_full=True`` (offline replay) the writer instead waits until every registered reader
has consumed the item it would overwrite, so nothing is ever dropped.

Torn reads are impossible by construction (seqlock): the writer marks a slot invalid (seq -1)
before touching its payload and publishes the slot's new seq after; a reader checks the slot's
seq before and after copying and discards the copy if it changed. Marks only ever move forward,
so "same seq before and after" proves the copy is whole. The writer takes no lock on the hot path;
the condition variable is only touched when a reader (or, in blocking mode, the writer) waits.
This relies on CPython's GIL for ordering between the plain attribute/list stores.
"""

from __future__ import annotations

import bisect
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from live.core.errors import LivecapError

_INVALID = -1  # slot seq while a slot is empty, evicted or being rewritten
_NO_READER = 2**62  # the blocking floor when no reader is registered


class RingClosedError(LivecapError):
    """A write to a ring that was closed (the pipeline is stopping)."""

    def __init__(self, name: str = "ring"):
        super().__init__(f"{name} is closed: no more writes")


class RingFullError(LivecapError, TimeoutError):
    """A blocking-mode write waited longer than its timeout for a reader to make room."""

    def __init__(self, name: str, timeout: float):
        super().__init__(f"{name} is full: a reader did not make room within {timeout:g} s")


@dataclass(frozen=True, slots=True)
class Item:
    """One ring item: its sequence number, host timestamp (ns) and payload (a copy for numpy rings)."""

    seq: int
    t_ns: int
    payload: Any


class _RingBase:
    """Slot bookkeeping, blocking, seqlock reads and the query API shared by the three rings.

    Subclasses implement ``_prepare(payload) -> (payload, first_kept_seq)`` (validate, and say
    which seqs the write must evict), ``_put(slot, payload)`` (store) and ``_load(slot)`` (copy out).
    """

    # An attribute, not a method, so that a subclass can store a bound C method in it (no Python
    # frame per write); CloudRing defines it as a method.
    _put: Callable[[int, Any], None]

    def __init__(self, capacity: int, *, block_when_full: bool = False, name: str = "ring"):
        if int(capacity) < 1:
            raise ValueError(f"ring capacity must be >= 1, got {capacity}")
        self._cap = int(capacity)
        self.name = name
        self._block = bool(block_when_full)
        self._seqs: list[int] = [_INVALID] * self._cap  # seq held by each slot (the seqlock word)
        self._ts: list[int] = [0] * self._cap
        self._head = -1  # last published seq
        self._tail = 0  # oldest seq still stored (== head + 1 when empty)
        self._last_t = -(2**63)
        self._closed = False
        self._cond = threading.Condition(threading.Lock())
        # Wake-up flags, so that the hot paths skip the condition variable: the writer notifies
        # only when a reader waits and was not notified since it began waiting; a reader
        # notifies only while the blocking writer waits, and then once.
        self._waiters = 0
        self._notified = False
        self._writer_waiting = False
        self._readers: weakref.WeakSet[Reader] = weakref.WeakSet()
        self._floor = 0  # cached min over registered readers' next seq (blocking mode)

    # ---- properties -------------------------------------------------------------------------
    @property
    def capacity(self) -> int:
        return self._cap

    @property
    def head_seq(self) -> int:
        """Last written seq, -1 before the first write."""
        return self._head

    @property
    def tail_seq(self) -> int:
        """Oldest seq still stored (head_seq + 1 when the ring is empty)."""
        return self._tail

    @property
    def last_t_ns(self) -> int | None:
        """Timestamp of the last write (the next one must not be older), None before any."""
        return None if self._head < 0 else self._last_t

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def block_when_full(self) -> bool:
        return self._block

    def __len__(self) -> int:
        return self._head - self._tail + 1

    # ---- writer -----------------------------------------------------------------------------
    def write(self, payload: Any, t_ns: int, timeout: float | None = None) -> int:
        """Store one item and return its seq. ``timeout`` only matters with block_when_full.

        Raises RingClosedError after close(), RingFullError when a blocking write times out,
        ValueError for a bad payload or a timestamp older than the previous one.
        """
        if self._closed:
            raise RingClosedError(self.name)
        t_ns = int(t_ns)
        if t_ns < self._last_t:
            raise ValueError(f"{self.name}: timestamps must not decrease ({t_ns} < {self._last_t})")
        payload, keep_from = self._prepare(payload)
        seq = self._head + 1
        if keep_from > self._tail:
            if self._block and keep_from > self._floor:
                self._wait_for_room(keep_from, timeout)
            # Publish the new tail before invalidating: a reader that sees an invalid slot
            # re-reads the tail and learns the item is gone, never waits on it.
            old_tail, self._tail = self._tail, keep_from
            seqs, cap = self._seqs, self._cap
            for s in range(old_tail, keep_from):
                seqs[s % cap] = _INVALID
        slot = seq % self._cap
        self._seqs[slot] = _INVALID
        self._put(slot, payload)
        self._ts[slot] = t_ns
        self._seqs[slot] = seq
        self._last_t = t_ns
        self._head = seq
        if self._waiters and not self._notified:
            with self._cond:
                self._notified = True
                self._cond.notify_all()
        return seq

    def _wait_for_room(self, keep_from: int, timeout: float | None) -> None:
        """Block until every registered reader has consumed the seqs below ``keep_from``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            try:
                while True:
                    # Flag first, then look: a reader that advances after this read sees the flag.
                    self._writer_waiting = True
                    # No reader: nothing to wait for until one registers (it lowers the floor).
                    self._floor = min((r._pos for r in list(self._readers)), default=_NO_READER)
                    if self._floor >= keep_from:
                        return
                    if self._closed:
                        raise RingClosedError(self.name)
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        raise RingFullError(self.name, float(timeout or 0.0))
                    self._cond.wait(remaining)
            finally:
                self._writer_waiting = False

    def _wake_writer(self) -> None:
        with self._cond:
            self._writer_waiting = False  # one wake-up is enough: the writer re-arms it to wait
            self._cond.notify_all()

    def close(self) -> None:
        """Stop the ring: wakes blocked readers (they drain what is left, then get None) and a
        blocked writer (RingClosedError); later writes raise RingClosedError."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    # ---- seqlock read -----------------------------------------------------------------------
    def _read(self, seq: int) -> Item | None:
        """A whole copy of item ``seq``, or None if it is not (or no longer) stored."""
        slot = seq % self._cap
        seqs = self._seqs
        if seqs[slot] != seq:
            return None
        payload = self._load(slot)
        t_ns = self._ts[slot]
        if seqs[slot] != seq:  # overwritten while we copied: the copy may be torn
            return None
        return Item(seq, t_ns, payload)

    # ---- queries ----------------------------------------------------------------------------
    def latest(self) -> Item | None:
        """The newest item, or None if nothing was written yet."""
        while True:
            head = self._head
            if head < 0:
                return None
            item = self._read(head)
            if item is not None:
                return item
            # Only possible when the writer lapped the slot during the copy: take the new head.

    def next(self, after_seq: int = -1, timeout: float | None = None) -> Item | None:
        """The oldest stored item with seq > after_seq, waiting up to ``timeout`` s (None: no
        limit) for one to be written. None on timeout, or when closed and nothing newer is left."""
        deadline = None
        while True:
            seq = max(after_seq + 1, self._tail)
            if self._head >= seq:
                item = self._read(seq)
                if item is not None:
                    return item
                continue  # evicted under us: the tail moved, try again from it
            if deadline is None and timeout is not None:
                deadline = time.monotonic() + timeout
            if not self._wait_past(seq - 1, deadline):
                return None

    def _wait_past(self, seq: int, deadline: float | None) -> bool:
        """Wait until head > seq; False on timeout or when closed with nothing newer."""
        with self._cond:
            self._waiters += 1
            try:
                while True:
                    # Clear first, then look: a write after this look sees the flag cleared.
                    self._notified = False
                    if self._head > seq:
                        return True
                    if self._closed:
                        return False
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        return False
                    self._cond.wait(remaining)
            finally:
                self._waiters -= 1

    def _search(self, t_ns: int, right: bool) -> tuple[int, int, int]:
        """(tail, head, i): the seq range snapshot and the bisect position of t_ns in it."""
        while True:
            tail, head = self._tail, self._head
            ts, cap = self._ts, self._cap
            find = bisect.bisect_right if right else bisect.bisect_left
            i = find(range(tail, head + 1), t_ns, key=lambda s: ts[s % cap])
            # The writer moves the tail before it touches any slot, so an unchanged tail means
            # every timestamp we compared was intact.
            if self._tail == tail:
                return tail, head, tail + i

    def nearest(self, t_ns: int) -> Item | None:
        """The stored item whose timestamp is closest to ``t_ns`` (the older one on a tie)."""
        t_ns = int(t_ns)
        while True:
            tail, head, s = self._search(t_ns, right=False)
            if head < tail:
                return None
            reads = [self._read(c) for c in (s - 1, s) if tail <= c <= head]
            cands = [it for it in reads if it is not None]
            if len(cands) < len(reads):
                continue  # overwritten while reading: search again
            return min(cands, key=lambda it: abs(it.t_ns - t_ns))

    def window(self, t0_ns: int, t1_ns: int) -> list[Item]:
        """Stored items with t0_ns <= t_ns <= t1_ns, oldest first (items overwritten during the
        copy are left out; they are always the oldest ones)."""
        t0_ns, t1_ns = int(t0_ns), int(t1_ns)
        if t1_ns < t0_ns:
            return []
        _, _, lo = self._search(t0_ns, right=False)
        _, head, hi = self._search(t1_ns, right=True)
        items = [self._read(s) for s in range(lo, min(hi, head + 1))]
        return [it for it in items if it is not None]

    def reader(self, start: Literal["oldest", "latest", "next"] = "next") -> Reader:
        """A registered cursor. start: "oldest" stored item, "latest" item, or "next" (only
        items written from now on)."""
        return Reader(self, start)

    # ---- subclass hooks ---------------------------------------------------------------------
    def _prepare(self, payload: Any) -> tuple[Any, int]:
        """Validate ``payload``; return it and the first seq to keep after this write."""
        seq = self._head + 1
        return payload, seq - self._cap + 1

    def _load(self, slot: int) -> Any:
        raise NotImplementedError


class Reader:
    """A cursor over one ring with exact loss accounting.

    ``received`` counts items returned; ``dropped`` counts items overwritten before this reader
    got them plus items it skipped with ``latest()``. Once the reader has caught up with the
    writer: ``received + dropped == ring.head_seq + 1 - start_seq``.
    """

    def __init__(self, ring: _RingBase, start: str = "next"):
        if start == "oldest":
            pos = ring._tail
        elif start == "latest":
            pos = max(ring._head, 0)
        elif start == "next":
            pos = ring._head + 1
        else:
            raise ValueError(f"reader start must be 'oldest', 'latest' or 'next', got {start!r}")
        self._ring = ring
        self._pos = pos  # next seq this reader wants
        self.start_seq = pos
        self.received = 0
        self.dropped = 0
        self.retries = 0  # copies discarded because the writer overwrote the slot meanwhile
        self._attached = True
        with ring._cond:
            ring._readers.add(self)
            ring._floor = min(ring._floor, pos)  # a blocking writer must now wait for us too

    @property
    def position(self) -> int:
        """The next seq this reader will try to return."""
        return self._pos

    def _advance(self, pos: int) -> None:
        self._pos = pos
        if self._ring._writer_waiting:  # set before the writer reads our position
            self._ring._wake_writer()

    def next(self, timeout: float | None = None) -> Item | None:
        """The next item in seq order (skipping, and counting as dropped, what was overwritten).
        Waits up to ``timeout`` s (None: no limit); None on timeout or when closed and drained."""
        ring = self._ring
        seqs, cap = ring._seqs, ring._cap
        deadline = None
        while True:
            pos = self._pos
            if ring._head >= pos:
                tail = ring._tail
                if tail > pos:
                    self.dropped += tail - pos
                    pos = self._pos = tail
                # ring._read inlined: this is the hot path of every consumer.
                slot = pos % cap
                if seqs[slot] == pos:
                    payload = ring._load(slot)
                    t_ns = ring._ts[slot]
                    if seqs[slot] == pos:
                        self.received += 1
                        self._pos = pos + 1
                        if ring._writer_waiting:  # set before the writer reads our position
                            ring._wake_writer()
                        return Item(pos, t_ns, payload)
                self.retries += 1  # the tail passed pos meanwhile; the next loop counts the drop
                continue
            if deadline is None and timeout is not None:
                deadline = time.monotonic() + timeout
            if not ring._wait_past(pos - 1, deadline):
                return None

    def latest(self) -> Item | None:
        """Jump to the newest item (counting everything skipped as dropped); None if nothing
        newer than the last item read exists. Never waits."""
        ring = self._ring
        while True:
            head = ring._head
            if head < self._pos:
                return None
            item = ring._read(head)
            if item is None:
                self.retries += 1
                continue
            self.dropped += head - self._pos
            self.received += 1
            self._advance(head + 1)
            return item

    def detach(self) -> None:
        """Stop counting this reader (a blocking-mode writer no longer waits for it)."""
        if self._attached:
            self._attached = False
            ring = self._ring
            with ring._cond:
                ring._readers.discard(self)
                ring._floor = 0  # recompute on the next write that needs room
                ring._cond.notify_all()

    def __iter__(self) -> Iterator[Item]:
        """Items until the ring is closed and drained."""
        while (item := self.next()) is not None:
            yield item

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.detach()


class Ring(_RingBase):
    """Fixed-shape numpy payloads in one preallocated (capacity, *shape) array."""

    def __init__(
        self,
        capacity: int,
        shape: tuple[int, ...] | int,
        dtype: Any = np.float64,
        *,
        block_when_full: bool = False,
        name: str = "ring",
    ):
        super().__init__(capacity, block_when_full=block_when_full, name=name)
        self.shape = (int(shape),) if isinstance(shape, int | np.integer) else tuple(int(s) for s in shape)
        self.dtype = np.dtype(dtype)
        self._data = np.zeros((self._cap, *self.shape), dtype=self.dtype)
        self._put = self._data.__setitem__  # bound C method: no Python frame per write

    def _prepare(self, payload: Any) -> tuple[Any, int]:
        if type(payload) is not np.ndarray:
            payload = np.asarray(payload)
        if payload.shape != self.shape:
            raise ValueError(f"{self.name}: payload shape {payload.shape} != ring shape {self.shape}")
        return payload, self._head + 2 - self._cap

    def _load(self, slot: int) -> np.ndarray:
        return self._data[slot].copy()


class ObjectRing(_RingBase):
    """Any Python objects, stored by reference in a preallocated list (never copied)."""

    def __init__(self, capacity: int, *, block_when_full: bool = False, name: str = "ring"):
        super().__init__(capacity, block_when_full=block_when_full, name=name)
        self._objs: list[Any] = [None] * self._cap
        self._put = self._objs.__setitem__

    def _prepare(self, payload: Any) -> tuple[Any, int]:
        return payload, self._head + 2 - self._cap

    def _load(self, slot: int) -> Any:
        return self._objs[slot]


class CloudRing(_RingBase):
    """Variable-size (N, 3) float32 clouds in one preallocated circular point arena.

    Each cloud is stored contiguously at ``_off[slot]``; when it does not fit before the end of
    the arena it goes to offset 0 (the points left at the end stay unused until the next wrap).
    A write evicts the oldest clouds until its span is free (they count as overwritten).
    """

    def __init__(
        self,
        capacity: int,
        max_points_total: int,
        *,
        block_when_full: bool = False,
        name: str = "cloud ring",
    ):
        super().__init__(capacity, block_when_full=block_when_full, name=name)
        if int(max_points_total) < 1:
            raise ValueError(f"max_points_total must be >= 1, got {max_points_total}")
        self.max_points_total = int(max_points_total)
        self._arena = np.zeros((self.max_points_total, 3), dtype=np.float32)
        self._off = [0] * self._cap
        self._len = [0] * self._cap
        self._wpos = 0  # arena index where the next cloud starts (unless it must wrap)
        self._start = 0  # arena span chosen by _prepare for the pending write

    def _prepare(self, payload: Any) -> tuple[Any, int]:
        cloud = np.asarray(payload)
        if cloud.ndim != 2 or cloud.shape[1] != 3:
            raise ValueError(f"{self.name}: a cloud must be (N, 3), got shape {cloud.shape}")
        n = cloud.shape[0]
        if n > self.max_points_total:
            raise ValueError(
                f"{self.name}: cloud of {n} points exceeds the arena of {self.max_points_total} points"
            )
        start = self._wpos if self._wpos + n <= self.max_points_total else 0
        end = start + n
        seq = self._head + 1
        keep_from = max(self._tail, seq - self._cap + 1)
        # Stored clouds lie in seq order around the arena, so evicting in seq order until the
        # last overlapping cloud is gone frees [start, end) without tearing out newer ones.
        cap, off, ln = self._cap, self._off, self._len
        for s in range(keep_from, seq):
            o = off[s % cap]
            if n and ln[s % cap] and o < end and start < o + ln[s % cap]:
                keep_from = s + 1
        self._start = start
        return cloud, keep_from

    def _put(self, slot: int, cloud: np.ndarray) -> None:
        n = cloud.shape[0]
        start = self._start
        self._arena[start : start + n] = cloud
        self._off[slot] = start
        self._len[slot] = n
        self._wpos = start + n

    def _load(self, slot: int) -> np.ndarray:
        o = self._off[slot]
        return self._arena[o : o + self._len[slot]].copy()

    @property
    def points_stored(self) -> int:
        """Points held by the stored clouds (for stats)."""
        return sum(self._len[s % self._cap] for s in range(self._tail, self._head + 1))
