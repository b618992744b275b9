"""The pipeline runner: every-frame determinism, latest-frame drops, stop, broken sources."""

import threading
import time

import numpy as np
import pytest

from live.core.errors import DeviceError
from live.core.frames import DepthFrame, GroundTruth, MocapPacket
from live.core.protocols import StreamInfo
from live.pipeline.runner import Pipeline


class ListSource:
    """A source that emits a fixed list of frames (optionally forever, until stopped)."""

    def __init__(self, frames, name="src", forever=False, fail_after=None):
        self.frames = frames
        self.name = name
        self.forever = forever
        self.fail_after = fail_after
        self.counters = {}

    def streams(self):
        return [StreamInfo(self.name, "depth")]

    def run(self, emit, stop):
        i = 0
        while not stop.is_set():
            if i >= len(self.frames):
                if not self.forever:
                    return
                f = self.frames[-1]
                f = DepthFrame(t_ns=f.t_ns + (i - len(self.frames) + 1) * 1000, sensor=f.sensor, points=f.points)
            else:
                f = self.frames[i]
            if self.fail_after is not None and i == self.fail_after:
                raise DeviceError("camera unplugged")
            emit(f)
            i += 1


class CentroidStage:
    """Computes each cloud's centroid (a real, checkable computation) and can be slow."""

    name = "centroid"

    def __init__(self, delay=0.0):
        self.delay = delay
        self.out = []
        self.observed = []

    def process(self, result):
        if self.delay:
            time.sleep(self.delay)
        self.out.append((result.t_ns, result.depth.points.mean(axis=0),
                         None if result.truth is None else result.truth.t_ns))
        return True

    def observe(self, frame):
        self.observed.append(type(frame).__name__)


def _clouds(n, seed=0, sensor="cam", t0=0):
    rng = np.random.default_rng(seed)
    return [DepthFrame(t_ns=t0 + i * 1000, sensor=sensor, points=rng.normal(size=(50, 3)).astype(np.float32))
            for i in range(n)]


def test_every_mode_processes_everything_in_order_with_backpressure():
    frames = _clouds(200)
    stage = CentroidStage()
    stats = Pipeline([ListSource(frames)], [stage], mode="every", ring_capacity=4).run()
    assert stats["frames"] == 200
    assert [t for t, _, _ in stage.out] == [f.t_ns for f in frames]
    np.testing.assert_allclose(stage.out[7][1], frames[7].points.mean(axis=0))
    assert stats["drops"] == {"ring_overwrites": 0, "skipped_for_latest": 0}
    assert stats["stages"]["centroid"]["frames_in"] == 200
    assert stats["stages"]["centroid"]["latency_ms"]["count"] == 200


def test_every_mode_is_deterministic():
    frames = _clouds(100)
    runs = []
    for _ in range(2):
        stage = CentroidStage()
        Pipeline([ListSource(frames)], [stage], mode="every", ring_capacity=3).run()
        runs.append(np.array([c for _, c, _ in stage.out]))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_every_mode_merges_sources_by_time_and_attaches_truth():
    a = _clouds(20, seed=1, sensor="a", t0=0)
    b = _clouds(20, seed=2, sensor="b", t0=500)

    class WithTruth(ListSource):
        def run(self, emit, stop):
            for f in self.frames:
                emit(GroundTruth(f.t_ns, np.zeros((22, 3)), np.zeros((22, 4)), np.zeros(3)))
                emit(f)

    stage = CentroidStage()
    Pipeline([WithTruth(a, "a"), ListSource(b, "b")], [stage], mode="every", ring_capacity=2).run()
    times = [t for t, _, _ in stage.out]
    assert times == sorted(times) and len(times) == 40
    truth = {t: gt for t, _, gt in stage.out}
    assert truth[0] == 0 and truth[500] == 0 and truth[1000] == 1000
    assert stage.observed.count("GroundTruth") == 20


def test_latest_mode_drops_and_counts():
    frames = _clouds(300)
    stage = CentroidStage(delay=0.002)
    stats = Pipeline([ListSource(frames)], [stage], mode="latest", ring_capacity=8).run()
    processed = stats["frames"]
    lost = stats["drops"]["ring_overwrites"] + stats["drops"]["skipped_for_latest"]
    assert processed + lost == 300
    assert processed < 300  # a slow stage cannot keep up with a source that never waits
    times = [t for t, _, _ in stage.out]
    assert times == sorted(times)


def test_stop_ends_an_endless_source_quickly():
    stop = threading.Event()
    pipe = Pipeline([ListSource(_clouds(5), forever=True)], [CentroidStage()], mode="latest")
    timer = threading.Timer(0.3, stop.set)
    timer.start()
    t0 = time.monotonic()
    pipe.run(stop)
    assert time.monotonic() - t0 < 0.3 + 1.0
    assert all(not t.name.startswith("source-") for t in threading.enumerate())


def test_a_failing_source_does_not_crash_the_pipeline():
    stats = Pipeline([ListSource(_clouds(50), fail_after=10)], [CentroidStage()], mode="every").run()
    assert stats["frames"] == 10
    assert "camera unplugged" in stats["sources"]["src"]["error"]


def test_every_mode_with_one_source_runs_it_in_the_callers_thread():
    """No read-ahead thread competes with the stages for the GIL; each frame is handled before
    the source reads the next one, and a stop from a stage's thread still ends it."""
    seen = []

    class Recording(ListSource):
        def run(self, emit, stop):
            seen.append(threading.current_thread())
            super().run(emit, stop)

    stop = threading.Event()
    stage = CentroidStage()
    stage_calls = []
    process = stage.process

    def process_and_stop(result):
        stage_calls.append(len(stage.out))
        if len(stage.out) == 29:
            stop.set()
        return process(result)

    stage.process = process_and_stop
    stats = Pipeline([Recording(_clouds(100))], [stage], mode="every", ring_capacity=2).run(stop)
    assert seen == [threading.current_thread()]
    assert stats["frames"] == 30 and stage_calls == list(range(30))
    assert stats["ring_wait_ms"]["count"] == 30


def test_inline_false_keeps_a_source_thread_with_the_same_results():
    seen = []

    class Recording(ListSource):
        def run(self, emit, stop):
            seen.append(threading.current_thread())
            super().run(emit, stop)

    frames = _clouds(40)
    outs = []
    for inline in (True, False):
        stage = CentroidStage()
        Pipeline([Recording(frames)], [stage], mode="every", ring_capacity=3, inline=inline).run()
        outs.append(np.array([c for _, c, _ in stage.out]))
    assert seen[0] is threading.current_thread() and seen[1] is not threading.current_thread()
    np.testing.assert_array_equal(outs[0], outs[1])


def test_a_failing_consumer_is_not_taken_for_a_failing_source():
    def broken(result):
        raise ValueError("bug in on_result")

    with pytest.raises(ValueError, match="bug in on_result"):
        Pipeline([ListSource(_clouds(5))], [CentroidStage()], mode="every", on_result=broken).run()


def test_a_failing_sink_is_counted():
    class Broken:
        def send(self, result):
            raise RuntimeError("disk full")

        def close(self):
            pass

    stats = Pipeline([ListSource(_clouds(5))], [CentroidStage()], [Broken()], mode="every").run()
    assert stats["frames"] == 5 and stats["sink_errors"] == 5


def test_mocap_only_pipeline_triggers_on_decoded_packets():
    class Suit:
        name = "suit"
        counters = {}

        def streams(self):
            return [StreamInfo("suit", "serial")]

        def run(self, emit, stop):
            for i in range(10):
                emit(MocapPacket(i, "suit", raw=b"x", sensors=np.array([1]), quats=np.array([[1.0, 0, 0, 0]])))

    class Count:
        name = "count"
        n = 0

        def process(self, result):
            self.n += result.mocap is not None
            return True

    c = Count()
    Pipeline([Suit()], [c], mode="every").run()
    assert c.n == 10


def test_the_cloud_stage_counts_points_apart_from_the_stage_timings():
    from live.pipeline.stages import CloudStage

    results = []
    Pipeline([ListSource(_clouds(3))], [CloudStage()], on_result=results.append).run()
    assert [r.points for r in results] == [50, 50, 50]
    assert all(list(r.latency_ms) == ["cloud"] for r in results)  # timings only: no point count among them
