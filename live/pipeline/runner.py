"""The pipeline runner: sources in threads -> rings -> stages -> sinks.

Two ways to consume frames:
- ``every`` (replay, offline): every frame is processed in timestamp order; rings apply
  backpressure instead of overwriting, so nothing is dropped and two runs give identical
  results.
- ``latest`` (live): each source writes into an overwrite-oldest ring; the runner reads every
  item but runs the stages only on the newest depth frame, so latency stays bounded; frames
  skipped or overwritten are counted as drops.

Stages get a FrameResult for each trigger frame (a depth frame, or a decoded mocap packet when
no camera runs), fill their part, and report whether they produced output. Side frames (mocap
packets, ground truth) go to every stage's ``observe``. Sinks receive every processed result.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from live.core.frames import DepthFrame, FrameResult, GroundTruth, MocapPacket
from live.core.protocols import Sink, Source, Stage
from live.core.ring import ObjectRing, RingClosedError, RingFullError
from live.io.session import SessionWriter
from live.pipeline.stats import LatencyRecorder, StageStats

log = logging.getLogger("livecap.pipeline")

MODES = ("every", "latest")
#: A sensor timestamp older than this is not on the host clock (a replayed or simulated source).
_HOST_CLOCK_MAX_AGE_NS = 10_000_000_000
_POLL_S = 0.05


@dataclass
class _Arrival:
    """A frame with the host time it entered the ring (end-to-end latency of replays)."""

    frame: object
    arrived_ns: int


@dataclass
class _SourceRun:
    source: Source
    ring: ObjectRing
    reader: object
    thread: threading.Thread | None = None
    done: threading.Event = field(default_factory=threading.Event)
    frames: int = 0
    error: str | None = None
    ended_on_its_own: bool = False  # its run returned before the pipeline was stopped


class Pipeline:
    """Runs sources, stages and sinks until the sources end or ``stop`` is set."""

    def __init__(
        self,
        sources: Sequence[Source],
        stages: Sequence[Stage] = (),
        sinks: Sequence[Sink] = (),
        *,
        mode: str = "every",
        recorder: SessionWriter | None = None,
        ring_capacity: int = 64,
        on_result: Callable[[FrameResult], None] | None = None,
        inline: bool = True,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}")
        self.mode = mode
        self.stages = list(stages)
        self.sinks = list(sinks)
        self.recorder = recorder
        self.on_result = on_result
        # Every mode with one source runs it in the caller's thread (``_run_inline``); False keeps
        # a source thread (what benchmarks/bench_replay.py compares it with).
        self.inline = inline
        self._record_lock = threading.Lock()
        self._runs = []
        for src in sources:
            ring = ObjectRing(ring_capacity, block_when_full=(mode == "every"))
            self._runs.append(_SourceRun(src, ring, ring.reader(start="oldest")))
        kinds = {s.kind for run in self._runs for s in run.source.streams()}
        self.trigger = DepthFrame if "depth" in kinds or not kinds else MocapPacket
        self.stage_stats = {s.name: StageStats(s.name) for s in self.stages}
        self.end_to_end = LatencyRecorder()
        self._not_host_clock = 0  # latest mode: frames timed from arrival, their stamps not on this host's clock
        self.queue_wait = LatencyRecorder()
        self.sink_errors = 0
        self.processed = 0
        self.drained = 0  # results stages gave at the end of the stream (``_drain``)
        self.skipped_latest = 0
        self.recorded = 0
        self._latest_truth: GroundTruth | None = None
        self._wall_s = 0.0

    # -- source side ---------------------------------------------------------------------
    def _emit_for(self, run: _SourceRun, stop: threading.Event) -> Callable[[object], None]:
        def emit(frame: object) -> None:
            if self.recorder is not None:
                with self._record_lock:
                    self.recorder.write(frame)
                    self.recorded += 1
            run.frames += 1
            arrived = time.monotonic_ns()
            while not stop.is_set():
                # In "every" mode a full ring blocks; wake regularly to honour stop. The ring is
                # keyed by arrival time (always nondecreasing); frames keep their sensor time.
                try:
                    run.ring.write(_Arrival(frame, arrived), arrived, timeout=_POLL_S)
                    return
                except RingFullError:
                    continue
                except RingClosedError:
                    return

        return emit

    def _source_main(self, run: _SourceRun, stop: threading.Event, emit: Callable[[object], None] | None = None,
                     own_failures: Sequence[BaseException] = ()) -> None:
        """Run a source to its end (in its thread, or inline with ``emit`` handling each frame);
        its failure is recorded, not raised, but for ``own_failures`` (the consumer's, raised on)."""
        try:
            run.source.run(emit or self._emit_for(run, stop), stop)
        except Exception as exc:  # noqa: BLE001 - a dead source must not take the pipeline down
            if own_failures and exc is own_failures[0]:
                raise
            run.error = f"{type(exc).__name__}: {exc}"
            log.error("source %s stopped: %s", run.source.name, run.error)
        finally:
            run.ended_on_its_own = not stop.is_set()
            run.done.set()
            run.ring.close()

    def source_status(self) -> dict[str, dict]:
        """Each source's state for the session recorder (live.io.recording.summarise): its
        streams, the error that stopped it, whether its run returned, whether its device is
        connected (None: it does not say) and how many times it was disconnected. ``ended``: its
        run returned before the pipeline was stopped (a replay that reached its end, a device
        that failed)."""
        out = {}
        for run in self._runs:
            src = run.source
            # A device source keeps its disconnections as [start_ns, end_ns or None] (the serial
            # transport): the last one still open means disconnected, even once it is stopped.
            gaps = getattr(src, "gaps", None)
            connected = None if not isinstance(gaps, list) else not (gaps and gaps[-1][1] is None)
            out[src.name] = {"streams": [s.name for s in src.streams()], "error": run.error,
                             "ended": run.ended_on_its_own, "connected": connected,
                             "disconnects": len(gaps) if isinstance(gaps, list) else 0}
        return out

    # -- consumer side -------------------------------------------------------------------
    def _handle(self, arrival: _Arrival) -> None:
        frame = arrival.frame
        if isinstance(frame, GroundTruth):
            self._latest_truth = frame
        is_trigger = isinstance(frame, self.trigger) and (
            not isinstance(frame, MocapPacket) or frame.decoded
        )
        if not is_trigger:
            for stage in self.stages:
                observe = getattr(stage, "observe", None)
                if observe is not None:
                    observe(frame)
            return
        started_ns = time.monotonic_ns()
        result = FrameResult(t_ns=frame.t_ns)
        if isinstance(frame, DepthFrame):
            result.depth = frame
        else:
            result.mocap = frame
            for stage in self.stages:
                observe = getattr(stage, "observe", None)
                if observe is not None:
                    observe(frame)
        truth = self._latest_truth
        if truth is not None and truth.t_ns <= frame.t_ns:
            result.truth = truth
        self._run_stages(result, self.stages)
        self._send(result)
        now = time.monotonic_ns()
        # Live: from the sensor timestamp (what a performer feels), when it is on this host's
        # monotonic clock (drivers stamp frames so); a replayed or simulated source in `run`
        # carries timestamps from another clock, so from the frame's arrival. Replay: recorded
        # timestamps are from another day and frames queue on purpose, so from the start of processing.
        if self.mode == "every":
            origin = started_ns
        elif 0 <= now - frame.t_ns <= _HOST_CLOCK_MAX_AGE_NS:
            origin = frame.t_ns
        else:
            origin = arrival.arrived_ns
            self._not_host_clock += 1
        self.end_to_end.add((now - origin) / 1e6)
        if self.mode == "every":
            self.queue_wait.add((started_ns - arrival.arrived_ns) / 1e6)
        self.processed += 1

    def _run_stages(self, result: FrameResult, stages: Sequence[Stage]) -> None:
        for stage in stages:
            st = self.stage_stats[stage.name]
            st.frames_in += 1
            t0 = time.perf_counter()
            try:
                produced = stage.process(result)
            except Exception as exc:  # noqa: BLE001 - counted; the stream goes on
                st.errors += 1
                produced = False
                log.warning("stage %s failed on frame %d: %s", stage.name, result.t_ns, exc)
            ms = (time.perf_counter() - t0) * 1e3
            result.latency_ms[stage.name] = ms
            st.latency.add(ms)
            st.frames_out += bool(produced)

    def _send(self, result: FrameResult) -> None:
        for sink in self.sinks:
            try:
                sink.send(result)
            except Exception as exc:  # noqa: BLE001 - a broken sink never stops capture
                self.sink_errors += 1
                log.warning("sink %s failed: %s", type(sink).__name__, exc)
        if self.on_result is not None:
            self.on_result(result)

    def _drain(self) -> None:
        """The sources have ended: what a stage still holds goes through the stages after it and
        the sinks (not timed: these are no new frames)."""
        for i, stage in enumerate(self.stages):
            drain = getattr(stage, "drain", None)
            if drain is None:
                continue
            try:
                results = drain()
            except Exception as exc:  # noqa: BLE001 - counted, as a failed frame would be
                self.stage_stats[stage.name].errors += 1
                log.warning("stage %s failed to drain: %s", stage.name, exc)
                continue
            for result in results:
                self._run_stages(result, self.stages[i + 1:])
                self._send(result)
                self.drained += 1

    def _next_of(self, run: _SourceRun, timeout: float):
        item = run.reader.next(timeout=timeout)
        return None if item is None else item.payload

    def _run_every(self, stop: threading.Event) -> None:
        heads: list[_Arrival | None] = [None] * len(self._runs)
        finished = [False] * len(self._runs)
        while not stop.is_set():
            for i, run in enumerate(self._runs):
                while heads[i] is None and not finished[i] and not stop.is_set():
                    was_done = run.done.is_set()
                    heads[i] = self._next_of(run, 0.0 if was_done else _POLL_S)
                    if heads[i] is None and was_done:
                        finished[i] = True
            live = [i for i, h in enumerate(heads) if h is not None]
            if not live:
                return
            # Merge sources by timestamp; ties go to the source listed first (deterministic).
            i = min(live, key=lambda k: (heads[k].frame.t_ns, k))
            arrival, heads[i] = heads[i], None
            self._handle(arrival)

    def _run_inline(self, stop: threading.Event) -> None:
        """Every mode with one source: the source runs in this thread, and each frame it emits
        goes through its ring and is handled before the source reads the next one. A source
        thread would only read ahead, and its decoding then takes the GIL from the stages each
        time they release it (on the bundled demo the person finder waited 3.7 ms a frame for it:
        6.2 ms of wall time for 2.5 of its own)."""
        run = self._runs[0]
        emit = self._emit_for(run, stop)
        handling: list[BaseException] = []

        def emit_and_handle(frame: object) -> None:
            emit(frame)
            try:
                while (arrival := self._next_of(run, 0.0)) is not None:
                    self._handle(arrival)
            except BaseException as exc:  # the consumer's own failure, not the source's
                handling.append(exc)
                raise

        self._source_main(run, stop, emit_and_handle, handling)

    def _run_latest(self, stop: threading.Event) -> None:
        pending: list[_Arrival] = []
        while not stop.is_set():
            for run in self._runs:
                while (arrival := self._next_of(run, 0.0)) is not None:
                    pending.append(arrival)
            if not pending:
                if all(run.done.is_set() for run in self._runs):
                    return
                # Block briefly on the first unfinished source rather than spin.
                run = next(r for r in self._runs if not r.done.is_set())
                arrival = self._next_of(run, _POLL_S)
                if arrival is not None:
                    pending.append(arrival)
                continue
            triggers = [a for a in pending if isinstance(a.frame, self.trigger)]
            self.skipped_latest += max(0, len(triggers) - 1)
            newest = triggers[-1] if triggers else None
            # Side frames are cheap and all of them matter (IMU state, truth): handle each.
            for arrival in pending:
                if not isinstance(arrival.frame, self.trigger):
                    self._handle(arrival)
            pending.clear()
            if newest is not None:
                self._handle(newest)

    def run(self, stop: threading.Event | None = None) -> dict:
        stop = stop or threading.Event()
        t0 = time.perf_counter()
        inline = self.inline and self.mode == "every" and len(self._runs) == 1
        for run in [] if inline else self._runs:
            run.thread = threading.Thread(target=self._source_main, args=(run, stop),
                                          name=f"source-{run.source.name}", daemon=True)
            run.thread.start()
        try:
            if inline:
                self._run_inline(stop)
            elif self.mode == "every":
                self._run_every(stop)
            else:
                self._run_latest(stop)
            self._drain()
        finally:
            stop.set()
            for run in self._runs:
                run.ring.close()
                if run.thread is not None:
                    run.thread.join(timeout=1.0)
            for sink in self.sinks:
                try:
                    sink.close()
                except Exception as exc:  # noqa: BLE001
                    self.sink_errors += 1
                    log.warning("sink %s failed to close: %s", type(sink).__name__, exc)
            self._wall_s = time.perf_counter() - t0
        return self.stats()

    def _stage_dict(self, stage: Stage) -> dict:
        """A stage's timing and frame counts, with its own event counters when it keeps some
        (the skeleton stage: nobody in view, flips, resets, frames flushed at the end...)."""
        out = self.stage_stats[stage.name].as_dict()
        counters = getattr(stage, "counters", None)
        if isinstance(counters, dict) and counters:
            out["counters"] = {k: int(v) for k, v in counters.items()}
        details = getattr(stage, "details", None)  # JSON-ready facts a stage reports (not counts)
        if isinstance(details, dict) and details:
            out["details"] = details
        return out

    def _sink_dicts(self) -> dict:
        """Each sink's own event counters and facts (``counters`` / ``details`` attributes, as
        for stages), under its ``name`` (else its class name); sinks that keep none are left out."""
        out: dict = {}
        for sink in self.sinks:
            entry: dict = {}
            counters = getattr(sink, "counters", None)
            if isinstance(counters, dict) and counters:
                entry["counters"] = {k: int(v) for k, v in counters.items()}
            details = getattr(sink, "details", None)
            if isinstance(details, dict) and details:
                entry["details"] = details
            if entry:
                name = str(getattr(sink, "name", "") or type(sink).__name__)
                out[name if name not in out else f"{name}_{len(out)}"] = entry
        return out

    def _latency_origin(self) -> str:
        if self.mode == "every":
            return "processing start"
        if self._not_host_clock == 0:
            return "sensor timestamp"
        if self._not_host_clock >= self.end_to_end.count:
            return "arrival (timestamps not on this host's clock)"
        return f"sensor timestamp, arrival for {self._not_host_clock} frames not on this host's clock"

    def stats(self) -> dict:
        sources = {}
        overwritten = 0
        for run in self._runs:
            dropped = int(getattr(run.reader, "dropped", 0))
            overwritten += dropped
            counters = dict(getattr(run.source, "counters", {}) or {})
            sources[run.source.name] = {"frames": run.frames, "ring_drops": dropped,
                                        "counters": counters, "error": run.error}
        return {
            "mode": self.mode,
            "frames": self.processed,
            "drained": self.drained,
            "wall_s": round(self._wall_s, 4),
            "fps": round(self.processed / self._wall_s, 3) if self._wall_s > 0 else 0.0,
            "sources": sources,
            "stages": {stage.name: self._stage_dict(stage) for stage in self.stages},
            "end_to_end": {"frames": self.end_to_end.count, "latency_ms": self.end_to_end.summary(),
                           "origin": self._latency_origin()},
            "ring_wait_ms": self.queue_wait.summary(),
            "drops": {"ring_overwrites": overwritten, "skipped_for_latest": self.skipped_latest},
            "sink_errors": self.sink_errors,
            "sinks": self._sink_dicts(),
            "recorded_messages": self.recorded,
        }
