"""Recording survives what happens to it: a killed recorder loses at most a second of every
stream, a suit that goes away is reported (exit 1) and stored in the session as a gap, and a
recording never writes over its own input."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from live.app.cli import main
from live.app.running import refuse_overwriting_inputs, run_pipeline
from live.core.errors import SessionError, UserInputError
from live.core.frames import MocapPacket
from live.core.protocols import StreamInfo
from live.io.session import SessionReader, SessionWriter
from sim.imu_device import SimulatedSuit
from sim.imu_model import random_smooth_motion
from sim.replay import ReplaySource

REPO = Path(__file__).resolve().parents[1]


def _wait_for(condition, timeout_s: float = 20.0, what: str = "condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.02)  # polling a file another process writes; the condition is what syncs
    raise AssertionError(f"timed out waiting for {what}")


def _packets(path: Path) -> list[MocapPacket]:
    try:
        r = SessionReader(path)
        return [f for _, f in r.frames()]
    except (SessionError, UserInputError):  # no file, or not even its magic bytes yet
        return []


def test_a_live_writer_closes_chunks_on_a_timer(tmp_path):
    path = tmp_path / "s.mcap"
    w = SessionWriter(path, [StreamInfo("suit", "serial", {})], flush_interval_s=0.05)
    try:
        for i in range(3):
            w.write(MocapPacket(t_ns=i, device="suit", raw=b"line %d\n" % i))
        # Far below the chunk size: only the timer puts them in the file while it is open.
        got = _wait_for(lambda: len(_packets(path)) == 3, what="the open writer's frames in the file")
        assert got
        assert not SessionReader(path).finished
    finally:
        w.close()
    r = SessionReader(path)
    assert r.finished and [f.raw for _, f in r.frames()] == [b"line %d\n" % i for i in range(3)]


@pytest.mark.parametrize("protocol,rate_hz", [("lines", 10.0), ("xbus", 100.0)])
def test_kill_9_during_record_loses_at_most_a_second(tmp_path, protocol, rate_hz):
    out = tmp_path / "killed.mcap"
    motion = random_smooth_motion(240, fps=60.0, seed=3)
    with SimulatedSuit(motion, protocol=protocol, rate_hz=rate_hz, realtime=True, loop=True) as suit:
        proc = subprocess.Popen([sys.executable, "-m", "live.app.cli", "record", "--source",
                                 f"serial:{suit.port}:{protocol}", "--out", str(out), "--quiet"],
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            def a_second_recorded():
                assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
                p = _packets(out)
                return p and p[-1].t_ns - p[0].t_ns > 1e9

            # Wait until a second of data is in the file, then kill the recorder outright.
            _wait_for(a_second_recorded, what="a second recorded")
            killed_ns = time.monotonic_ns()
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
    r = SessionReader(out)
    packets = [f for _, f in r.frames()]
    assert not r.finished
    assert r.error is None or "truncated" in r.error
    lost_s = (killed_ns - packets[-1].t_ns) / 1e9
    assert lost_s <= 1.0, f"{lost_s:.2f} s lost"
    # The unfinished file opens, replays and exports.
    assert main(["info", str(out)]) in (0, 1)
    assert main(["export", str(out), "--out", str(tmp_path / "exp")]) in (0, 1)
    raw = np.load(tmp_path / "exp" / "serial_serial.npz")
    assert len(raw["t_ns"]) == len(packets)


def test_a_suit_gone_for_good_is_reported_and_stored_as_a_gap(tmp_path, capsys):
    out = tmp_path / "gone.mcap"
    motion = random_smooth_motion(240, fps=60.0, seed=4)
    with SimulatedSuit(motion, protocol="lines", rate_hz=50, realtime=True, loop=True) as suit:
        def unplug_after_some_data():
            _wait_for(lambda: suit.counters["records"] > 200, what="the suit streaming")
            suit.close()

        unplug = threading.Thread(target=unplug_after_some_data)
        unplug.start()
        rc = main(["record", "--source", f"serial:{suit.port}:lines", "--out", str(out), "--seconds", "3",
                   "--quiet"])
        unplug.join()
    err = capsys.readouterr().err
    assert rc == 1 and "never came back" in err and "disconnected" in err
    r = SessionReader(out)
    packets = [f for _, f in r.frames()]
    assert packets and r.error is None and r.finished
    log = r.info.recording
    assert log.end is not None and log.end["problems"]
    assert [g.until_t_ns for g in log.gaps] == [None] and log.gaps[0].seconds >= 1.0
    assert log.status["serial"]["connected"] is False
    assert main(["info", str(out)]) == 0
    assert "gap: serial: no data for" in capsys.readouterr().out


def _small_session(path: Path) -> Path:
    with SessionWriter(path, [StreamInfo("suit", "serial", {})], start_wall_time_ns=0) as w:
        for i in range(5):
            w.write(MocapPacket(t_ns=i * 10_000_000, device="suit", raw=b"x" * 10))
    return path


def test_a_recording_never_writes_over_its_input(tmp_path):
    session = _small_session(tmp_path / "in.mcap")
    before = session.read_bytes()
    with pytest.raises(UserInputError, match="input"):
        run_pipeline([ReplaySource(session)], [], [], mode="latest", record=session, progress=False)
    link = tmp_path / "link.mcap"
    link.symlink_to(session)
    hard = tmp_path / "hard.mcap"
    os.link(session, hard)
    for out in (session, link, hard, tmp_path / "." / "in.mcap"):
        with pytest.raises(UserInputError, match="input"):
            refuse_overwriting_inputs(out, [str(session)])
    assert main(["record", "--source", f"replay:{session}", "--out", str(session)]) == 2
    assert main(["run", "--source", f"replay:{session}", "--record", str(link), "--out",
                 str(tmp_path / "run")]) == 2
    assert session.read_bytes() == before
    refuse_overwriting_inputs(tmp_path / "other.mcap", [str(session)])  # any other file is fine
