"""Ctrl-C / SIGTERM stop a live run within a second, with the recording flushed and closed."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_run_and_closes_the_recording(tmp_path, shared_bvh, sig):
    session = tmp_path / "live.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "live.app.cli", "run", "--source", f"sim:{shared_bvh / 'cc_002_01.bvh'}?loop=1",
         "--record", str(session), "--out", str(tmp_path / "out"), "--quiet"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Wait until frames are being recorded (the session file grows past its header).
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (not session.exists() or session.stat().st_size < 300_000):
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        t0 = time.monotonic()
        proc.send_signal(sig)
        proc.wait(timeout=10)
        assert time.monotonic() - t0 < 1.0 + 0.5  # 1 s budget, plus process exit
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, proc.stderr.read()
    with open(session, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None  # finished: footer and summary written
        assert sum(1 for _ in reader.iter_messages()) > 0
    assert (tmp_path / "out" / "stats.json").is_file()
